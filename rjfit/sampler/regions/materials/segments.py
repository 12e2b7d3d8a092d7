"""A fixed family of candidate pixel sets for the material model's segment moves, from the data alone.

Why: the cluster moves grow their clusters pixel by pixel along bonds, and on measured data a
paint's per-pixel features are too noisy for bonds to follow its outline (psm-rock: the
large pebble's diffuse feature lies 2.1 within-material sd from the matrix's, and the bonds
across its outline, q 0.54, are nearly those inside it, 0.65), so no cluster move proposes a
compact region of a second paint, and no chain found the pebble. Averaged over a region of a
few hundred pixels, the same features separate it clearly. So the family pools first:

1. the per-pixel features (:func:`~rjfit.sampler.regions.materials.layout.pixel_features`),
   each mapped by ``log(1 + x / median)`` (the specular one is heavy-tailed), divided by the
   robust spread of neighbour differences (about the noise), a pixel without a fit given its
   nearest fitted pixel's;
2. superpixels of about ``superpixel_size`` pixels by SLIC (Achanta et al., "SLIC
   superpixels compared to state-of-the-art superpixel methods", IEEE PAMI 34(11), 2012;
   :func:`skimage.segmentation.slic`) over the labelled pixels; with too few labelled pixels
   for two superpixels, each pixel is one;
3. Ward's agglomeration of neighbouring superpixels (the merge that least raises the sum of
   squared deviations from the regions' mean features, ``n_i n_j / (n_i + n_j) |m_i - m_j|^2``),
   until one region per connected part is left.

Every node of that hierarchy is a connected candidate set. A segment move draws one with a
fixed weight: the hierarchy cut at M regions, M drawn with probability proportional to
``1 / M`` over ``2 .. max_regions``, then one region of the cut uniformly; a node's weight is
the sum over the cuts it belongs to. The weights depend on the data only, so a move's
probability of proposing a set is the same forwards and backwards and cancels in its ratio
(:mod:`rjfit.sampler.regions.materials.segment_move`).

Storage: the superpixels are ordered by a depth-first walk of the hierarchy, so every node's
pixels are one contiguous range of one pixel permutation.
"""
from __future__ import annotations

import heapq
from typing import NamedTuple

import numpy as np
from scipy import ndimage
from skimage.measure import label
from skimage.segmentation import slic

__all__ = ["Segments", "segment_family"]

#: labelled pixels up to which SLIC runs on the mask. A masked SLIC seeds its centres by k-means
#: over the mask's pixels (scikit-image's ``_get_mask_centroids``), whose cost is pixels x
#: superpixels: 9 s at 176,000 labelled pixels, 8 minutes at 706,000 (a 1024 x 1024 scanner stack,
#: measured 2026-11-28). Above it SLIC is seeded on a grid over the whole image (linear cost: 28 s
#: at 706,000). The grid's superpixels follow a blob's outline a little less closely (a blob's best
#: candidate set: IoU 0.73 to 0.89 against 0.85 to 0.92 masked, 3 seeds x 2 places on a 530 x 530
#: mask; docs/results/2026-11-28-scale.md). Every shared stack and the rendered ones lie below it.
SLIC_WHOLE_MAX = 2 ** 18


class Segments(NamedTuple):
    """The candidate sets: ``order`` (the labelled pixels, flat indices, grouped by set);
    set s is ``order[start[s]:stop[s]]``; ``cdf`` the sets' cumulative weights."""

    order: np.ndarray
    start: np.ndarray
    stop: np.ndarray
    cdf: np.ndarray

    def draw(self, rng) -> np.ndarray:
        """One set's pixels (flat indices, ascending), drawn with the fixed weights by one uniform of ``rng``."""
        s = int(min(np.searchsorted(self.cdf, rng.random() * self.cdf[-1], side="right"), self.cdf.size - 1))
        return np.sort(self.order[self.start[s]:self.stop[s]])

    @property
    def n_sets(self) -> int:
        return int(self.cdf.size)


