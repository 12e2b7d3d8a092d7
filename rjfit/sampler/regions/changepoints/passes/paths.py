"""Chains along the lines: forward filtering, backward sampling and path probabilities.

The vector redraw proposes a whole change-point vector as a path of cells along the lines
(:func:`forward_filter`, :func:`cell_backward_sample`, :func:`cell_path_log_prob`), then
the positions inside the cells (:func:`within_cells_draw`,
:func:`within_cells_log_density`); the free death draws the rank removed from each line
from a chain of ranks (:func:`rank_forward`, :func:`rank_backward_sample`,
:func:`rank_path_log_prob`). Each is the compiled twin of a NumPy reference in
:mod:`rjfit.sampler.reference` (same random inputs, same draws), which the tests compare
them against.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from rjfit.sampler.passes.special import LOG_2PI, fast_exp, log_sum_exp, ndtr, ndtri, truncated_mass

__all__ = ["forward_filter", "cell_path_log_prob", "cell_backward_sample", "rank_forward", "rank_path_log_prob",
           "rank_backward_sample", "within_cells_draw", "within_cells_log_density"]


@njit(cache=True, nogil=True, fastmath={"contract"})
def _convolve_into(conv, previous, kernel, reach_max):
    """``conv[j] = sum_d previous[j - d] kernel[d + reach_max]`` over the steps that stay on the line.

    One step d at a time over whole lines, through views so that the inner loop indexes
    from 0 (no negative-index wraparound to check) and vectorises; each cell's terms are
    still added in increasing d.
    """
    n_cells = previous.shape[0]
    for j in range(n_cells):
        conv[j] = 0.0
    for d in range(-reach_max, reach_max + 1):
        w = kernel[d + reach_max]
        lo, hi = max(0, d), min(n_cells, n_cells + d)
        source = previous[lo - d:hi - d]
        target = conv[lo:hi]
        for k in range(hi - lo):
            target[k] += source[k] * w


@njit(cache=True, nogil=True, fastmath={"contract"})
def _exp_shifted_into(values, shift, out):
    """``out[j] = e^(values[j] - shift)`` (:func:`fast_exp`, vectorised) and their sum."""
    for j in range(out.shape[0]):
        out[j] = fast_exp(values[j] - shift)
    total = 0.0
    for j in range(out.shape[0]):
        total += out[j]
    return total


@njit(cache=True, nogil=True)
def forward_filter(log_emit, kernel, reach_max):
    """Normalised forward log alphas (L, S) of the cell chain; ``ok`` False if a line has no finite cell.

    ``kernel[d + reach_max]`` is the linear weight of a step of d cells between lines
    (|d| <= reach_max, the step's weight beyond is below 1e-30 of its peak and left out:
    only the proposal changes, and the move computes its density from these same alphas
    both ways, so it stays exact). An empty kernel means independent lines. The
    normalising exps use :func:`fast_exp` (0 below e^-708, where libm's would be
    subnormal): again only the proposal can change.
    """
    n_lines, n_cells = log_emit.shape
    alpha = np.empty_like(log_emit)
    previous = np.zeros(n_cells)
    conv = np.empty(n_cells)
    linear = np.zeros(n_cells)
    coupled = kernel.shape[0] > 0
    for r in range(n_lines):
        row = alpha[r]
        if r > 0 and coupled:
            _convolve_into(conv, previous, kernel, reach_max)
            for j in range(n_cells):
                row[j] = log_emit[r, j] + math.log(max(conv[j], 1e-300))
        else:
            for j in range(n_cells):
                row[j] = log_emit[r, j]
        top = -np.inf
        for j in range(n_cells):
            if row[j] > top:
                top = row[j]
        if not np.isfinite(top):
            return alpha, False
        total = _exp_shifted_into(row, top, linear)
        log_total = math.log(total)
        for j in range(n_cells):
            row[j] = row[j] - top - log_total
            previous[j] = linear[j] / total
    return alpha, True


@njit(cache=True, nogil=True)
def _step_window(log_kernel, cell_next, n_cells):
    """Cells [lo, hi) that line r may take given line r + 1's cell, and the kernel's centre index.

    ``log_kernel`` holds the log weights of steps -K..K (length 2 K + 1, K = its reach); an
    empty one means independent lines (every cell). Cells beyond the reach have weight 0.
    """
    if log_kernel.shape[0] == 0:
        return 0, n_cells, 0
    reach = (log_kernel.shape[0] - 1) // 2
    return max(0, cell_next - reach), min(n_cells, cell_next + reach + 1), reach - cell_next


@njit(cache=True, nogil=True)
def _step_logits(alpha, r, cell_next, log_kernel, out):
    """Backward logits of line r's cells given line r + 1's (``out``, -inf outside the window); their log-sum-exp."""
    n_cells = alpha.shape[1]
    lo, hi, offset = _step_window(log_kernel, cell_next, n_cells)
    top = -np.inf
    for j in range(n_cells):
        out[j] = -np.inf
    for j in range(lo, hi):
        v = alpha[r, j]
        if log_kernel.shape[0] > 0:
            v += log_kernel[j + offset]
        out[j] = v
        if v > top:
            top = v
    total = 0.0
    for j in range(lo, hi):
        total += math.exp(out[j] - top)
    return top + math.log(total)


@njit(cache=True, nogil=True)
def cell_path_log_prob(alpha, path, log_kernel):
    """Log probability that backward sampling from ``alpha`` with step weights ``log_kernel`` draws ``path``.

    ``log_kernel`` (2 K + 1,) log weights of cell steps -K..K (empty: independent lines);
    a path with a step beyond K has probability 0.
    """
    n_lines, n_cells = alpha.shape
    logits = np.empty(n_cells)
    total = alpha[n_lines - 1, path[n_lines - 1]]
    for r in range(n_lines - 2, -1, -1):
        log_norm = _step_logits(alpha, r, path[r + 1], log_kernel, logits)
        if not np.isfinite(logits[path[r]]):
            return -np.inf
        total += logits[path[r]] - log_norm
    return total


@njit(cache=True, nogil=True)
def cell_backward_sample(alpha, log_kernel, uniforms):
    """A cell path drawn backwards from ``alpha`` (last line first), one uniform per line.

    Line r's draw looks only at the cells within the kernel's reach of line r + 1's cell;
    where none of them has a finite logit (a dead end: the forward pass floors a step's
    weight at 1e-300, the backward draw has none) line r gets -1 and the path is no draw
    of the chain (the caller rejects it).
    """
    n_lines, n_cells = alpha.shape
    logits = np.empty(n_cells)
    weights = np.empty(n_cells)
    path = np.empty(n_lines, np.int64)
    for r in range(n_lines - 1, -1, -1):
        if r == n_lines - 1:
            lo, hi = 0, n_cells
            for j in range(n_cells):
                logits[j] = alpha[r, j]
        else:
            lo, hi, _ = _step_window(log_kernel, path[r + 1], n_cells)
            _step_logits(alpha, r, path[r + 1], log_kernel, logits)
        top = -np.inf
        for j in range(lo, hi):
            if logits[j] > top:
                top = logits[j]
        total = 0.0
        for j in range(lo, hi):
            weights[j] = math.exp(logits[j] - top)
            total += weights[j]
        target = uniforms[r] * total
        running = 0.0
        chosen = -1
        for j in range(lo, hi):
            if weights[j] > 0.0:
                chosen = j      # rounding may leave running <= target: the last cell of weight > 0 then
            running += weights[j]
            if running > target and weights[j] > 0.0:
                break
        path[r] = chosen
    return path


@njit(cache=True, nogil=True)
def rank_forward(log_emit, log_t):
    """Normalised forward log alphas (L, n) of the chain of removed ranks with log transitions ``log_t[from, to]``.

    The compiled twin of :func:`rjfit.sampler.reference.rank_chain`'s forward pass.
    """
    n_lines, n = log_emit.shape
    alpha = np.empty_like(log_emit)
    terms = np.empty(n)
    for r in range(n_lines):
        for j in range(n):
            a = log_emit[r, j]
            if r > 0:
                for i in range(n):
                    terms[i] = alpha[r - 1, i] + log_t[i, j]
                a += log_sum_exp(terms)
            alpha[r, j] = a
        norm = log_sum_exp(alpha[r])
        for j in range(n):
            alpha[r, j] -= norm
    return alpha


@njit(cache=True, nogil=True)
def rank_path_log_prob(alpha, path, log_t):
    """Log probability that backward sampling from ``alpha`` (:func:`rank_backward_sample`) draws ``path``."""
    n_lines, n = alpha.shape
    logits = np.empty(n)
    total = alpha[n_lines - 1, path[n_lines - 1]]
    for r in range(n_lines - 2, -1, -1):
        for j in range(n):
            logits[j] = alpha[r, j] + log_t[j, path[r + 1]]
        if not np.isfinite(logits[path[r]]):
            return -np.inf
        total += logits[path[r]] - log_sum_exp(logits)
    return total


@njit(cache=True, nogil=True)
def rank_backward_sample(alpha, log_t, uniforms):
    """A path of ranks drawn backwards from ``alpha``, last line first with ``uniforms[0]``.

    Each line's draw is the first rank whose cumulative weight exceeds ``u`` times the total,
    as :func:`rjfit.sampler.reference.backward_sample` (its reference) does with ``np.searchsorted(..., side='right')``.
    """
    n_lines, n = alpha.shape
    logits = np.empty(n)
    path = np.empty(n_lines, np.int64)
    for step in range(n_lines):
        r = n_lines - 1 - step
        for j in range(n):
            logits[j] = alpha[r, j] + (log_t[j, path[r + 1]] if r < n_lines - 1 else 0.0)
        top = -np.inf
        for j in range(n):
            if logits[j] > top:
                top = logits[j]
        cumulative = np.empty(n)
        running = 0.0
        for j in range(n):
            running += math.exp(logits[j] - top)
            cumulative[j] = running
        target = uniforms[step] * cumulative[n - 1]
        chosen = n - 1
        for j in range(n):
            if cumulative[j] > target:
                chosen = j
                break
        path[r] = chosen
    return path


@njit(cache=True, nogil=True)
def within_cells_draw(lo, hi, sd, uniforms):
    """Compiled twin of :func:`rjfit.sampler.reference.draw_within_cells`; ``sd`` <= 0: no step model.

    ``uniforms[r]`` is line r's uniform (the reference draws them last line first).
    """
    n_lines = lo.shape[0]
    x = np.empty(n_lines)
    last = n_lines - 1
    x[last] = lo[last] + (hi[last] - lo[last]) * uniforms[last]
    for r in range(n_lines - 2, -1, -1):
        u = uniforms[r]
        if sd > 0.0:
            a, b = (lo[r] - x[r + 1]) / sd, (hi[r] - x[r + 1]) / sd
            if truncated_mass(a, b) > 1e-12:
                if a > 0.0:      # mirrored, so the inverse CDF works away from 1
                    z = -ndtri(ndtr(-a) - u * (ndtr(-a) - ndtr(-b)))
                else:
                    z = ndtri(ndtr(a) + u * (ndtr(b) - ndtr(a)))
                x[r] = min(max(x[r + 1] + sd * z, lo[r]), np.nextafter(hi[r], lo[r]))
                continue
        x[r] = lo[r] + (hi[r] - lo[r]) * u
    return x


@njit(cache=True, nogil=True)
def within_cells_log_density(x, lo, hi, sd):
    """Compiled twin of :func:`rjfit.sampler.reference.within_cell_log_density` (summed; next line = x[r + 1])."""
    n_lines = x.shape[0]
    total = 0.0
    for r in range(n_lines):
        uniform = -math.log(hi[r] - lo[r])
        if sd > 0.0 and r < n_lines - 1:
            a, b = (lo[r] - x[r + 1]) / sd, (hi[r] - x[r + 1]) / sd
            mass = truncated_mass(a, b)
            if mass > 1e-12:
                d = (x[r] - x[r + 1]) / sd
                total += -0.5 * d * d - math.log(sd) - 0.5 * LOG_2PI - math.log(mass)
                continue
        total += uniform
    return total
