"""How far a measured surface's shading is off by a local factor that a pair of pixels 3 px apart shares: the sd
of the edge term's local gain (:mod:`rjfit.sampler.regions.materials.edges`, "The local gain").

Measured once per fit on the data, before any material is known, from each pixel's gain against one material
fitted to every observation (the edge term's reference).
"""
from __future__ import annotations

import numpy as np

__all__ = ["shared_gain_sd", "robust_sd", "GAIN_CLIP", "GAIN_CLIP_ROUNDS"]

#: the estimate leaves out pairs whose gain lies this many robust sd from the median (a paint's), at most this many
#: rounds (:func:`shared_gain_sd`)
GAIN_CLIP, GAIN_CLIP_ROUNDS = 3.0, 20


def robust_sd(x) -> float:
    """1.4826 times the median absolute deviation from the median: the sd of a Gaussian, robust to a few outliers."""
    return 1.4826 * float(np.median(np.abs(x - np.median(x))))


def shared_gain_sd(y, prediction, pixel, first, second, n_pixels: int, weight=None) -> float:
    """tau of the local gain (module docstring): the sd of the gain that the two ends of a pair share.

    Each pixel's gain against the reference, ``g = sum y mu / sum mu^2 - 1`` over its observations (``mu`` the
    reference's ``prediction``; a colour fit's observations weighted by ``weight``, their channel's ``1 / s_c^2``),
    holds the shared local gain and a part of its own (noise, its own normal's error). Over the pairs
    (``first``, ``second``), the ends' mean varies by ``tau^2 + w^2 / 2`` and their half difference by
    ``w^2 / 2``, so ``tau^2`` is the first less the second, each a robust variance (1.4826 MAD, squared). A
    paint's pixels have a gain of their own against the reference (a quarter of the albedo: -0.75), which would
    widen the first: pairs whose mean lies more than :data:`GAIN_CLIP` robust sd from the median are left out and
    the rest measured again, until none changes side (a paint on a fifth of a test surface raised the estimate
    1.6-fold without it: tests/sampler/test_edge_term.py), and the spread is taken relative to the kept pairs' level
    (the reference, fitted to the paints too, is off the surface's level by a common factor). 0 where it is not
    positive or too few pairs have both gains (fewer than 10).
    """
    y, mu = np.asarray(y, np.float64), np.asarray(prediction, np.float64)
    w = np.ones(y.size) if weight is None else np.asarray(weight, np.float64)
    pixel = np.asarray(pixel, np.int64)
    num = np.bincount(pixel, w * y * mu, minlength=n_pixels)
    den = np.bincount(pixel, w * mu * mu, minlength=n_pixels)
    count = np.bincount(pixel, minlength=n_pixels)
    gain = np.full(n_pixels, np.nan)
    fitted = (count >= 3) & (den > 0)
    gain[fitted] = num[fitted] / den[fitted] - 1.0
    a, b = gain[first], gain[second]
    both = np.isfinite(a) & np.isfinite(b)
    if np.count_nonzero(both) < 10:
        return 0.0
    mean, half = 0.5 * (a[both] + b[both]), 0.5 * (a[both] - b[both])
    kept = np.ones(mean.size, bool)
    for _ in range(GAIN_CLIP_ROUNDS):     # a paint's pairs lie far from the surface's own: left out, as they show
        new = np.abs(mean - np.median(mean[kept])) <= GAIN_CLIP * robust_sd(mean[kept])
        if np.array_equal(new, kept) or np.count_nonzero(new) < 10:
            break
        kept = new
    # relative to the kept pairs' own level: the reference is fitted to the paints too, so the surface's gains
    # against it are off by a common factor
    level = 1.0 + float(np.median(mean[kept]))
    shared = (robust_sd(mean[kept]) ** 2 - robust_sd(half[kept]) ** 2) / level ** 2 if level > 0 else np.nan
    return float(np.sqrt(shared)) if np.isfinite(shared) and shared > 0 else 0.0
