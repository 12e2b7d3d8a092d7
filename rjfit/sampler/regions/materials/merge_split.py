"""Merge and split of whole materials (material region model), by sequential allocation.

Twins (two materials of one paint, their pixels scattered) die only when a move carries a
whole material at once; a material that holds two paints separates only when a move
proposes most of the second paint's pixels together. This move does both, between K and
K + 1 materials (after Jain and Neal 2004 and Dahl 2005):

- **Merge** (K -> K - 1): a pair j < k uniformly among the K (K - 1) / 2; k's pixels join
  j (labels above k shift down), and the merged material's parameters are drawn from the
  region proposal built from its pixels' data (the births' Laplace / conditional proposal,
  :func:`~rjfit.sampler.moves.region_proposals.region_term`); j's and k's parameters are
  evaluated under the proposals built from their own pixels.
- **Split** (K -> K + 1), its reverse: a material m uniformly among the K (none with one
  pixel: no move), the new material's slot k uniformly in m + 1 .. K (labels at and above
  k shift up), the pixels of m allocated to two parts (below), a fair coin for which part
  keeps slot m; both parts' parameters drawn from the proposals built from their pixels,
  m's evaluated under the one built from all of them. Parameters are drawn afresh: the
  Jacobian is 1. An allocation that leaves a part empty is rejected.

**The allocation** (:func:`split_guide`, :func:`~rjfit.sampler.regions.materials.passes.labels.allocate_split`).
A guide computed from the split material's pixels alone (the same set in both directions):
a deterministic 2-means of their per-pixel features (the bonds' (a, b) fits,
:func:`~rjfit.sampler.regions.materials.kmeans.two_means_labels`), and per cluster a deterministic fit, the
guide parameters: gamma at the Laplace mode of the cluster's data (the births' fit; gamma
:data:`GUIDE_FALLBACK_GAMMA` when it fails), (a, b) at their (non-negative) least-squares
point there, sigma^2 the mean squared residual. The pixels are then allocated one at a time
in raster order, part c with probability proportional to

    exp(zeta log p(y_p | guide_c) + beta #{4-neighbours already allocated to c}),

so the probability of any allocation is a product of these (the Potts factor of the edges
to earlier pixels, times the pixel's tempered likelihood under the guide). With no guide
(fewer than two featured pixels, or all alike) the likelihood factors are 1. The split of
m into sets X (slot m) and Y (slot k) has probability

    q(X, Y) = 1/2 P(X to part 0, Y to part 1) + 1/2 P(X to part 1, Y to part 0)

(the coin), which the merge evaluates for the pair it removes.

The log ratio of a split from K materials (the merge's is its negative, read backwards):

    Delta log L + log rho - log(K + 1) - beta E(X, Y)                (the target; E: X-Y edges)
    + term(theta_X) + term(theta_Y) - term(theta_m)                  (prior over proposal)
    + log P(merge | K + 1) - log(K (K + 1) / 2)                      (the reverse's choices)
    - log P(split | K) + log K + log(K - m) - log q(X, Y)            (this move's choices)

A joint colour fit (:mod:`rjfit.sampler.colour`): the guides and the proposed materials
have a row per channel sharing gamma, and every likelihood sums the channels.

``log(K + 1)`` is the labelled state's 1 / K! (``K! / (K + 1)!``); ``term`` is
:func:`region_term`'s log prior in the proposal's coordinates minus log proposal density.

**Spatial splits** (kinds 'spatial_split', 'spatial_merge'; ``MergeSplitSettings.spatial_moves`` per
iteration). Every allocation above reads the per-pixel data, and where a material's pixels carry one or two
observations each (the back-lit sphere's upper left quadrant, kd 0.5, beside the upper right, kd 0.6) no guide
tells two paints apart, though the whole of each differs by hundreds of nats
(docs/results/2026-12-01-revised-trials.md). A spatial split reads positions only: m's pixels go to their two
halves by a deterministic 2-means of their image positions
(:func:`~rjfit.sampler.regions.materials.kmeans.spatial_halves`), the coin as above, so
``q(X, Y) = 1/2`` where X and Y are the halves of their union and 0 otherwise; its reverse, the spatial merge of a
pair, is proposed only where the pair are the halves of their union (else rejected). The rest of the ratio is the
split's above.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rjfit.sampler.colour import PixelSetData, guide_rows, material_log_lik, material_rows, material_term
from rjfit.sampler.regions.materials.kmeans import spatial_halves, two_means_labels
from rjfit.sampler.likelihood import log_likelihood_from_stats, memoised
from rjfit.sampler.regions.materials.cluster_swc import cluster_data, stats_rows, with_rows
from rjfit.sampler.moves.proposal import Proposal
from rjfit.sampler.regions.materials.passes.labels import allocate_split, pixel_log_lik, pixel_log_lik_colour

__all__ = ["MergeSplitSettings", "GUIDE_FALLBACK_GAMMA", "split_probability", "split_guide", "split_log_prob",
           "propose_merge_split"]

GUIDE_FALLBACK_GAMMA = 10.0
#: log q(X, Y) of a spatial split into its halves: the coin for which half keeps the slot
HALVES_LOG_PROB = -math.log(2.0)


@dataclass(frozen=True)
class MergeSplitSettings:
    """How the merge/split moves run.

    Attributes
    ----------
    moves : int
        Merge/split moves per iteration.
    spatial_moves : int
        Spatial merge/split moves per iteration (the module docstring).
    split_prob : float
        Probability of proposing a split (else a merge) when 1 < K < K_max.
    """

    moves: int = 1
    split_prob: float = 0.5
    spatial_moves: int = 1

    def __post_init__(self):
        if self.moves < 0 or self.spatial_moves < 0:
            raise ValueError(f"merge/split moves per iteration must be >= 0, got {self.moves}, {self.spatial_moves}")
        if not 0.0 < self.split_prob < 1.0:
            raise ValueError(f"split_prob must lie in (0, 1), got {self.split_prob}")


def split_probability(n_materials: int, max_materials: int, split_prob: float, jumps: bool = True) -> float:
    """P(split) in a state with K materials: 0 at K_max (or K fixed), 1 at K = 1, else ``split_prob``."""
    if not jumps or n_materials >= max_materials:
        return 0.0
    return 1.0 if n_materials == 1 else split_prob


def _guide_theta(problem, prior, members, pixel_sets=None):
    """The deterministic fit (rows of (I0, kd, gamma, sigma^2), one per channel) of the pixels ``members``
    (see the module docstring), or None."""
    data = cluster_data(problem, members, pixel_sets)
    if data.n == 0:
        return None
    return guide_rows(data, prior, GUIDE_FALLBACK_GAMMA)


def split_guide(problem, prior, members, features, pixel_sets=None) -> np.ndarray:
    """(2, n): the guide log-likelihood of each of the pixels ``members`` (ascending) under the two guides.

    A function of the pixel set, the data and the prior only. Zeros (no guide) when the
    2-means or a cluster's fit fails. ``features`` (H W, 2) are the per-pixel features.
    With ``pixel_sets`` (the chain's :class:`~rjfit.sampler.pixel_sets.PixelSets`) it is
    kept with the set's data for the next split or merge of the same set (callers only read it).
    """
    data = cluster_data(problem, members, pixel_sets)
    return memoised(data, "split_guide", (prior, features),
                    lambda: _split_guide(problem, prior, members, features, data, pixel_sets))


def _split_guide(problem, prior, members, features, data, pixel_sets):
    """:func:`split_guide` computed (``data``: the observations of ``members``)."""
    guide = np.zeros((2, members.size))
    featured = members[np.all(np.isfinite(features[members]), axis=1)]
    clusters = two_means_labels(features[featured]) if featured.size >= 2 else None
    if clusters is None:
        return guide
    thetas = [_guide_theta(problem, prior, featured[clusters == c], pixel_sets) for c in (0, 1)]
    if thetas[0] is None or thetas[1] is None:
        return guide
    idx = _observations(data)
    n_pix, n_ch = problem.height * problem.width, problem.n_channels
    if n_ch == 1:
        lobe = None if problem.lobe is None else problem.lobe.take(idx)
        per_pixel = pixel_log_lik(problem.y[idx], problem.C[idx], problem.log_cos_hn[idx], problem.pixel[idx],
                                  np.concatenate(thetas), n_pix, lobe)
    else:
        key = problem.pixel[idx].astype(np.int64) * n_ch + problem.channel[idx]
        bounds = np.searchsorted(key, np.arange(n_pix * n_ch + 1)).astype(np.int64)
        per_pixel = pixel_log_lik_colour(problem.y[idx], problem.C[idx], problem.log_cos_hn[idx], bounds,
                                         np.concatenate(thetas), n_ch, n_pix)
    return per_pixel[:, members]


def _observations(data) -> np.ndarray:
    """The observation indices (ascending) of a pixel set's ``data``, not kept on it (a memoised set's data
    would hold them: 8 bytes per observation)."""
    if isinstance(data, PixelSetData):
        return np.sort(np.concatenate([channel.positions() for channel in data.channels]))
    return data.positions()


def split_log_prob(members, guide, in_first, problem, beta) -> float:
    """log q(X, Y): the probability that the split sends ``members[in_first]`` to one slot and the rest to the other."""
    power, (height, width) = float(problem.likelihood_power), problem.image_shape
    first = np.asarray(in_first, np.int8)
    none = np.empty(0)
    _, log_a = allocate_split(members, guide, power, beta, height, width, none, 1 - first)
    _, log_b = allocate_split(members, guide, power, beta, height, width, none, first)
    return float(np.logaddexp(log_a, log_b) - math.log(2.0))


def _edges_between(shape, first, second) -> int:
    """Number of 4-neighbour edges between the pixel sets ``first`` and ``second`` (flat indices)."""
    part = np.full(shape[0] * shape[1], -1, np.int8)
    part[first], part[second] = 0, 1
    part = part.reshape(shape)
    horizontal = (part[:, 1:] >= 0) & (part[:, :-1] >= 0) & (part[:, 1:] != part[:, :-1])
    vertical = (part[1:] >= 0) & (part[:-1] >= 0) & (part[1:] != part[:-1])
    return int(np.count_nonzero(horizontal) + np.count_nonzero(vertical))


def _proposal(work, problem, pixels, n_materials, theta, stats, log_ratio) -> Proposal:
    layout = work.layout.with_pixels(pixels.reshape(work.layout.pixels.shape), n_materials)
    return Proposal(layout, theta, layout.labels(problem), stats, log_likelihood_from_stats(stats, theta),
                    float(log_ratio))


def propose_merge_split(work, rng, problem, prior, settings: MergeSplitSettings, proposals, potts,
                        max_materials: int, jumps: bool = True, spatial: bool = False):
    """One merge/split proposal, of kind 'split' or 'merge' (with ``spatial``: 'spatial_split' or 'spatial_merge',
    the module docstring); both jumps, untested when there is no move to test.

    Draws, in order: the kind's uniform; for a split the material, the slot, the coin, one
    uniform per pixel of the material (not for a spatial split), the two parts' parameters; for
    a merge the pair and the merged parameters.
    """
    prefix = "spatial_" if spatial else ""
    n_mat = work.layout.n_materials
    p_split = split_probability(n_mat, max_materials, settings.split_prob, jumps)
    if p_split == 0.0 and n_mat == 1:
        return Proposal.untested(prefix + "merge")
    if rng.random() < p_split:
        proposal = _split(work, rng, problem, prior, settings, proposals, potts, max_materials, p_split, spatial)
        return Proposal.untested(prefix + "split") if proposal is None else proposal.named(prefix + "split", jump=True)
    return _merge(work, rng, problem, prior, settings, proposals, potts, max_materials, p_split,
                  spatial).named(prefix + "merge", jump=True)


def _halves_log_prob(members, in_first, width) -> float:
    """log q(X, Y) of a spatial split: log 1/2 where ``members[in_first]`` and the rest are the two spatial halves of
    ``members``, else -inf."""
    halves = spatial_halves(members, width)
    if halves is None:
        return -math.inf
    first = halves == 1
    return HALVES_LOG_PROB if np.array_equal(first, in_first) or np.array_equal(~first, in_first) else -math.inf


def _ratio_choices(n_mat, m, max_materials, settings, p_split):
    """The split's proposal-choice terms from K = ``n_mat`` (material m): reverse merge over this split."""
    p_merge_back = 1.0 - split_probability(n_mat + 1, max_materials, settings.split_prob)
    return (math.log(p_merge_back) - math.log(n_mat * (n_mat + 1) / 2.0)
            - math.log(p_split) + math.log(n_mat) + math.log(n_mat - m))