def segment_family(features, labelled, superpixel_size: int = 32, max_regions: int = 64) -> Segments:
    """The candidate sets of the segment moves (see the module docstring).

    Parameters
    ----------
    features : (H W, F) array
        Per-pixel features, NaN where a pixel has no fit.
    labelled : (H, W) bool array
        The labelled pixels.
    superpixel_size : int
        SLIC's target superpixel size in pixels.
    max_regions : int
        The finest cut of the hierarchy that sets are drawn from.

    Raises
    ------
    ValueError
        If no pixel is labelled, ``features`` has another number of rows than ``labelled``
        pixels, or ``superpixel_size`` or ``max_regions`` is below 1 and 2.
    """
    labelled = np.asarray(labelled, bool)
    features = np.asarray(features, float)
    if features.ndim != 2 or features.shape[0] != labelled.size:
        raise ValueError(f"features must be (H W, F) = ({labelled.size}, F), got {features.shape}")
    if not labelled.any():
        raise ValueError("segment_family needs at least one labelled pixel")
    if superpixel_size < 1 or max_regions < 2:
        raise ValueError(f"superpixel_size must be >= 1 and max_regions >= 2, got {superpixel_size}, {max_regions}")
    image = _standardised(features.reshape(*labelled.shape, -1), labelled)
    superpixels = _superpixels(image, labelled, superpixel_size)
    children, birth, death, n_leaves = _ward_tree(image, labelled, superpixels)
    return _family(superpixels, labelled, children, birth, death, n_leaves, max_regions)


def _standardised(features, labelled):
    """(H, W, F): ``log(1 + x / median)`` per feature over the noise's spread; unfitted pixels filled."""
    fitted = np.all(np.isfinite(features), axis=-1) & labelled
    if not fitted.any():
        return np.zeros(features.shape)
    median = np.array([np.median(features[..., j][fitted]) for j in range(features.shape[-1])])
    image = np.log1p(np.maximum(np.nan_to_num(features), 0.0) / np.where(median > 0, median, 1.0))
    nearest = ndimage.distance_transform_edt(~fitted, return_distances=False, return_indices=True)
    image = image[nearest[0], nearest[1]]
    across = [np.abs(np.diff(image, axis=axis))[fitted_pair] for axis, fitted_pair in
              ((1, fitted[:, 1:] & fitted[:, :-1]), (0, fitted[1:] & fitted[:-1]))]
    across = np.concatenate(across, axis=0)
    spread = 1.4826 * np.median(across, axis=0) if across.size else np.ones(image.shape[-1])
    image = image / np.where(spread > 0, spread, 1.0)
    image[~labelled] = 0.0
    return image


