"""Within-region moves for every region, and their settings: which moves, in which order.

A region model's regions all get the same within-region moves: they see only the region's
observations (through its labels), statistics and parameters, never the layout. 'adaptive'
(the default) runs per region the gamma moves (:mod:`rjfit.sampler.moves.gamma`), the
(a, b) redraw (:mod:`rjfit.sampler.moves.ab_conditional`), the sigma^2 move
(:mod:`rjfit.sampler.moves.sigma2`) and, for small regions, the phi-space random walk
(:mod:`rjfit.sampler.moves.phi_walk`); 'paper' runs the paper's component-wise MH
(:mod:`rjfit.sampler.moves.paper_mh`). The gamma random walk's width is adapted during
burn-in only (:func:`adapt_log_g_scale`, called by the kernel).

Each move family is an object holding its settings (:class:`GammaMove`, :class:`PhiWalk`,
:class:`AmplitudesAndVariance`, :class:`PaperMH`) whose ``run`` moves one parameter row and
counts its tests under the family's ``kind``; :func:`within_moves` builds from
:class:`WithinSettings` the one object (:class:`AdaptiveWithin`, :class:`PaperWithin`,
:class:`ColourWithin`) whose ``run`` is one iteration's within-region moves, in a fixed
order. None changes the model's dimension. Each row move still draws its uniform where it
always has (some before they know whether the proposal is valid) and decides with the one
:func:`~rjfit.sampler.moves.accept.accept`, so it is not yet a
:class:`~rjfit.sampler.moves.proposal.Proposal` tested by :func:`~rjfit.sampler.moves.base.decide`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from rjfit.sampler.likelihood import STAT_N
from rjfit.sampler.moves.colour_within import update_materials_colour
from rjfit.sampler.moves.edge_walk import move_ab_walk, move_ridge_walk
from rjfit.sampler.moves.gamma import move_gamma_newton, move_gamma_rw
from rjfit.sampler.moves.paper_mh import update_region_paper
from rjfit.sampler.moves.phi_walk import move_phi_rw
from rjfit.sampler.moves.sigma2 import move_amplitudes_and_variance

__all__ = ["WithinSettings", "within_moves", "AdaptiveWithin", "PaperWithin", "ColourWithin", "GammaMove", "PhiWalk",
           "AmplitudesAndVariance", "PaperMH", "adapt_log_g_scale", "LOG_G_SCALE_BOUNDS"]

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


class PhiWalk(NamedTuple):
    """The phi-space random walk of one row (:func:`~rjfit.sampler.moves.phi_walk.move_phi_rw`): four component
    steps of sd ``step``, counted as four tests of kind 'phi_rw'."""

    step: float
    kind: str = "phi_rw"

    def run(self, work, r, rng, problem, prior, info) -> None:
        """Run it on row ``r`` of ``work`` (in place)."""
        info.count(self.kind, move_phi_rw(work, r, rng, prior, problem, self.step, info), 4)


class GammaMove(NamedTuple):
    """One gamma move of a row with (a, b) redrawn given the new gamma: a random walk on log gamma
    (:func:`~rjfit.sampler.moves.gamma.move_gamma_rw`, kind 'gamma_ab') or, with ``newton``, a Newton proposal
    whose sd is times ``scale`` (:func:`~rjfit.sampler.moves.gamma.move_gamma_newton`, kind 'gamma_newton')."""

    newton: bool
    scale: float

    @property
    def kind(self) -> str:
        """The move's name in the step's acceptance counts."""
        return "gamma_newton" if self.newton else "gamma_ab"

    def run(self, work, r, rng, problem, prior, info, rw_sd: float):
        """Run it on row ``r`` (random walk sd ``rw_sd``); whether it accepted (counted), or None where (a, b)
        have no conditional (nothing counted)."""
        if self.newton:
            result = move_gamma_newton(work, r, rng, prior, problem, self.scale, rw_sd, info)
        else:
            result = move_gamma_rw(work, r, rng, prior, problem, rw_sd, info)
        if result is not None:
            info.count(self.kind, result)
        return result


class EdgeWalks(NamedTuple):
    """Where the target has an edge term: per row, a ridge walk (:func:`~rjfit.sampler.moves.edge_walk.move_ridge_walk`)
    at each of ``ridge_steps`` times the gamma random walk's sd, and an (a, b) walk
    (:func:`~rjfit.sampler.moves.edge_walk.move_ab_walk`) at each of ``ab_scales``. The term sharpens a material's
    posterior by a factor the data set decides, so the steps form a ladder rather than one adapted width (each
    rung is a valid move of its own)."""

    ridge_steps: tuple = (10.0, 3.0, 1.0)
    ab_scales: tuple = (0.3, 0.1, 0.03)

    def run(self, work, r, rng, problem, prior, info, rw_sd: float) -> None:
        """Run them on row ``r`` of ``work`` (in place) when it has an edge term; nothing otherwise."""
        if work.edges is None:
            return
        for factor in self.ridge_steps:
            result = move_ridge_walk(work, r, rng, prior, problem, factor * rw_sd, info)
            if result is not None:
                info.count("ridge_walk", result)
        for scale in self.ab_scales:
            result = move_ab_walk(work, r, rng, prior, scale, info)
            if result is not None:
                info.count("ab_walk", result)


class AmplitudesAndVariance(NamedTuple):
    """Row ``r``'s (a, b) redraw and then its sigma^2 move, given gamma
    (:func:`~rjfit.sampler.moves.sigma2.move_amplitudes_and_variance`; kinds 'ab' and 'sigma2')."""

    def run(self, work, r, rng, problem, prior, info) -> None:
        """Run both on row ``r`` of ``work`` (in place)."""
        move_amplitudes_and_variance(work, r, rng, prior, info)


class PaperMH(NamedTuple):
    """The paper's component-wise random-walk MH of a row (:func:`~rjfit.sampler.moves.paper_mh.update_region_paper`,
    kinds 'rw_0' .. 'rw_3'); ``full_recompute``: each proposal evaluated by a pass over all observations."""

    full_recompute: bool = False

    def run(self, work, r, rng, problem, prior, info) -> None:
        """Run it on row ``r`` of ``work`` (in place)."""
        update_region_paper(work, r, rng, prior, problem, info, self.full_recompute)


class PaperWithin(NamedTuple):
    """The 'paper' sampler's within-region moves: :class:`PaperMH` on every region in turn."""

    move: PaperMH

    def run(self, work, rng, problem, prior, info, g_step: float) -> list:
        """One iteration's moves on ``work`` (in place); no gamma random walk to adapt (an empty list)."""
        for r in range(work.theta.shape[0]):
            self.move.run(work, r, rng, problem, prior, info)
        return []


