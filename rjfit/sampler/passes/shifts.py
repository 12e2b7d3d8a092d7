"""Element moves of change points: which observations change region, their density change, their statistics moved.

When one element of a line moves within its rank, the pixels between its old and new
position change side, so their observations' label moves by the vector's label step
(:func:`element_shift`); :func:`obs_log_density_delta` is the log-likelihood change of
those observations (the sweep's acceptance ratio), and :func:`shift_stats` relabels them
and moves their terms between the regions' statistics when the move is accepted. The
element sweeps and the vector redraw use them (:mod:`rjfit.sampler.regions.changepoints.sweeps`,
:mod:`rjfit.sampler.regions.changepoints.vector_redraw`). Both take the problem's lobe terms last (None for
the plain model: :mod:`rjfit.sampler.passes.lobe`).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from rjfit.sampler.passes.densities import coefficients, log_density
from rjfit.sampler.passes.lobe import lobe_at, lobe_rows
from rjfit.sampler.passes.special import INV_PI

__all__ = ["element_shift", "obs_log_density_delta", "add_obs_terms", "add_lobe_terms", "shift_stats"]


@njit(cache=True, nogil=True)
def element_shift(x_old, x_new, lines, size, offsets, step_label):
    """``(starts, ends, delta)`` of :func:`rjfit.sampler.regions.changepoints.sweeps.element_shift` (compiled: NumPy took 47 us).

    Line ``lines[j]``'s pixels t with ``min < t + 0.5 <= max`` of its two positions change
    side; ``offsets`` maps ``line * size + t`` to the first of that pixel's observations.
    """
    n = lines.shape[0]
    starts = np.empty(n, np.int64)
    ends = np.empty(n, np.int64)
    delta = np.empty(n, np.int64)
    for j in range(n):
        lo = min(max(np.int64(math.floor(min(x_old[j], x_new[j]) - 0.5)) + 1, 0), size)
        hi = min(max(np.int64(math.floor(max(x_old[j], x_new[j]) - 0.5)) + 1, 0), size)
        starts[j] = offsets[lines[j] * size + lo]
        ends[j] = offsets[lines[j] * size + hi]
        delta[j] = -step_label if x_new[j] > x_old[j] else step_label
    return starts, ends, delta


@njit(cache=True, nogil=True)
def obs_log_density_delta(y, C, log_cos_hn, order, use_order, starts, ends, labels, delta, theta, ext=None):
    """Per line j: sum over observations ``p in [starts[j], ends[j])`` of log p(y | new) - log p(y | old).

    Observation ``i = order[p]`` if ``use_order`` (columns: ``colmajor_order``) else ``p``
    (rows: observations are stored row-major). The old region is ``labels[i]``, the new one
    ``labels[i] + delta[j]`` (an element move shifts every observation it passes by one
    region step). Serial: a sweep's lines hold too few observations for threads (on 2
    threads this pass took 1.35 times as long, measured at 256 x 256).
    """
    n_lines = starts.shape[0]
    out = np.zeros(n_lines)
    coef = coefficients(theta)
    if ext is not None:
        _obs_log_density_delta_lobe(y, C, log_cos_hn, order, use_order, starts, ends, labels, delta, coef, ext, out)
        return out
    for j in range(n_lines):
        total = 0.0
        for p in range(starts[j], ends[j]):
            i = order[p] if use_order else p
            yv, c, lh = np.float64(y[i]), np.float64(C[i]), np.float64(log_cos_hn[i])
            r = labels[i]
            total += log_density(yv, c, lh, coef, r + delta[j]) - log_density(yv, c, lh, coef, r)
        out[j] = total
    return out


@njit(cache=True, nogil=True)
def _line_lobes(log_cos_hn, order, use_order, start, end, labels, step, gammas, ext, rows, idx, old, new, b_old, b_new):
    """The observations ``p in [start, end)`` of one line: their indices, regions (old and old + ``step``) and lobe
    columns in both, into the first ``end - start`` entries of the buffers."""
    m = end - start
    for k in range(m):
        i = order[start + k] if use_order else start + k
        idx[k] = i
        old[k] = labels[i]
        new[k] = old[k] + step
    lobe_at(ext, idx[:m], log_cos_hn, gammas, rows, old[:m], b_old[:m])
    lobe_at(ext, idx[:m], log_cos_hn, gammas, rows, new[:m], b_new[:m])


@njit(cache=True, nogil=True)
def _line_buffers(starts, ends):
    """Buffers for :func:`_line_lobes` as long as the longest line."""
    longest = 0
    for j in range(starts.shape[0]):
        longest = max(longest, ends[j] - starts[j])
    return (np.empty(longest, np.int64), np.empty(longest, np.int64), np.empty(longest, np.int64),
            np.empty(longest), np.empty(longest))


@njit(cache=True, nogil=True)
def _obs_log_density_delta_lobe(y, C, log_cos_hn, order, use_order, starts, ends, labels, delta, coef, ext, out):
    """:func:`obs_log_density_delta` with effects' lobe terms (each line's lobe columns first, :func:`_line_lobes`)."""
    rows = lobe_rows(ext, coef[:, 2])
    idx, old, new, b_old, b_new = _line_buffers(starts, ends)
    for j in range(starts.shape[0]):
        _line_lobes(log_cos_hn, order, use_order, starts[j], ends[j], labels, delta[j], coef[:, 2], ext, rows, idx,
                    old, new, b_old, b_new)
        total = 0.0
        for k in range(ends[j] - starts[j]):
            i, r, s = idx[k], old[k], new[k]
            yv, c = np.float64(y[i]), np.float64(C[i])
            resid_old = yv - coef[r, 0] * c - coef[r, 1] * b_old[k]
            resid_new = yv - coef[s, 0] * c - coef[s, 1] * b_new[k]
            total += coef[s, 3] - coef[s, 4] * resid_new * resid_new - coef[r, 3] + coef[r, 4] * resid_old * resid_old
        out[j] = total


@njit(cache=True, nogil=True)
def add_obs_terms(stats, r, sign, yv, c, a, lh, gamma):
    """Add ``sign`` times one observation's seven sufficient-statistic terms to region ``r``."""
    add_lobe_terms(stats, r, sign, yv, a, c * math.exp(gamma * lh))


