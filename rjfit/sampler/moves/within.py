"""Within-region moves for every region, and their settings: which moves, in which order.

A region model's regions all get the same within-region moves: they see only the region's
observations (through its labels), statistics and parameters, never the layout. 'adaptive'
(the default) runs per region the gamma moves (:mod:`rjfit.sampler.moves.gamma`), the
(a, b) redraw (:mod:`rjfit.sampler.moves.ab_conditional`), the sigma^2 move
(:mod:`rjfit.sampler.moves.sigma2`) and, for small regions, the phi-space random walk
(:mod:`rjfit.sampler.moves.phi_walk`); 'paper' runs the paper's component-wise MH
(:mod:`rjfit.sampler.moves.paper_mh`). The gamma random walk's width is adapted during
burn-in only (:func:`adapt_log_g_scale`, called by the kernel).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rjfit.sampler.likelihood import STAT_N
from rjfit.sampler.moves.colour_within import update_materials_colour
from rjfit.sampler.moves.gamma import move_gamma_newton, move_gamma_rw
from rjfit.sampler.moves.paper_mh import update_region_paper
from rjfit.sampler.moves.phi_walk import move_phi_rw
from rjfit.sampler.moves.sigma2 import move_amplitudes_and_variance

__all__ = ["WithinSettings", "update_regions", "update_region_adaptive", "adapt_log_g_scale", "LOG_G_SCALE_BOUNDS"]

LOG_G_SCALE_BOUNDS = (np.log(0.2), np.log(50.0))


@dataclass(frozen=True)
class WithinSettings:
    """How the within-region moves run.

    Attributes
    ----------
    sampler : {'adaptive', 'paper'}
        'adaptive' (default): per region an exact conditional-Gaussian redraw of the linear
        parameters (a, b) = (I0 kd, I0 (1-kd) N(g)), a conditional inverse-gamma proposal
        for sigma^2 and moves of log gamma that redraw (a, b) from their conditional given
        the new gamma (this follows the kd-gamma correlation). 'paper': component-wise
        normal random-walk MH in natural space with the prior preset's widths (the paper's
        sampler).
    gamma_move : {'newton', 'rw'}
        The 'adaptive' sampler's gamma moves. 'rw': random walks on log gamma whose width
        is adapted during burn-in. 'newton' (default): every second move is instead a
        Newton move (normal with the mean and sd of a Newton step on the profile
        log-likelihood at the current gamma, sd times ``newton_scale``; a random walk where
        the profile is not concave). Near the mode it draws gamma and kd almost
        independently each time; the random walks carry chains in from far starts and
        tails, where the Newton proposal's reverse density is negligible.
    newton_scale : float
        Factor on the Newton proposal's sd.
    g_moves : int
        Gamma moves per region and iteration.
    target_accept : float
        Target acceptance rate of the gamma random walk during burn-in.
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
    """

    sampler: str = "adaptive"
    gamma_move: str = "newton"
    newton_scale: float = 1.0
    g_moves: int = 2
    target_accept: float = 0.44
    min_obs_conditional: int = 6
    fallback_step: float = 0.3
    small_region_obs: int = 200
    full_recompute: bool = False

    def __post_init__(self):
        if self.sampler not in ("adaptive", "paper"):
            raise ValueError(f"sampler must be 'adaptive' or 'paper', got {self.sampler!r}")
        if self.gamma_move not in ("newton", "rw"):
            raise ValueError(f"gamma_move must be 'newton' or 'rw', got {self.gamma_move!r}")
        if not (np.isfinite(self.newton_scale) and self.newton_scale > 0):
            raise ValueError(f"newton_scale must be a positive number, got {self.newton_scale}")


def update_regions(work, rng, prior, problem, settings: WithinSettings, g_step: float, info) -> list:
    """Run the within-region moves for every region in turn; returns the gamma random walks' acceptances.

    A joint colour fit (``problem.n_channels > 1``, 'adaptive' only) runs each material's
    rows together (:func:`~rjfit.sampler.moves.colour_within.update_materials_colour`).
    ``g_step`` is the current multiplier of the gamma random walk's width (the kernel adapts
    it during burn-in from the returned acceptances).
    """
    if problem.n_channels > 1:      # a joint colour fit: a material's rows share gamma
        return update_materials_colour(work, rng, prior, problem, settings, g_step, info)
    g_acc = []
    for r in range(work.theta.shape[0]):
        if settings.sampler == "adaptive":
            g_acc += update_region_adaptive(work, r, rng, prior, problem, settings, g_step, info)
        else:
            update_region_paper(work, r, rng, prior, problem, info, settings.full_recompute)
    return g_acc


def update_region_adaptive(work, r, rng, prior, problem, settings: WithinSettings, g_step, info):
    """The default within-region update of region ``r``; returns the gamma random walks' acceptances."""
    n = work.stats[r, STAT_N]
    g_acc = []
    if n < settings.min_obs_conditional:
        info.count("phi_rw", move_phi_rw(work, r, rng, prior, problem, settings.fallback_step, info), 4)
        return g_acc
    for k in range(settings.g_moves):
        # 'newton' alternates a random walk and a Newton move: the Newton proposal crosses
        # the posterior in one step near the mode, but from far away (a start, a tail) its
        # reverse density is negligible and it is rarely accepted; the random walk gets there.
        newton = settings.gamma_move == "newton" and k % 2 == 1
        if newton:
            result = move_gamma_newton(work, r, rng, prior, problem, settings.newton_scale, g_step / np.sqrt(n), info)
        else:
            result = move_gamma_rw(work, r, rng, prior, problem, g_step / np.sqrt(n), info)
        if result is None:
            info.count("phi_rw", move_phi_rw(work, r, rng, prior, problem, settings.fallback_step, info), 4)
            return g_acc
        if not newton:       # the adapted step is the random walk's
            g_acc.append(result)
        info.count("gamma_newton" if newton else "gamma_ab", result)
    move_amplitudes_and_variance(work, r, rng, prior, info)
    if n < settings.small_region_obs:
        # Small regions: the conditional proposals ignore the prior, which then matters;
        # a cheap phi-space random walk on top keeps them mixing (chosen by n only: valid).
        info.count("phi_rw", move_phi_rw(work, r, rng, prior, problem, settings.fallback_step, info), 4)
    return g_acc


def adapt_log_g_scale(log_g_scale: float, g_acc: list, iteration: int, target_accept: float) -> float:
    """One Robbins-Monro step of the gamma random walk's log width towards ``target_accept`` (burn-in only).

    Bounded: rejections caused by the (a, b) > 0 constraint (kd near 0 or 1) must not shrink
    the step to nothing and freeze gamma.
    """
    log_g_scale += (np.mean(g_acc) - target_accept) * 2.0 / (iteration + 1.0) ** 0.6
    return float(np.clip(log_g_scale, LOG_G_SCALE_BOUNDS[0], LOG_G_SCALE_BOUNDS[1]))