class AdaptiveWithin(NamedTuple):
    """The 'adaptive' sampler's within-region moves of one region, in order: ``gamma`` (one :class:`GammaMove`
    per gamma move), then ``amplitudes``, then ``edge_walks`` (where the target has an edge term);
    :class:`PhiWalk` instead for a region of fewer than ``min_obs_conditional`` observations or where (a, b) have
    no conditional, and after the rest for one of fewer than ``small_region_obs``."""

    gamma: tuple
    amplitudes: AmplitudesAndVariance
    phi_walk: PhiWalk
    min_obs_conditional: int
    small_region_obs: int
    edge_walks: EdgeWalks = EdgeWalks()

    def run(self, work, rng, problem, prior, info, g_step: float) -> list:
        """One iteration's moves of every region in turn (in place); returns the gamma random walks' acceptances.

        ``g_step`` is the current multiplier of the gamma random walk's width (the kernel adapts it during
        burn-in from the returned acceptances).
        """
        g_acc = []
        for r in range(work.theta.shape[0]):
            g_acc += self.run_region(work, r, rng, problem, prior, info, g_step)
        return g_acc

    def run_region(self, work, r, rng, problem, prior, info, g_step: float) -> list:
        """The moves of region ``r``; returns its gamma random walks' acceptances."""
        n = work.stats[r, STAT_N]
        g_acc = []
        if n < self.min_obs_conditional:
            self.phi_walk.run(work, r, rng, problem, prior, info)
            return g_acc
        for move in self.gamma:
            result = move.run(work, r, rng, problem, prior, info, g_step / np.sqrt(n))
            if result is None:
                self.phi_walk.run(work, r, rng, problem, prior, info)
                return g_acc
            if not move.newton:       # the adapted step is the random walk's
                g_acc.append(result)
        self.amplitudes.run(work, r, rng, problem, prior, info)
        self.edge_walks.run(work, r, rng, problem, prior, info, g_step / np.sqrt(n))
        if n < self.small_region_obs:
            # Small regions: the conditional proposals ignore the prior, which then matters;
            # a cheap phi-space random walk on top keeps them mixing (chosen by n only: valid).
            self.phi_walk.run(work, r, rng, problem, prior, info)
        return g_acc


class ColourWithin(NamedTuple):
    """A joint colour fit's within-material moves (:func:`~rjfit.sampler.moves.colour_within.update_materials_colour`:
    a material's rows share gamma), with their ``settings``."""

    settings: WithinSettings

    def run(self, work, rng, problem, prior, info, g_step: float) -> list:
        """One iteration's moves of every material (in place); returns the gamma random walks' acceptances."""
        return update_materials_colour(work, rng, prior, problem, self.settings, g_step, info)


def within_moves(settings: WithinSettings, n_channels: int = 1):
    """The within-region moves that ``settings`` name, as one object whose ``run`` is one iteration's.

    A joint colour fit (``n_channels > 1``) runs each material's rows together (:class:`ColourWithin`, whatever
    the sampler); otherwise 'adaptive' gives :class:`AdaptiveWithin` and 'paper' :class:`PaperWithin`.
    """
    if n_channels > 1:      # a joint colour fit: a material's rows share gamma
        return ColourWithin(settings)
    if settings.sampler == "paper":
        return PaperWithin(PaperMH(settings.full_recompute))
    # 'newton' alternates a random walk and a Newton move: the Newton proposal crosses
    # the posterior in one step near the mode, but from far away (a start, a tail) its
    # reverse density is negligible and it is rarely accepted; the random walk gets there.
    gamma = tuple(GammaMove(settings.gamma_move == "newton" and k % 2 == 1, settings.newton_scale)
                  for k in range(settings.g_moves))
    return AdaptiveWithin(gamma, AmplitudesAndVariance(), PhiWalk(settings.fallback_step),
                          settings.min_obs_conditional, settings.small_region_obs)


def adapt_log_g_scale(log_g_scale: float, g_acc: list, iteration: int, target_accept: float) -> float:
    """One Robbins-Monro step of the gamma random walk's log width towards ``target_accept`` (burn-in only).

    Bounded: rejections caused by the (a, b) > 0 constraint (kd near 0 or 1) must not shrink
    the step to nothing and freeze gamma.
    """
    log_g_scale += (np.mean(g_acc) - target_accept) * 2.0 / (iteration + 1.0) ** 0.6
    return float(np.clip(log_g_scale, LOG_G_SCALE_BOUNDS[0], LOG_G_SCALE_BOUNDS[1]))
