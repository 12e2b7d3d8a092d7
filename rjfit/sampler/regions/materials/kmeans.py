"""k-means of per-pixel features: the material model's random start and its split proposals' deterministic guide;
the 2-means of a material's pixel positions, its spatial splits' halves.

Plain Lloyd iterations on standardised rows (:func:`lloyd`): :func:`kmeans_labels` starts
from rows drawn from the chain's generator, :func:`two_means_labels` from a split of the
first principal axis (no random draw: a proposal's guide must be a function of the data).
"""
from __future__ import annotations

import numpy as np

from rjfit.sampler.regions.materials.passes.lloyd import MAX_FEATURES, MIN_FEATURES, lloyd_iterations

__all__ = ["standardised", "lloyd", "lloyd_numpy", "kmeans_labels", "two_means_labels", "spatial_halves"]


def standardised(features) -> np.ndarray:
    """Columns centred and scaled to unit sd (constant columns only centred); NaN rows set to the centre."""
    x = np.asarray(features, float)
    finite = bool(np.isfinite(x).all())
    spread = np.std(x, axis=0) if finite else np.nanstd(x, axis=0)
    x = (x - (np.mean(x, axis=0) if finite else np.nanmean(x, axis=0))) / np.where(spread > 0, spread, 1.0)
    return x if finite else np.nan_to_num(x, nan=0.0)


def lloyd(x, centres, iterations: int = 20) -> np.ndarray:
    """Lloyd's iterations of k-means from ``centres`` (k, d) (updated in place): the labels of the rows of ``x``.

    A cluster left empty takes the row farthest from its centre, so every label 0 .. k - 1
    is used (needs at least k rows). Stops early once the labels repeat (what further
    iterations would give). Compiled (:func:`~rjfit.sampler.regions.materials.passes.lloyd.lloyd_iterations`,
    the same numbers) where the features' count allows, else :func:`lloyd_numpy`.
    """
    x = np.asarray(x)
    compiled = (MIN_FEATURES <= x.shape[1] <= MAX_FEATURES and x.dtype == np.float64 and centres.dtype == np.float64
                and centres.flags.c_contiguous)
    if compiled:
        return lloyd_iterations(np.ascontiguousarray(x), centres, int(iterations))
    return lloyd_numpy(x, centres, iterations)


def lloyd_numpy(x, centres, iterations: int = 20) -> np.ndarray:
    """:func:`lloyd` in NumPy: the reference of the compiled form, and the form for one or many features."""
    n_clusters = centres.shape[0]
    labels = np.full(x.shape[0], -1, np.int64)
    for _ in range(iterations):
        dist = ((x[:, None, :] - centres[None]) ** 2).sum(-1)
        previous, labels = labels, np.argmin(dist, axis=1)
        if np.array_equal(labels, previous):
            break       # converged: the centres are these labels' means already
        for k in range(n_clusters):
            members = labels == k
            if not np.any(members):
                far = int(np.argmax(dist[np.arange(x.shape[0]), labels]))
                labels[far] = k
                members = labels == k
            centres[k] = x[members].mean(axis=0)
    for k in range(n_clusters):      # the final assignment may leave one empty: give it a row
        if not np.any(labels == k):
            counts = np.bincount(labels, minlength=n_clusters)
            donor = np.flatnonzero(counts[labels] > 1)[0]
            labels[donor] = k
    return labels


def kmeans_labels(features, n_clusters: int, rng, iterations: int = 20) -> np.ndarray:
    """Lloyd's k-means of the rows of ``features`` (standardised; NaN rows go to the nearest centre by the others).

    Centres start at distinct rows drawn from ``rng``; every label 0 .. n_clusters - 1 is
    used (:func:`lloyd`; needs at least ``n_clusters`` rows).
    """
    x = standardised(features)
    centres = x[rng.choice(x.shape[0], n_clusters, replace=False)]
    return lloyd(x, centres, iterations)


def two_means_labels(features, iterations: int = 20) -> np.ndarray | None:
    """A deterministic 2-means of the rows of ``features`` (all finite): labels 0 / 1, or None if they are alike.

    Standardised rows are split at the median of their projection on the first principal
    axis, and Lloyd's iterations start from the two halves' means: a function of the rows
    alone (no random draw), as the guide of a split proposal must be. None when fewer than
    two rows differ along that axis.
    """
    return _principal_two_means(standardised(features), iterations)


def _principal_two_means(x, iterations: int) -> np.ndarray | None:
    """Lloyd's 2-means of the centred rows ``x`` from the halves of their first principal axis (split at the
    median), or None for fewer than two rows or none apart along that axis."""
    if x.shape[0] < 2:
        return None
    # the first principal axis: the top eigenvector of the (d, d) scatter matrix (d is 2
    # here; an SVD of the (n, d) rows costs more than the rest of a small split)
    _, axes = np.linalg.eigh(x.T @ x)
    projection = x @ axes[:, -1]
    upper = projection > np.median(projection)
    if upper.all() or not upper.any():
        return None
    centres = np.stack([x[~upper].mean(axis=0), x[upper].mean(axis=0)])
    return lloyd(x, centres, iterations)


def spatial_halves(members, width: int, iterations: int = 20) -> np.ndarray | None:
    """A deterministic 2-means of the image positions (row, column) of the pixels ``members`` (flat indices):
    labels 0 / 1, or None for fewer than two pixels or none apart along the first principal axis.

    As :func:`two_means_labels` but on positions centred and NOT standardised, so both axes keep one scale (a
    distance in pixels): the split of a material's pixels into its two spatial halves, a function of the set
    alone, as a spatial split proposal's must be (:mod:`rjfit.sampler.regions.materials.merge_split`).
    """
    members = np.asarray(members, np.int64)
    x = np.stack([members // width, members % width], axis=1).astype(np.float64)
    return _principal_two_means(x - x.mean(axis=0) if members.size else x, iterations)