def _superpixels(image, labelled, superpixel_size):
    """(H, W) superpixel per labelled pixel, 0 .. S - 1 (-1 elsewhere).

    Up to :data:`SLIC_WHOLE_MAX` labelled pixels, SLIC on the mask; above, SLIC seeded on a grid
    over the whole image, so that the cost grows with the pixels and not with their square (why:
    the constant's comment).
    """
    n_labelled = int(labelled.sum())
    out = np.full(labelled.shape, -1, np.int64)
    if n_labelled < 2 * superpixel_size:
        out[labelled] = np.arange(n_labelled)
        return out
    # compactness 0.1 on features in noise units: the features decide the superpixels'
    # outlines more than their extent (a blob 2 noise sd from its surround, per pixel: the
    # best set's overlap with it 0.87 to 0.93 at 0.1, 0.76 to 0.83 at 1; docs/results/materials.md)
    settings = {"compactness": 0.1, "channel_axis": -1, "start_label": 1, "sigma": 0}
    if n_labelled <= SLIC_WHOLE_MAX:
        raw = slic(image, n_segments=max(2, n_labelled // superpixel_size), mask=labelled, **settings)
    else:
        # seeded on a grid over the whole image (no mask: no k-means), then each superpixel's part inside the
        # mask split into its 4-connected pieces, since a candidate set must be connected
        grid = slic(image, n_segments=max(2, labelled.size // superpixel_size), **settings)
        raw = label(np.where(labelled, grid, 0), background=0, connectivity=1)
    used, dense = np.unique(np.where(labelled, raw, 0)[labelled], return_inverse=True)
    out[labelled] = dense
    return out


def _adjacent_pairs(superpixels):
    """The unordered pairs of different superpixels that share a 4-neighbour edge."""
    pairs = []
    for first, second in ((superpixels[:, :-1], superpixels[:, 1:]), (superpixels[:-1], superpixels[1:])):
        both = (first >= 0) & (second >= 0) & (first != second)
        pairs.append(np.stack([first[both], second[both]], axis=1))
    pairs = np.sort(np.concatenate(pairs), axis=1)
    return np.unique(pairs, axis=0)


def _ward_tree(image, labelled, superpixels):
    """Ward's agglomeration of neighbouring superpixels: ``(children, birth, death, S)``; node s < S is
    superpixel s, node S + t - 1 the t-th merge's; birth / death the merge steps that made / took a node."""
    n_leaves = int(superpixels.max()) + 1
    flat = superpixels[labelled]
    size = list(np.bincount(flat, minlength=n_leaves).astype(float))
    sums = list(np.stack([np.bincount(flat, weights=image[..., j][labelled], minlength=n_leaves)
                          for j in range(image.shape[-1])], axis=1))
    neighbours = [set() for _ in range(n_leaves)]
    for i, j in _adjacent_pairs(superpixels):
        neighbours[i].add(int(j))
        neighbours[j].add(int(i))

    def cost(i, j):
        gap = sums[i] / size[i] - sums[j] / size[j]
        return size[i] * size[j] / (size[i] + size[j]) * float(gap @ gap)

    heap = [(cost(i, j), i, j) for i in range(n_leaves) for j in neighbours[i] if i < j]
    heapq.heapify(heap)
    alive = [True] * n_leaves
    children = [()] * n_leaves
    birth, death = [0] * n_leaves, [None] * n_leaves
    while heap:
        _, i, j = heapq.heappop(heap)
        if not (alive[i] and alive[j]):
            continue                               # a stale entry: one of the pair was merged already
        node, step = len(size), len(size) - n_leaves + 1
        size.append(size[i] + size[j])
        sums.append(sums[i] + sums[j])
        children.append((i, j))
        alive.append(True)
        birth.append(step)
        death.append(None)
        alive[i] = alive[j] = False
        death[i] = death[j] = step
        joined = (neighbours[i] | neighbours[j]) - {i, j}
        neighbours.append(joined)
        for other in joined:
            neighbours[other] -= {i, j}
            neighbours[other].add(node)
            heapq.heappush(heap, (cost(node, other), node, other))
    return children, birth, death, n_leaves


def _family(superpixels, labelled, children, birth, death, n_leaves, max_regions) -> Segments:
    """The nodes with positive weight, as contiguous ranges of a depth-first pixel order."""
    n_nodes = len(children)
    n_merges = n_nodes - n_leaves
    n_roots = n_leaves - n_merges
    cuts = np.arange(max(2, n_roots), min(max_regions, n_leaves) + 1)
    weight = np.zeros(n_nodes)
    if cuts.size:
        p_cut = (1.0 / cuts) / np.sum(1.0 / cuts)
        for node in range(n_nodes):
            # node is a region of the cut at M regions when birth <= n_leaves - M < death
            lo = n_leaves - (n_merges + 1 if death[node] is None else death[node]) + 1
            hi = n_leaves - birth[node]
            inside = (cuts >= lo) & (cuts <= hi)
            weight[node] = float(np.sum(p_cut[inside] / cuts[inside]))
    else:                                          # no cut of 2 regions or more: the parts alone
        weight[[node for node in range(n_nodes) if death[node] is None]] = 1.0
    leaf_order, first_leaf, last_leaf = _depth_first(children, death, n_leaves)
    rank = np.empty(n_leaves, np.int64)
    rank[leaf_order] = np.arange(n_leaves)
    flat_index = np.flatnonzero(labelled.ravel())
    leaf_of_pixel = superpixels.ravel()[flat_index]
    order = flat_index[np.argsort(rank[leaf_of_pixel], kind="stable")]
    offsets = np.concatenate([[0], np.cumsum(np.bincount(leaf_of_pixel, minlength=n_leaves)[leaf_order])])
    kept = np.flatnonzero(weight > 0)
    start = offsets[first_leaf[kept]]
    stop = offsets[last_leaf[kept] + 1]
    return Segments(order=order, start=start, stop=stop, cdf=np.cumsum(weight[kept]))


def _depth_first(children, death, n_leaves):
    """The leaves in depth-first order from the roots, and each node's first and last leaf position."""
    n_nodes = len(children)
    first = np.zeros(n_nodes, np.int64)
    last = np.zeros(n_nodes, np.int64)
    order = []
    for root in (node for node in range(n_nodes) if death[node] is None):
        stack = [(root, False)]
        while stack:
            node, done = stack.pop()
            if node < n_leaves:
                first[node] = last[node] = len(order)
                order.append(node)
            elif done:
                left, right = children[node]
                first[node], last[node] = first[left], last[right]
            else:
                left, right = children[node]
                stack.extend([(node, True), (right, False), (left, False)])
    return np.array(order, np.int64), first, last
