"""Per-pixel and per-cell log-likelihood sums of change-point vectors.

:func:`per_pixel_two_cases` and :func:`cell_log_lik` give, for one vector, every line's
log-likelihood with its element in each cell (the vector redraw's emissions);
:func:`removal_sums` gives every line's log-likelihood change when an element of a given
rank is removed (the free death's emissions). Both phase each block of observations: the
regions and keys (scalar), the densities over runs of one region (vectorised,
:func:`rjfit.sampler.passes.densities.log_densities_into`), the sums per key and their
scatter (scalar). The per-pixel pass runs in :data:`~rjfit.sampler.passes.sums.PARTS`
pieces on the chain's threads for large problems, each cut at a pixel's first observation
(:func:`pixel_cuts`). Both take the problem's lobe terms last (None for the plain model:
:mod:`rjfit.sampler.passes.lobe`).
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from rjfit.sampler.passes.densities import coefficients, log_densities_into, run_end
from rjfit.sampler.passes.lobe import lobe_rows
from rjfit.sampler.passes.sums import BLOCK, PARALLEL_MIN_OBS, PARTS

__all__ = ["per_pixel_two_cases", "pixel_cuts", "cell_log_lik", "removal_sums"]


@njit(cache=True, nogil=True)
def _per_pixel_range(y, C, log_cos_hn, line_of, along_of, labels, x_old, step_label, coef, size,
                     right_case, left_case, lo, hi, ext, rows):
    """:func:`per_pixel_two_cases` of observations ``lo .. hi - 1``."""
    base_of = np.empty(BLOCK, np.int64)
    keys = np.empty(BLOCK, np.int64)
    right_density = np.empty(BLOCK)
    left_density = np.empty(BLOCK)
    for start in range(lo, hi, BLOCK):
        m = min(BLOCK, hi - start)
        for k in range(m):
            i = start + k
            base = np.int64(labels[i])
            if x_old[line_of[i]] < along_of[i] + 0.5:
                base -= step_label
            base_of[k] = base
            keys[k] = np.int64(line_of[i]) * size + np.int64(along_of[i])
        ys, cs, ls = y[start:start + m], C[start:start + m], log_cos_hn[start:start + m]
        first = 0
        while first < m:
            base = base_of[first]
            last = run_end(base_of, first, m)
            log_densities_into(ys[first:last], cs[first:last], ls[first:last], coef, base, right_density[first:last],
                               ext, rows, start + first)
            log_densities_into(ys[first:last], cs[first:last], ls[first:last], coef, base + step_label,
                               left_density[first:last], ext, rows, start + first)
            first = last
        # a pixel's observations are consecutive (sorted by pixel): sum them in registers and
        # write each pixel's two sums once, not once per observation
        key = -1
        right = left = 0.0
        for k in range(m):
            if keys[k] != key:
                if key >= 0:
                    right_case[key] += right
                    left_case[key] += left
                key, right, left = keys[k], 0.0, 0.0
            right += right_density[k]
            left += left_density[k]
        if key >= 0:
            right_case[key] += right
            left_case[key] += left


@njit(cache=True, nogil=True, parallel=True)
def _per_pixel_parts(y, C, log_cos_hn, line_of, along_of, labels, x_old, step_label, coef, size,
                     right_case, left_case, bounds, ext, rows):
    # parts start at a pixel's first observation, so no two parts write the same entry
    for p in prange(bounds.shape[0] - 1):
        _per_pixel_range(y, C, log_cos_hn, line_of, along_of, labels, x_old, step_label, coef, size,
                         right_case, left_case, bounds[p], bounds[p + 1], ext, rows)


# Plain Python, not jitted: it calls a parallel=True kernel, and Numba 0.68 mis-compiles such a call
# made from inside another jitted function (with effects' lobe terms its first call returned zero sums,
# and its cached form crashed); dispatched from Python the kernel compiles and runs on its own.
def per_pixel_two_cases(y, C, log_cos_hn, line_of, along_of, labels, x_old, step_label, theta, size,
                        right_case, left_case, ext=None):
    """Per-pixel log-likelihood sums with one vector's element right of the pixel and left of it.

    For observation ``i`` on line ``line_of[i]`` at ``along_of[i]``, the base
    region is its label minus ``step_label`` if the vector's current element ``x_old`` of
    its line lies left of it; ``right_case`` gets its log density in the base region and
    ``left_case`` in base + step_label (flat index ``line * size + along``; both
    accumulate).

    Three phases per block of observations: base regions and pixel keys (scalar); the
    densities over each run of one base region (:func:`log_densities_into`, vectorised: the
    exps are most of the work, and observations sorted by pixel make the runs long); the
    sums per pixel and their scatter (scalar). With :data:`PARALLEL_MIN_OBS` observations or
    more, in :data:`PARTS` pieces on the chain's threads, each cut at a pixel's first
    observation.
    """
    coef = coefficients(theta)
    rows = lobe_rows(ext, coef[:, 2])
    n = y.shape[0]
    if n < PARALLEL_MIN_OBS:
        _per_pixel_range(y, C, log_cos_hn, line_of, along_of, labels, x_old, step_label, coef, size,
                         right_case, left_case, 0, n, ext, rows)
        return
    _per_pixel_parts(y, C, log_cos_hn, line_of, along_of, labels, x_old, step_label, coef, size,
                     right_case, left_case, pixel_cuts(line_of, along_of), ext, rows)


@njit(cache=True, nogil=True)
def pixel_cuts(line_of, along_of):
    """Bounds of :data:`PARTS` near-equal pieces of observations sorted by pixel, each cut at a
    pixel's first observation: (PARTS + 1,) from 0 to n, non-decreasing.

    Whole pixels per piece, because the pieces of :func:`per_pixel_two_cases` run at once and
    each adds into its pixels' entries: a pixel split between two pieces would be written by
    two threads at a time, a race whose lost updates are rare and would go unseen.
    """
    n = line_of.shape[0]
    bounds = np.empty(PARTS + 1, np.int64)
    bounds[0], bounds[PARTS] = 0, n
    for p in range(1, PARTS):
        cut = max(n * p // PARTS, bounds[p - 1])
        while 0 < cut < n and line_of[cut] == line_of[cut - 1] and along_of[cut] == along_of[cut - 1]:
            cut += 1
        bounds[p] = cut
    return bounds


@njit(cache=True, nogil=True)
def cell_log_lik(right_case, left_case, n_lines, size, power):
    """(L, S + 1): line r's log-likelihood with its element in cell j, from :func:`per_pixel_two_cases`' sums.

    Pixels ``t < j`` lie left of the element (``right_case``: the element is right of them),
    pixels ``t >= j`` right of it (``left_case``); both sums scaled by the likelihood power.
    """
    out = np.empty((n_lines, size + 1))
    for r in range(n_lines):
        row_right = right_case[r * size:(r + 1) * size]
        row_left = left_case[r * size:(r + 1) * size]
        suffix = 0.0
        for t in range(size):
            suffix += row_left[t]
        prefix = 0.0
        out[r, 0] = power * suffix
        for j in range(size):
            prefix += row_right[j]
            suffix -= row_left[j]
            out[r, j + 1] = power * (prefix + suffix)
    return out


@njit(cache=True, nogil=True)
def removal_sums(y, C, log_cos_hn, line_of, labels, theta, n, n_v, step, axis_u, sums, ext=None):
    """Per (line, column) log-likelihood sums: as labelled, moved one column down, moved one column up.

    ``sums`` (3, L * (n + 1)) accumulates; column = the observation's region index along the
    axis (``label // (n_v + 1)`` for u, ``label % (n_v + 1)`` for v). See
    :func:`rjfit.sampler.regions.changepoints.birth_death_free.removal_log_emit`. Phased per block like
    :func:`per_pixel_two_cases` (the densities over runs of one label, vectorised).
    """
    coef = coefficients(theta)
    rows = lobe_rows(ext, coef[:, 2])
    total = y.shape[0]
    # a label's column from a table: an integer division per observation costs more than its exps
    column_of = np.empty(theta.shape[0], np.int64)
    for lab in range(theta.shape[0]):
        column_of[lab] = lab // (n_v + 1) if axis_u else lab % (n_v + 1)
    labels_of = np.empty(BLOCK, np.int64)
    keys = np.empty(BLOCK, np.int64)
    density = np.empty((3, BLOCK))
    for start in range(0, total, BLOCK):
        m = min(BLOCK, total - start)
        for k in range(m):
            i = start + k
            lab = np.int64(labels[i])
            labels_of[k] = lab
            keys[k] = np.int64(line_of[i]) * (n + 1) + column_of[lab]
        ys, cs, ls = y[start:start + m], C[start:start + m], log_cos_hn[start:start + m]
        lo = 0
        while lo < m:
            lab = labels_of[lo]
            hi = run_end(labels_of, lo, m)
            column = column_of[lab]
            # as labelled, moved one column down, moved one column up; at the edges a move keeps
            # the observations where they are, so their densities are copied, not recomputed
            log_densities_into(ys[lo:hi], cs[lo:hi], ls[lo:hi], coef, lab, density[0, lo:hi], ext, rows, start + lo)
            if column > 0:
                log_densities_into(ys[lo:hi], cs[lo:hi], ls[lo:hi], coef, lab - step, density[1, lo:hi], ext, rows,
                                   start + lo)
            else:
                density[1, lo:hi] = density[0, lo:hi]
            if column < n:
                log_densities_into(ys[lo:hi], cs[lo:hi], ls[lo:hi], coef, lab + step, density[2, lo:hi], ext, rows,
                                   start + lo)
            else:
                density[2, lo:hi] = density[0, lo:hi]
            lo = hi
        # consecutive observations share a (line, column) key: add them in registers
        key = keys[0]
        as_labelled = down = up = 0.0
        for k in range(m):
            if keys[k] != key:
                sums[0, key] += as_labelled
                sums[1, key] += down
                sums[2, key] += up
                key, as_labelled, down, up = keys[k], 0.0, 0.0, 0.0
            as_labelled += density[0, k]
            down += density[1, k]
            up += density[2, k]
        sums[0, key] += as_labelled
        sums[1, key] += down
        sums[2, key] += up
