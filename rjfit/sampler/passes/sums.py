"""Sufficient statistics of regions: the B sums at any gamma (with their gamma-derivatives) and the fixed sums.

A region's observations are runs ``[starts[k], ends[k])`` of the problem's arrays
(:func:`rjfit.sampler.likelihood.label_runs`), so each pass reads the float32 arrays in
place, with no per-observation lookup. Every sum is accumulated in float64 in blocks of
:data:`BLOCK` terms (a block's partial sum is added to the total), so rounding error grows
like ``BLOCK + n / BLOCK`` ulps, not n.

Threads within one chain: :func:`b_sums` and :func:`b_sums_newton` cut a pass of at least
:data:`PARALLEL_MIN_OBS` observations into :data:`PARTS` pieces of near-equal size
(:func:`split_runs`) and add the pieces' sums in order; the pieces run on the chain's
Numba threads. The pieces do not depend on the number of threads, so neither does any
sum, to the last bit. The NumPy reference of the statistics is
:func:`rjfit.sampler.reference.region_stats_numpy`.

Every pass takes the problem's lobe terms ``ext`` last (:mod:`rjfit.sampler.passes.lobe`):
None for the plain model, whose code the branches on it leave as it was (pruned at compile
time); a :class:`~rjfit.sampler.passes.lobe.LobeTerms` for a problem with effects.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from rjfit.sampler.passes.lobe import lobe_fill, lobe_row, lobe_rows
from rjfit.sampler.passes.special import INV_PI, fast_exp

__all__ = ["BLOCK", "PARTS", "PARALLEL_MIN_OBS", "split_runs", "b_sums", "b_sums_many", "b_sums_newton", "fixed_sums",
           "run_indices", "region_stats_runs"]


BLOCK = 512


PARTS = 8                 # pieces of a parallel pass: fixed, so that its sums do not depend on the threads


PARALLEL_MIN_OBS = 32768  # below this a pass runs whole (about 45 us; threads would save less than they cost)


@njit(cache=True, nogil=True, fastmath={"reassoc", "contract"})
def _b_sums_range_lobe(y, C, log_cos_hn, lo, hi, gamma, ext, row):
    """:func:`_b_sums_range` with effects' lobe terms: each block's lobe column first (:func:`lobe_fill`)."""
    yb = cb = bb = 0.0
    bs = np.empty(BLOCK)
    for start in range(lo, hi, BLOCK):
        m = min(BLOCK, hi - start)
        ys, cs = y[start:start + m], C[start:start + m]
        lobe_fill(ext, start, log_cos_hn[start:start + m], gamma, row, bs[:m])
        pyb = pcb = pbb = 0.0
        for k in range(m):
            b = bs[k]
            pyb += np.float64(ys[k]) * b
            pcb += np.float64(cs[k]) * b
            pbb += b * b
        yb += pyb
        cb += pcb
        bb += pbb
    return yb, cb, bb


@njit(cache=True, nogil=True, fastmath={"reassoc", "contract"})
def _b_sums_range(y, C, log_cos_hn, lo, hi, gamma, ext, row):
    """Unscaled ``(SyB, SCB, SBB)`` of observations ``lo .. hi - 1`` (see :func:`b_sums`)."""
    if ext is not None:
        return _b_sums_range_lobe(y, C, log_cos_hn, lo, hi, gamma, ext, row)
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


def b_sums(y, C, log_cos_hn, starts, ends, gamma, ext=None):
    """``(SyB, SAB, SBB)`` (unscaled, float64) of the observations in the runs ``[starts[k], ends[k])``.

    ``B = C <h.n>^gamma`` with the power from :func:`fast_exp`, fused with the sums: one
    vectorised pass per run that reads the float32 arrays once; in :data:`PARTS` pieces on
    the chain's threads when the runs hold :data:`PARALLEL_MIN_OBS` observations or more.
    """
    out = _gamma_sums(y, C, log_cos_hn, starts, ends, gamma, False, ext)
    out[1] *= INV_PI
    return out


def b_sums_many(y, C, log_cos_hn, starts, ends, gammas, ext=None):
    """:func:`b_sums` at each of ``gammas``: (G, 3)."""
    out = np.empty((gammas.shape[0], 3))
    for q in range(gammas.shape[0]):
        out[q] = b_sums(y, C, log_cos_hn, starts, ends, gammas[q], ext)
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
def _b_sums_newton_range(y, C, log_cos_hn, lo, hi, gamma, out, powers, ext, row):
    """Add the nine unscaled sums of :func:`b_sums_newton` of observations ``lo .. hi - 1`` to ``out``.

    Per block: the B terms into ``powers`` (one vectorised loop with the exps), then one
    loop per weight (yB, CB, BB) with its three sums. Nine accumulators in one loop spill
    out of the 16 vector registers: this takes the pass from 2.4 to 1.4 ns per observation.
    """
    for start in range(lo, hi, BLOCK):
        m = min(BLOCK, hi - start)
        ys, cs, ls = y[start:start + m], C[start:start + m], log_cos_hn[start:start + m]   # as in b_sums
        bs = powers[:m]
        if ext is not None:
            lobe_fill(ext, start, ls, gamma, row, bs)
        else:
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
def _gamma_sums_part(y, C, log_cos_hn, starts, ends, first, last, gamma, newton, out, ext, row):
    """Add runs ``first .. last - 1``'s sums to ``out``: :func:`b_sums`' three (unscaled) or, with ``newton``, nine."""
    if newton:
        powers = np.empty(BLOCK)
        for k in range(first, last):
            _b_sums_newton_range(y, C, log_cos_hn, starts[k], ends[k], gamma, out, powers, ext, row)
    else:
        for k in range(first, last):
            a, b, c = _b_sums_range(y, C, log_cos_hn, starts[k], ends[k], gamma, ext, row)
            out[0] += a
            out[1] += b
            out[2] += c


@njit(cache=True, nogil=True, parallel=True)
def _gamma_sums_parts(y, C, log_cos_hn, starts, ends, offsets, gamma, newton, part_sums, ext, row):
    # only the prange loop: Numba would run any array expression here as a parallel loop too
    for p in prange(offsets.shape[0] - 1):
        _gamma_sums_part(y, C, log_cos_hn, starts, ends, offsets[p], offsets[p + 1], gamma, newton, part_sums[p],
                         ext, row)


# Plain Python, not jitted: it calls a parallel=True kernel, and Numba 0.68 mis-compiles such a call
# made from inside another jitted function (with effects' lobe terms its first call returned zero sums,
# and its cached form crashed); dispatched from Python the kernel compiles and runs on its own.
def _gamma_sums(y, C, log_cos_hn, starts, ends, gamma, newton, ext):
    """:func:`_gamma_sums_part` over all the runs, in :func:`split_runs`' pieces, the pieces added in order."""
    out = _gamma_sums_whole(y, C, log_cos_hn, starts, ends, gamma, newton, ext)
    if out.shape[0]:            # fewer than PARALLEL_MIN_OBS observations: done in one jitted call
        return out
    row = lobe_row(ext, gamma)
    piece_starts, piece_ends, offsets = split_runs(starts, ends)
    part_sums = np.zeros((offsets.shape[0] - 1, 9 if newton else 3))
    _gamma_sums_parts(y, C, log_cos_hn, piece_starts, piece_ends, offsets, gamma, newton, part_sums, ext, row)
    out = np.zeros(part_sums.shape[1])
    for sums_of_part in part_sums:       # in order, so the sums do not depend on the threads
        out += sums_of_part
    return out


