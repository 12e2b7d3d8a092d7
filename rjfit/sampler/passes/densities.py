"""Per-observation Gaussian log densities, the building block of the change-point passes.

:func:`coefficients` turns the region parameters into the per-region constants of the log
density once per pass, so the per-observation work is one exponential;
:func:`log_densities_into` evaluates a run of observations of one region in a loop that
vectorises (no gather by label), which is why the passes that need densities of many
regions first cut their observations into runs of one region (:func:`run_end`). With an
effects' lobe terms ``ext`` (:mod:`rjfit.sampler.passes.lobe`; None for the plain model) the
lobe column is evaluated per observation from them, with the regions' ``rows``
(:func:`~rjfit.sampler.passes.lobe.lobe_rows`).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from rjfit.sampler.passes.lobe import lobe_fill
from rjfit.sampler.passes.special import INV_PI, LOG_2PI, fast_exp

__all__ = ["coefficients", "log_density", "log_densities_into", "run_end", "block_log_likelihood"]


@njit(cache=True, nogil=True)
def coefficients(theta):
    """Per-region constants of the log density, (R, 5): ``a / pi, b, gamma, log-normaliser, 1 / (2 sigma^2)``.

    Computed once per call of a pass, so the per-observation work is one ``exp``.
    """
    out = np.empty((theta.shape[0], 5))
    for r in range(theta.shape[0]):
        I0, kd, g, s2 = theta[r, 0], theta[r, 1], theta[r, 2], theta[r, 3]
        # Giesen's normalisation, as rjfit.model.blinn.blinn_normalisation (not callable from Numba)
        norm = (g + 2.0) * (g + 4.0) / (8.0 * math.pi * (2.0 ** (-g / 2.0) + g))
        out[r, 0] = I0 * kd * INV_PI
        out[r, 1] = I0 * (1.0 - kd) * norm
        out[r, 2] = g
        out[r, 3] = -0.5 * (LOG_2PI + math.log(s2))
        out[r, 4] = 0.5 / s2
    return out


@njit(cache=True, nogil=True)
def log_density(yv, c, lh, coef, r):
    """Gaussian log density of one observation in region ``r`` (``coef`` from :func:`coefficients`)."""
    resid = yv - coef[r, 0] * c - coef[r, 1] * c * math.exp(coef[r, 2] * lh)
    return coef[r, 3] - coef[r, 4] * resid * resid


@njit(inline="always")
def run_end(values, lo, m):
    """End of the run of equal values that starts at ``lo``: ``values[lo:hi]`` all equal, ``hi <= m``."""
    hi = lo + 1
    while hi < m and values[hi] == values[lo]:
        hi += 1
    return hi


@njit(cache=True, nogil=True, fastmath={"contract"})
def log_densities_into(y, C, log_cos_hn, coef, r, out, ext=None, rows=None, offset=0):
    """``out[k]``: the log density of observation k in region ``r`` (one region: no gather, so it vectorises).

    With lobe terms ``ext``, observation k of the slices is ``offset + k`` of the problem.
    """
    ca, cb, g, c0, c1 = coef[r, 0], coef[r, 1], coef[r, 2], coef[r, 3], coef[r, 4]
    if ext is not None:
        lobe_fill(ext, offset, log_cos_hn, g, rows[r], out)       # the lobe column first, then the densities
        for k in range(out.shape[0]):
            resid = np.float64(y[k]) - ca * np.float64(C[k]) - cb * out[k]
            out[k] = c0 - c1 * resid * resid
        return
    for k in range(out.shape[0]):
        c = np.float64(C[k])
        resid = np.float64(y[k]) - ca * c - cb * c * fast_exp(g * np.float64(log_cos_hn[k]))
        out[k] = c0 - c1 * resid * resid


@njit(cache=True, nogil=True)
def block_log_likelihood(y, C, log_cos_hn, rows, coef, log_s2, inverse_s2, block, out):
    """``out[block[i]] +=`` the log density of observation i in region ``rows[i]`` (``coef`` from
    :func:`coefficients`), with the exact exponential (what a fit writes to chains.nc, not a pass of the chain).

    ``log_s2`` and ``inverse_s2`` are each observation's ``log s^2`` and ``1 / s^2`` of known noise scales s, or
    empty arrays where there are none. Without the GIL, so draws run on threads side by side.
    """
    scaled = log_s2.shape[0] > 0
    for i in range(y.shape[0]):
        r = rows[i]
        c = C[i]
        resid = y[i] - coef[r, 0] * c - coef[r, 1] * c * math.exp(coef[r, 2] * log_cos_hn[i])
        if scaled:
            out[block[i]] += coef[r, 3] - 0.5 * log_s2[i] - coef[r, 4] * inverse_s2[i] * resid * resid
        else:
            out[block[i]] += coef[r, 3] - coef[r, 4] * resid * resid
