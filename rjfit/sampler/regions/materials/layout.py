"""The layout of the material region model: a material label per pixel, its Potts prior, bonds and start.

:class:`MaterialLabels` holds the labels ``(H, W)`` (-1 off the labelled pixels), the
number K of materials (every label 0 .. K - 1 in use) and the data-driven bond
probabilities of the Swendsen-Wang-cut moves (:class:`Bonds`; a function of the data only,
computed once and carried from layout to layout).

Labelled pixels are the object mask's pixels and every pixel with an observation. Their
4-neighbour pairs are the edges of the Potts prior ``pi(S) ~ rho^K exp(-beta B(S))``,
``B`` the number of edges whose two pixels carry different materials
(:func:`boundary_count`).

Bond probabilities (:func:`bond_probabilities`). Every pixel with at least three
observations is fitted on its own: least squares of its observations on ``A = E <l.n> / pi``
and ``B = E <l.n> <h.n>^g0`` at ``g0 =`` :data:`BOND_GAMMA` (a, b clipped at 0), the two
coefficients its appearance with the shading removed. Feature j of an edge differs by
``d_j``; each is divided by ``s_j = 1.4826 median |d_j|`` over all edges (a robust spread of
the differences between neighbours, most of which lie inside one material), and
``q_e = q_max exp(-|d / s|^2 / (2 tau^2))``. An edge touching a pixel without a fit gets
``q_max / 2``. A joint colour fit's features are every channel's (a, b) (2 C of them), so
the bonds and the split guides see hue. Every q lies in [0, q_max] with q_max < 1, so every cut weight
``log(1 - q)`` is finite; the cluster moves take ``q_max = 1 - exp(-beta)`` (Swendsen and
Wang's bond for the Potts prior: see :class:`~rjfit.sampler.regions.materials.cluster_swc.ClusterSettings`). The cluster moves are exact for any such q; q only decides which
clusters they propose.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy import ndimage
from scipy.special import gammaln

from rjfit.sampler.colour import colour_pixel_features
from rjfit.sampler.likelihood import b_terms
from rjfit.sampler.regions.base import pixel_labels_per_observation
from rjfit.sampler.regions.materials.kmeans import kmeans_labels

__all__ = ["MaterialLabels", "Bonds", "bond_probabilities", "pixel_features", "boundary_count", "labelled_pixels",
           "kmeans_labels", "majority_labels", "PottsPrior", "BOND_GAMMA"]

BOND_GAMMA = 10.0


class Bonds(NamedTuple):
    """What the label moves read from the data alone, computed once: the bonds and the per-pixel features.

    ``q`` (2 H W,): the bond probabilities of the cluster moves, edge ``2 p`` to the right of
    p, ``2 p + 1`` below it; ``features`` (H W, 2): :func:`pixel_features`, which the bonds
    and the split proposals' guides use; ``seed_cdf`` (H W,): the cumulative seed weights of
    the cluster moves (:func:`seed_weights`); ``segments``: the segment moves' candidate sets
    (:class:`~rjfit.sampler.regions.materials.segments.Segments`; None without segment moves);
    ``edges``: the target's edge term (:class:`~rjfit.sampler.regions.materials.edges.EdgeTerm`; None without one);
    ``potts_q`` (2 H W,): ``q_max`` on every edge between two labelled pixels, the bonds of the component moves
    (:mod:`rjfit.sampler.regions.materials.component_move`), which do not read the data.
    """

    q: np.ndarray
    q_max: float
    tau: float
    features: np.ndarray
    seed_cdf: np.ndarray
    segments: object = None
    edges: object = None
    potts_q: np.ndarray = None

    def draw_seed(self, rng) -> int:
        """A cluster move's seed pixel, drawn with the seed weights by one uniform of ``rng``."""
        cdf = self.seed_cdf
        # argmax: the first index at the total, the last pixel of positive weight (a guard
        # against rounding at u * total == total; never reached otherwise)
        return int(min(np.searchsorted(cdf, rng.random() * cdf[-1], side="right"), np.argmax(cdf)))


def labelled_pixels(problem) -> np.ndarray:
    """(H, W) bool: the object mask's pixels and every pixel with an observation."""
    counts = np.diff(problem.pixel_start).reshape(problem.image_shape)
    return np.asarray(problem.object_mask, bool) | (counts > 0)


