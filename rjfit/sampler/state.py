"""Chain state, sampler configuration and per-step info (kept apart, BlackJAX style).

The state is a frozen dataclass whose arrays the kernel never writes to: a step builds new
arrays for what it changes. ``labels`` (region per observation), ``stats`` and ``log_lik``
are functions of the rest (change points, parameters) cached for speed;
:func:`rjfit.sampler.kernel.refresh` recomputes them from scratch.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["ChainState", "SamplerConfig", "StepInfo"]


@dataclass(frozen=True, eq=False)
class ChainState:
    """One state of a chain.

    Attributes
    ----------
    u : ndarray (H, n_u)
        u change points, each row sorted (vector k = k-th order statistic of every row).
    v : ndarray (W, n_v)
        v change points, each column's elements sorted.
    theta : ndarray (R, 4)
        Region parameters ``(I0, kd, gamma, sigma2)``, region ``iu * (n_v + 1) + iv``.
    stats : ndarray (R, 7)
        Sufficient statistics of each region (see :mod:`rjfit.sampler.likelihood`).
    log_lik : ndarray (R,)
        Log-likelihood of each region.
    labels : ndarray (N,)
        Region of each observation.
    log_g_scale : float
        Log of the global multiplier of the gamma random-walk width (adapted in burn-in only).
    iteration : int
        Number of completed steps.
    """

    u: np.ndarray
    v: np.ndarray
    theta: np.ndarray
    stats: np.ndarray
    log_lik: np.ndarray
    labels: np.ndarray
    log_g_scale: float = 0.0
    iteration: int = 0

    @property
    def n_u(self) -> int:
        return int(self.u.shape[1])

    @property
    def n_v(self) -> int:
        return int(self.v.shape[1])

    @property
    def n_regions(self) -> int:
        return int(self.theta.shape[0])

    @property
    def total_log_lik(self) -> float:
        return float(np.sum(self.log_lik))


@dataclass(frozen=True)
class SamplerConfig:
    """How the kernel moves.

    Attributes
    ----------
    max_u, max_v : int
        Maximum numbers of u and v change-point vectors (the model space).
    sampler : {'adaptive', 'paper'}
        Within-model moves. 'adaptive' (default): per region an exact conditional-Gaussian
        redraw of the linear parameters (a, b) = (I0 kd, I0 (1-kd) N(g)), a conditional
        inverse-gamma proposal for sigma^2 and a random walk on log gamma that redraws
        (a, b) from their conditional given the new gamma (this follows the kd-gamma
        correlation); the random-walk width is adapted during burn-in only. 'paper':
        component-wise normal random-walk MH in natural space with the prior preset's
        widths (the paper's sampler).
    split_map : {'conditional', 'mean', 'paper'}
        Parameters of the regions a birth (death) creates. 'conditional' (default): each new
        region's parameters are drawn afresh from a proposal built from its own data (a
        deterministic Laplace fit of log gamma's profile, then sigma^2 and (a, b) from their
        conditionals), and the reverse move evaluates the same kind of proposal for the
        removed regions; old and new parameters swap places, so the Jacobian is 1.
        The bijective maps work in phi space: 'mean' is
        ``phi_a = phi - w, phi_b = phi + w`` (|det| = 2 per component); 'paper' is a
        stand-in for the paper's eq. 10 with |det| = 3 per component:
        ``phi_a = phi - w, phi_b = phi + 2 w``.
    drop_jacobian : bool
        Leave the split Jacobian out of the acceptance ratio as the paper did (wrong; for
        the negative-control test only).
    split_scale : float
        Standard deviation of the split's auxiliary variables w (phi space; bijective maps).
    birth_straight_prob, birth_straight_sd : float
        The new vector's elements are, with this probability, a near-straight line
        (one uniform position plus normal jitter of this sd, pixels), otherwise uniform in
        each row's gap; the proposal density is the mixture's.
    birth_gamma_inflation : float
        Widening of the Laplace sd of log gamma in conditional birth proposals.
    update_changepoints, jumps : bool
        Whether change-point elements move and whether births/deaths are tried
        (both False: the segmentation is fixed).
    jump_prob : float
        Probability per iteration of one birth/death attempt.
    cp_step : float
        Random-walk width (pixels) of a change-point element move.
    cp_prior : {'smooth', 'paper'}
        Prior of change-point elements (see :mod:`rjfit.sampler.changepoints`): 'paper'
        iid uniform; 'smooth' (default) a random walk along the vector with step sd
        ``cp_smooth_sd`` pixels.
    cp_uniform_prob : float
        Probability that an element move redraws uniformly over [-1, size + 1] instead.
    cp_neighbour_prob, cp_neighbour_sd : float
        Probability that an element move proposes a normal (width ``cp_neighbour_sd``
        pixels) around the same-rank element of a neighbouring row (column): lets an element
        that strayed snap back to the boundary its neighbours found.
    gamma_move : {'newton', 'rw'}
        The 'adaptive' sampler's gamma moves. 'rw': random walks on log gamma whose width
        is adapted during burn-in. 'newton' (default): every second move is instead a
        Newton move: normal with the mean and sd of a Newton step on the profile
        log-likelihood at the current gamma (sd times ``newton_scale``; the reverse density
        is the same rule at the proposed gamma; a random walk where the profile is not
        concave). Near the mode it draws gamma and kd almost independently each time; the
        random walks carry chains in from far starts and tails, where the Newton
        proposal's reverse density is negligible.
    newton_scale : float
        Factor on the Newton proposal's sd.
    g_moves : int
        Gamma moves per region and iteration.
    burn_in : int
        Iterations during which the gamma step adapts (0: no adaptation).
    target_accept : float
        Target acceptance rate of the gamma random walk.
    min_obs_conditional : int
        Regions with fewer observations use a phi-space random walk instead of the
        conditional moves (which need a well-posed least-squares problem).
    fallback_step : float
        Width of that phi-space random walk.
    small_region_obs : int
        Regions with fewer observations also get that random walk after the conditional
        moves (their posterior is prior-influenced, which those proposals ignore).
    full_recompute : bool
        'paper' sampler only: evaluate every proposal with a full pass over all observations
        (as the paper's implementation did) instead of the sufficient statistics; for the
        benchmark's like-for-like baseline.
    block_prob, block_max, block_shift_sd : float, int, float
        Probability per iteration of a block shift (a run of up to ``block_max`` elements of
        one vector moved by a common N(0, block_shift_sd^2) pixels, with the changed regions'
        parameters redrawn; see :func:`rjfit.sampler.moves.propose_block_shift`).
    anneal : int
        Iterations of tempered warm-up at the start of the burn-in (0: none): the
        likelihood power is multiplied by ``anneal_start ** (1 - t / anneal)`` at iteration
        t (:func:`rjfit.sampler.kernel.anneal_power`). Must not exceed ``burn_in``.
    anneal_start : float
        Factor on the likelihood power at the first iteration of the warm-up.
    free_jump_prob : float
        Probability that a birth/death attempt uses the pair whose vector may take any rank
        in each line (:func:`rjfit.sampler.moves.propose_birth_free`,
        :func:`~rjfit.sampler.moves.propose_death_free`) instead of the rank-keeping pair.
    vector_prob : float
        Probability per iteration of redrawing one whole change-point vector from an
        approximation of its conditional (forward filtering, backward sampling along the
        lines; :func:`rjfit.sampler.moves.propose_vector_redraw`).
    refresh_every : int
        Recompute the cached statistics from scratch every so many iterations (bounds
        floating-point drift of the incremental updates).
    """

    max_u: int = 3
    max_v: int = 3
    sampler: str = "adaptive"
    split_map: str = "conditional"
    drop_jacobian: bool = False
    split_scale: float = 0.1
    birth_straight_prob: float = 0.5
    birth_straight_sd: float = 1.0
    birth_gamma_inflation: float = 1.5
    update_changepoints: bool = True
    jumps: bool = True
    jump_prob: float = 0.2
    cp_step: float = 2.0
    cp_prior: str = "smooth"
    cp_smooth_sd: float = 2.0
    cp_uniform_prob: float = 0.05
    cp_neighbour_prob: float = 0.3
    cp_neighbour_sd: float = 0.5
    gamma_move: str = "newton"
    newton_scale: float = 1.0
    g_moves: int = 2
    burn_in: int = 0
    target_accept: float = 0.44
    min_obs_conditional: int = 6
    fallback_step: float = 0.3
    small_region_obs: int = 200
    refresh_every: int = 200
    block_prob: float = 0.05
    block_max: int = 128
    block_shift_sd: float = 20.0
    full_recompute: bool = False
    vector_prob: float = 0.3
    free_jump_prob: float = 0.5
    anneal: int = 0
    anneal_start: float = 1e-3

    def __post_init__(self):
        if self.sampler not in ("adaptive", "paper"):
            raise ValueError(f"sampler must be 'adaptive' or 'paper', got {self.sampler!r}")
        if self.gamma_move not in ("newton", "rw"):
            raise ValueError(f"gamma_move must be 'newton' or 'rw', got {self.gamma_move!r}")
        if not (np.isfinite(self.newton_scale) and self.newton_scale > 0):
            raise ValueError(f"newton_scale must be a positive number, got {self.newton_scale}")
        if self.cp_prior not in ("smooth", "paper"):
            raise ValueError(f"cp_prior must be 'smooth' or 'paper', got {self.cp_prior!r}")
        if self.split_map not in ("conditional", "mean", "paper"):
            raise ValueError(f"split_map must be 'conditional', 'mean' or 'paper', got {self.split_map!r}")
        if self.max_u < 0 or self.max_v < 0:
            raise ValueError(f"max_u and max_v must be >= 0, got {self.max_u}, {self.max_v}")
        if self.anneal < 0 or self.anneal > max(self.burn_in, 0):
            raise ValueError(f"anneal ({self.anneal}) must lie in [0, burn_in = {self.burn_in}]: "
                             "only burn-in iterations may be tempered")
        if not 0.0 < self.anneal_start <= 1.0:
            raise ValueError(f"anneal_start must lie in (0, 1], got {self.anneal_start}")
        if not 0.0 <= self.free_jump_prob <= 1.0:
            raise ValueError(f"free_jump_prob must lie in [0, 1], got {self.free_jump_prob}")
        if not 0.0 <= self.vector_prob <= 1.0:
            raise ValueError(f"vector_prob must lie in [0, 1], got {self.vector_prob}")
        if not 0.0 <= self.jump_prob <= 1.0:
            raise ValueError(f"jump_prob must lie in [0, 1], got {self.jump_prob}")
        if self.split_scale <= 0 or self.cp_step <= 0 or self.cp_neighbour_sd <= 0:
            raise ValueError("split_scale, cp_step and cp_neighbour_sd must be positive")
        if self.cp_uniform_prob < 0 or self.cp_neighbour_prob < 0 or self.cp_uniform_prob + self.cp_neighbour_prob > 1:
            raise ValueError("cp_uniform_prob and cp_neighbour_prob must be >= 0 and sum to at most 1")


@dataclass
class StepInfo:
    """What happened in one step (acceptance counts per move kind); not part of the state."""

    accepted: dict = field(default_factory=dict)
    proposed: dict = field(default_factory=dict)
    jump: str = ""

    def count(self, kind: str, accepted, proposed=1):
        n_accepted = int(accepted) if isinstance(accepted, (bool, int, np.bool_)) else int(np.sum(accepted))
        self.accepted[kind] = self.accepted.get(kind, 0) + n_accepted
        self.proposed[kind] = self.proposed.get(kind, 0) + int(proposed)
