"""Checks shared by the data set loaders: each raises :class:`DatasetError` naming the source.

These are the checks that hold for every layout (rjfit's own and photometric-stereo
folders): images of finite, non-negative radiance, a non-empty object mask, finite unit
normals on the object, and lights that illuminate at least part of the object.
"""
from __future__ import annotations

import numpy as np

from rjfit.data.lights import geometry_terms
from rjfit.errors import DatasetError

__all__ = ["NORMAL_TOLERANCE", "NOISE_FLOOR_SDS", "check_finite", "check_radiance", "radiance_floor", "check_mask",
           "check_unit_normals", "check_lights_face_object"]

NORMAL_TOLERANCE = 1e-3
"""Largest allowed ``| |n| - 1 |`` of a normal inside the object mask."""


def _first_pixel(bad):
    rows, cols = np.nonzero(bad)
    return int(rows[0]), int(cols[0])


def check_finite(array, source, what="pixels") -> None:
    """Raise if ``array`` (H, W[, C]) holds NaN or Inf; ``source`` names the file.

    Parameters
    ----------
    array : array_like, shape (H, W) or (H, W, C)
        The values; arrays of a non-floating dtype (integers, bool) are not checked.
    source : str or Path
        What to name in the message (the file).
    what : str
        What the entries are, for the message (default ``"pixels"``).

    Raises
    ------
    DatasetError
        If an entry is NaN or +-Inf (a pixel counts once, whatever its channels); the
        message gives the count and, for (H, W[, C]) arrays, the first pixel's row and column.
    """
    array = np.asarray(array)
    if not np.issubdtype(array.dtype, np.floating):
        return
    bad = ~np.isfinite(array)
    if bad.ndim == 3:
        bad = bad.any(axis=-1)
    if bad.any():
        row, col = _first_pixel(bad) if bad.ndim == 2 else (None, None)
        where = f" (first at row {row}, column {col})" if row is not None else ""
        raise DatasetError(f"{source}: {int(bad.sum())} {what} are NaN or Inf{where}")


NOISE_FLOOR_SDS = 8.0
"""How far below zero a data set's declared Gaussian noise may take a value, in standard deviations:
radiance is >= 0, so a value below ``-8 sd`` has probability below 7e-16 (about 1e-6 over a stack of
10^9 values); anything lower is not noise."""


def radiance_floor(noise_variance) -> float:
    """The lowest value an image may hold: 0, or ``-NOISE_FLOOR_SDS`` standard deviations of the
    Gaussian noise a data set declares (``noise_variance`` in ``dataset.json``; None or 0: none)."""
    return -NOISE_FLOOR_SDS * float(noise_variance) ** 0.5 if noise_variance else 0.0


def check_radiance(image, source, floor: float = 0.0) -> None:
    """Raise unless every value of ``image`` (H, W[, C]) is a finite radiance of at least ``floor``.

    Radiance is not negative: a negative value is an unsubtracted or over-subtracted sensor
    offset, or a broken file, not a measurement the model can explain. Only a data set that
    declares Gaussian noise may dip below zero, by at most :data:`NOISE_FLOOR_SDS` of its
    standard deviations (``floor``, from :func:`radiance_floor`).

    Parameters
    ----------
    image : array_like, shape (H, W) or (H, W, C)
        The values as read (codes or radiance); integer images are checked too.
    source : str or Path
        What to name in the message (the file).
    floor : float
        The lowest value allowed (default 0).

    Raises
    ------
    DatasetError
        If a value is NaN or Inf (:func:`check_finite`), or below ``floor``: the message gives the
        count of pixels, the first one's row, column and value, and the rule.
    """
    array = np.asarray(image)
    check_finite(array, source)
    below = array < floor
    if below.ndim == 3:
        below = below.any(axis=-1)
    if below.any():
        row, col = _first_pixel(below)
        value = float(np.min(array[row, col]))
        rule = (f"below {floor:.4g}, the floor of the declared noise ({NOISE_FLOOR_SDS:g} sd below 0)" if floor < 0
                else "negative")
        raise DatasetError(f"{source}: {int(below.sum())} pixels are {rule} (first at row {row}, column {col}: "
                           f"{value:.4g}); radiance cannot be negative: subtract a sensor's black level only to zero, "
                           f"not below it (docs/dataset-format.md, Bad input)")