def pixel_features(problem, gamma: float = BOND_GAMMA) -> np.ndarray:
    """(H W, 2) per-pixel least-squares (a, b) at exponent ``gamma`` (clipped at 0); NaN with < 3 observations."""
    n_pix = problem.height * problem.width
    pixel = np.asarray(problem.pixel, np.int64)
    y = problem.y.astype(np.float64)
    A = problem.A
    B = b_terms(problem.C, problem.log_cos_hn, gamma)

    def sums(w):
        return np.bincount(pixel, weights=w, minlength=n_pix)

    s_ya, s_yb, s_aa, s_ab, s_bb = sums(y * A), sums(y * B), sums(A * A), sums(A * B), sums(B * B)
    count = np.bincount(pixel, minlength=n_pix)
    det = s_aa * s_bb - s_ab * s_ab
    ok = (count >= 3) & (det > 1e-12 * np.maximum(s_aa * s_bb, 1e-300))
    safe = np.where(ok, det, 1.0)
    a = (s_bb * s_ya - s_ab * s_yb) / safe
    b = (s_aa * s_yb - s_ab * s_ya) / safe
    features = np.stack([np.clip(a, 0, None), np.clip(b, 0, None)], axis=1)
    features[~ok] = np.nan
    return features


def _edge_pairs(labelled):
    """(first, second) flat pixel indices and edge ids of every edge between two labelled pixels."""
    height, width = labelled.shape
    flat = labelled.ravel()
    p = np.arange(height * width)
    right = (p % width < width - 1) & flat & np.roll(flat, -1)
    down = (p < (height - 1) * width) & flat & np.concatenate([flat[width:], np.zeros(width, bool)])
    first = np.concatenate([p[right], p[down]])
    second = np.concatenate([p[right] + 1, p[down] + width])
    edges = np.concatenate([2 * p[right], 2 * p[down] + 1])
    return first, second, edges


def bond_probabilities(problem, q_max: float = 1.0 - np.exp(-1.0), tau: float = 2.0) -> Bonds:
    """The bonds of the cluster moves from the data (see the module docstring).

    Raises
    ------
    ValueError
        If ``q_max`` is not in (0, 1) or ``tau`` not positive.
    """
    if not 0.0 <= q_max < 1.0 or not tau > 0:
        raise ValueError(f"bond q_max must lie in [0, 1) and tau be positive, got {q_max}, {tau}")
    labelled = labelled_pixels(problem)
    features = pixel_features(problem) if problem.n_channels == 1 else colour_pixel_features(problem, BOND_GAMMA)
    first, second, edges = _edge_pairs(labelled)
    q = np.zeros(2 * labelled.size)
    diff = np.abs(features[first] - features[second])
    fitted = np.all(np.isfinite(diff), axis=1)
    if np.any(fitted):
        spread = 1.4826 * np.median(diff[fitted], axis=0)
        scale = np.nanmedian(np.abs(features), axis=0)
        spread = np.maximum(spread, 1e-6 * np.where(np.isfinite(scale) & (scale > 0), scale, 1.0))
        d2 = np.sum((diff / spread) ** 2, axis=1)
        q[edges] = np.where(fitted, q_max * np.exp(-0.5 * np.nan_to_num(d2, nan=np.inf) / tau ** 2), 0.5 * q_max)
    else:
        q[edges] = 0.5 * q_max
    seeds = seed_weights(labelled, q, q_max, first, second, edges)
    potts_q = np.zeros(2 * labelled.size)
    potts_q[edges] = q_max
    return Bonds(q=q, q_max=float(q_max), tau=float(tau), features=features, seed_cdf=np.cumsum(seeds),
                 potts_q=potts_q)


def seed_weights(labelled, q, q_max, first, second, edges) -> np.ndarray:
    """(H W,) the cluster moves' seed probabilities: half uniform over the labelled pixels, half by weak bonds.

    A pixel's weakness is the mean over its edges of ``1 - q_e / q_max`` (1 with no edge):
    about 0.2 inside a uniform paint (the noise of its features), 0.3 to 0.5 on a boundary,
    about 1 at a pixel unlike all its neighbours. The second half goes by its cube, so that
    those pixels stand out against a paint's noise: seeds fall there more often, and the
    clusters of one or a few such pixels (births and deaths of small materials, boundary
    moves) are proposed often. The weights are a
    function of the data alone, and a cluster move's proposal probability holds them only
    as the sum over its cluster, the same both ways: they cancel in every ratio.
    """
    n_pix = labelled.size
    strength = np.zeros(n_pix)
    degree = np.zeros(n_pix)
    rel = q[edges] / q_max if q_max > 0 else np.zeros(edges.size)
    for end in (first, second):
        np.add.at(strength, end, rel)
        np.add.at(degree, end, 1.0)
    weakness = (np.where(degree > 0, 1.0 - strength / np.maximum(degree, 1.0), 1.0) * labelled.ravel()) ** 3
    uniform = labelled.ravel() / max(int(labelled.sum()), 1)
    total = weakness.sum()
    return 0.5 * uniform + 0.5 * (weakness / total if total > 0 else uniform)


