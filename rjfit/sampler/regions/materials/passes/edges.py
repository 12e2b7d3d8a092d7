"""Compiled passes of the material model's edge term (:mod:`rjfit.sampler.regions.materials.edges`).

A pair ``j`` joins pixel ``first[j]`` to ``second[j]`` (``gap`` px to its right or below);
its matched observations (one per light seen by both pixels) are ``start[j] .. start[j + 1]``
of the per-match arrays: the data's difference ``d``, and each end's columns ``C`` and
``log <h.n>``. A pair whose ends carry materials k != m adds to the boundary {k, m}'s sums
(``sums[k, m]`` with k < m): ``sums[k, m, 0]`` += SS of the two materials' step,
``sums[k, m, 1]`` += SS with both ends in k, ``sums[k, m, 2]`` += SS with both in m, where

    SS(a at first, b at second) = sum over its matches (d - mu_a(first) + mu_b(second))^2,

and ``sums[k, m, 3]`` += ``no_step[j]``, the pair's SS of no step (a constant of the data:
:func:`rjfit.sampler.regions.materials.edges.no_step_sums`). With ``alone = min(sums[., ., 1],
sums[., ., 2])`` a boundary adds ``scale`` times

    min(alone, no_step) - step

``step = sums[., ., 0]``: what its step explains beyond the better of one material across it and no step (it
earns), or misfits beyond it (it costs): :func:`boundary_value`.
``coef`` are the materials' constants of :func:`rjfit.sampler.passes.densities.coefficients`
(``mu = C (coef0 + coef1 <h.n>^coef2)``).

A joint colour fit (``n_channels`` C > 1) has one match per light and channel seen by both
pixels: ``channel`` (M,) gives each match's, whose material k has the parameter row ``k C + c``,
and each match's squared misfit is weighted by ``weight[c]`` (``1 / s_c^2``: every channel on its
own noise scale), as is ``no_step`` already; one channel (``n_channels`` 1) reads neither (empty
arrays) and sums as before, unweighted (:func:`pair_sums`).

The local gain (``gain`` = ``(tau^2, u)``, :func:`pair_misfit`): a pair's two ends may share a gain ``1 + e``
on both predictions (a local error of the shading that scales the step with everything else), ``e ~ N(0, tau^2)``
integrated out per pair and hypothesis: with ``r = d - delta`` and ``delta`` the hypothesis' predicted
difference, its SS becomes ``SS - (sum r delta)^2 / (sum delta^2 + u / tau^2) + u log(1 + tau^2 sum delta^2 / u)``,
``u`` the unit of the sums (``s^2`` for one channel, 1 for the weighted sums of a colour fit). ``tau`` 0: the
plain SS.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["boundary_value", "pair_misfit", "pairs_misfit", "pair_sums", "pair_sums_changed", "pair_sums_colour",
           "boundary_sums", "changed_sums", "changed_sums_from", "changed_value", "with_changed", "changed_delta",
           "edge_value", "edge_sums", "keep_new_label"]


@njit(cache=True, nogil=True)
def pair_misfit(ss, rd, dd, gain):
    """A pair's SS under one hypothesis with its local gain integrated out (module docstring): ``ss``, ``rd``,
    ``dd`` its sums of r^2, r delta and delta^2; ``gain`` = (tau^2, unit). tau^2 0: ``ss`` itself."""
    var, unit = gain[0], gain[1]
    if var <= 0.0:
        return ss
    lam = unit / var
    return ss - rd * rd / (dd + lam) + unit * math.log1p(dd / lam)


@njit(cache=True, nogil=True)
def pairs_misfit(ss, rd, dd, gain):
    """:func:`pair_misfit` of each pair of arrays' entries (the no-step baseline's, once per fit)."""
    out = np.empty(ss.shape[0])
    for j in range(ss.shape[0]):
        out[j] = pair_misfit(ss[j], rd[j], dd[j], gain)
    return out


@njit(inline="always")
def _predict(c, a, b, g, log_cos_hn):
    """One end's predicted value ``C (coef0 + coef1 <h.n>^coef2)`` (module docstring), float64."""
    return c * (a + b * math.exp(g * log_cos_hn))


