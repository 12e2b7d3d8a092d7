"""Compiled loops (Numba) for the sampler's passes over observations.

Why a JIT: profiling the full kernel (``validation/bench_sampler.py``'s segmentation-sampled
row, 256 x 256 chains) showed it spending its time in
NumPy passes that each make several float64 temporaries of up to N entries (upcast,
``exp``, products, ``bincount``), and in Python loops over lines (the vector redraw's
forward filter). Fused into one loop each, a pass reads the float32 arrays once and keeps
every temporary in registers.

What makes a loop fast here (measured; ``tests/test_jit.py`` checks each against NumPy):
the exponentials use :func:`fast_exp`, plain arithmetic that vectorises, where libm's scalar
``exp`` costs about 5 ns; a loop vectorises only without gathers (per-observation lookups by
label: those go to a scalar phase per block, then the densities over each run of one
region in a vectorised phase, then a scalar scatter; a region's passes run over its runs of
consecutive observations, see :func:`rjfit.sampler.likelihood.label_runs`, so they need no
lookup at all), when it indexes views from 0 (``y[start + k]`` inside the loop left the
gamma-move sums scalar and 3 times slower) and when its accumulators fit in the vector
registers (nine in one loop made the gamma-move sums 1.7 times slower than three loops of
three). Each function here has a plain NumPy counterpart that stays the test oracle
(:func:`rjfit.sampler.likelihood.oracle_log_likelihood`,
:func:`rjfit.sampler.likelihood.region_stats_numpy`).

Every sum is accumulated in float64 in blocks of :data:`BLOCK` terms (a block's partial
sum is added to the total), so rounding error grows like ``BLOCK + n / BLOCK`` ulps, not n.
Compiled once per machine (``cache=True`` keeps the machine code beside this file).

Threads within one chain: the passes that dominate an iteration (:func:`b_sums`,
:func:`b_sums_newton`, :func:`per_pixel_two_cases`) cut a pass of at least
:data:`PARALLEL_MIN_OBS` observations into :data:`PARTS` pieces of near-equal size and add
the pieces' sums in order; the pieces run on the chain's Numba threads
(``numba.set_num_threads``, set by :func:`rjfit.sampler.runner.run_chain`). The pieces do
not depend on the number of threads, so neither does any sum, to the last bit: a chain
gives the same samples on one thread or eight. Smaller passes run whole, as before,
because starting threads (a few microseconds) would cost more than they save.
"""
from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import njit, prange, types
from numba.extending import intrinsic

__all__ = ["fast_exp", "b_sums", "b_sums_many", "b_sums_newton", "fixed_sums", "run_indices", "region_stats_runs", "obs_log_density_delta", "element_shift", "shift_stats", "per_pixel_two_cases", "cell_log_lik",
           "forward_filter", "removal_sums", "rank_forward", "rank_path_log_prob", "rank_backward_sample", "cell_path_log_prob", "cell_backward_sample", "sweep_proposal",
           "ndtr", "ndtri", "within_cells_draw", "within_cells_log_density", "split_runs", "pixel_cuts", "BLOCK", "PARTS",
           "PARALLEL_MIN_OBS"]

BLOCK = 512
PARTS = 8                 # pieces of a parallel pass: fixed, so that its sums do not depend on the threads
PARALLEL_MIN_OBS = 32768  # below this a pass runs whole (about 45 us; threads would save less than they cost)
LOG_2PI = math.log(2.0 * math.pi)
INV_PI = 1.0 / math.pi


@intrinsic
def _float64_from_bits(typingctx, bits):
    """The float64 whose IEEE bits are the int64 ``bits`` (an LLVM bitcast, no memory round trip)."""
    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.DoubleType())
    return types.float64(types.int64), codegen


_LOG2_E = 1.4426950408889634
_LN2_HI = 6.93147180369123816490e-01     # ln 2 split so that k * _LN2_HI is exact (Cody-Waite)
_LN2_LO = 1.90821492927058770002e-10