def majority_labels(pixels, n_labels: int, radius: int = 2) -> tuple[np.ndarray, int]:
    """``pixels`` (H, W; -1 unlabelled) with each labelled pixel given the most common label of the
    labelled pixels within ``radius`` (a (2 r + 1)^2 window), and the labels in use renumbered 0 .. K' - 1.

    What a chain's start does to its k-means labels: per-pixel features of measured data are
    noisy, so the k-means scatters each cluster pixel by pixel, and under the Potts prior such a
    start costs beta per unlike neighbour pair; its first moves then merge materials wholesale
    to shed that cost (psm-rock: K 3 -> 1 within 14 iterations) rather than let the label
    sweeps clean up a compact material (the rock's pebble). A start changes nothing in the
    target. Returns ``(labels, K')``, K' <= ``n_labels`` (a cluster with no window majority goes).
    """
    z = np.asarray(pixels)
    labelled = z >= 0
    size = 2 * int(radius) + 1
    votes = np.stack([ndimage.uniform_filter((z == k).astype(float), size, mode="constant")
                      for k in range(int(n_labels))], axis=-1)
    out = np.where(labelled, np.argmax(votes, axis=-1), -1)
    used = np.unique(out[labelled])
    renumber = np.full(int(n_labels), -1, np.int64)
    renumber[used] = np.arange(used.size)
    return np.where(labelled, renumber[np.maximum(out, 0)], -1).astype(z.dtype), int(used.size)


def boundary_count(pixel_labels) -> int:
    """B(S): 4-neighbour pairs of labelled pixels (label >= 0) with different labels."""
    z = np.asarray(pixel_labels)
    horizontal = (z[:, 1:] >= 0) & (z[:, :-1] >= 0) & (z[:, 1:] != z[:, :-1])
    vertical = (z[1:] >= 0) & (z[:-1] >= 0) & (z[1:] != z[:-1])
    return int(np.count_nonzero(horizontal) + np.count_nonzero(vertical))


class MaterialLabels(NamedTuple):
    """The material model's layout: ``pixels`` (H, W) material per pixel (-1 unlabelled), K, bonds.

    Immutable by convention: a move builds a new one (the bonds are shared, never written).
    """

    pixels: np.ndarray
    n_materials: int
    bonds: Bonds

    @property
    def n_regions(self) -> int:
        return int(self.n_materials)

    @property
    def model_key(self) -> tuple[int]:
        """``(K,)``: the number of materials."""
        return (int(self.n_materials),)

    def labels(self, problem) -> np.ndarray:
        """The material of every observation of ``problem`` (its pixel's label, repeated per observation);
        for a joint colour fit its parameter row, ``material C + channel``."""
        return pixel_labels_per_observation(self.pixels, self.n_materials, problem)

    def counts(self) -> np.ndarray:
        """Pixels per material (K,)."""
        z = self.pixels.ravel()
        return np.bincount(z[z >= 0], minlength=self.n_materials)

    def with_pixels(self, pixels, n_materials: int) -> MaterialLabels:
        return MaterialLabels(pixels, int(n_materials), self.bonds)


@dataclass(frozen=True)
class PottsPrior:
    """The prior of partitions ``pi(S) ~ rho^K exp(-beta B(S))``, with the K! labellings of a partition.

    The labelled state has log density ``K log rho - beta B - log K!`` (:meth:`log_density`);
    its normaliser depends on (beta, rho) only, so every acceptance ratio is exact without it.
    """

    beta: float = 3.0
    rho: float = 1.0

    def log_density(self, pixels, n_materials: int) -> float:
        """Log prior of a labelled state (materials numbered 0 .. K - 1, every one in use)."""
        return float(n_materials * np.log(self.rho) - self.beta * boundary_count(pixels) - gammaln(n_materials + 1))