@njit(cache=True, nogil=True)
def pair_sums(j, k, m, coef, start, d, c_first, c_second, l_first, l_second, gain):
    """(SS(k, m), SS(k, k), SS(m, m)) of pair ``j``: its first pixel in material k and its second in m, and both
    in either one, each with the local gain integrated out (:func:`pair_misfit`)."""
    a_k, b_k, g_k = coef[k, 0], coef[k, 1], coef[k, 2]
    a_m, b_m, g_m = coef[m, 0], coef[m, 1], coef[m, 2]
    with_gain = gain[0] > 0.0
    two = one_k = one_m = 0.0
    two_rd = two_dd = k_rd = k_dd = m_rd = m_dd = 0.0      # sum r delta, sum delta^2: read only with a gain
    for i in range(start[j], start[j + 1]):
        cf, cs = np.float64(c_first[i]), np.float64(c_second[i])
        lf, ls = np.float64(l_first[i]), np.float64(l_second[i])
        k_first, k_second = _predict(cf, a_k, b_k, g_k, lf), _predict(cs, a_k, b_k, g_k, ls)
        m_first, m_second = _predict(cf, a_m, b_m, g_m, lf), _predict(cs, a_m, b_m, g_m, ls)
        r_two, r_k, r_m = d[i] - k_first + m_second, d[i] - k_first + k_second, d[i] - m_first + m_second
        two += r_two * r_two
        one_k += r_k * r_k
        one_m += r_m * r_m
        if with_gain:
            two_rd, two_dd = _add_gain_match(two_rd, two_dd, r_two, k_first - m_second, 1.0)
            k_rd, k_dd = _add_gain_match(k_rd, k_dd, r_k, k_first - k_second, 1.0)
            m_rd, m_dd = _add_gain_match(m_rd, m_dd, r_m, m_first - m_second, 1.0)
    return (pair_misfit(two, two_rd, two_dd, gain), pair_misfit(one_k, k_rd, k_dd, gain),
            pair_misfit(one_m, m_rd, m_dd, gain))


@njit(cache=True, nogil=True)
def pair_sums_changed(j, k, m, k_changed, coef, start, d, c_first, c_second, l_first, l_second, gain):
    """:func:`pair_sums`' SS(k, m) and SS of the changed end's material alone (SS(k, k) if ``k_changed``, else
    SS(m, m)), by the same operations; the unchanged material alone is not summed (its share has not moved): three
    exponentials per match instead of four."""
    a_k, b_k, g_k = coef[k, 0], coef[k, 1], coef[k, 2]
    a_m, b_m, g_m = coef[m, 0], coef[m, 1], coef[m, 2]
    with_gain = gain[0] > 0.0
    two = alone = 0.0
    two_rd = two_dd = rd = dd = 0.0      # read only with a gain
    for i in range(start[j], start[j + 1]):
        cf, cs = np.float64(c_first[i]), np.float64(c_second[i])
        lf, ls = np.float64(l_first[i]), np.float64(l_second[i])
        if k_changed:
            k_first, k_second = _predict(cf, a_k, b_k, g_k, lf), _predict(cs, a_k, b_k, g_k, ls)
            m_second = _predict(cs, a_m, b_m, g_m, ls)
            r, delta = d[i] - k_first + k_second, k_first - k_second
        else:
            k_first = _predict(cf, a_k, b_k, g_k, lf)
            m_first, m_second = _predict(cf, a_m, b_m, g_m, lf), _predict(cs, a_m, b_m, g_m, ls)
            r, delta = d[i] - m_first + m_second, m_first - m_second
        r_two = d[i] - k_first + m_second
        two += r_two * r_two
        alone += r * r
        if with_gain:
            two_rd, two_dd = _add_gain_match(two_rd, two_dd, r_two, k_first - m_second, 1.0)
            rd, dd = _add_gain_match(rd, dd, r, delta, 1.0)
    return pair_misfit(two, two_rd, two_dd, gain), pair_misfit(alone, rd, dd, gain)


