"""Compiled loops (Numba) for the sampler's passes over observations.

Why a JIT: ``validation/bench_sampler.py --full`` showed the kernel spending its time in
NumPy passes that each make several float64 temporaries of up to N entries (upcast,
``exp``, products, ``bincount``), and in Python loops over lines (the vector redraw's
forward filter). Fused into one loop each, a pass reads the float32 arrays once and keeps
every temporary in registers. Each function here has a plain NumPy counterpart that stays
the test oracle (:func:`rjfit.sampler.likelihood.oracle_log_likelihood`,
:func:`rjfit.sampler.likelihood.region_stats_numpy`).

Every sum is accumulated in float64 in blocks of :data:`BLOCK` terms (a block's partial
sum is added to the total), so rounding error grows like ``BLOCK + n / BLOCK`` ulps, not n.
Compiled once per machine (``cache=True`` keeps the machine code beside this file).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["b_sums", "b_dots", "region_stats_labels", "obs_log_density_delta", "shift_stats", "per_pixel_two_cases",
           "forward_filter", "removal_sums", "cell_path_log_prob", "cell_backward_sample", "BLOCK"]

BLOCK = 512
LOG_2PI = math.log(2.0 * math.pi)
INV_PI = 1.0 / math.pi


@njit(cache=True, nogil=True, fastmath={"reassoc", "contract"})
def b_dots(y, C, power):
    """``(SyB, SAB / pi, SBB)`` sums (unscaled) with ``B = C * power``; ``power`` = <h.n>^gamma, float64.

    The power is computed by NumPy beforehand (:func:`b_sums`): its SIMD ``exp`` is about
    3.5 times faster than the scalar one a compiled loop calls.
    """
    yb = cb = bb = 0.0
    n = y.shape[0]
    for start in range(0, n, BLOCK):
        pyb = pcb = pbb = 0.0
        for i in range(start, min(start + BLOCK, n)):
            c = np.float64(C[i])
            b = c * power[i]
            pyb += np.float64(y[i]) * b
            pcb += c * b
            pbb += b * b
        yb += pyb
        cb += pcb
        bb += pbb
    return yb, cb * INV_PI, bb


def b_sums(y, C, log_cos_hn, gamma, chunk=1 << 16):
    """``(SyB, SAB, SBB)`` (unscaled, float64) of one region's gathered arrays at exponent ``gamma``."""
    total = np.zeros(3)
    buffer = np.empty(min(chunk, y.shape[0]))
    for start in range(0, y.shape[0], chunk):
        stop = min(start + chunk, y.shape[0])
        power = np.multiply(log_cos_hn[start:stop], gamma, out=buffer[:stop - start], dtype=np.float64)
        np.exp(power, out=power)
        total += b_dots(y[start:stop], C[start:stop], power)
    return total


@njit(cache=True, nogil=True)
def region_stats_labels(y, C, log_cos_hn, labels, gammas, n_regions):
    """Unscaled sufficient statistics (R, 7) of every region in one pass over all observations."""
    out = np.zeros((n_regions, 7))
    part = np.zeros((n_regions, 7))
    n = y.shape[0]
    for start in range(0, n, BLOCK):
        part[:] = 0.0
        for i in range(start, min(start + BLOCK, n)):
            r = labels[i]
            yv = np.float64(y[i])
            c = np.float64(C[i])
            a = c * INV_PI
            b = c * math.exp(gammas[r] * np.float64(log_cos_hn[i]))
            part[r, 0] += 1.0
            part[r, 1] += yv * yv
            part[r, 2] += yv * a
            part[r, 3] += a * a
            part[r, 4] += yv * b
            part[r, 5] += a * b
            part[r, 6] += b * b
        out += part
    return out


@njit(cache=True, nogil=True)
def _log_density(yv, c, lh, theta_r):
    """Gaussian log density of one observation under region parameters ``theta_r``; also returns B."""
    I0, kd, g, s2 = theta_r[0], theta_r[1], theta_r[2], theta_r[3]
    norm = (g + 2.0) * (g + 4.0) / (8.0 * math.pi * (2.0 ** (-g / 2.0) + g))
    b = c * math.exp(g * lh)
    resid = yv - I0 * kd * INV_PI * c - I0 * (1.0 - kd) * norm * b
    return -0.5 * (LOG_2PI + math.log(s2)) - 0.5 * resid * resid / s2, b


@njit(cache=True, nogil=True)
def obs_log_density_delta(y, C, log_cos_hn, order, use_order, starts, ends, labels, delta, theta):
    """Per line j: sum over observations ``p in [starts[j], ends[j])`` of log p(y | new) - log p(y | old).

    Observation ``i = order[p]`` if ``use_order`` (columns: ``colmajor_order``) else ``p``
    (rows: observations are stored row-major). The old region is ``labels[i]``, the new one
    ``labels[i] + delta[j]`` (an element move shifts every observation it passes by one
    region step).
    """
    n_lines = starts.shape[0]
    out = np.zeros(n_lines)
    for j in range(n_lines):
        total = 0.0
        for p in range(starts[j], ends[j]):
            i = order[p] if use_order else p
            yv, c, lh = np.float64(y[i]), np.float64(C[i]), np.float64(log_cos_hn[i])
            r = labels[i]
            ll_old, _ = _log_density(yv, c, lh, theta[r])
            ll_new, _ = _log_density(yv, c, lh, theta[r + delta[j]])
            total += ll_new - ll_old
        out[j] = total
    return out


@njit(cache=True, nogil=True)
def _add_terms(stats, r, sign, yv, c, a, lh, gamma):
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
            _add_terms(stats, r_old, -weight, yv, c, a, lh, gammas[r_old])
            _add_terms(stats, r_new, weight, yv, c, a, lh, gammas[r_new])
            labels[i] = r_new


