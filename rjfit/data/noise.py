"""Noise models: known per-observation noise scales of a heteroscedastic Gaussian likelihood.

rjfit's likelihood (paper, eq. 1) is ``y_i ~ N(mu_i, sigma_r^2 s_i^2)``: ``sigma_r^2`` is the
region's variance parameter (sampled) and ``s_i > 0`` a known, fixed scale per observation.
With ``s_i = 1`` (``noise='constant'``, the default and the paper's model) the noise is
homoscedastic per region. Any other known ``s`` is weighted least squares: dividing ``y_i``
and ``E <l.n>`` of every observation by ``s_i`` when the :class:`rjfit.sampler.forward.Problem`
is built gives exactly this density, up to the constant ``-sum(log s_i)`` (times the
likelihood power), which is the same for every segmentation and parameter value. The
sampler itself is unchanged.

Models (``ybar`` is the mean of the observed ``y``; ``c = floor * ybar`` is a read-noise
floor that keeps every scale positive; ``m_i`` is a reference signal, see below):

``constant``
    ``s_i = 1``: homoscedastic per region.
``shot``
    ``s_i^2 = (m_i + c) / ybar``: variance proportional to the signal plus a floor (photon
    shot noise plus read noise).
``relative``
    ``s_i = (m_i + c) / ybar``: standard deviation proportional to the signal plus a floor
    (a multiplicative error: a misfit or calibration error that grows with the signal).
``normals``
    ``s_i^2 = 1 + k g_i^2``: the normals' error carried as noise, ``g_i`` the tangential
    gradient of the prediction with respect to the normal, k by maximum likelihood
    (:mod:`rjfit.data.normal_error`, whose reference is a fit of small pixel tiles, not the
    per-pixel fit below). Needs ``Observations.cos_lh``.
``footprint``
    ``s_i^2 = 1 + k g_i^2 + t f_i^2``: ``normals`` plus a pixel's footprint, ``f_i^2`` the
    squared gradient of the observed image over 12 (:mod:`rjfit.data.footprint`), k and t by
    maximum likelihood together. One channel only.

The reference signal ``m_i`` is not ``y_i`` itself (a weight built from the noisy value
would favour observations that happen to fall low and bias the fit), but the prediction of
a separate least-squares fit of every pixel (:func:`rjfit.data.pixelfit.per_pixel_residuals`:
Lambert plus one Blinn lobe, exponent on a grid), clipped at 0. It needs no segmentation
and follows every material of a multi-material surface. Pixels with fewer than 4 valid
observations (no per-pixel fit) use ``max(y_i, 0)``.

Choose a model that the noise really follows. A wrong one splits regions as a wrong BRDF
does: on the synthetic four-quadrant sphere (homoscedastic noise, 128 px, 10 lights),
dividing each true quadrant into an inner and an outer part gains 2,300 ('shot', floor
0.05) to 6,400 ('relative', floor 0.05) log-likelihood units over the four true regions
against a penalty of about 90, and 2 x 1000-iteration fits over-segment, while 'constant'
loses 65 by such a split and finds the four regions. On the DiLiGenT ball 'relative' cuts
the gain of the best split from 168,000 to about 4,000 to 12,000 units (zeta recomputed),
which is still far above the penalty: it does not make one region the posterior's choice.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from rjfit.data.normal_error import normal_error_noise
from rjfit.data.pixelfit import per_pixel_residuals

__all__ = ["NOISE_MODELS", "DEFAULT_FLOOR", "reference_signal", "noise_scale", "weighted_observations",
           "describe_noise"]

NOISE_MODELS = ("constant", "shot", "relative", "normals", "footprint")
DEFAULT_FLOOR = 0.05


def reference_signal(observations) -> np.ndarray:
    """Per-observation reference signal ``m_i``: the per-pixel fit's prediction, clipped at 0.

    Parameters
    ----------
    observations : rjfit.data.observations.Observations

    Returns
    -------
    ndarray of float64, shape (N,)
        ``max(y_i - r_i, 0)`` with ``r_i`` the residual of the pixel's own fit, or
        ``max(y_i, 0)`` where the pixel has fewer than 4 observations.
    """
    y = np.asarray(observations.y, float)
    residuals = per_pixel_residuals(observations)
    return np.maximum(np.where(np.isfinite(residuals), y - residuals, y), 0.0)


def noise_scale(observations, model: str = "constant", floor: float = DEFAULT_FLOOR, reference=None):
    """Known noise scales ``s_i`` of the observations under a noise model.

    Parameters
    ----------
    observations : rjfit.data.observations.Observations
    model : {'constant', 'shot', 'relative', 'normals', 'footprint'}
        See the module docstring.
    floor : float
        ``c / ybar``: the floor added to the reference signal, as a fraction of the mean
        observed value (default 0.05). Must be positive for 'shot' and 'relative'.
    reference : ndarray (N,), optional
        The reference signal ``m_i`` (default :func:`reference_signal`).

    Returns
    -------
    ndarray of float64, shape (N,), or None
        ``None`` for 'constant' (every scale 1), else the positive scales in the
        observations' order.

    Raises
    ------
    ValueError
        For an unknown model, a non-positive or non-finite floor, a mean observed value
        that is not positive, or a reference of the wrong shape or with negative or
        non-finite entries.
    """
    if model not in NOISE_MODELS:
        raise ValueError(f"unknown noise model {model!r}: choose one of {', '.join(NOISE_MODELS)}")
    if model == "constant":
        return None
    if model in ("normals", "footprint"):
        return normal_error_noise(observations, footprint=model == "footprint")[0]
    if not (np.isfinite(floor) and floor > 0):
        raise ValueError(f"the noise floor must be a positive fraction of the mean value, got {floor}")
    y = np.asarray(observations.y, float)
    ybar = float(np.mean(y)) if y.size else float("nan")
    if not (np.isfinite(ybar) and ybar > 0):
        raise ValueError(f"the '{model}' noise model needs a positive mean observed value, got {ybar}")
    if reference is None:
        reference = reference_signal(observations)
    reference = np.asarray(reference, float)
    if reference.shape != y.shape:
        raise ValueError(f"reference must have one value per observation {y.shape}, got {reference.shape}")
    if not np.all(np.isfinite(reference)) or np.any(reference < 0):
        raise ValueError("reference signal must be finite and non-negative")
    level = (reference + floor * ybar) / ybar
    return np.sqrt(level) if model == "shot" else level


def weighted_observations(observations, scale):
    """Observations with ``y`` and the irradiance divided by ``scale`` (weighted least squares).

    ``mu`` is linear in the irradiance, so the result's residuals are ``(y - mu) / s``.
    ``scale=None`` returns ``observations`` unchanged.
    """
    if scale is None:
        return observations
    scale = np.asarray(scale, float)
    return dataclasses.replace(observations, y=np.asarray(observations.y, float) / scale,
                               irradiance=np.asarray(observations.irradiance, float) / scale)


def describe_noise(model: str, floor: float, scale=None) -> dict:
    """A JSON-ready record of the noise model (for summary.json)."""
    formula = {"constant": "var_i = sigma_r^2", "normals": "var_i = sigma_r^2 (1 + k g_i^2), g_i = |d mu_i / d n|",
               "footprint": "var_i = sigma_r^2 (1 + k g_i^2 + t f_i^2), g_i = |d mu_i / d n|, f_i^2 = |grad_x y_i|^2 / 12",
               "shot": "var_i = sigma_r^2 (m_i + c) / ybar, c = floor * ybar",
               "relative": "sd_i = sigma_r (m_i + c) / ybar, c = floor * ybar"}[model]
    tiles = "Lambert + one Blinn lobe fitted to each 5 x 5 pixel tile"
    reference = {"constant": None, "normals": tiles, "footprint": tiles}.get(
        model, "per-pixel least-squares fit (Lambert + one Blinn lobe)")
    record = {"model": model, "formula": formula, "floor": None if model in ("constant", "normals", "footprint") else float(floor),
              "reference": reference}
    if scale is not None:
        s = np.asarray(scale, float)
        record.update(scale_min=float(s.min()), scale_median=float(np.median(s)), scale_max=float(s.max()),
                      sum_log_scale=float(np.sum(np.log(s))))
    return record
