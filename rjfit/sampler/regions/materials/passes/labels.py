"""Compiled passes of the material region model: per-pixel log-likelihoods, the label sweep, clusters.

- :func:`pixel_log_lik`: every pixel's log-likelihood under every material (one pass over
  the observations; the densities of a block are evaluated material by material in a loop
  that vectorises, then summed per pixel);
- :func:`gibbs_sweep`: one colour of the checkerboard Gibbs sweep of pixel labels (pixels
  of one colour are not 4-neighbours, so each one's conditional depends only on the other
  colour's labels), with the edge term's delayed acceptance where the target holds one
  (:func:`rjfit.sampler.regions.materials.passes.edges.keep_new_label`);
- :func:`relabel_pixels`: move the observations of relabelled pixels between the
  materials' sufficient statistics (and relabel them);
- :func:`grow_cluster`: a Swendsen-Wang-cut cluster from a seed pixel, with the counts and
  cut weights of its boundary edges by the label across them;
- :func:`edge_uniform`: the uniform of one edge's bond, a hash of the move's key and the
  edge (SplitMix64), so a cluster move draws one number from the chain's generator whatever
  the size of its cluster;
- :func:`allocate_split`: the sequential allocation of a material's pixels to two parts
  (the split of the merge/split move), drawing or evaluating its probability;
- :func:`pixel_log_lik_colour`, :func:`relabel_pixels_colour`: the first and third for a
  joint colour fit (a row of parameters per material and channel).

Pixels are flat row-major indices ``r * W + c``; an edge is named by its first pixel and
its direction: edge ``2 p`` joins p to its right neighbour, edge ``2 p + 1`` to the pixel
below. The NumPy twins are in :mod:`rjfit.sampler.reference`.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from rjfit.sampler.passes.cells import pixel_cuts
from rjfit.sampler.passes.densities import coefficients, log_densities_into
from rjfit.sampler.regions.materials.passes.edges import edge_sums, keep_new_label
from rjfit.sampler.passes.lobe import lobe_at, lobe_rows
from rjfit.sampler.passes.shifts import add_lobe_terms, add_obs_terms
from rjfit.sampler.passes.special import INV_PI, fast_exp
from rjfit.sampler.passes.sums import BLOCK, PARALLEL_MIN_OBS, PARTS

__all__ = ["pixel_log_lik", "gibbs_draw", "gibbs_sweep", "relabel_pixels", "grow_cluster", "edge_uniform",
           "allocate_split",
           "pixel_log_lik_colour", "relabel_pixels_colour"]


@njit(cache=True, nogil=True)
def _pixel_log_lik_range(y, C, log_cos_hn, pixel, coef, out, lo, hi, ext, rows):
    density = np.empty(BLOCK)
    for start in range(lo, hi, BLOCK):
        m = min(BLOCK, hi - start)
        ys, cs, ls, ps = y[start:start + m], C[start:start + m], log_cos_hn[start:start + m], pixel[start:start + m]
        for k in range(coef.shape[0]):
            log_densities_into(ys, cs, ls, coef, k, density[:m], ext, rows, start)
            # observations are sorted by pixel: sum a pixel's in a register, write once
            key = -1
            total = 0.0
            for j in range(m):
                if ps[j] != key:
                    if key >= 0:
                        out[k, key] += total
                    key, total = ps[j], 0.0
                total += density[j]
            if key >= 0:
                out[k, key] += total


@njit(cache=True, nogil=True, parallel=True)
def _pixel_log_lik_parts(y, C, log_cos_hn, pixel, coef, out, bounds, ext, rows):
    # parts start at a pixel's first observation: no two parts write one pixel's entries
    for p in prange(bounds.shape[0] - 1):
        _pixel_log_lik_range(y, C, log_cos_hn, pixel, coef, out, bounds[p], bounds[p + 1], ext, rows)


# Plain Python, not jitted: it calls a parallel=True kernel, and Numba 0.68 mis-compiles such a call
# made from inside another jitted function (with effects' lobe terms its first call returned zero sums,
# and its cached form crashed); dispatched from Python the kernel compiles and runs on its own.
def pixel_log_lik(y, C, log_cos_hn, pixel, theta, n_pixels, ext=None):
    """(K, n_pixels): the sum of each pixel's observations' log densities under each material (unweighted).

    ``theta`` (K, 4) are the materials' parameters; a pixel without observations gets 0.
    ``ext``: the lobe terms of a problem with effects (``Problem.lobe``, in the order of
    ``y``; None for the plain lobe).
    In :data:`~rjfit.sampler.passes.sums.PARTS` pieces on the chain's threads for large
    problems, each cut at a pixel's first observation (the pieces do not depend on the
    threads, so neither do the sums).
    """
    coef = coefficients(theta)
    rows = lobe_rows(ext, np.ascontiguousarray(coef[:, 2]))
    out = np.zeros((theta.shape[0], n_pixels))
    n = y.shape[0]
    if n < PARALLEL_MIN_OBS:
        _pixel_log_lik_range(y, C, log_cos_hn, pixel, coef, out, 0, n, ext, rows)
    else:
        _pixel_log_lik_parts(y, C, log_cos_hn, pixel, coef, out, pixel_cuts(pixel, pixel), ext, rows)
    return out


@njit(cache=True, nogil=True)
def gibbs_draw(p, r, c, pixel_labels, labelled, log_lik, power, beta, height, width, uniform, logits):
    """Pixel p's (row r, column c) label drawn from ``power * log_lik[k, p] + beta * (4-neighbours labelled k)``
    over the K materials by inverse CDF with ``uniform``; ``logits`` (K,) is scratch."""
    n_labels = log_lik.shape[0]
    for k in range(n_labels):
        logits[k] = power * log_lik[k, p]
    if r > 0 and labelled[p - width]:
        logits[pixel_labels[p - width]] += beta
    if r < height - 1 and labelled[p + width]:
        logits[pixel_labels[p + width]] += beta
    if c > 0 and labelled[p - 1]:
        logits[pixel_labels[p - 1]] += beta
    if c < width - 1 and labelled[p + 1]:
        logits[pixel_labels[p + 1]] += beta
    top = logits.max()
    total = 0.0
    for k in range(n_labels):
        logits[k] = math.exp(logits[k] - top)
        total += logits[k]
    target = uniform * total
    running = 0.0
    for k in range(n_labels):
        running += logits[k]
        if target < running:
            return k
    return n_labels - 1


@njit(cache=True, nogil=True)
def gibbs_sweep(pixel_labels, labelled, log_lik, power, beta, height, width, counts, uniforms, parity,
                second_uniforms=None, edge=None):
    """Gibbs updates of the labelled pixels with ``(r + c) % 2 == parity``, in row-major order; returns how many changed.

    Pixel p's label is drawn by :func:`gibbs_draw` with ``uniforms[p]``, unless p is the last
    pixel of its material (``counts[label] == 1``): then it keeps its label, the conditional of
    the target restricted to states with no empty material. ``pixel_labels`` and ``counts``
    are updated in place. With the target's edge term (``edge``: the arrays of
    :meth:`rjfit.sampler.regions.materials.edges.EdgeTerm.sweep_arrays`) a new label is then kept by delayed
    acceptance with ``second_uniforms[p]`` (:func:`rjfit.sampler.regions.materials.passes.edges.keep_new_label`).
    """
    logits = np.empty(log_lik.shape[0])
    sums = np.zeros((0, 0, 3))
    if edge is not None:
        sums = edge_sums(pixel_labels, log_lik.shape[0], edge)
    changed = 0
    for r in range(height):
        for c in range((r + parity) % 2, width, 2):
            p = r * width + c
            if not labelled[p]:
                continue
            old = pixel_labels[p]
            if counts[old] <= 1:
                continue
            new = gibbs_draw(p, r, c, pixel_labels, labelled, log_lik, power, beta, height, width, uniforms[p], logits)
            if new == old:
                continue
            if edge is not None and not keep_new_label(sums, p, old, new, pixel_labels, edge, second_uniforms[p]):
                continue
            counts[old] -= 1
            counts[new] += 1
            pixel_labels[p] = new
            changed += 1
    return changed


@njit(cache=True, nogil=True)
def relabel_pixels(y, C, log_cos_hn, pixel_start, pixels, old, new, gammas, stats, weight, obs_labels, ext=None):
    """Move the observations of ``pixels`` from material ``old[j]`` to ``new[j]``: statistics and labels, in place.

    ``stats`` (K, 7) loses ``weight`` (the likelihood power) times each observation's terms
    in its old material and gains them in its new one (at each material's gamma);
    ``obs_labels`` gets the new label. ``ext``: the lobe terms of a problem with effects
    (None: the plain lobe).
    """
    if ext is not None:
        _relabel_pixels_lobe(y, C, log_cos_hn, pixel_start, pixels, old, new, gammas, stats, weight, obs_labels, ext)
        return
    for j in range(pixels.shape[0]):
        p = pixels[j]
        for i in range(pixel_start[p], pixel_start[p + 1]):
            yv, c, lh = np.float64(y[i]), np.float64(C[i]), np.float64(log_cos_hn[i])
            a = c * INV_PI
            add_obs_terms(stats, old[j], -weight, yv, c, a, lh, gammas[old[j]])
            add_obs_terms(stats, new[j], weight, yv, c, a, lh, gammas[new[j]])
            obs_labels[i] = new[j]


@njit(cache=True, nogil=True)
def _relabel_pixels_lobe(y, C, log_cos_hn, pixel_start, pixels, old, new, gammas, stats, weight, obs_labels, ext):
    """:func:`relabel_pixels` with an effects' lobe column (:mod:`rjfit.sampler.passes.lobe`)."""
    n = 0
    for j in range(pixels.shape[0]):
        n += pixel_start[pixels[j] + 1] - pixel_start[pixels[j]]
    idx = np.empty(n, np.int64)
    r_old, r_new = np.empty(n, np.int64), np.empty(n, np.int64)
    k = 0
    for j in range(pixels.shape[0]):
        for i in range(pixel_start[pixels[j]], pixel_start[pixels[j] + 1]):
            idx[k], r_old[k], r_new[k] = i, old[j], new[j]
            k += 1
    rows = lobe_rows(ext, gammas)
    b_old, b_new = np.empty(n), np.empty(n)
    lobe_at(ext, idx, log_cos_hn, gammas, rows, r_old, b_old)
    lobe_at(ext, idx, log_cos_hn, gammas, rows, r_new, b_new)
    for k in range(n):
        i = idx[k]
        yv, a = np.float64(y[i]), np.float64(C[i]) * INV_PI
        add_lobe_terms(stats, r_old[k], -weight, yv, a, b_old[k])
        add_lobe_terms(stats, r_new[k], weight, yv, a, b_new[k])
        obs_labels[i] = r_new[k]


@njit(cache=True, nogil=True)
def edge_uniform(key, edge):
    """A uniform in [0, 1) for ``edge`` under the move's ``key`` (SplitMix64 of ``key + edge``; both uint64)."""
    z = key + edge + np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    z = z ^ (z >> np.uint64(31))
    return np.float64(z >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@njit(inline="always")
def _neighbour(p, direction, height, width):
    """``(neighbour, edge)`` of pixel p in direction 0 right, 1 down, 2 left, 3 up; neighbour -1 off the image."""
    r, c = p // width, p % width
    if direction == 0:
        return (p + 1, 2 * p) if c < width - 1 else (-1, -1)
    if direction == 1:
        return (p + width, 2 * p + 1) if r < height - 1 else (-1, -1)
    if direction == 2:
        return (p - 1, 2 * (p - 1)) if c > 0 else (-1, -1)
    return (p - width, 2 * (p - width) + 1) if r > 0 else (-1, -1)


@njit(cache=True, nogil=True)
def grow_cluster(pixel_labels, labelled, bond_q, key, seed, height, width, n_labels):
    """The Swendsen-Wang-cut cluster of ``seed``: pixels of its label joined by bonds that are on.

    Edge e between two labelled pixels of one label is on when ``edge_uniform(key, e) <
    bond_q[e]``. Returns ``(members, n_to, log_cut_to)``: the cluster's pixels (ascending),
    and per label k the number of edges from the cluster to labelled pixels of label k
    outside it and the sum of their ``log(1 - bond_q)``.
    """
    n_pix = height * width
    in_cluster = np.zeros(n_pix, np.bool_)
    stack = np.empty(n_pix, np.int64)
    members = np.empty(n_pix, np.int64)
    label = pixel_labels[seed]
    in_cluster[seed] = True
    stack[0] = seed
    top, count = 1, 0
    while top > 0:
        top -= 1
        p = stack[top]
        members[count] = p
        count += 1
        for direction in range(4):
            q, edge = _neighbour(p, direction, height, width)
            if q < 0 or in_cluster[q] or not labelled[q] or pixel_labels[q] != label:
                continue
            if edge_uniform(key, np.uint64(edge)) < bond_q[edge]:
                in_cluster[q] = True
                stack[top] = q
                top += 1
    n_to = np.zeros(n_labels, np.int64)
    log_cut_to = np.zeros(n_labels)
    for j in range(count):
        p = members[j]
        for direction in range(4):
            q, edge = _neighbour(p, direction, height, width)
            if q < 0 or in_cluster[q] or not labelled[q]:
                continue
            n_to[pixel_labels[q]] += 1
            log_cut_to[pixel_labels[q]] += math.log1p(-bond_q[edge])
    return np.sort(members[:count]), n_to, log_cut_to


@njit(cache=True, nogil=True)
def edges_to_labels(pixel_labels, members, n_labels, height, width):
    """Per label, the number of 4-neighbour edges from the pixels ``members`` to labelled pixels (label >= 0) of
    that label outside them (``pixel_labels`` flat, -1 unlabelled): ``grow_cluster``'s ``n_to`` for a given set."""
    inside = np.zeros(height * width, np.bool_)
    for p in members:
        inside[p] = True
    counts = np.zeros(n_labels, np.int64)
    for p in members:
        for direction in range(4):
            q, _ = _neighbour(p, direction, height, width)
            if q >= 0 and not inside[q] and pixel_labels[q] >= 0:
                counts[pixel_labels[q]] += 1
    return counts


@njit(cache=True, nogil=True)
def allocate_split(members, guide_log_lik, power, beta, height, width, uniforms, forced):
    """Sequential allocation of the pixels ``members`` to parts 0 and 1: ``(parts, log probability)``.

    Pixel ``members[j]``, in the given order, goes to part c with probability proportional
    to ``exp(power * guide_log_lik[c, j] + beta * n_c)``, n_c its 4-neighbours among
    ``members[:j]`` already in part c. With ``forced[j] >= 0`` the pixel goes to that part
    (the probability of a given allocation, for the reverse move); else to part 0 when
    ``uniforms[j]`` is below its probability. The log probability is the sum of the chosen
    parts' log probabilities.
    """
    n = members.shape[0]
    part_of = np.full(height * width, -1, np.int8)
    parts = np.empty(n, np.int8)
    log_prob = 0.0
    for j in range(n):
        p = members[j]
        r, c = p // width, p % width
        same0, same1 = 0, 0
        for q, inside in ((p - width, r > 0), (p + width, r < height - 1), (p - 1, c > 0), (p + 1, c < width - 1)):
            if inside and part_of[q] == 0:
                same0 += 1
            elif inside and part_of[q] == 1:
                same1 += 1
        # logit of part 1 against part 0, and the two log probabilities by a stable log-sigmoid
        d = power * (guide_log_lik[1, j] - guide_log_lik[0, j]) + beta * (same1 - same0)
        log_p1 = -math.log1p(math.exp(-d)) if d > 0 else d - math.log1p(math.exp(d))
        log_p0 = -math.log1p(math.exp(d)) if d < 0 else -d - math.log1p(math.exp(-d))
        part = forced[j] if forced[j] >= 0 else (0 if uniforms[j] < math.exp(log_p0) else 1)
        parts[j] = part
        part_of[p] = part
        log_prob += log_p0 if part == 0 else log_p1
    return parts, log_prob


# ---- a joint colour fit (rjfit.sampler.colour): material k's channel c is parameter row k C + c ----

@njit(cache=True, nogil=True)
def _colour_pixel_log_lik_range(y, C, log_cos_hn, channel_start, coef, n_channels, out, p_lo, p_hi):
    for p in range(p_lo, p_hi):
        for c in range(n_channels):
            lo, hi = channel_start[p * n_channels + c], channel_start[p * n_channels + c + 1]
            if hi == lo:
                continue
            for k in range(out.shape[0]):
                row = k * n_channels + c
                ca, cb, g, c0, c1 = coef[row, 0], coef[row, 1], coef[row, 2], coef[row, 3], coef[row, 4]
                total = 0.0
                for i in range(lo, hi):
                    cc = np.float64(C[i])
                    resid = np.float64(y[i]) - ca * cc - cb * cc * fast_exp(g * np.float64(log_cos_hn[i]))
                    total += c0 - c1 * resid * resid
                out[k, p] += total


@njit(cache=True, nogil=True, parallel=True)
def _colour_pixel_log_lik_parts(y, C, log_cos_hn, channel_start, coef, n_channels, out, bounds):
    for part in prange(bounds.shape[0] - 1):        # whole pixels per part: no pixel is written twice
        _colour_pixel_log_lik_range(y, C, log_cos_hn, channel_start, coef, n_channels, out, bounds[part],
                                    bounds[part + 1])


# Plain Python, not jitted: it calls a parallel=True kernel, and Numba 0.68 mis-compiles such a call
# made from inside another jitted function (with effects' lobe terms its first call returned zero sums,
# and its cached form crashed); dispatched from Python the kernel compiles and runs on its own.
def pixel_log_lik_colour(y, C, log_cos_hn, channel_start, theta, n_channels, n_pixels):
    """(K, n_pixels): each pixel's log densities summed over its observations and channels, under each material.

    ``theta`` (K C, 4): material k's channel c is row ``k C + c``; ``channel_start``
    (:attr:`rjfit.sampler.forward.Problem.channel_start`) bounds each (pixel, channel)'s
    observations. Each pixel's sum runs channel by channel in a fixed order, in
    :data:`~rjfit.sampler.passes.sums.PARTS` pieces of whole pixels for large problems, so
    it does not depend on the threads.
    """
    coef = coefficients(theta)
    out = np.zeros((theta.shape[0] // n_channels, n_pixels))
    if y.shape[0] < PARALLEL_MIN_OBS:
        _colour_pixel_log_lik_range(y, C, log_cos_hn, channel_start, coef, n_channels, out, 0, n_pixels)
    else:
        bounds = np.empty(PARTS + 1, np.int64)
        for part in range(PARTS + 1):
            bounds[part] = n_pixels * part // PARTS
        _colour_pixel_log_lik_parts(y, C, log_cos_hn, channel_start, coef, n_channels, out, bounds)
    return out


@njit(cache=True, nogil=True)
def relabel_pixels_colour(y, C, log_cos_hn, pixel_start, channel, n_channels, pixels, old, new, gammas, stats,
                          weight, obs_labels):
    """:func:`relabel_pixels` of a joint colour fit: observation i of channel c moves between rows ``k C + c``.

    ``gammas`` and ``stats`` have a row per material and channel; ``obs_labels`` gets
    ``new[j] C + c``.
    """
    for j in range(pixels.shape[0]):
        p = pixels[j]
        for i in range(pixel_start[p], pixel_start[p + 1]):
            yv, c, lh = np.float64(y[i]), np.float64(C[i]), np.float64(log_cos_hn[i])
            a = c * INV_PI
            row_old, row_new = old[j] * n_channels + channel[i], new[j] * n_channels + channel[i]
            add_obs_terms(stats, row_old, -weight, yv, c, a, lh, gammas[row_old])
            add_obs_terms(stats, row_new, weight, yv, c, a, lh, gammas[row_new])
            obs_labels[i] = row_new