@njit(cache=True, nogil=True)
def add_lobe_terms(stats, r, sign, yv, a, b):
    """Add ``sign`` times one observation's seven terms to region ``r``, its lobe column ``b`` given."""
    stats[r, 0] += sign
    stats[r, 1] += sign * yv * yv
    stats[r, 2] += sign * yv * a
    stats[r, 3] += sign * a * a
    stats[r, 4] += sign * yv * b
    stats[r, 5] += sign * a * b
    stats[r, 6] += sign * b * b


@njit(cache=True, nogil=True)
def shift_stats(y, C, log_cos_hn, order, use_order, starts, ends, labels, delta, gammas, stats, weight, ext=None):
    """Apply accepted element moves: relabel observations of lines j and move their terms between regions.

    ``stats`` (R, 7) is updated in place by ``weight`` (the likelihood power) times the
    terms of each moved observation, subtracted from its old region and added to its new
    one; ``labels`` is updated in place.
    """
    if ext is not None:
        _shift_stats_lobe(y, C, log_cos_hn, order, use_order, starts, ends, labels, delta, gammas, stats, weight, ext)
        return
    for j in range(starts.shape[0]):
        for p in range(starts[j], ends[j]):
            i = order[p] if use_order else p
            yv, c = np.float64(y[i]), np.float64(C[i])
            lh = np.float64(log_cos_hn[i])
            a = c * INV_PI
            r_old = np.int64(labels[i])
            r_new = r_old + delta[j]
            add_obs_terms(stats, r_old, -weight, yv, c, a, lh, gammas[r_old])
            add_obs_terms(stats, r_new, weight, yv, c, a, lh, gammas[r_new])
            labels[i] = r_new


@njit(cache=True, nogil=True)
def _shift_stats_lobe(y, C, log_cos_hn, order, use_order, starts, ends, labels, delta, gammas, stats, weight, ext):
    """:func:`shift_stats` with effects' lobe terms (each line's lobe columns first, :func:`_line_lobes`)."""
    rows = lobe_rows(ext, gammas)
    idx, old, new, b_old, b_new = _line_buffers(starts, ends)
    for j in range(starts.shape[0]):
        _line_lobes(log_cos_hn, order, use_order, starts[j], ends[j], labels, delta[j], gammas, ext, rows, idx, old,
                    new, b_old, b_new)
        for k in range(ends[j] - starts[j]):
            i = idx[k]
            yv = np.float64(y[i])
            a = np.float64(C[i]) * INV_PI
            add_lobe_terms(stats, old[k], -weight, yv, a, b_old[k])
            add_lobe_terms(stats, new[k], weight, yv, a, b_new[k])
            labels[i] = new[k]