@njit(inline="always", fastmath={"contract"})
def fast_exp(x):
    """``e^x`` within 1 ulp of NumPy's (0 below ``e^-708``, where NumPy's is subnormal or 0).

    Why not ``math.exp``: a compiled loop calls libm's scalar ``exp`` (about 5 ns), while this
    is plain arithmetic that the compiler vectorises with the loop around it (about 0.5 ns):
    ``x = k ln 2 + r`` with |r| <= ln 2 / 2, ``e^r`` by its Taylor polynomial of degree 13
    (truncation error below 1e-17), ``2^k`` written into the exponent bits. Measured against
    ``np.exp`` on 300,000 arguments in [-750, 0]: at most 1 ulp apart, 92 % equal.
    """
    clamped = min(max(x, -708.0), 709.0)
    k = np.floor(clamped * _LOG2_E + 0.5)
    r = (clamped - k * _LN2_HI) - k * _LN2_LO
    p = 1.0 / 6227020800.0
    p = p * r + 1.0 / 479001600.0
    p = p * r + 1.0 / 39916800.0
    p = p * r + 1.0 / 3628800.0
    p = p * r + 1.0 / 362880.0
    p = p * r + 1.0 / 40320.0
    p = p * r + 1.0 / 5040.0
    p = p * r + 1.0 / 720.0
    p = p * r + 1.0 / 120.0
    p = p * r + 1.0 / 24.0
    p = p * r + 1.0 / 6.0
    p = p * r + 0.5
    p = p * r + 1.0
    p = p * r + 1.0
    value = p * _float64_from_bits((np.int64(k) + 1023) << 52)
    return value if x >= -708.0 else 0.0


@njit(cache=True, nogil=True, fastmath={"reassoc", "contract"})
def _b_sums_range(y, C, log_cos_hn, lo, hi, gamma):
    """Unscaled ``(SyB, SCB, SBB)`` of observations ``lo .. hi - 1`` (see :func:`b_sums`)."""
    yb = cb = bb = 0.0
    for start in range(lo, hi, BLOCK):
        # views indexed from 0: no negative-index wraparound in the loop, which then vectorises
        # (indexing y[start + k] instead makes this pass 3 times slower)
        m = min(BLOCK, hi - start)
        ys, cs, ls = y[start:start + m], C[start:start + m], log_cos_hn[start:start + m]
        pyb = pcb = pbb = 0.0
        for k in range(m):
            c = np.float64(cs[k])
            b = c * fast_exp(gamma * np.float64(ls[k]))
            pyb += np.float64(ys[k]) * b
            pcb += c * b
            pbb += b * b
        yb += pyb
        cb += pcb
        bb += pbb
    return yb, cb, bb


@njit(cache=True, nogil=True)
def split_runs(starts, ends):
    """The runs ``[starts[k], ends[k])`` cut into :data:`PARTS` pieces of near-equal observation counts.

    Returns ``(piece_starts, piece_ends, offsets)``: part p is the runs
    ``offsets[p] .. offsets[p + 1] - 1`` of the pieces (a run is cut where a part ends). With
    fewer than :data:`PARALLEL_MIN_OBS` observations, one part: the runs themselves.
    """
    total = 0
    for k in range(starts.shape[0]):
        total += ends[k] - starts[k]
    if total < PARALLEL_MIN_OBS:
        offsets = np.zeros(2, np.int64)
        offsets[1] = starts.shape[0]
        return starts, ends, offsets
    piece_starts = np.empty(starts.shape[0] + PARTS, np.int64)
    piece_ends = np.empty(starts.shape[0] + PARTS, np.int64)
    offsets = np.zeros(PARTS + 1, np.int64)
    part = 0
    cut = total // PARTS          # observations before the end of the current part
    seen = j = 0
    for k in range(starts.shape[0]):
        lo = starts[k]
        while lo < ends[k]:
            take = min(ends[k] - lo, cut - seen)
            if take > 0:
                piece_starts[j], piece_ends[j] = lo, lo + take
                j += 1
                lo += take
                seen += take
            if seen == cut and part < PARTS - 1:
                part += 1
                offsets[part] = j
                cut = total * (part + 1) // PARTS
    offsets[PARTS] = j
    return piece_starts[:j], piece_ends[:j], offsets


@njit(cache=True, nogil=True)
def b_sums(y, C, log_cos_hn, starts, ends, gamma):
    """``(SyB, SAB, SBB)`` (unscaled, float64) of the observations in the runs ``[starts[k], ends[k])``.

    ``B = C <h.n>^gamma`` with the power from :func:`fast_exp`, fused with the sums: one
    vectorised pass per run that reads the float32 arrays once; in :data:`PARTS` pieces on
    the chain's threads when the runs hold :data:`PARALLEL_MIN_OBS` observations or more.
    """
    out = _gamma_sums(y, C, log_cos_hn, starts, ends, gamma, False)
    out[1] *= INV_PI
    return out


