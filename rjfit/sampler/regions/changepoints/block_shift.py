"""Block shift: a run of one vector's elements moved by a common shift, the regions it changes redrawn.

The block (first line uniform, length uniform in 1..``max_lines``) and the shift
``delta ~ N(0, shift_sd^2)`` are chosen independently of the state, and a shift that would
reorder a line's elements or leave [-1, size + 1] is rejected, so the reverse move (same
block, -delta) has the same density. The parameters of every region whose pixel set changes
are redrawn from the conditional proposals used by birth/death
(:mod:`rjfit.sampler.moves.region_proposals`), and the reverse move's density of the current
parameters enters the ratio. This lets a stretch of a boundary that settled on the wrong
side of an object move back together with the parameters that had adapted to it (a trap
for element-by-element moves).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rjfit.sampler.likelihood import log_likelihood_from_stats, region_stats
from rjfit.sampler.moves.proposal import Proposal
from rjfit.sampler.moves.region_proposals import regions_term

__all__ = ["BlockSettings", "propose_block_shift"]


@dataclass(frozen=True)
class BlockSettings:
    """How often and how far a block shift moves.

    Attributes
    ----------
    prob : float
        Probability per iteration of a block shift (flat option ``block_prob``).
    max_lines : int
        Most lines in a block (``block_max``).
    shift_sd : float
        Standard deviation of the common shift, pixels (``block_shift_sd``).
    """

    prob: float = 0.05
    max_lines: int = 128
    shift_sd: float = 20.0


def propose_block_shift(work, rng, problem, prior, settings: BlockSettings, proposals, cp_prior,
                        axis: str) -> Proposal:
    """Shift a contiguous block of one u (v) vector's elements by a common delta, redrawing the regions it changes.

    ``proposals`` are the region proposals' settings, ``cp_prior`` the change-point prior.
    """
    layout = work.layout
    cps = layout.u if axis == "u" else layout.v
    size = problem.width if axis == "u" else problem.height
    n_lines, n = cps.shape
    k = int(rng.integers(n))
    start = int(rng.integers(n_lines))
    length = int(rng.integers(1, settings.max_lines + 1))
    stop = min(n_lines, start + length)
    delta = settings.shift_sd * rng.normal()
    new_cps = cps.copy()
    new_cps[start:stop, k] += delta
    block = new_cps[start:stop]
    new_layout = layout.with_axis(axis, new_cps)
    invalid = (np.any(block[:, k] < -1.0) or np.any(block[:, k] > size + 1.0)
               or np.any(np.diff(block, axis=1) <= 0))
    if invalid:
        return Proposal.invalid(new_layout)
    labels = new_layout.labels(problem)
    changed = labels != work.labels
    if not np.any(changed):
        log_lik = work.log_lik
        theta_new, theta_term = work.theta, 0.0
        stats = work.stats
    else:
        affected = np.union1d(np.unique(labels[changed]), np.unique(work.labels[changed]))
        theta_new, term_new = regions_term(problem, prior, proposals, labels, work.theta, affected, draw_rng=rng)
        if theta_new is None:
            return Proposal.invalid(new_layout, labels)
        _, term_old = regions_term(problem, prior, proposals, work.labels, work.theta, affected)
        theta_term = term_new - term_old
        stats = region_stats(problem, labels, theta_new[:, 2], theta_new.shape[0])
        log_lik = log_likelihood_from_stats(stats, theta_new)
    log_ratio = (float(np.sum(log_lik)) - float(np.sum(work.log_lik))
                 + cp_prior.log_density(new_layout.u, new_layout.v, problem.image_shape)
                 - cp_prior.log_density(layout.u, layout.v, problem.image_shape)
                 + theta_term)
    return Proposal(new_layout, theta_new, labels, stats, log_lik, float(log_ratio))