@njit(cache=True, nogil=True)
def _add_gain_match(rd, dd, r, delta, w):
    """A pair's sums ``(sum r delta, sum delta^2)`` with one match added (misfit ``r`` = the data's difference less
    the hypothesis' ``delta``, weight ``w``)."""
    return rd + w * r * delta, dd + w * delta * delta


@njit(cache=True, nogil=True)
def pair_sums_colour(j, k, m, coef, start, d, c_first, c_second, l_first, l_second, channel, weight, n_channels, gain):
    """:func:`pair_sums` of a joint colour fit: each match under its channel's rows of k and m (``k C + c``), its
    squared misfits weighted by ``weight[c]``; one gain per pair, shared by the channels."""
    with_gain = gain[0] > 0.0
    two = one_k = one_m = 0.0
    two_rd = two_dd = k_rd = k_dd = m_rd = m_dd = 0.0
    for i in range(start[j], start[j + 1]):
        c = channel[i]
        rk, rm = k * n_channels + c, m * n_channels + c
        cf, cs = np.float64(c_first[i]), np.float64(c_second[i])
        lf, ls = np.float64(l_first[i]), np.float64(l_second[i])
        k_first = _predict(cf, coef[rk, 0], coef[rk, 1], coef[rk, 2], lf)
        k_second = _predict(cs, coef[rk, 0], coef[rk, 1], coef[rk, 2], ls)
        m_first = _predict(cf, coef[rm, 0], coef[rm, 1], coef[rm, 2], lf)
        m_second = _predict(cs, coef[rm, 0], coef[rm, 1], coef[rm, 2], ls)
        r_two, r_k, r_m = d[i] - k_first + m_second, d[i] - k_first + k_second, d[i] - m_first + m_second
        w = weight[c]
        two += w * r_two * r_two
        one_k += w * r_k * r_k
        one_m += w * r_m * r_m
        if with_gain:
            two_rd, two_dd = _add_gain_match(two_rd, two_dd, r_two, k_first - m_second, w)
            k_rd, k_dd = _add_gain_match(k_rd, k_dd, r_k, k_first - k_second, w)
            m_rd, m_dd = _add_gain_match(m_rd, m_dd, r_m, m_first - m_second, w)
    return (pair_misfit(two, two_rd, two_dd, gain), pair_misfit(one_k, k_rd, k_dd, gain),
            pair_misfit(one_m, m_rd, m_dd, gain))


@njit(cache=True, nogil=True)
def _add_pair(sums, sign, j, k, m, coef, start, d, c_first, c_second, l_first, l_second, no_step, channel, weight,
              n_channels, gain):
    """Add (``sign`` 1) or remove (-1) pair ``j`` with ends in (k, m), k != m, to its boundary's sums."""
    if n_channels == 1:
        two, one_k, one_m = pair_sums(j, k, m, coef, start, d, c_first, c_second, l_first, l_second, gain)
    else:
        two, one_k, one_m = pair_sums_colour(j, k, m, coef, start, d, c_first, c_second, l_first, l_second, channel,
                                             weight, n_channels, gain)
    lo, hi = (k, m) if k < m else (m, k)
    sums[lo, hi, 0] += sign * two
    sums[lo, hi, 1] += sign * (one_k if k < m else one_m)
    sums[lo, hi, 2] += sign * (one_m if k < m else one_k)
    sums[lo, hi, 3] += sign * no_step[j]


@njit(cache=True, nogil=True)
def boundary_sums(labels, n_materials, coef, first, second, start, d, c_first, c_second, l_first, l_second,
                  no_step, channel, weight, n_channels, gain):
    """(K, K, 4) the sums of every boundary of flat ``labels`` (-1: unlabelled, in no pair's sums); ``coef`` has
    ``n_channels`` rows per material."""
    sums = np.zeros((n_materials, n_materials, 4))
    for j in range(first.shape[0]):
        k, m = labels[first[j]], labels[second[j]]
        if k >= 0 and m >= 0 and k != m:
            _add_pair(sums, 1.0, j, k, m, coef, start, d, c_first, c_second, l_first, l_second, no_step, channel,
                      weight, n_channels, gain)
    return sums