@njit(cache=True, nogil=True)
def per_pixel_two_cases(y, C, log_cos_hn, line_of, along_of, labels, x_old, step_label, theta, size,
                        right_case, left_case):
    """Per-pixel log-likelihood sums with one vector's element right of the pixel and left of it.

    For observation ``i`` on line ``line_of[i]`` at ``along_of[i]``, the base
    region is its label minus ``step_label`` if the vector's current element ``x_old`` of
    its line lies left of it; ``right_case`` gets its log density in the base region and
    ``left_case`` in base + step_label (flat index ``line * size + along``; both
    accumulate).
    """
    for i in range(y.shape[0]):
        line = line_of[i]
        along = along_of[i]
        base = labels[i]
        if x_old[line] < along + 0.5:
            base -= step_label
        yv, c, lh = np.float64(y[i]), np.float64(C[i]), np.float64(log_cos_hn[i])
        ll_right, _ = _log_density(yv, c, lh, theta[base])
        ll_left, _ = _log_density(yv, c, lh, theta[base + step_label])
        key = line * size + along
        right_case[key] += ll_right
        left_case[key] += ll_left


@njit(cache=True, nogil=True)
def forward_filter(log_emit, kernel, reach_max):
    """Normalised forward log alphas (L, S) of the cell chain; ``ok`` False if a line has no finite cell.

    ``kernel[d + reach_max]`` is the linear weight of a step of d cells between lines
    (|d| <= reach_max, the step's weight beyond is below 1e-30 of its peak and left out:
    only the proposal changes, and the move computes its density from these same alphas
    both ways, so it stays exact). An empty kernel means independent lines.
    """
    n_lines, n_cells = log_emit.shape
    alpha = np.empty_like(log_emit)
    previous = np.zeros(n_cells)
    reach = np.zeros(n_cells)
    for r in range(n_lines):
        top = -np.inf
        for j in range(n_cells):
            a = log_emit[r, j]
            if r > 0 and kernel.shape[0] > 0:
                s = 0.0
                for d in range(max(-reach_max, j - n_cells + 1), min(reach_max, j) + 1):
                    s += previous[j - d] * kernel[d + reach_max]
                a += math.log(max(s, 1e-300))
            alpha[r, j] = a
            if a > top:
                top = a
        if not np.isfinite(top):
            return alpha, False
        total = 0.0
        for j in range(n_cells):
            reach[j] = math.exp(alpha[r, j] - top)
            total += reach[j]
        log_total = math.log(total)
        for j in range(n_cells):
            alpha[r, j] = alpha[r, j] - top - log_total
            previous[j] = reach[j] / total
    return alpha, True


@njit(cache=True, nogil=True)
def removal_sums(y, C, log_cos_hn, line_of, labels, theta, n, n_v, step, axis_u, sums):
    """Per (line, column) log-likelihood sums: as labelled, moved one column down, moved one column up.

    ``sums`` (3, L * (n + 1)) accumulates; column = the observation's region index along the
    axis (``label // (n_v + 1)`` for u, ``label % (n_v + 1)`` for v). See
    :func:`rjfit.sampler.moves._removal_log_emit`.
    """
    for i in range(y.shape[0]):
        lab = np.int64(labels[i])
        column = lab // (n_v + 1) if axis_u else lab % (n_v + 1)
        key = np.int64(line_of[i]) * (n + 1) + column
        yv, c, lh = np.float64(y[i]), np.float64(C[i]), np.float64(log_cos_hn[i])
        ll, _ = _log_density(yv, c, lh, theta[lab])
        sums[0, key] += ll
        if column > 0:
            ll_down, _ = _log_density(yv, c, lh, theta[lab - step])
        else:
            ll_down = ll
        sums[1, key] += ll_down
        if column < n:
            ll_up, _ = _log_density(yv, c, lh, theta[lab + step])
        else:
            ll_up = ll
        sums[2, key] += ll_up


@njit(cache=True, nogil=True)
def _step_logits(alpha, r, cell_next, log_kernel, out):
    n_cells = alpha.shape[1]
    top = -np.inf
    for j in range(n_cells):
        v = alpha[r, j]
        if log_kernel.shape[0] > 0:
            v += log_kernel[n_cells - 1 - cell_next + j]
        out[j] = v
        if v > top:
            top = v
    total = 0.0
    for j in range(n_cells):
        total += math.exp(out[j] - top)
    return top + math.log(total)


@njit(cache=True, nogil=True)
def cell_path_log_prob(alpha, path, log_kernel):
    """Log probability that backward sampling from ``alpha`` with step weights ``log_kernel`` draws ``path``.

    ``log_kernel`` (2 S + 1,) log weights of cell steps -S..S (empty: independent lines).
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
    """A cell path drawn backwards from ``alpha`` (last line first), one uniform per line."""
    n_lines, n_cells = alpha.shape
    logits = np.empty(n_cells)
    path = np.empty(n_lines, np.int64)
    for r in range(n_lines - 1, -1, -1):
        if r == n_lines - 1:
            for j in range(n_cells):
                logits[j] = alpha[r, j]
        else:
            _step_logits(alpha, r, path[r + 1], log_kernel, logits)
        top = -np.inf
        for j in range(n_cells):
            if logits[j] > top:
                top = logits[j]
        total = 0.0
        for j in range(n_cells):
            total += math.exp(logits[j] - top)
        target = uniforms[r] * total
        running = 0.0
        chosen = n_cells - 1
        for j in range(n_cells):
            running += math.exp(logits[j] - top)
            if running > target:
                chosen = j
                break
        path[r] = chosen
    return path