def check_mask(mask, source) -> None:
    """Raise if the object mask selects no pixel.

    Parameters
    ----------
    mask : array_like, shape (H, W)
        The object mask, read as bool.
    source : str or Path
        What to name in the message (the file and channel).

    Raises
    ------
    DatasetError
        If no entry of ``mask`` is true.
    """
    if not np.asarray(mask, dtype=bool).any():
        raise DatasetError(f"{source}: the object mask selects no pixel (every value is background), so "
                           f"there is nothing to fit")


def check_unit_normals(normals, mask, source, tolerance=NORMAL_TOLERANCE) -> None:
    """Raise if a normal inside ``mask`` is not finite or not of unit length (within ``tolerance``).

    Normals outside the mask are not looked at.

    Parameters
    ----------
    normals : array_like, shape (H, W, 3)
    mask : ndarray of bool, shape (H, W)
        The object mask.
    source : str or Path
        What to name in the message (the file and channels).
    tolerance : float
        Largest allowed ``| |n| - 1 |`` (default :data:`NORMAL_TOLERANCE`).

    Raises
    ------
    DatasetError
        If a normal inside the mask has a NaN or Inf component, or else if one has
        ``| |n| - 1 | > tolerance``; the message gives the count, the first pixel's row and
        column, the range of lengths and how many are zero (a hint that the mask does not
        match the normal map).
    """
    inside = np.asarray(normals, dtype=float)[mask]
    finite = np.isfinite(inside).all(axis=-1)
    if not finite.all():
        bad = np.zeros(mask.shape, dtype=bool)
        bad[mask] = ~finite
        row, col = _first_pixel(bad)
        raise DatasetError(f"{source}: {int((~finite).sum())} normals inside the object mask are NaN or Inf "
                           f"(first at row {row}, column {col})")
    length = np.linalg.norm(inside, axis=-1)
    off = np.abs(length - 1.0) > tolerance
    if off.any():
        bad = np.zeros(mask.shape, dtype=bool)
        bad[mask] = off
        row, col = _first_pixel(bad)
        zero = int((length[off] == 0).sum())
        hint = f"; {zero} of them are zero (does the mask match the normal map?)" if zero else ""
        raise DatasetError(
            f"{source}: {int(off.sum())} of {inside.shape[0]} normals inside the object mask are not unit length "
            f"(|n| from {length[off].min():.4g} to {length[off].max():.4g}, first at row {row}, column {col}; "
            f"allowed | |n| - 1 | <= {tolerance:g}){hint}")


def check_lights_face_object(lights, normals, positions, view_dirs, mask, describe) -> None:
    """Raise if a light is behind the object: ``<l.n> <= 0`` at every pixel of the mask.

    Such a light illuminates nothing; every one, or all of them, being behind is the mark
    of a flipped axis (z points towards the camera) or a typo in a light's direction.

    Parameters
    ----------
    lights : sequence of Light
    normals, view_dirs : array_like, shape (H, W, 3)
        Unit shading normals and unit directions towards the camera.
    positions : array_like, shape (H, W, 3) or None
        Surface points (needed for point lights); None for directional lights only.
    mask : array_like of bool, shape (H, W)
        The object mask; only its pixels are looked at.
    describe : callable
        ``describe(i)`` names light ``i`` and where it was read from; ``describe(None)``
        names the source of all lights.

    Raises
    ------
    DatasetError
        If one or more lights have ``<l.n> <= 0`` at every pixel of the mask: one message
        for all of them being behind (suggesting a flipped z axis or direction sign), or one
        naming the lights behind (the first five).
    """
    mask = np.asarray(mask, dtype=bool)
    n = np.asarray(normals, dtype=float)[mask]
    v = np.asarray(view_dirs, dtype=float)[mask]
    p = np.zeros_like(n) if positions is None else np.asarray(positions, dtype=float)[mask]
    behind = []
    for index, light in enumerate(lights):
        cos_ln, _, _ = geometry_terms(p, n, v, light)
        if not (cos_ln > 0).any():
            behind.append(index)
    if not behind:
        return
    if len(behind) == len(lights):
        raise DatasetError(
            f"{describe(None)}: all {len(lights)} lights are behind the object (<l.n> <= 0 at every one of the "
            f"{int(mask.sum())} mask pixels); directions point towards the light and z points towards the "
            f"camera: is the z axis (or the direction sign) flipped?")
    names = "; ".join(describe(i) for i in behind[:5]) + ("; ..." if len(behind) > 5 else "")
    raise DatasetError(
        f"{len(behind)} of {len(lights)} lights are behind the object (<l.n> <= 0 at every one of the "
        f"{int(mask.sum())} mask pixels), so their images hold no usable observation: {names}")