def _split(work, rng, problem, prior, settings, proposals, potts, max_materials, p_split, spatial=False):
    n_mat = work.layout.n_materials
    flat = work.layout.pixels.ravel()
    m = int(rng.integers(n_mat))
    members = np.flatnonzero(flat == m)
    if members.size < 2:
        return None
    k = int(rng.integers(m + 1, n_mat + 1))
    swap = rng.random() < 0.5
    if spatial:
        parts = spatial_halves(members, problem.width)
        if parts is None:
            return None
    else:
        guide = split_guide(problem, prior, members, work.layout.bonds.features, work.pixel_sets)
        parts, _ = allocate_split(members, guide, float(problem.likelihood_power), float(potts.beta),
                                  problem.height, problem.width, rng.random(members.size),
                                  np.full(members.size, -1, np.int8))
    stay = parts == (1 if swap else 0)
    pixels = flat.copy()
    pixels[pixels >= k] += 1
    pixels[members[~stay]] = k
    if stay.all() or not stay.any():
        return Proposal.invalid(work.layout.with_pixels(pixels.reshape(work.layout.pixels.shape), n_mat + 1))
    n_ch = problem.n_channels
    rows_m = material_rows(m, n_ch)
    data_x, data_y = (cluster_data(problem, members[stay], work.pixel_sets),
                      cluster_data(problem, members[~stay], work.pixel_sets))
    theta_x, term_x = material_term(data_x, None, prior, proposals, draw_rng=rng)
    theta_y, term_y = (material_term(data_y, None, prior, proposals, draw_rng=rng) if theta_x is not None
                       else (None, 0))
    if theta_x is None or theta_y is None:
        return Proposal.invalid(work.layout.with_pixels(pixels.reshape(work.layout.pixels.shape), n_mat + 1))
    _, term_m = material_term(cluster_data(problem, members, work.pixel_sets), work.theta[rows_m], prior, proposals)
    stats_x, stats_y = stats_rows(data_x, theta_x[0, 2]), stats_rows(data_y, theta_y[0, 2])
    delta_lik = (material_log_lik(stats_x, theta_x) + material_log_lik(stats_y, theta_y)
                 - float(np.sum(work.log_lik[rows_m])))
    log_ratio = (delta_lik + math.log(potts.rho) - math.log(n_mat + 1)
                 - potts.beta * _edges_between(problem.image_shape, members[stay], members[~stay])
                 + term_x + term_y - term_m
                 + _ratio_choices(n_mat, m, max_materials, settings, p_split)
                 - (HALVES_LOG_PROB if spatial  # the parts are the halves, by construction
                    else split_log_prob(members, guide, stay, problem, float(potts.beta))))
    theta = with_rows(work.theta, k * n_ch, theta_y)
    theta[rows_m] = theta_x
    stats = with_rows(work.stats, k * n_ch, stats_y)
    stats[rows_m] = stats_x
    return _proposal(work, problem, pixels, n_mat + 1, theta, stats, log_ratio)