@njit(cache=True, nogil=True)
def b_sums_many(y, C, log_cos_hn, starts, ends, gammas):
    """:func:`b_sums` at each of ``gammas``: (G, 3)."""
    out = np.empty((gammas.shape[0], 3))
    for q in range(gammas.shape[0]):
        out[q] = b_sums(y, C, log_cos_hn, starts, ends, gammas[q])
    return out


@njit(inline="always", fastmath={"reassoc", "contract"})
def _log_moments(first, second, log_cos_hn):
    """``(sum w, sum w lh, sum w lh^2)`` with ``w = first * second`` and ``lh = log <h.n>``, float64."""
    s0 = s1 = s2 = 0.0      # scalar accumulators (not an array) so the loop vectorises
    for k in range(second.shape[0]):
        lh = np.float64(log_cos_hn[k])
        w = np.float64(first[k]) * second[k]
        s0 += w
        w *= lh
        s1 += w
        s2 += w * lh
    return s0, s1, s2


@njit(cache=True, nogil=True, fastmath={"reassoc", "contract"})
def _b_sums_newton_range(y, C, log_cos_hn, lo, hi, gamma, out, powers):
    """Add the nine unscaled sums of :func:`b_sums_newton` of observations ``lo .. hi - 1`` to ``out``.

    Per block: the B terms into ``powers`` (one vectorised loop with the exps), then one
    loop per weight (yB, CB, BB) with its three sums. Nine accumulators in one loop spill
    out of the 16 vector registers: this takes the pass from 2.4 to 1.4 ns per observation.
    """
    for start in range(lo, hi, BLOCK):
        m = min(BLOCK, hi - start)
        ys, cs, ls = y[start:start + m], C[start:start + m], log_cos_hn[start:start + m]   # as in b_sums
        bs = powers[:m]
        for k in range(m):
            bs[k] = np.float64(cs[k]) * fast_exp(gamma * np.float64(ls[k]))
        yb, yb1, yb2 = _log_moments(ys, bs, ls)
        cb, cb1, cb2 = _log_moments(cs, bs, ls)
        bb, bb1, bb2 = _log_moments(bs, bs, ls)
        out[0] += yb
        out[1] += cb * INV_PI
        out[2] += bb
        out[3] += yb1
        out[4] += cb1 * INV_PI
        out[5] += bb1
        out[6] += yb2
        out[7] += cb2 * INV_PI
        out[8] += bb2


@njit(cache=True, nogil=True)
def _gamma_sums_part(y, C, log_cos_hn, starts, ends, first, last, gamma, newton, out):
    """Add runs ``first .. last - 1``'s sums to ``out``: :func:`b_sums`' three (unscaled) or, with ``newton``, nine."""
    if newton:
        powers = np.empty(BLOCK)
        for k in range(first, last):
            _b_sums_newton_range(y, C, log_cos_hn, starts[k], ends[k], gamma, out, powers)
    else:
        for k in range(first, last):
            a, b, c = _b_sums_range(y, C, log_cos_hn, starts[k], ends[k], gamma)
            out[0] += a
            out[1] += b
            out[2] += c


@njit(cache=True, nogil=True, parallel=True)
def _gamma_sums_parts(y, C, log_cos_hn, starts, ends, offsets, gamma, newton, part_sums):
    # only the prange loop: Numba would run any array expression here as a parallel loop too
    for p in prange(offsets.shape[0] - 1):
        _gamma_sums_part(y, C, log_cos_hn, starts, ends, offsets[p], offsets[p + 1], gamma, newton, part_sums[p])


@njit(cache=True, nogil=True)
def _gamma_sums(y, C, log_cos_hn, starts, ends, gamma, newton):
    """:func:`_gamma_sums_part` over all the runs, in :func:`split_runs`' pieces, the pieces added in order."""
    piece_starts, piece_ends, offsets = split_runs(starts, ends)
    parts = offsets.shape[0] - 1
    part_sums = np.zeros((parts, 9 if newton else 3))
    if parts == 1:
        _gamma_sums_part(y, C, log_cos_hn, starts, ends, 0, starts.shape[0], gamma, newton, part_sums[0])
    else:
        _gamma_sums_parts(y, C, log_cos_hn, piece_starts, piece_ends, offsets, gamma, newton, part_sums)
    out = np.zeros(part_sums.shape[1])
    for p in range(parts):
        out += part_sums[p]
    return out


