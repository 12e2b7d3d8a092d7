"""Birth and death of a change-point vector that keep ranks: split and merge the regions it cuts.

A birth inserts a new vector at rank ``j`` (uniform over the n + 1 gaps) whose elements lie
in the gaps of their lines (:func:`draw_vector`, density :func:`vector_log_q`), so every
region of grid column ``j`` splits in two; its death (the reverse) removes one of the
n + 1 vectors and merges the two columns it separated. The parameters of the regions made
are proposed by the ``split_map``: 'conditional' (default) draws every new region afresh
from its own data and evaluates the same proposal for the removed ones
(:mod:`rjfit.sampler.moves.region_proposals`; Jacobian 1); 'mean' and 'paper' are bijective
maps in phi space with auxiliary variables w and their Jacobians (:func:`split_phi`,
:func:`merge_phi`). The acceptance ratio is complete: posterior ratio, change-point prior,
birth/death probabilities, proposal densities and Jacobian.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import log_ndtr

from rjfit.sampler.likelihood import LOG_2PI, log_likelihood_from_stats, region_stats
from rjfit.sampler.moves.proposal import Proposal
from rjfit.sampler.moves.region_proposals import regions_term
from rjfit.sampler.priors import from_phi, to_phi

__all__ = ["BirthDeathSettings", "split_phi", "merge_phi", "birth_probability", "gaps", "vector_log_q", "draw_vector",
           "propose_birth", "propose_death"]


@dataclass(frozen=True)
class BirthDeathSettings:
    """How births and deaths of change-point vectors are tried and proposed.

    Attributes
    ----------
    prob : float
        Probability per iteration of one birth/death attempt (flat option ``jump_prob``).
    free_prob : float
        Probability that an attempt uses the pair whose vector may take any rank in each
        line (:mod:`rjfit.sampler.regions.changepoints.birth_death_free`) instead of the rank-keeping pair
        (``free_jump_prob``).
    split_map : {'conditional', 'mean', 'paper'}
        Parameters of the regions a birth (death) creates. 'conditional' (default): each new
        region's parameters are drawn afresh from a proposal built from its own data (a
        deterministic Laplace fit of log gamma's profile, then sigma^2 and (a, b) from their
        conditionals), and the reverse move evaluates the same kind of proposal for the
        removed regions; old and new parameters swap places, so the Jacobian is 1.
        The bijective maps work in phi space: 'mean' is ``phi_a = phi - w, phi_b = phi + w``
        (|det| = 2 per component); 'paper' is a stand-in for the paper's eq. 10 with
        |det| = 3 per component: ``phi_a = phi - w, phi_b = phi + 2 w``.
    drop_jacobian : bool
        Leave the split Jacobian out of the acceptance ratio as the paper did (wrong; for
        the negative-control test only).
    split_scale : float
        Standard deviation of the split's auxiliary variables w (phi space; bijective maps).
    straight_prob, straight_sd : float
        The new vector's elements are, with this probability, a near-straight line (one
        uniform position plus normal jitter of this sd, pixels), otherwise drawn from the
        change-point prior's shape; the proposal density is the mixture's
        (``birth_straight_prob``, ``birth_straight_sd``).
    """

    prob: float = 0.2
    free_prob: float = 0.5
    split_map: str = "conditional"
    drop_jacobian: bool = False
    split_scale: float = 0.1
    straight_prob: float = 0.5
    straight_sd: float = 1.0

    def __post_init__(self):
        if self.split_map not in ("conditional", "mean", "paper"):
            raise ValueError(f"split_map must be 'conditional', 'mean' or 'paper', got {self.split_map!r}")
        if not 0.0 <= self.free_prob <= 1.0:
            raise ValueError(f"free_jump_prob must lie in [0, 1], got {self.free_prob}")
        if not 0.0 <= self.prob <= 1.0:
            raise ValueError(f"jump_prob must lie in [0, 1], got {self.prob}")
        if self.split_scale <= 0:
            raise ValueError(f"split_scale must be positive, got {self.split_scale}")


def split_phi(phi, w, split_map: str):
    """Split a region's phi (.., 4) with auxiliary w into (phi_a, phi_b); returns also log|det J|.

    'mean': phi_a = phi - w, phi_b = phi + w, |det| = 2 per component.
    'paper': phi_a = phi - w, phi_b = phi + 2 w, |det| = 3 per component (the size of the
    determinant the design notes give for the paper's eq. 10).
    """
    n_components = np.size(phi)
    if split_map == "mean":
        return phi - w, phi + w, n_components * np.log(2.0)
    return phi - w, phi + 2.0 * w, n_components * np.log(3.0)


def merge_phi(phi_a, phi_b, split_map: str):
    """Inverse of :func:`split_phi`: (phi, w, log|det J| of the split)."""
    n_components = np.size(phi_a)
    if split_map == "mean":
        return 0.5 * (phi_a + phi_b), 0.5 * (phi_b - phi_a), n_components * np.log(2.0)
    w = (phi_b - phi_a) / 3.0
    return phi_a + w, w, n_components * np.log(3.0)


def birth_probability(n: int, n_max: int) -> float:
    """Probability that an attempt with n of at most n_max vectors is a birth."""
    if n_max == 0:
        return 0.0
    return 1.0 if n == 0 else (0.0 if n >= n_max else 0.5)


def gaps(cps, j, size):
    """Lower and upper ends of the gap before element j of each line (the image edges beyond the last)."""
    lower = cps[:, j - 1] if j > 0 else np.full(cps.shape[0], -1.0)
    upper = cps[:, j] if j < cps.shape[1] else np.full(cps.shape[0], size + 1.0)
    return lower, upper


def _log_normal(w, scale):
    return float(np.sum(-0.5 * (w / scale) ** 2 - np.log(scale) - 0.5 * LOG_2PI))


def vector_log_q(x, lower, upper, size, settings: BirthDeathSettings, cp_prior) -> float:
    """Log density of proposing the elements ``x`` of a new vector inside the gaps (lower, upper).

    Mixture: with probability ``straight_prob`` a near-straight vector (``x0 ~ U(-1,
    size+1)``, ``x_r = x0 + tau z_r``; the density integrates x0 out in closed form),
    otherwise a draw from the change-point prior's own shape: for the 'smooth' prior its
    random walk, for the 'paper' prior each element uniform in its gap. Elements outside
    their gap: -inf (the proposal is rejected).
    """
    if not np.all((x > lower) & (x < upper)):
        return -np.inf
    if cp_prior.kind == "smooth":
        # the prior's own random walk (x0 uniform, steps N(0, s^2)) replaces the uniform component
        sd = cp_prior.smooth_sd
        log_unif = float(-math.log(size + 2.0) + np.sum(-0.5 * (np.diff(x) / sd) ** 2 - math.log(sd) - 0.5 * LOG_2PI))
    else:
        log_unif = -float(np.sum(np.log(upper - lower)))
    p_s = settings.straight_prob
    if p_s <= 0:
        return log_unif
    tau, H = settings.straight_sd, x.size
    xbar = float(np.mean(x))
    hi, lo = (size + 1.0 - xbar) * math.sqrt(H) / tau, (-1.0 - xbar) * math.sqrt(H) / tau
    log_mass = log_ndtr(hi) + math.log1p(-math.exp(min(0.0, log_ndtr(lo) - log_ndtr(hi))))
    log_s = (-0.5 * (H - 1) * math.log(2 * math.pi * tau * tau) - 0.5 * math.log(H)
             - float(np.sum((x - xbar) ** 2)) / (2 * tau * tau) + log_mass - math.log(size + 2.0))
    if p_s >= 1:
        return log_s
    return float(np.logaddexp(math.log(p_s) + log_s, math.log1p(-p_s) + log_unif))


def draw_vector(rng, lower, upper, size, settings: BirthDeathSettings, cp_prior):
    """The elements of a new vector, one per line, from the mixture of :func:`vector_log_q`."""
    if rng.random() < settings.straight_prob:
        x0 = rng.uniform(-1.0, size + 1.0)
        return x0 + settings.straight_sd * rng.normal(size=lower.size)
    if cp_prior.kind == "smooth":
        x0 = rng.uniform(-1.0, size + 1.0)
        steps = cp_prior.smooth_sd * rng.normal(size=lower.size - 1)
        return x0 + np.concatenate([[0.0], np.cumsum(steps)])
    return lower + (upper - lower) * rng.random(lower.size)


def _grid(theta, n_u, n_v, axis):
    grid = theta.reshape(n_u + 1, n_v + 1, -1)
    return grid.transpose(1, 0, 2) if axis == "v" else grid


def _ungrid(grid, axis):
    grid = grid.transpose(1, 0, 2) if axis == "v" else grid
    return grid.reshape(-1, grid.shape[-1])


def _region_ids(n_u, n_v, axis, columns):
    """Region indices of grid columns ``columns`` (along ``axis``) in model (n_u, n_v)."""
    ids = np.arange((n_u + 1) * (n_v + 1)).reshape(n_u + 1, n_v + 1)
    ids = ids.T if axis == "v" else ids
    return np.concatenate([ids[c] for c in columns])


def _jump_ratio(problem, settings, cp_prior, small, big, x, gaps_bounds, size, n, n_max, theta_term):
    """Log acceptance ratio of the birth small -> big (the vector x inserted)."""
    lower, upper = gaps_bounds
    log_q_vec = vector_log_q(x, lower, upper, size, settings, cp_prior)
    (small_layout, ll_s), (big_layout, ll_b) = small, big
    return (ll_b - ll_s
            + cp_prior.log_density(big_layout.u, big_layout.v, problem.image_shape)
            - cp_prior.log_density(small_layout.u, small_layout.v, problem.image_shape)
            + math.log(1.0 - birth_probability(n + 1, n_max)) - math.log(birth_probability(n, n_max))
            - log_q_vec + theta_term)


def _bijective_term(prior, theta_big, theta_small, w, log_jac, settings):
    """The parameter term of a birth small -> big by a bijective split map: prior ratio, w's density, Jacobian."""
    return (float(np.sum(prior.logpdf_phi(to_phi(theta_big))) - np.sum(prior.logpdf_phi(to_phi(theta_small))))
            - _log_normal(w, settings.split_scale) + (0.0 if settings.drop_jacobian else log_jac))


def propose_birth(work, rng, problem, prior, settings: BirthDeathSettings, proposals, cp_prior, n_max: int,
                  axis: str) -> Proposal:
    """Birth of a u (v) vector, splitting every region it cuts.

    The rank ``j`` of the new vector is uniform over the n + 1 gaps and the death picks one
    of the n + 1 vectors, so these choices cancel. ``proposals`` are the region proposals'
    settings, ``cp_prior`` the change-point prior, ``n_max`` the axis's maximum of vectors.
    """
    layout = work.layout
    cps = layout.u if axis == "u" else layout.v
    size = problem.width if axis == "u" else problem.height
    n, (n_u, n_v) = cps.shape[1], layout.model_key
    j = int(rng.integers(n + 1))
    lower, upper = gaps(cps, j, size)
    x = draw_vector(rng, lower, upper, size, settings, cp_prior)
    new_layout = layout.with_axis(axis, np.insert(cps, j, x, axis=1))
    grid = _grid(work.theta, n_u, n_v, axis)
    if settings.split_map == "conditional":
        theta_new = _ungrid(np.concatenate([grid[:j], grid[j:j + 1], grid[j:]], axis=0), axis)
    else:
        w = rng.normal(0.0, settings.split_scale, grid[j].shape)
        phi_a, phi_b, log_jac = split_phi(to_phi(grid[j]), w, settings.split_map)
        theta_new = _ungrid(np.concatenate([grid[:j], from_phi(phi_a)[None], from_phi(phi_b)[None], grid[j + 1:]],
                                           axis=0), axis)
    labels = new_layout.labels(problem)
    if not np.isfinite(vector_log_q(x, lower, upper, size, settings, cp_prior)):
        return Proposal.invalid(new_layout, labels)
    if settings.split_map == "conditional":
        old_ids = _region_ids(n_u, n_v, axis, [j])
        new_ids = _region_ids(*new_layout.model_key, axis, [j, j + 1])
        theta_new, term_new = regions_term(problem, prior, proposals, labels, theta_new, new_ids, draw_rng=rng)
        if theta_new is None:
            return Proposal.invalid(new_layout, labels)
        _, term_old = regions_term(problem, prior, proposals, work.labels, work.theta, old_ids)
        theta_term = term_new - term_old
    else:
        theta_term = _bijective_term(prior, theta_new, work.theta, w, log_jac, settings)
    stats = region_stats(problem, labels, theta_new[:, 2], theta_new.shape[0])
    log_lik = log_likelihood_from_stats(stats, theta_new)
    log_ratio = _jump_ratio(problem, settings, cp_prior, (layout, float(np.sum(work.log_lik))),
                            (new_layout, float(np.sum(log_lik))), x, (lower, upper), size, n, n_max, theta_term)
    return Proposal(new_layout, theta_new, labels, stats, log_lik, float(log_ratio))


def propose_death(work, rng, problem, prior, settings: BirthDeathSettings, proposals, cp_prior, n_max: int,
                  axis: str) -> Proposal:
    """Death of a u (v) vector, merging the regions on its two sides (the reverse of :func:`propose_birth`)."""
    layout = work.layout
    cps = layout.u if axis == "u" else layout.v
    size = problem.width if axis == "u" else problem.height
    n, (n_u, n_v) = cps.shape[1], layout.model_key
    k = int(rng.integers(n))
    x = cps[:, k]
    new_cps = np.delete(cps, k, axis=1)
    lower, upper = gaps(new_cps, k, size)     # the gap the reverse birth draws in
    new_layout = layout.with_axis(axis, new_cps)
    grid = _grid(work.theta, n_u, n_v, axis)
    labels = new_layout.labels(problem)
    if settings.split_map == "conditional":
        theta_new = _ungrid(np.concatenate([grid[:k + 1], grid[k + 2:]], axis=0), axis)
        new_ids = _region_ids(*new_layout.model_key, axis, [k])
        old_ids = _region_ids(n_u, n_v, axis, [k, k + 1])
        theta_new, term_new = regions_term(problem, prior, proposals, labels, theta_new, new_ids, draw_rng=rng)
        if theta_new is None:
            return Proposal.invalid(new_layout, labels)
        _, term_old = regions_term(problem, prior, proposals, work.labels, work.theta, old_ids)
        theta_term = term_old - term_new          # as seen by the reverse birth
    else:
        phi, w, log_jac = merge_phi(to_phi(grid[k]), to_phi(grid[k + 1]), settings.split_map)
        theta_new = _ungrid(np.concatenate([grid[:k], from_phi(phi)[None], grid[k + 2:]], axis=0), axis)
        theta_term = _bijective_term(prior, work.theta, theta_new, w, log_jac, settings)
    stats = region_stats(problem, labels, theta_new[:, 2], theta_new.shape[0])
    log_lik = log_likelihood_from_stats(stats, theta_new)
    birth_ratio = _jump_ratio(problem, settings, cp_prior, (new_layout, float(np.sum(log_lik))),
                              (layout, float(np.sum(work.log_lik))), x, (lower, upper), size, n - 1, n_max,
                              theta_term)
    return Proposal(new_layout, theta_new, labels, stats, log_lik, float(-birth_ratio))
