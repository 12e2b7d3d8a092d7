"""Whole-vector redraw: every element of one change-point vector at once (forward filtering, backward sampling).

Given the parameters and the other vectors, the likelihood of vector k depends on each
element only through its cell (:func:`vector_cells`), and the 'smooth' prior couples
neighbouring lines by a Gaussian step, so the conditional of the cell path is close to a
hidden Markov chain along the lines. The proposal draws the path from that chain (steps
between cells weighted by N(0, s^2 + 1/12)), then the positions inside the cells and gaps,
each line's from the prior's step around the next line's position, so every element keeps
its rank. It is an independence proposal from an approximation of the exact conditional;
the acceptance ratio uses the exact continuous prior and the proposal's density of both
the new and the current vector, so the move is exact (for the 'paper' prior the chain is
exact and every proposal is accepted). One move can carry a whole vector across the image:
what element-wise steps and block shifts cannot do when two vectors compensate each other's
errors. The compiled passes are in :mod:`rjfit.sampler.passes.cells` (emissions) and
:mod:`rjfit.sampler.regions.changepoints.passes.paths` (the chain); their NumPy twins in
:mod:`rjfit.sampler.reference`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rjfit.sampler.regions.changepoints.birth_death import gaps
from rjfit.sampler.moves.proposal import Proposal
from rjfit.sampler.regions.changepoints.sweeps import apply_shift, element_shift
from rjfit.sampler.passes import cells
from rjfit.sampler.regions.changepoints.passes import paths

__all__ = ["VectorSettings", "vector_cells", "cell_of", "truncated_log_kernel", "propose_vector_redraw",
           "accept_vector_redraw"]


@dataclass(frozen=True)
class VectorSettings:
    """How often a whole vector is redrawn.

    Attributes
    ----------
    prob : float
        Probability per iteration of redrawing one whole change-point vector (flat option
        ``vector_prob``).
    """

    prob: float = 0.3

    def __post_init__(self):
        if not 0.0 <= self.prob <= 1.0:
            raise ValueError(f"vector_prob must lie in [0, 1], got {self.prob}")


def vector_cells(lower, upper, size):
    """Width (L, size + 1) of each likelihood cell of an element inside its gap (lower, upper), and their lower ends.

    An element ``x`` is left of the pixel with along-line index ``t`` when ``x < t + 0.5``, so
    the likelihood depends on x only through its cell ``j``: [j - 0.5, j + 0.5), widened to
    [-1, 0.5) for j = 0 and [size - 0.5, size + 1] for j = size.
    """
    j = np.arange(size + 1, dtype=float)
    cell_lo = np.maximum(j - 0.5, -1.0)
    cell_lo[0] = -1.0
    cell_hi = j + 0.5
    cell_hi[-1] = size + 1.0
    lo = np.maximum(cell_lo[None, :], lower[:, None])
    hi = np.minimum(cell_hi[None, :], upper[:, None])
    return np.maximum(hi - lo, 0.0), lo


def cell_of(x, size):
    """The likelihood cell of positions ``x`` (see :func:`vector_cells`)."""
    return np.clip(np.floor(np.asarray(x) + 0.5).astype(np.int64), 0, size)


def _filter_cells(log_emit, log_kernel):
    """Forward pass of the chain of cells along the lines: normalised log alphas (L, S + 1), or None.

    ``log_kernel`` (2 K + 1,) holds the log weights of cell steps -K..K between neighbouring
    lines (:func:`truncated_log_kernel`: the steps whose weight is at least 1e-30 of the
    largest), or is None for independent lines. The sums run in linear space (compiled:
    :func:`rjfit.sampler.regions.changepoints.passes.paths.forward_filter`); round-off and the cut only perturb the
    proposal, whose density the move computes from the same alphas and steps both ways, so
    it stays exact.
    """
    if log_kernel is None:
        kernel, reach = np.zeros(0), 0
    else:
        reach = (log_kernel.size - 1) // 2
        kernel = np.exp(log_kernel - log_kernel.max())
    alpha, ok = paths.forward_filter(np.ascontiguousarray(log_emit, dtype=float), kernel, reach)
    return alpha if ok else None


def truncated_log_kernel(log_kernel):
    """The log step weights -K..K whose weight is at least 1e-30 of the largest (the chain's steps)."""
    centre = log_kernel.size // 2
    keep = np.flatnonzero(log_kernel - log_kernel.max() >= math.log(1e-30))
    reach = int(max(abs(keep[0] - centre), abs(keep[-1] - centre)))
    return log_kernel[centre - reach: centre + reach + 1]


def propose_vector_redraw(work, rng, problem, cp_prior, axis: str) -> Proposal | None:
    """Redraw every element of one u (v) vector at once (forward filtering, backward sampling).

    Returns an incremental :class:`Proposal` (``shift``: the observations that change
    region, for :func:`accept_vector_redraw`), or None when no path exists (a line without
    a finite cell): nothing to test then. The chain's steps reach K cells
    (:func:`truncated_log_kernel`); where the gaps of two neighbouring lines lie further
    apart, the backward draw meets a line with no reachable cell (a dead end, measured on
    the DiLiGenT ball: 46 of 1000 iterations of a chain) and draws no path: the proposal is
    invalid (log ratio -inf, a plain rejection). Where the current vector's own path has
    such a step, its proposal density is 0 and every proposal is rejected: the other
    change-point moves move it. Neither gives a NaN ratio.
    """
    height, width = problem.image_shape
    layout = work.layout
    cps = layout.u if axis == "u" else layout.v
    n_lines, n = cps.shape
    size = width if axis == "u" else height
    k = int(rng.integers(n))
    lower, upper = gaps(np.delete(cps, k, axis=1), k, size)
    step_label = (layout.v.shape[1] + 1) if axis == "u" else 1
    x_old = cps[:, k]
    # per-pixel log-likelihood with the element right of the pixel (base) or left of it (base + step)
    per_pixel = [np.zeros(n_lines * size), np.zeros(n_lines * size)]
    line_of, along_of = (problem.row, problem.col) if axis == "u" else (problem.col, problem.row)
    cells.per_pixel_two_cases(problem.y, problem.C, problem.log_cos_hn, line_of, along_of, work.labels,
                              np.ascontiguousarray(x_old), step_label, work.theta, size, per_pixel[0], per_pixel[1],
                              problem.lobe)
    log_lik_cell = cells.cell_log_lik(per_pixel[0], per_pixel[1], n_lines, size, problem.likelihood_power)  # (L, S+1)
    widths, cell_lo = vector_cells(lower, upper, size)
    with np.errstate(divide="ignore"):
        log_emit = log_lik_cell + np.log(widths)
    log_kernel, sd = None, None
    if cp_prior.kind == "smooth":
        sd = cp_prior.smooth_sd
        offsets = np.arange(-size, size + 1)
        log_kernel = truncated_log_kernel(-0.5 * offsets ** 2 / (sd ** 2 + 1.0 / 12.0))
    alpha = _filter_cells(log_emit, log_kernel)
    if alpha is None:
        return None
    rows = np.arange(n_lines)
    # compiled twins of reference.backward_sample / path_log_prob with reference.cell_step_logits' steps
    log_steps = np.zeros(0) if log_kernel is None else log_kernel
    cells_new = paths.cell_backward_sample(alpha, log_steps, rng.random(n_lines))
    # compiled twins of reference.draw_within_cells / within_cell_log_density (sd <= 0: no step
    # model); the reference draws one uniform per line, last line first (drawn before the
    # dead-end test, so that the random stream does not depend on it)
    within_uniforms = rng.random(n_lines)[::-1].copy()
    if cells_new.min() < 0:         # a dead end (cell -1): no path was drawn
        return Proposal.invalid(layout)
    lo_new, hi_new = cell_lo[rows, cells_new], cell_lo[rows, cells_new] + widths[rows, cells_new]
    step_sd = -1.0 if sd is None else float(sd)
    x_new = paths.within_cells_draw(lo_new, hi_new, step_sd, within_uniforms)
    cells_old = cell_of(x_old, size)
    lo_old, hi_old = cell_lo[rows, cells_old], cell_lo[rows, cells_old] + widths[rows, cells_old]
    log_q_new = (paths.cell_path_log_prob(alpha, cells_new, log_steps)
                 + paths.within_cells_log_density(x_new, lo_new, hi_new, step_sd))
    log_q_old = (paths.cell_path_log_prob(alpha, cells_old, log_steps)
                 + paths.within_cells_log_density(np.ascontiguousarray(x_old), lo_old, hi_old, step_sd))
    new_cps = cps.copy()
    new_cps[:, k] = x_new
    new_layout = layout.with_axis(axis, new_cps)
    log_ratio = (float(np.sum(log_lik_cell[rows, cells_new]) - np.sum(log_lik_cell[rows, cells_old]))
                 + cp_prior.log_density(new_layout.u, new_layout.v, problem.image_shape)
                 - cp_prior.log_density(layout.u, layout.v, problem.image_shape)
                 + log_q_old - log_q_new)
    return Proposal(new_layout, work.theta, None, None, None, float(log_ratio),
                    shift=element_shift(problem, work, axis, rows, x_old, x_new))


def accept_vector_redraw(work, problem, axis: str, proposal: Proposal) -> None:
    """Make an accepted :func:`propose_vector_redraw` the current state of ``work`` (in place).

    Only the observations between each line's old and new element change region: their
    terms move between the statistics as in an element move, O(changed) instead of a pass
    over every observation.
    """
    work.layout = proposal.layout
    apply_shift(work, problem, axis, *proposal.shift)
