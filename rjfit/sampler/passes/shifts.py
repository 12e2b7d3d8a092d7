"""Element moves of change points: which observations change region, their density change, their statistics moved.

When one element of a line moves within its rank, the pixels between its old and new
position change side, so their observations' label moves by the vector's label step
(:func:`element_shift`); :func:`obs_log_density_delta` is the log-likelihood change of
those observations (the sweep's acceptance ratio), and :func:`shift_stats` relabels them
and moves their terms between the regions' statistics when the move is accepted. The
element sweeps and the vector redraw use them (:mod:`rjfit.sampler.moves.sweeps`,
:mod:`rjfit.sampler.moves.vector_redraw`).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from rjfit.sampler.passes.densities import coefficients, log_density
from rjfit.sampler.passes.special import INV_PI

__all__ = ["element_shift", "obs_log_density_delta", "add_obs_terms", "shift_stats"]


@njit(cache=True, nogil=True)
def element_shift(x_old, x_new, lines, size, offsets, step_label):
    """``(starts, ends, delta)`` of :func:`rjfit.sampler.moves.sweeps.element_shift` (compiled: NumPy took 47 us).

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
def obs_log_density_delta(y, C, log_cos_hn, order, use_order, starts, ends, labels, delta, theta):
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
def add_obs_terms(stats, r, sign, yv, c, a, lh, gamma):
    """Add ``sign`` times one observation's seven sufficient-statistic terms to region ``r``."""
    b = c * math.exp(gamma * lh)
    stats[r, 0] += sign
    stats[r, 1] += sign * yv * yv
    stats[r, 2] += sign * yv * a
    stats[r, 3] += sign * a * a
    stats[r, 4] += sign * yv * b
    stats[r, 5] += sign * a * b
    stats[r, 6] += sign * b * b


@njit(cache=True, nogil=True)
def shift_stats(y, C, log_cos_hn, order, use_order, starts, ends, labels, delta, gammas, stats, weight):
    """Apply accepted element moves: relabel observations of lines j and move their terms between regions.

    ``stats`` (R, 7) is updated in place by ``weight`` (the likelihood power) times the
    terms of each moved observation, subtracted from its old region and added to its new
    one; ``labels`` is updated in place.
    """
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