@njit(cache=True, nogil=True)
def _gamma_sums_whole(y, C, log_cos_hn, starts, ends, gamma, newton, ext):
    """:func:`_gamma_sums` of runs with fewer than :data:`PARALLEL_MIN_OBS` observations (one part); an
    empty array for more (the caller runs the parallel kernel)."""
    total = 0
    for k in range(starts.shape[0]):
        total += ends[k] - starts[k]
    if total >= PARALLEL_MIN_OBS:
        return np.zeros(0)
    out = np.zeros(9 if newton else 3)
    row = lobe_row(ext, gamma)
    _gamma_sums_part(y, C, log_cos_hn, starts, ends, 0, starts.shape[0], gamma, newton, out, ext, row)
    return out


def b_sums_newton(y, C, log_cos_hn, starts, ends, gamma, ext=None):
    """:func:`b_sums` plus the same three sums weighted by ``log <h.n>`` and by its square (9 values).

    ``d B / d gamma = B log <h.n>``: these are the first and second gamma-derivatives of
    ``(SyB, SAB, SBB / 2)``, for the Newton proposal of the gamma move. In pieces on the
    chain's threads as :func:`b_sums`. With effects' lobe terms the two weighted sums are
    those of the plain lobe's derivative (:mod:`rjfit.sampler.passes.lobe`).
    """
    return _gamma_sums(y, C, log_cos_hn, starts, ends, gamma, True, ext)


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


@njit(cache=True, nogil=True, fastmath={"reassoc", "contract"})
def _stats_range_lobe(y, C, log_cos_hn, lo, hi, gamma, ext, row):
    """:func:`_stats_range` with effects' lobe terms (scalar: the terms gather by view angle)."""
    yy, yc, cc = fixed_sums(y, C, np.full(1, lo), np.full(1, hi))
    yb, cb, bb = _b_sums_range_lobe(y, C, log_cos_hn, lo, hi, gamma, ext, row)
    return yy, yc, cc, yb, cb, bb


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
def region_stats_runs(y, C, log_cos_hn, offsets, starts, ends, gammas, ext=None):
    """Unscaled sufficient statistics (R, 7) of every region from its runs (``likelihood.label_runs``).

    Each run is one vectorised pass that reads the problem's arrays in place; region r's
    runs ``offsets[r] .. offsets[r + 1] - 1`` are summed at its exponent ``gammas[r]``.
    """
    n_regions = offsets.shape[0] - 1
    out = np.zeros((n_regions, 7))
    rows = lobe_rows(ext, gammas)
    for r in range(n_regions):
        for k in range(offsets[r], offsets[r + 1]):
            if ext is not None:
                yy, yc, cc, yb, cb, bb = _stats_range_lobe(y, C, log_cos_hn, starts[k], ends[k], gammas[r], ext,
                                                           rows[r])
            else:
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
