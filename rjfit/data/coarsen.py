"""How much a measured stack's misfit is shared by neighbouring pixels: the likelihood power of a coarsened fit.

The Gaussian likelihood treats every observation as independent. When the BRDF family
cannot follow the measured angular behaviour (a real surface is not exactly Lambert +
Blinn-Phong), the misfit is a smooth function of the geometry, so neighbouring pixels under
one light carry nearly the same residual. A million such observations then carry far less
independent information than their count says, and the plain posterior splits a uniform
material into regions that absorb the misfit. The coarsened posterior (Miller and Dunson,
"Robust Bayesian inference via coarsening", JASA 2019) raises the likelihood to a power
zeta; :func:`suggest_likelihood_power` sets zeta to the effective fraction of independent
observations.

Method. Every pixel is fitted on its own (the amplitudes of Lambert and of the Blinn lobe by
least squares, the exponent by a grid), so nothing ties pixels together and white noise
leaves residuals uncorrelated between pixels. The lag-1 correlation rho of the residuals of
horizontally and vertically adjacent pixels under the same light measures the misfit's
spatial coherence; for a field with that correlation in each image direction (separable
AR(1)), the variance of a mean over n observations is that of
n ((1 - rho) / (1 + rho))^2 independent ones, so zeta = ((1 - rho) / (1 + rho))^2 (1 when
rho <= 0). Rendered data with white noise give zeta near 1: the plain posterior.
"""
from __future__ import annotations

import numpy as np

from rjfit.data.noise import weighted_observations
from rjfit.data.pixelfit import group_fit, patch_index, per_pixel_residuals

__all__ = ["suggest_likelihood_power", "neighbour_correlations", "misfit_warning", "MISFIT_ZETA", "area_likelihood_power",
           "summed_autocorrelation", "AREA_WINDOW", "AREA_PATCH"]

# Lags summed by the area rule: within +-40 px (the DiLiGenT ball's residual correlation falls to ~0 by
# about 20 px), at most a quarter of the image's side.
AREA_WINDOW = 40
AREA_PATCH = 5
_MIN_LAG_PAIRS = 100

# Below this suggested zeta (rho above 0.17) fewer than half of the observations count as
# independent: the BRDF family misses a smooth part of the data, which can split one material.
MISFIT_ZETA = 0.5


def suggest_likelihood_power(observations, noise_scale=None) -> dict:
    """zeta = ((1 - rho) / (1 + rho))^2 from the lag-1 correlation of per-pixel-fit residuals.

    Parameters
    ----------
    observations : rjfit.data.observations.Observations
    noise_scale : ndarray (N,), optional
        Known noise scales of a heteroscedastic noise model (:mod:`rjfit.data.noise`): the
        per-pixel fits are then weighted least squares and rho is measured on the
        standardised residuals ``(y - mu) / s``, the ones the fit's likelihood sees.

    Returns
    -------
    dict
        ``rho_rows`` (horizontal neighbours), ``rho_cols`` (vertical), ``rho`` (their mean,
        floored at 0), ``pairs`` (neighbour pairs used) and ``likelihood_power`` (zeta,
        at least 1 / N).

    Raises
    ------
    ValueError
        If no two adjacent pixels under one light both have a residual.

    References
    ----------
    J. W. Miller and D. B. Dunson, "Robust Bayesian inference via coarsening", JASA 114
    (2019) 1113-1125.
    """
    obs = weighted_observations(observations, noise_scale)
    rhos, pairs = neighbour_correlations(obs.dense(per_pixel_residuals(obs)))
    if pairs == 0 or not np.any(np.isfinite(rhos)):
        raise ValueError("no two adjacent pixels under one light have a residual: cannot measure the misfit's "
                         "spatial correlation; give --likelihood-power as a number")
    rho = max(0.0, float(np.nanmean(rhos)))
    zeta = max(((1.0 - rho) / (1.0 + rho)) ** 2, 1.0 / obs.n_obs)
    return {"rho_rows": rhos[0], "rho_cols": rhos[1], "rho": rho, "pairs": pairs, "likelihood_power": zeta}


def neighbour_correlations(dense) -> tuple[list, int]:
    """Pearson correlation of the values of horizontally and of vertically adjacent pixels in one image.

    Parameters
    ----------
    dense : ndarray (..., H, W)
        One image of values per leading index (a light, a channel); NaN where there is none.
        Pairs are formed within an image only.

    Returns
    -------
    ([rho_rows, rho_cols], pairs)
        The correlations (NaN where fewer than 3 pairs or a constant side) and the number of
        pairs with both values finite, over both directions.
    """
    dense = np.asarray(dense, float)
    rhos, pairs = [], 0
    for first, second in ((dense[..., :, :-1], dense[..., :, 1:]), (dense[..., :-1, :], dense[..., 1:, :])):
        keep = np.isfinite(first) & np.isfinite(second)
        x, z = first[keep], second[keep]
        pairs += int(x.size)
        rhos.append(float(np.corrcoef(x, z)[0, 1]) if x.size > 2 and np.std(x) > 0 and np.std(z) > 0 else np.nan)
    return rhos, pairs