def _merge(work, rng, problem, prior, settings, proposals, potts, max_materials, p_split, spatial=False):
    n_mat = work.layout.n_materials
    flat = work.layout.pixels.ravel()
    j, k = sorted(int(x) for x in rng.choice(n_mat, 2, replace=False))
    members = np.flatnonzero((flat == j) | (flat == k))
    n_ch = problem.n_channels
    rows_j, rows_k = material_rows(j, n_ch), material_rows(k, n_ch)
    pixels = flat.copy()
    pixels[pixels == k] = j
    pixels[pixels > k] -= 1
    in_j = flat[members] == j
    # a spatial merge only of a pair that a spatial split proposes: the two halves of their union
    log_q = _halves_log_prob(members, in_j, problem.width) if spatial else None
    if log_q == -math.inf:
        return Proposal.invalid(work.layout.with_pixels(pixels.reshape(work.layout.pixels.shape), n_mat - 1))
    data = cluster_data(problem, members, work.pixel_sets)
    theta_m, term_m = material_term(data, None, prior, proposals, draw_rng=rng)
    if theta_m is None:
        return Proposal.invalid(work.layout.with_pixels(pixels.reshape(work.layout.pixels.shape), n_mat - 1))
    _, term_j = material_term(cluster_data(problem, members[in_j], work.pixel_sets), work.theta[rows_j], prior,
                              proposals)
    _, term_k = material_term(cluster_data(problem, members[~in_j], work.pixel_sets), work.theta[rows_k], prior,
                              proposals)
    stats_m = stats_rows(data, theta_m[0, 2])
    log_lik_jk = (float(work.log_lik[j] + work.log_lik[k]) if n_ch == 1
                  else float(np.sum(work.log_lik[rows_j]) + np.sum(work.log_lik[rows_k])))
    delta_lik = material_log_lik(stats_m, theta_m) - log_lik_jk
    if not spatial:
        guide = split_guide(problem, prior, members, work.layout.bonds.features, work.pixel_sets)
        log_q = split_log_prob(members, guide, in_j, problem, float(potts.beta))
    p_split_back = split_probability(n_mat - 1, max_materials, settings.split_prob)
    log_ratio = (delta_lik - math.log(potts.rho) + math.log(n_mat)
                 + potts.beta * _edges_between(problem.image_shape, members[in_j], members[~in_j])
                 + term_m - term_j - term_k
                 - _ratio_choices(n_mat - 1, j, max_materials, settings, p_split_back)
                 + log_q)
    theta = np.delete(work.theta, np.arange(k * n_ch, (k + 1) * n_ch), axis=0)
    theta[rows_j] = theta_m
    stats = np.delete(work.stats, np.arange(k * n_ch, (k + 1) * n_ch), axis=0)
    stats[rows_j] = stats_m
    return _proposal(work, problem, pixels, n_mat - 1, theta, stats, log_ratio)