@njit(cache=True, nogil=True)
def b_sums_newton(y, C, log_cos_hn, starts, ends, gamma):
    """:func:`b_sums` plus the same three sums weighted by ``log <h.n>`` and by its square (9 values).

    ``d B / d gamma = B log <h.n>``: these are the first and second gamma-derivatives of
    ``(SyB, SAB, SBB / 2)``, for the Newton proposal of the gamma move. In pieces on the
    chain's threads as :func:`b_sums`.
    """
    return _gamma_sums(y, C, log_cos_hn, starts, ends, gamma, True)


@njit(cache=True, nogil=True)
def fixed_sums(y, C, starts, ends):
    """Unscaled ``(Syy, SyC, SCC)`` of the observations in the runs, float64 (blocked like :func:`b_sums`)."""
    yy = yc = cc = 0.0
    for k in range(starts.shape[0]):
        for start in range(starts[k], ends[k], BLOCK):
            m = min(BLOCK, ends[k] - start)
            ys, cs = y[start:start + m], C[start:start + m]
            pyy = pyc = pcc = 0.0
            for j in range(m):
                yv, c = np.float64(ys[j]), np.float64(cs[j])
                pyy += yv * yv
                pyc += yv * c
                pcc += c * c
            yy += pyy
            yc += pyc
            cc += pcc
    return yy, yc, cc