@njit(cache=True, nogil=True)
def changed_sums(labels, changed, coef, first, second, start, d, c_first, c_second, l_first, l_second, no_step,
                 channel, weight, n_channels, gain):
    """:func:`boundary_sums` of the boundaries of the materials marked in ``changed`` (K,) only (the others' sums
    0): their pairs in the same order, so each such boundary's sums equal :func:`boundary_sums`' to the bit."""
    n_materials = changed.shape[0]
    sums = np.zeros((n_materials, n_materials, 4))
    for j in range(first.shape[0]):
        k, m = labels[first[j]], labels[second[j]]
        if k >= 0 and m >= 0 and k != m and (changed[k] or changed[m]):
            _add_pair(sums, 1.0, j, k, m, coef, start, d, c_first, c_second, l_first, l_second, no_step, channel,
                      weight, n_channels, gain)
    return sums


@njit(cache=True, nogil=True)
def changed_sums_from(before, labels, changed, coef, first, second, start, d, c_first, c_second, l_first, l_second,
                      no_step, gain):
    """The whole term's sums (one channel) once the materials marked in ``changed`` take ``coef``, from ``before``,
    the sums before they did: the changed materials' boundaries summed again (:func:`changed_sums`, to the bit),
    except the share of an unchanged material alone across a boundary, which is ``before``'s
    (:func:`pair_sums_changed`); the other boundaries ``before``'s."""
    n_materials = changed.shape[0]
    sums = np.zeros((n_materials, n_materials, 4))
    for j in range(first.shape[0]):
        k, m = labels[first[j]], labels[second[j]]
        if k < 0 or m < 0 or k == m or not (changed[k] or changed[m]):
            continue
        lo, hi = (k, m) if k < m else (m, k)
        if changed[k] and changed[m]:
            two, one_k, one_m = pair_sums(j, k, m, coef, start, d, c_first, c_second, l_first, l_second, gain)
            sums[lo, hi, 1] += one_k if k < m else one_m
            sums[lo, hi, 2] += one_m if k < m else one_k
        else:
            two, alone = pair_sums_changed(j, k, m, changed[k], coef, start, d, c_first, c_second, l_first, l_second,
                                           gain)
            sums[lo, hi, 1 if (k if changed[k] else m) == lo else 2] += alone
        sums[lo, hi, 0] += two
        sums[lo, hi, 3] += no_step[j]
    out = before.copy()
    for k in range(n_materials):
        for m in range(k + 1, n_materials):
            if changed[k] and changed[m]:
                out[k, m, :] = sums[k, m, :]
            elif changed[k] or changed[m]:
                out[k, m, 0] = sums[k, m, 0]
                out[k, m, 1 if changed[k] else 2] = sums[k, m, 1 if changed[k] else 2]
                out[k, m, 3] = sums[k, m, 3]
    return out


@njit(cache=True, nogil=True)
def changed_value(sums, changed, scale):
    """:func:`edge_value` of the boundaries of the materials marked in ``changed`` alone (in the same order)."""
    total = 0.0
    for k in range(sums.shape[0]):
        for m in range(k + 1, sums.shape[0]):
            if changed[k] or changed[m]:
                total += scale * boundary_value(sums[k, m, 0], min(sums[k, m, 1], sums[k, m, 2]), sums[k, m, 3])
    return total


@njit(cache=True, nogil=True)
def with_changed(before, after, changed):
    """``before`` with the boundaries of the materials marked in ``changed`` taken from ``after``: the whole
    term's sums once only those materials' parameters changed (the other boundaries' sums do not read them)."""
    out = before.copy()
    for k in range(before.shape[0]):
        for m in range(k + 1, before.shape[0]):
            if changed[k] or changed[m]:
                out[k, m, :] = after[k, m, :]
    return out


