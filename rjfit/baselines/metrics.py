"""Segmentation metrics against ground-truth labels, on the object pixels only.

Every metric compares a predicted label image with the truth inside a boolean object mask;
pixels outside the mask never count. Predicted labels are arbitrary integers (a method's
cluster numbers mean nothing), so they are first matched to the true regions one to one by
the Hungarian method (:func:`scipy.optimize.linear_sum_assignment` on the overlap table,
maximising the number of agreeing pixels). With more predicted clusters than true regions,
the surplus clusters stay unmatched and all their pixels count as errors; negative predicted
labels inside the mask (a method's "no label") are never matched either.

- pixel accuracy: fraction of object pixels whose matched predicted region is the true one;
- adjusted Rand index (:func:`sklearn.metrics.adjusted_rand_score`): needs no matching;
- boundary F1 at a tolerance of ``tolerance`` pixels (default 2), see :func:`boundary_f1`.
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage
from scipy.optimize import linear_sum_assignment

__all__ = ["match_labels", "relabel_to_truth", "pixel_accuracy", "adjusted_rand", "boundary_map", "boundary_f1",
           "segmentation_metrics", "BOUNDARY_TOLERANCE"]

BOUNDARY_TOLERANCE = 2.0


def _check_pair(truth, predicted, mask):
    truth = np.asarray(truth)
    predicted = np.asarray(predicted)
    if truth.ndim != 2:
        raise ValueError(f"truth must be a 2-D label image (H, W), got shape {truth.shape}")
    if predicted.shape != truth.shape:
        raise ValueError(f"predicted labels have shape {predicted.shape} but the truth has {truth.shape}; "
                         f"segment the same images the truth belongs to (same resolution)")
    if mask is None:
        mask = truth >= 0
    mask = np.asarray(mask)
    if mask.shape != truth.shape or mask.dtype != bool:
        raise ValueError(f"mask must be a boolean array of shape {truth.shape}, got {mask.dtype} {mask.shape}; "
                         f"pass e.g. dataset.object_mask")
    if not mask.any():
        raise ValueError("the mask selects no pixel; pass the object mask of the data set")
    if np.issubdtype(predicted.dtype, np.floating):
        if not np.isfinite(predicted[mask]).all():
            raise ValueError("predicted labels are NaN or Inf inside the mask; mark unlabelled object pixels with -1")
        predicted = np.rint(predicted)
    predicted = predicted.astype(np.int64)
    truth = truth.astype(np.int64)
    if (truth[mask] < 0).any():
        raise ValueError("truth labels are negative inside the mask; the mask must only select labelled pixels "
                         "(truth >= 0)")
    return truth, predicted, mask


def match_labels(truth, predicted, mask=None) -> dict[int, int]:
    """Match predicted clusters to true regions one to one, maximising agreeing pixels.

    Parameters
    ----------
    truth : ndarray of int, shape (H, W)
        True region index per pixel (>= 0 inside ``mask``).
    predicted : ndarray of int or float, shape (H, W)
        Predicted cluster per pixel; negative values inside the mask mean "unlabelled".
    mask : ndarray of bool, shape (H, W), optional
        Pixels to compare; default ``truth >= 0``.

    Returns
    -------
    dict
        ``{predicted label: true label}`` for the matched clusters only (at most
        ``min(#clusters, #regions)`` entries); unmatched clusters are absent.
    """
    truth, predicted, mask = _check_pair(truth, predicted, mask)
    t = truth[mask]
    p = predicted[mask]
    keep = p >= 0
    t, p = t[keep], p[keep]
    if t.size == 0:
        return {}
    pred_ids, p_index = np.unique(p, return_inverse=True)
    true_ids, t_index = np.unique(t, return_inverse=True)
    overlap = np.zeros((pred_ids.size, true_ids.size), dtype=np.int64)
    np.add.at(overlap, (p_index, t_index), 1)
    rows, cols = linear_sum_assignment(overlap, maximize=True)
    return {int(pred_ids[r]): int(true_ids[c]) for r, c in zip(rows, cols)}


def relabel_to_truth(truth, predicted, mask=None) -> np.ndarray:
    """Predicted labels renamed after their matched true region (for figures).

    Matched clusters take their true region's index; unmatched clusters get
    ``max(truth) + 1, max(truth) + 2, ...`` in order of size; pixels outside ``mask`` and
    unlabelled pixels get -1.
    """
    truth, predicted, mask = _check_pair(truth, predicted, mask)
    mapping = match_labels(truth, predicted, mask)
    out = np.full(truth.shape, -1, dtype=np.int64)
    inside = mask & (predicted >= 0)
    unmatched, counts = np.unique(predicted[inside], return_counts=True)
    order = [int(label) for label in unmatched[np.argsort(-counts, kind="stable")] if int(label) not in mapping]
    next_label = int(truth[mask].max()) + 1
    for label in order:
        mapping[label] = next_label
        next_label += 1
    for label, target in mapping.items():
        out[inside & (predicted == label)] = target
    return out


def pixel_accuracy(truth, predicted, mask=None) -> float:
    """Fraction of mask pixels whose matched predicted region equals the true region.

    Unmatched clusters (more clusters than regions) and unlabelled pixels count as errors.
    Invariant to renaming the predicted labels.
    """
    truth, predicted, mask = _check_pair(truth, predicted, mask)
    mapping = match_labels(truth, predicted, mask)
    t = truth[mask]
    p = predicted[mask]
    mapped = np.full(p.shape, -1, dtype=np.int64)
    for label, target in mapping.items():
        mapped[p == label] = target
    return float(np.mean(mapped == t))


def adjusted_rand(truth, predicted, mask=None) -> float:
    """Adjusted Rand index of the mask pixels (unlabelled pixels form one more cluster)."""
    from sklearn.metrics import adjusted_rand_score

    truth, predicted, mask = _check_pair(truth, predicted, mask)
    return float(adjusted_rand_score(truth[mask], predicted[mask]))


def boundary_map(labels, mask) -> np.ndarray:
    """Boundary pixels of a label image inside a mask.

    A pixel is a boundary pixel when it lies in ``mask`` and at least one of its four
    neighbours (up, down, left, right) also lies in ``mask`` and carries a different label.
    Both pixels of every such pair are marked, so a straight border between two regions is
    two pixels wide; the silhouette of the mask itself is not a boundary.

    Returns
    -------
    ndarray of bool, shape (H, W)
    """
    labels = np.asarray(labels)
    mask = np.asarray(mask, dtype=bool)
    if labels.shape != mask.shape or labels.ndim != 2:
        raise ValueError(f"labels {labels.shape} and mask {mask.shape} must be 2-D arrays of one shape")
    boundary = np.zeros(mask.shape, dtype=bool)
    # vertical neighbours (row r, r + 1) and horizontal ones (col c, c + 1)
    differ = (labels[1:, :] != labels[:-1, :]) & mask[1:, :] & mask[:-1, :]
    boundary[1:, :] |= differ
    boundary[:-1, :] |= differ
    differ = (labels[:, 1:] != labels[:, :-1]) & mask[:, 1:] & mask[:, :-1]
    boundary[:, 1:] |= differ
    boundary[:, :-1] |= differ
    return boundary


def boundary_f1(truth, predicted, mask=None, tolerance: float = BOUNDARY_TOLERANCE) -> dict[str, float]:
    """Boundary precision, recall and F1 with a distance tolerance.

    Boundaries are those of :func:`boundary_map`. A predicted boundary pixel is correct when
    the Euclidean distance from its centre to the nearest true boundary pixel is at most
    ``tolerance`` pixels (:func:`scipy.ndimage.distance_transform_edt`); precision is the
    fraction of correct predicted boundary pixels. Recall is the same with the roles swapped.
    Without predicted boundary pixels precision is 1, without true ones recall is 1 (so two
    label images without any boundary score F1 = 1, and a prediction without boundaries
    against a truth with some scores F1 = 0).

    Returns
    -------
    dict
        ``precision``, ``recall``, ``f1``.
    """
    if tolerance < 0:
        raise ValueError(f"tolerance must be >= 0 pixels, got {tolerance}")
    truth, predicted, mask = _check_pair(truth, predicted, mask)
    true_boundary = boundary_map(truth, mask)
    pred_boundary = boundary_map(predicted, mask)
    if true_boundary.any():
        distance_to_true = ndimage.distance_transform_edt(~true_boundary)
        precision = float(np.mean(distance_to_true[pred_boundary] <= tolerance)) if pred_boundary.any() else 1.0
    else:
        precision = 0.0 if pred_boundary.any() else 1.0
    if pred_boundary.any():
        distance_to_pred = ndimage.distance_transform_edt(~pred_boundary)
        recall = float(np.mean(distance_to_pred[true_boundary] <= tolerance)) if true_boundary.any() else 1.0
    else:
        recall = 0.0 if true_boundary.any() else 1.0
    f1 = 0.0 if precision + recall == 0 else 2 * precision * recall / (precision + recall)
    return {"precision": precision, "recall": recall, "f1": f1}


def segmentation_metrics(truth, predicted, mask=None, tolerance: float = BOUNDARY_TOLERANCE) -> dict[str, float]:
    """All metrics of one segmentation: pixel accuracy, ARI, boundary precision / recall / F1.

    Returns
    -------
    dict
        ``pixel_accuracy``, ``ari``, ``boundary_precision``, ``boundary_recall``,
        ``boundary_f1``, ``n_clusters`` (distinct labels >= 0 inside the mask).
    """
    truth, predicted, mask = _check_pair(truth, predicted, mask)
    boundary = boundary_f1(truth, predicted, mask, tolerance)
    inside = predicted[mask]
    return {"pixel_accuracy": pixel_accuracy(truth, predicted, mask), "ari": adjusted_rand(truth, predicted, mask),
            "boundary_precision": boundary["precision"], "boundary_recall": boundary["recall"],
            "boundary_f1": boundary["f1"], "n_clusters": int(np.unique(inside[inside >= 0]).size)}