@njit(cache=True, nogil=True)
def run_indices(starts, ends, every=1):
    """Every ``every``-th of the indices ``[starts[0], ends[0]) + [starts[1], ends[1]) + ...``, int64."""
    total = 0
    for k in range(starts.shape[0]):
        total += ends[k] - starts[k]
    out = np.empty((total + every - 1) // every, np.int64)
    p = q = 0
    for k in range(starts.shape[0]):
        # the first index of this run that is a multiple of `every` along the concatenation
        i = starts[k] + (-q) % every
        while i < ends[k]:
            out[p] = i
            p += 1
            i += every
        q += ends[k] - starts[k]
    return out


@njit(cache=True, nogil=True)
def _add_terms(stats, r, sign, yv, c, a, lh, gamma):
    """Add ``sign`` times one observation's seven sufficient-statistic terms to region ``r``."""
    b = c * math.exp(gamma * lh)
    stats[r, 0] += sign
    stats[r, 1] += sign * yv * yv
    stats[r, 2] += sign * yv * a
    stats[r, 3] += sign * a * a
    stats[r, 4] += sign * yv * b
    stats[r, 5] += sign * a * b
    stats[r, 6] += sign * b * b


@njit(cache=True, nogil=True, fastmath={"reassoc", "contract"})
def _stats_range(y, C, log_cos_hn, lo, hi, gamma):
    """Unscaled ``(Syy, SyC, SCC, SyB, SCB, SBB)`` of observations ``lo .. hi - 1`` at exponent ``gamma``."""
    yy = yc = cc = yb = cb = bb = 0.0
    for start in range(lo, hi, BLOCK):
        m = min(BLOCK, hi - start)
        ys, cs, ls = y[start:start + m], C[start:start + m], log_cos_hn[start:start + m]   # as in b_sums
        pyy = pyc = pcc = pyb = pcb = pbb = 0.0
        for k in range(m):
            yv, c = np.float64(ys[k]), np.float64(cs[k])
            b = c * fast_exp(gamma * np.float64(ls[k]))
            pyy += yv * yv
            pyc += yv * c
            pcc += c * c
            pyb += yv * b
            pcb += c * b
            pbb += b * b
        yy += pyy
        yc += pyc
        cc += pcc
        yb += pyb
        cb += pcb
        bb += pbb
    return yy, yc, cc, yb, cb, bb


@njit(cache=True, nogil=True)
def region_stats_runs(y, C, log_cos_hn, offsets, starts, ends, gammas):
    """Unscaled sufficient statistics (R, 7) of every region from its runs (:func:`rjfit.sampler.likelihood.label_runs`).

    Each run is one vectorised pass that reads the problem's arrays in place; region r's
    runs ``offsets[r] .. offsets[r + 1] - 1`` are summed at its exponent ``gammas[r]``.
    """
    n_regions = offsets.shape[0] - 1
    out = np.zeros((n_regions, 7))
    for r in range(n_regions):
        for k in range(offsets[r], offsets[r + 1]):
            yy, yc, cc, yb, cb, bb = _stats_range(y, C, log_cos_hn, starts[k], ends[k], gammas[r])
            out[r, 0] += ends[k] - starts[k]
            out[r, 1] += yy
            out[r, 2] += yc
            out[r, 3] += cc
            out[r, 4] += yb
            out[r, 5] += cb
            out[r, 6] += bb
        out[r, 2] *= INV_PI
        out[r, 3] *= INV_PI * INV_PI
        out[r, 5] *= INV_PI
    return out


@njit(cache=True, nogil=True)
def coefficients(theta):
    """Per-region constants of the log density, (R, 5): ``a / pi, b, gamma, log-normaliser, 1 / (2 sigma^2)``.

    Computed once per call of a pass, so the per-observation work is one ``exp``.
    """
    out = np.empty((theta.shape[0], 5))
    for r in range(theta.shape[0]):
        I0, kd, g, s2 = theta[r, 0], theta[r, 1], theta[r, 2], theta[r, 3]
        # Giesen's normalisation, as rjfit.model.blinn.blinn_normalisation (not callable from Numba)
        norm = (g + 2.0) * (g + 4.0) / (8.0 * math.pi * (2.0 ** (-g / 2.0) + g))
        out[r, 0] = I0 * kd * INV_PI
        out[r, 1] = I0 * (1.0 - kd) * norm
        out[r, 2] = g
        out[r, 3] = -0.5 * (LOG_2PI + math.log(s2))
        out[r, 4] = 0.5 / s2
    return out


@njit(cache=True, nogil=True)
def _log_density(yv, c, lh, coef, r):
    """Gaussian log density of one observation in region ``r`` (``coef`` from :func:`coefficients`)."""
    resid = yv - coef[r, 0] * c - coef[r, 1] * c * math.exp(coef[r, 2] * lh)
    return coef[r, 3] - coef[r, 4] * resid * resid


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
            total += _log_density(yv, c, lh, coef, r + delta[j]) - _log_density(yv, c, lh, coef, r)
        out[j] = total
    return out


@njit(cache=True, nogil=True)
def element_shift(x_old, x_new, lines, size, offsets, step_label):
    """``(starts, ends, delta)`` of :func:`rjfit.sampler.moves._element_shift`, compiled (a sweep's numpy took 47 us).

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


@njit(inline="always")
def _run_end(values, lo, m):
    """End of the run of equal values that starts at ``lo``: ``values[lo:hi]`` all equal, ``hi <= m``."""
    hi = lo + 1
    while hi < m and values[hi] == values[lo]:
        hi += 1
    return hi


@njit(cache=True, nogil=True, fastmath={"contract"})
def _log_densities_into(y, C, log_cos_hn, coef, r, out):
    """``out[k]``: the log density of observation k in region ``r`` (one region: no gather, so it vectorises)."""
    ca, cb, g, c0, c1 = coef[r, 0], coef[r, 1], coef[r, 2], coef[r, 3], coef[r, 4]
    for k in range(out.shape[0]):
        c = np.float64(C[k])
        resid = np.float64(y[k]) - ca * c - cb * c * fast_exp(g * np.float64(log_cos_hn[k]))
        out[k] = c0 - c1 * resid * resid


@njit(cache=True, nogil=True)
def _per_pixel_range(y, C, log_cos_hn, line_of, along_of, labels, x_old, step_label, coef, size,
                     right_case, left_case, lo, hi):
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
            last = _run_end(base_of, first, m)
            _log_densities_into(ys[first:last], cs[first:last], ls[first:last], coef, base, right_density[first:last])
            _log_densities_into(ys[first:last], cs[first:last], ls[first:last], coef, base + step_label,
                                left_density[first:last])
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
                     right_case, left_case, bounds):
    # parts start at a pixel's first observation, so no two parts write the same entry
    for p in prange(bounds.shape[0] - 1):
        _per_pixel_range(y, C, log_cos_hn, line_of, along_of, labels, x_old, step_label, coef, size,
                         right_case, left_case, bounds[p], bounds[p + 1])


@njit(cache=True, nogil=True)
def per_pixel_two_cases(y, C, log_cos_hn, line_of, along_of, labels, x_old, step_label, theta, size,
                        right_case, left_case):
    """Per-pixel log-likelihood sums with one vector's element right of the pixel and left of it.

    For observation ``i`` on line ``line_of[i]`` at ``along_of[i]``, the base
    region is its label minus ``step_label`` if the vector's current element ``x_old`` of
    its line lies left of it; ``right_case`` gets its log density in the base region and
    ``left_case`` in base + step_label (flat index ``line * size + along``; both
    accumulate).

    Three phases per block of observations: base regions and pixel keys (scalar); the
    densities over each run of one base region (:func:`_log_densities_into`, vectorised: the
    exps are most of the work, and observations sorted by pixel make the runs long); the
    sums per pixel and their scatter (scalar). With :data:`PARALLEL_MIN_OBS` observations or
    more, in :data:`PARTS` pieces on the chain's threads, each cut at a pixel's first
    observation.
    """
    coef = coefficients(theta)
    n = y.shape[0]
    if n < PARALLEL_MIN_OBS:
        _per_pixel_range(y, C, log_cos_hn, line_of, along_of, labels, x_old, step_label, coef, size,
                         right_case, left_case, 0, n)
        return
    _per_pixel_parts(y, C, log_cos_hn, line_of, along_of, labels, x_old, step_label, coef, size,
                     right_case, left_case, pixel_cuts(line_of, along_of))


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
def removal_sums(y, C, log_cos_hn, line_of, labels, theta, n, n_v, step, axis_u, sums):
    """Per (line, column) log-likelihood sums: as labelled, moved one column down, moved one column up.

    ``sums`` (3, L * (n + 1)) accumulates; column = the observation's region index along the
    axis (``label // (n_v + 1)`` for u, ``label % (n_v + 1)`` for v). See
    :func:`rjfit.sampler.moves._removal_log_emit`. Phased per block like
    :func:`per_pixel_two_cases` (the densities over runs of one label, vectorised).
    """
    coef = coefficients(theta)
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
            hi = _run_end(labels_of, lo, m)
            column = column_of[lab]
            # as labelled, moved one column down, moved one column up; at the edges a move keeps
            # the observations where they are, so their densities are copied, not recomputed
            _log_densities_into(ys[lo:hi], cs[lo:hi], ls[lo:hi], coef, lab, density[0, lo:hi])
            if column > 0:
                _log_densities_into(ys[lo:hi], cs[lo:hi], ls[lo:hi], coef, lab - step, density[1, lo:hi])
            else:
                density[1, lo:hi] = density[0, lo:hi]
            if column < n:
                _log_densities_into(ys[lo:hi], cs[lo:hi], ls[lo:hi], coef, lab + step, density[2, lo:hi])
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

    Line r's draw looks only at the cells within the kernel's reach of line r + 1's cell.
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
def _log_sum_exp(values):
    top = -np.inf
    for v in values:
        if v > top:
            top = v
    if not np.isfinite(top):
        return top
    total = 0.0
    for v in values:
        total += math.exp(v - top)
    return top + math.log(total)


@njit(cache=True, nogil=True)
def rank_forward(log_emit, log_t):
    """Normalised forward log alphas (L, n) of the chain of removed ranks with log transitions ``log_t[from, to]``.

    The compiled twin of :func:`rjfit.sampler.moves._rank_chain`'s forward pass.
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
                a += _log_sum_exp(terms)
            alpha[r, j] = a
        norm = _log_sum_exp(alpha[r])
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
        total += logits[path[r]] - _log_sum_exp(logits)
    return total


@njit(cache=True, nogil=True)
def rank_backward_sample(alpha, log_t, uniforms):
    """A path of ranks drawn backwards from ``alpha``, last line first with ``uniforms[0]``.

    Each line's draw is the first rank whose cumulative weight exceeds ``u`` times the total,
    as ``moves._draw_index`` (its reference) does with ``np.searchsorted(..., side='right')``.
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
def _log_normal(x, mean, sd):
    d = (x - mean) / sd
    return -0.5 * d * d - math.log(sd) - 0.5 * LOG_2PI


@njit(cache=True, nogil=True)
def _logaddexp(a, b):
    if a == -np.inf:
        return b
    if b == -np.inf:
        return a
    top = max(a, b)
    return top + math.log(math.exp(a - top) + math.exp(b - top))


@njit(cache=True, nogil=True)
def _element_log_q(x_to, x_from, nb_up, nb_down, size, p_unif, p_nb, step, nb_sd):
    """Log density of proposing element position ``x_to`` from ``x_from`` (NaN marks a missing neighbour).

    Mixture of a uniform redraw over [-1, size + 1], a normal random walk (sd ``step``) and a
    normal (sd ``nb_sd``) around the same-rank element of a neighbouring line, chosen
    uniformly among the existing neighbours.
    """
    p_rw = 1.0 - p_unif - p_nb
    out = -np.inf
    if p_unif > 0:
        out = math.log(p_unif) - math.log(size + 2.0)
    if p_rw > 0:
        out = _logaddexp(out, math.log(p_rw) + _log_normal(x_to, x_from, step))
    if p_nb > 0:
        dens, n_have = 0.0, 0
        for nb in (nb_up, nb_down):
            if np.isfinite(nb):
                dens += math.exp(_log_normal(x_to, nb, nb_sd))
                n_have += 1
        if n_have > 0 and dens > 0:
            out = _logaddexp(out, math.log(p_nb) + math.log(dens / n_have))
    return out


@njit(cache=True, nogil=True)
def _smooth_terms(row, cps, neighbour, sd):
    """Sum over ranks of log N(row[k] - cps[neighbour, k]; 0, sd); 0 without that neighbour."""
    if neighbour < 0:
        return 0.0
    total = 0.0
    for k in range(row.shape[0]):
        total += _log_normal(row[k], cps[neighbour, k], sd)
    return total


@njit(cache=True, nogil=True)
def sweep_proposal(cps, lines, k, kind, z, pick_up, unif, size, p_unif, p_nb, step, nb_sd, smooth_sd):
    """Element proposals of one sweep: ``(x_new, inside, log_q_ratio)`` per moved line.

    Compiled twin of the proposal half of :func:`rjfit.sampler.moves.sweep_changepoints`
    (same random inputs, same mixture; ``smooth_sd`` <= 0 for the 'paper' prior, whose
    terms cancel): element ``k[j]`` of line ``lines[j]`` is redrawn uniformly
    (``kind < p_unif``), around a neighbouring line's same-rank element (``kind < p_unif +
    p_nb``; the upper one if ``pick_up`` and it exists) or by a random walk; the ratio holds
    the reverse and forward proposal densities and the smooth prior's terms of the line.
    """
    n_all, n_cp = cps.shape
    n_lines = lines.shape[0]
    x_new = np.empty(n_lines)
    inside = np.empty(n_lines, np.bool_)
    log_q_ratio = np.empty(n_lines)
    row_old = np.empty(n_cp)
    row_new = np.empty(n_cp)
    for j in range(n_lines):
        line = lines[j]
        up = line - 1 if line > 0 else -1
        down = line + 1 if line < n_all - 1 else -1
        x_old = cps[line, k[j]]
        nb_up = cps[up, k[j]] if up >= 0 else np.nan
        nb_down = cps[down, k[j]] if down >= 0 else np.nan
        centre = nb_up if pick_up[j] else nb_down
        if not np.isfinite(centre):
            centre = nb_down if pick_up[j] else nb_up
        if kind[j] < p_unif:
            x = unif[j]
        elif kind[j] < p_unif + p_nb and np.isfinite(centre):
            x = centre + nb_sd * z[j]
        else:
            x = x_old + step * z[j]
        inside[j] = -1.0 <= x <= size + 1.0
        if not inside[j]:
            x = x_old
        x_new[j] = x
        # rank of the moved element after the move (the reverse move picks that rank)
        k_new = 0
        for m in range(n_cp):
            if cps[line, m] < x:
                k_new += 1
        if x_old < x:
            k_new -= 1
        back_up = cps[up, k_new] if up >= 0 else np.nan
        back_down = cps[down, k_new] if down >= 0 else np.nan
        ratio = (_element_log_q(x_old, x, back_up, back_down, size, p_unif, p_nb, step, nb_sd)
                 - _element_log_q(x, x_old, nb_up, nb_down, size, p_unif, p_nb, step, nb_sd))
        if smooth_sd > 0:
            for m in range(n_cp):
                row_old[m] = cps[line, m]
                row_new[m] = cps[line, m]
            row_new[k[j]] = x
            row_new.sort()
            ratio += (_smooth_terms(row_new, cps, up, smooth_sd) + _smooth_terms(row_new, cps, down, smooth_sd)
                      - _smooth_terms(row_old, cps, up, smooth_sd) - _smooth_terms(row_old, cps, down, smooth_sd))
        log_q_ratio[j] = ratio
    return x_new, inside, log_q_ratio


# ----------------------------------------------------------------------------- truncated normal steps

# Acklam's rational approximation of the normal quantile (relative error < 1.2e-9), refined
# below by one Halley step on ndtr to full double precision.
_Q_A = (-3.969683028665376e+01, 2.209460984245205e+02, -2.759285104469687e+02, 1.383577518672690e+02,
        -3.066479806614716e+01, 2.506628277459239e+00)
_Q_B = (-5.447609879822406e+01, 1.615858368580409e+02, -1.556989798598866e+02, 6.680131188771972e+01,
        -1.328068155288572e+01)
_Q_C = (-7.784894002430293e-03, -3.223964580411365e-01, -2.400758277161838e+00, -2.549732539343734e+00,
        4.374664141464968e+00, 2.938163982698783e+00)
_Q_D = (7.784695709041462e-03, 3.224671290700398e-01, 2.445134137142996e+00, 3.754408661907416e+00)
_SQRT_HALF = math.sqrt(0.5)
_SQRT_2PI = math.sqrt(2.0 * math.pi)


@njit(cache=True, nogil=True)
def ndtr(x):
    """Standard normal CDF (as :func:`scipy.special.ndtr`)."""
    return 0.5 * math.erfc(-x * _SQRT_HALF)


@njit(cache=True, nogil=True)
def _ndtri_lower(p):
    q = math.sqrt(-2.0 * math.log(p))
    c, d = _Q_C, _Q_D
    return ((((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5])
            / ((((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1.0))


@njit(cache=True, nogil=True)
def ndtri(p):
    """Standard normal quantile (as :func:`scipy.special.ndtri`): -inf at 0, inf at 1."""
    if p <= 0.0:
        return -np.inf
    if p >= 1.0:
        return np.inf
    if p < 0.02425:
        x = _ndtri_lower(p)
    elif p > 1.0 - 0.02425:
        x = -_ndtri_lower(1.0 - p)
    else:
        q = p - 0.5
        r = q * q
        a, b = _Q_A, _Q_B
        x = ((((((a[0] * r + a[1]) * r + a[2]) * r + a[3]) * r + a[4]) * r + a[5]) * q
             / (((((b[0] * r + b[1]) * r + b[2]) * r + b[3]) * r + b[4]) * r + 1.0))
    # one Halley step on ndtr(x) = p; in the upper half through the complement, so that
    # the step sees 1 - p's own rounding and not that of ndtr near 1
    if x > 0.0:
        e = 0.5 * math.erfc(x * _SQRT_HALF) - (1.0 - p)
        u = -e * _SQRT_2PI * math.exp(0.5 * x * x)
    else:
        e = ndtr(x) - p
        u = e * _SQRT_2PI * math.exp(0.5 * x * x)
    if math.isfinite(u):
        x = x - u / (1.0 + 0.5 * x * u)
    return x


@njit(cache=True, nogil=True)
def _truncated_mass(a, b):
    # P(a < Z < b); both ends in the upper tail: the mirrored lower tail keeps its digits
    if a > 0.0:
        return ndtr(-a) - ndtr(-b)
    return ndtr(b) - ndtr(a)


@njit(cache=True, nogil=True)
def within_cells_draw(lo, hi, sd, uniforms):
    """Compiled twin of :func:`rjfit.sampler.moves._draw_within_cells`; ``sd`` <= 0: no step model.

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
            if _truncated_mass(a, b) > 1e-12:
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
    """Compiled twin of :func:`rjfit.sampler.moves._within_cell_log_density` (summed; next line = x[r + 1])."""
    n_lines = x.shape[0]
    total = 0.0
    for r in range(n_lines):
        uniform = -math.log(hi[r] - lo[r])
        if sd > 0.0 and r < n_lines - 1:
            a, b = (lo[r] - x[r + 1]) / sd, (hi[r] - x[r + 1]) / sd
            mass = _truncated_mass(a, b)
            if mass > 1e-12:
                d = (x[r] - x[r + 1]) / sd
                total += -0.5 * d * d - math.log(sd) - 0.5 * LOG_2PI - math.log(mass)
                continue
        total += uniform
    return total
