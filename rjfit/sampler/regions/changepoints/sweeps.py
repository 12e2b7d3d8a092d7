"""Change-point element sweeps: one element of every other row (column) moved at once.

Given the parameters and the other axis, the target factorises over rows (a u element
changes only pixels of its row), so the rows' independent Metropolis-Hastings decisions
together form one valid move. Rows of one parity move together while the other rows stay
fixed, so the proposal around the same-rank element of a neighbouring row has a
well-defined reverse density. The compiled passes: the proposals
(:func:`rjfit.sampler.regions.changepoints.passes.sweep.sweep_proposal`), the observations that change region
and their density change (:mod:`rjfit.sampler.passes.shifts`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rjfit.sampler.likelihood import log_likelihood_from_stats
from rjfit.sampler.moves.accept import accept
from rjfit.sampler.passes import shifts
from rjfit.sampler.regions.changepoints.passes import sweep

__all__ = ["SweepSettings", "sweep_changepoints", "element_shift", "apply_shift"]


@dataclass(frozen=True)
class SweepSettings:
    """How an element move proposes (a mixture, per moved element).

    Attributes
    ----------
    step : float
        Random-walk width (pixels) of an element move (flat option ``cp_step``).
    uniform_prob : float
        Probability that an element move redraws uniformly over [-1, size + 1] instead
        (``cp_uniform_prob``).
    neighbour_prob, neighbour_sd : float
        Probability that an element move proposes a normal (width ``neighbour_sd`` pixels)
        around the same-rank element of a neighbouring row (column): lets an element that
        strayed snap back to the boundary its neighbours found (``cp_neighbour_prob``,
        ``cp_neighbour_sd``).
    """

    step: float = 2.0
    uniform_prob: float = 0.05
    neighbour_prob: float = 0.3
    neighbour_sd: float = 0.5

    def __post_init__(self):
        if self.step <= 0 or self.neighbour_sd <= 0:
            raise ValueError(f"cp_step and cp_neighbour_sd must be positive, got {self.step}, {self.neighbour_sd}")
        if self.uniform_prob < 0 or self.neighbour_prob < 0 or self.uniform_prob + self.neighbour_prob > 1:
            raise ValueError("cp_uniform_prob and cp_neighbour_prob must be >= 0 and sum to at most 1")


def sweep_changepoints(work, rng, problem, settings: SweepSettings, cp_prior, axis: str, info, parity: int = 0):
    """Move one element of every other row (axis 'u') or column (axis 'v') at once (kind 'cp_u' / 'cp_v').

    Rows of one ``parity`` move together while the other rows stay fixed. A proposal
    outside [-1, size + 1] has zero prior density and is rejected. ``cp_prior`` is the
    :class:`~rjfit.sampler.regions.changepoints.grid.ChangepointPrior`.
    """
    height, width = problem.image_shape
    cps = work.layout.u if axis == "u" else work.layout.v
    n_all, n_cp = cps.shape
    if n_cp == 0:
        return
    size = width if axis == "u" else height       # positions run along this size
    lines = np.arange(parity, n_all, 2)
    n_lines = len(lines)
    if n_lines == 0:
        return
    k = rng.integers(n_cp, size=n_lines)
    kind = rng.random(n_lines)
    z = rng.normal(size=n_lines)
    pick_up = rng.random(n_lines) < 0.5
    unif = rng.uniform(-1.0, size + 1.0, n_lines)
    # proposal and its log ratio (reverse / forward density, smooth prior's terms): compiled
    x_old = cps[lines, k]
    x_new, inside, log_q_ratio = sweep.sweep_proposal(
        np.ascontiguousarray(cps), lines, k, kind, z, pick_up, unif, float(size), settings.uniform_prob,
        settings.neighbour_prob, settings.step, settings.neighbour_sd,
        cp_prior.smooth_sd if cp_prior.kind == "smooth" else 0.0)
    starts, ends, delta = element_shift(problem, work, axis, lines, x_old, x_new)
    log_u = np.log(rng.random(n_lines))
    d_ll = problem.likelihood_power * shifts.obs_log_density_delta(
        problem.y, problem.C, problem.log_cos_hn, problem.colmajor_order, axis == "v", starts, ends, work.labels,
        delta, work.theta, problem.lobe)
    # a proposal outside [-1, size + 1] (not ``inside``) has zero density: -inf, never accepted
    accepted = accept(log_u, np.where(inside, d_ll + log_q_ratio, -np.inf), info, f"cp_{axis}")
    info.count(f"cp_{axis}", accepted, n_lines)
    if not np.any(accepted):
        return
    new_cps = cps.copy()
    new_cps[lines[accepted], k[accepted]] = x_new[accepted]
    new_cps.sort(axis=1)
    work.layout = work.layout.with_axis(axis, new_cps)
    apply_shift(work, problem, axis, starts[accepted], ends[accepted], delta[accepted])


def element_shift(problem, work, axis, lines, x_old, x_new):
    """The observations that change region when element positions move from ``x_old`` to ``x_new``.

    Each of ``lines`` has one element moving within its rank: the pixels t with
    ``min < t + 0.5 <= max`` of the two positions change side, so their label moves by the
    vector's label step, down when the element moves right. Returns ``(starts, ends, delta)``:
    per line the slice of its observations (row-major for 'u', ``colmajor_order`` for 'v')
    and the label change.
    """
    size = problem.width if axis == "u" else problem.height
    step_label = (work.layout.v.shape[1] + 1) if axis == "u" else 1
    offsets = problem.pixel_start if axis == "u" else problem.colmajor_start
    return shifts.element_shift(np.ascontiguousarray(x_old, dtype=float), np.ascontiguousarray(x_new, dtype=float),
                                np.ascontiguousarray(lines, dtype=np.int64), size, offsets, step_label)


def apply_shift(work, problem, axis, starts, ends, delta):
    """Relabel the observations of an :func:`element_shift` and move their terms between regions (in place)."""
    moved = ends > starts
    if not np.any(moved):
        return
    if not work.labels_owned:
        work.labels = work.labels.copy()
        work.labels_owned = True
    shifts.shift_stats(problem.y, problem.C, problem.log_cos_hn, problem.colmajor_order, axis == "v", starts[moved],
                       ends[moved], work.labels, delta[moved], np.ascontiguousarray(work.theta[:, 2]), work.stats,
                       problem.likelihood_power, problem.lobe)
    work.region_index = None
    work.log_lik = log_likelihood_from_stats(work.stats, work.theta)