def misfit_warning(suggestion, likelihood_power: float) -> str | None:
    """A warning for a fit's summary when per-pixel residuals are strongly shared by
    neighbouring pixels (suggested zeta < :data:`MISFIT_ZETA`), else None.

    Such a misfit means the BRDF family does not follow the data's reflectance; regions can
    then absorb the misfit instead of separating materials, even in a coarsened fit (the
    measured DiLiGenT ball: rho 0.41).
    """
    if suggestion is None or suggestion.get("likelihood_power", 1.0) >= MISFIT_ZETA:
        return None
    return (f"the per-pixel fits' residuals are shared by neighbouring pixels (lag-1 correlation rho "
            f"{suggestion['rho']:.2f}, as if only {suggestion['likelihood_power']:.0%} of the observations were "
            f"independent): the Lambert + Blinn-Phong model misses part of this data's reflectance, and regions "
            f"may split one material to absorb the misfit (this fit's likelihood power {likelihood_power:.3g}); "
            f"run `rjfit diagnose` before reading regions as materials")


def summed_autocorrelation(observations, residuals, window: int = AREA_WINDOW) -> dict:
    """The residuals' spatial autocorrelation under one light, pooled over lights and summed over lags.

    ``rho(d) = sum_l sum_x r_l(x) r_l(x + d) / (n_pairs(d) c(0))``, ``c(0)`` the mean squared
    residual, for every lag ``d = (dr, dc)`` with ``|dr|, |dc| <= window`` (each lag with at
    least 100 pixel pairs). For a stationary field the variance of a mean over a large region
    of n observations is ``sigma^2 / n * sum_d rho(d)``: ``area = sum_d rho(d)`` (in pixels) is
    how many observations carry one observation's information; white noise gives 1.

    Parameters
    ----------
    observations : rjfit.data.observations.Observations
    residuals : ndarray (N,)
        One per observation; NaN where there is none.
    window : int
        Largest lag summed, per image axis, in pixels (capped at a quarter of the image side).

    Returns
    -------
    dict
        ``area`` (pixels), ``window`` (the one used), ``rho_lag1`` (mean of the four nearest lags).

    Raises
    ------
    ValueError
        If no residual is finite or its mean square is 0.
    """
    height, width = observations.image_shape
    window = int(max(1, min(window, height // 4, width // 4)))
    pixel = np.asarray(observations.pixel, np.int64)
    light = np.asarray(observations.light, np.int64)
    residuals = np.asarray(residuals, float)
    keep = np.isfinite(residuals)
    if not keep.any() or not np.any(residuals[keep] != 0):
        raise ValueError("no finite, non-zero residual: cannot measure the residuals' autocorrelation")
    shape = (2 * height, 2 * width)          # zero padding: the circular correlation is the linear one
    numerator, pairs = np.zeros(shape), np.zeros(shape)
    for index in np.unique(light[keep]):
        chosen = keep & (light == index)
        dense, mask = np.zeros(height * width), np.zeros(height * width)
        dense[pixel[chosen]] = residuals[chosen]
        mask[pixel[chosen]] = 1.0
        for image, total in ((dense, numerator), (mask, pairs)):
            spectrum = np.fft.rfft2(image.reshape(height, width), shape)
            total += np.fft.irfft2(spectrum * np.conj(spectrum), shape)
    pairs = np.rint(pairs)
    c0 = numerator[0, 0] / pairs[0, 0]
    lags = np.r_[0:window + 1, -window:0]
    num, cnt = numerator[np.ix_(lags % shape[0], lags % shape[1])], pairs[np.ix_(lags % shape[0], lags % shape[1])]
    usable = cnt >= _MIN_LAG_PAIRS
    rho = np.where(usable, num / np.where(usable, cnt, 1.0) / c0, 0.0)
    return {"area": float(rho.sum()), "window": window,
            "rho_lag1": float(np.mean([rho[1, 0], rho[-1, 0], rho[0, 1], rho[0, -1]]))}


def area_likelihood_power(observations, noise_scale=None, patch: int = AREA_PATCH, window: int = AREA_WINDOW) -> dict:
    """zeta = 1 / area: the likelihood power of an effective number of independent observations.

    The residuals are those of Lambert + Blinn fits shared by ``patch`` x ``patch`` pixel tiles
    (:func:`rjfit.data.pixelfit.group_fit`; weighted by ``noise_scale`` when given, so they are
    the standardised residuals the fit's likelihood sees), and ``area`` is their summed spatial
    autocorrelation (:func:`summed_autocorrelation`). zeta = 1 / max(area, 1), at least 1 / N:
    white noise gives 1 (the plain posterior). Unlike the lag-1 rule (``suggest_likelihood_power``,
    which assumes an AR(1) field) it counts correlation at every lag up to ``window``.

    Returns
    -------
    dict
        ``likelihood_power``, ``area``, ``window``, ``rho_lag1``, ``patch_px``, ``rule``.

    Raises
    ------
    ValueError
        As :func:`summed_autocorrelation`.
    """
    obs = weighted_observations(observations, noise_scale)
    tile, n_tiles = patch_index(obs, patch)
    measured = summed_autocorrelation(obs, group_fit(obs, tile, n_tiles)["residuals"], window)
    zeta = max(1.0 / max(measured["area"], 1.0), 1.0 / obs.n_obs)
    return {**measured, "likelihood_power": zeta, "patch_px": patch,
            "rule": "zeta = 1 / max(1, sum of the spatial autocorrelation of the (standardised) residuals of "
                    f"{patch} x {patch} pixel tile fits over lags within +-window px, pooled over lights)"}
