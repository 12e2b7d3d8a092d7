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
from rjfit.data.pixelfit import per_pixel_residuals

__all__ = ["suggest_likelihood_power", "misfit_warning", "MISFIT_ZETA"]

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
    height, width = obs.image_shape
    residuals = per_pixel_residuals(obs)
    dense = np.full((obs.n_lights, height, width), np.nan)
    pixel = np.asarray(obs.pixel, np.int64)
    dense[np.asarray(obs.light), pixel // width, pixel % width] = residuals
    rhos, pairs = [], 0
    for first, second in ((dense[:, :, :-1], dense[:, :, 1:]), (dense[:, :-1, :], dense[:, 1:, :])):
        keep = np.isfinite(first) & np.isfinite(second)
        x, z = first[keep], second[keep]
        pairs += int(x.size)
        rhos.append(float(np.corrcoef(x, z)[0, 1]) if x.size > 2 and np.std(x) > 0 and np.std(z) > 0 else np.nan)
    if pairs == 0 or not np.any(np.isfinite(rhos)):
        raise ValueError("no two adjacent pixels under one light have a residual: cannot measure the misfit's "
                         "spatial correlation; give --likelihood-power as a number")
    rho = max(0.0, float(np.nanmean(rhos)))
    zeta = max(((1.0 - rho) / (1.0 + rho)) ** 2, 1.0 / obs.n_obs)
    return {"rho_rows": rhos[0], "rho_cols": rhos[1], "rho": rho, "pairs": pairs, "likelihood_power": zeta}


def misfit_warning(suggestion, likelihood_power: float) -> str | None:
    """A warning for a fit's summary when per-pixel residuals are strongly shared by
    neighbouring pixels (suggested zeta < :data:`MISFIT_ZETA`), else None.

    Such a misfit means the BRDF family does not follow the data's reflectance; regions can
    then absorb the misfit instead of separating materials, even in a coarsened fit (the
    measured DiLiGenT ball: rho 0.41).
    """
    if suggestion is None or suggestion["likelihood_power"] >= MISFIT_ZETA:
        return None
    return (f"the per-pixel fits' residuals are shared by neighbouring pixels (lag-1 correlation rho "
            f"{suggestion['rho']:.2f}, as if only {suggestion['likelihood_power']:.0%} of the observations were "
            f"independent): the Lambert + Blinn-Phong model misses part of this data's reflectance, and regions "
            f"may split one material to absorb the misfit (this fit's likelihood power {likelihood_power:.3g}); "
            f"run `rjfit diagnose` before reading regions as materials")
