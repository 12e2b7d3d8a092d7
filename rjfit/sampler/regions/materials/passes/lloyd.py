"""Compiled Lloyd iterations of k-means (:func:`rjfit.sampler.regions.materials.kmeans.lloyd`), the same numbers as its NumPy form.

A split proposal's guide runs a 2-means of its material's pixels in every merge/split move;
in NumPy each iteration makes (n, k, d) temporaries and a boolean mask per cluster, about
a tenth of a step on the DiLiGenT ball. This loop does the same arithmetic in the same
order, so its labels and centres equal the NumPy form's to the last bit (what keeps a
chain's draws unchanged; ``tests/sampler/test_materials.py`` compares the two):

- a squared distance is NumPy's ``sum(-1)`` of the squared differences: their sequential
  sum (NumPy sums fewer than 8 terms in sequence, more pairwise), so ``d <= MAX_FEATURES``;
- a centre is NumPy's ``mean(axis=0)`` of its rows: their sequential sum (a reduction
  along the slow axis is not pairwise) divided by their number; so ``d >= 2`` (with one
  column the rows are the fast axis, and NumPy sums them pairwise);
- ``argmin`` and ``argmax`` keep the first of equal values.
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["MIN_FEATURES", "MAX_FEATURES", "lloyd_iterations"]

MIN_FEATURES = 2      # one column: NumPy's centres are pairwise sums (not reproduced here)
MAX_FEATURES = 7      # NumPy sums fewer than 8 terms in sequence; more, pairwise (not reproduced here)


@njit(cache=True, nogil=True)
def _distances(x, centres, dist):
    """``dist[i, k] = sum_j (x[i, j] - centres[k, j])^2`` in NumPy's order (module docstring)."""
    for i in range(x.shape[0]):
        for k in range(centres.shape[0]):
            total = 0.0
            for j in range(x.shape[1]):
                diff = x[i, j] - centres[k, j]
                total += diff * diff
            dist[i, k] = total


@njit(cache=True, nogil=True)
def _nearest(dist, labels):
    """Each row's first nearest centre into ``labels``; whether any label changed."""
    changed = False
    for i in range(dist.shape[0]):
        best = 0
        for k in range(1, dist.shape[1]):
            if dist[i, k] < dist[i, best]:
                best = k
        if labels[i] != best:
            changed = True
        labels[i] = best
    return changed


@njit(cache=True, nogil=True)
def _fill_empty(dist, labels, k):
    """If cluster ``k`` has no row, give it the row farthest from its centre (the first of equals)."""
    for i in range(labels.shape[0]):
        if labels[i] == k:
            return
    far = 0
    for i in range(1, labels.shape[0]):
        if dist[i, labels[i]] > dist[far, labels[far]]:
            far = i
    labels[far] = k


@njit(cache=True, nogil=True)
def _centre(x, labels, k, centres):
    """``centres[k]``: the mean of the rows labelled ``k`` (at least one), summed in row order."""
    count = 0
    for j in range(x.shape[1]):
        centres[k, j] = 0.0
    for i in range(x.shape[0]):
        if labels[i] == k:
            for j in range(x.shape[1]):
                centres[k, j] = x[i, j] if count == 0 else centres[k, j] + x[i, j]
            count += 1
    for j in range(x.shape[1]):
        centres[k, j] /= count


@njit(cache=True, nogil=True)
def _donate(labels, k, n_clusters):
    """If cluster ``k`` has no row, give it the first row whose cluster has more than one."""
    counts = np.zeros(n_clusters, np.int64)
    for i in range(labels.shape[0]):
        counts[labels[i]] += 1
    if counts[k] > 0:
        return
    for i in range(labels.shape[0]):
        if counts[labels[i]] > 1:
            labels[i] = k
            return


@njit(cache=True, nogil=True)
def lloyd_iterations(x, centres, iterations):
    """:func:`rjfit.sampler.regions.materials.kmeans.lloyd` compiled: labels (int64) of the rows of ``x`` (n, d); ``centres`` updated in place.

    ``x`` and ``centres`` are float64 and C-contiguous, ``MIN_FEATURES <= d <= MAX_FEATURES``.
    """
    n, n_clusters = x.shape[0], centres.shape[0]
    labels = np.full(n, -1, np.int64)
    dist = np.empty((n, n_clusters))
    for _ in range(iterations):
        _distances(x, centres, dist)
        if not _nearest(dist, labels):
            break       # converged: the centres are these labels' means already
        for k in range(n_clusters):
            _fill_empty(dist, labels, k)
            _centre(x, labels, k, centres)
    for k in range(n_clusters):      # the final assignment may leave one empty: give it a row
        _donate(labels, k, n_clusters)
    return labels