def changed_delta(labels, changed, coef, new_coef, first, second, start, d, c_first, c_second, l_first, l_second,
                  no_step, channel, weight, n_channels, gain, scale):
    """The change of the term when the materials marked in ``changed`` (K,) take ``new_coef`` instead of ``coef``.

    Only the boundaries of a changed material move, so only their pairs are summed, at both
    coefficients (the others' shares cancel: a boundary with no pairs adds 0). A material's
    parameter move asks this of one material; with the current sums at hand (a chain's
    :class:`~rjfit.sampler.regions.materials.edge_memo.BoundaryMemo`) only the new ones are summed.
    """
    arrays = (first, second, start, d, c_first, c_second, l_first, l_second, no_step, channel, weight, n_channels,
              gain)
    after = changed_sums(labels, changed, new_coef, *arrays)
    before = changed_sums(labels, changed, coef, *arrays)
    return changed_value(after, changed, scale) - changed_value(before, changed, scale)


@njit(cache=True, nogil=True)
def edge_value(sums, scale):
    """The edge term of boundary sums ``sums`` (module docstring)."""
    total = 0.0
    for k in range(sums.shape[0]):
        for m in range(k + 1, sums.shape[0]):
            total += scale * boundary_value(sums[k, m, 0], min(sums[k, m, 1], sums[k, m, 2]), sums[k, m, 3])
    return total


@njit(cache=True, nogil=True)
def boundary_value(step, alone, no_step):
    """One boundary's share of the term over ``scale`` (module docstring): what its step explains beyond the better
    of either material alone and no step (negative: what it misfits beyond that)."""
    return min(alone, no_step) - step


@njit(cache=True, nogil=True)
def _move_pixel(sums, sign, p, label, labels, pair_of, coef, first, second, start, d, c_first, c_second, l_first,
                l_second, no_step, channel, weight, n_channels, gain):
    """Add (``sign`` 1) or remove (-1) the pairs of pixel ``p`` with ``p`` in material ``label``."""
    for slot in range(pair_of.shape[1]):
        j = pair_of[p, slot]
        if j < 0:
            continue
        if first[j] == p:
            k, m = label, labels[second[j]]
        else:
            k, m = labels[first[j]], label
        if k >= 0 and m >= 0 and k != m:
            _add_pair(sums, sign, j, k, m, coef, start, d, c_first, c_second, l_first, l_second, no_step, channel,
                      weight, n_channels, gain)


@njit(cache=True, nogil=True)
def edge_sums(labels, n_materials, edge):
    """:func:`boundary_sums` of ``edge``, the arrays of :meth:`rjfit.sampler.regions.materials.edges.EdgeTerm.sweep_arrays`."""
    (pair_of, coef, first, second, start, d, c_first, c_second, l_first, l_second, no_step, scale, channel, weight,
     n_channels, gain) = edge
    return boundary_sums(labels, n_materials, coef, first, second, start, d, c_first, c_second, l_first, l_second,
                         no_step, channel, weight, n_channels, gain)


@njit(cache=True, nogil=True)
def keep_new_label(sums, p, old, new, labels, edge, uniform):
    """The delayed acceptance of pixel p's Gibbs draw ``new`` (from ``old``) under the edge term: kept with
    probability ``min(1, exp(delta))`` (by ``uniform``), ``delta`` the change of the term; ``sums`` follow.

    A Gibbs draw is reversible for the target without the term, so this second stage makes the
    update reversible for the target with it (Christen and Fox 2005). The boundaries' sums are
    kept up to date pixel by pixel and each update sees the labels as they are then (a scan of
    reversible updates).
    """
    (pair_of, coef, first, second, start, d, c_first, c_second, l_first, l_second, no_step, scale, channel, weight,
     n_channels, gain) = edge
    arrays = (pair_of, coef, first, second, start, d, c_first, c_second, l_first, l_second, no_step, channel, weight,
              n_channels, gain)
    before = edge_value(sums, scale)
    _move_pixel(sums, -1.0, p, old, labels, *arrays)
    _move_pixel(sums, 1.0, p, new, labels, *arrays)
    delta = edge_value(sums, scale) - before
    if delta < 0.0 and uniform >= math.exp(delta):
        _move_pixel(sums, -1.0, p, new, labels, *arrays)
        _move_pixel(sums, 1.0, p, old, labels, *arrays)
        return False
    return True
