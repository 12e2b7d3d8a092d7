"""The normals' error as noise: a known per-observation scale from a reference fit of small patches.

Measured normals (photometric stereo, a scan) are a degree or two off. Where the prediction
changes fast with the normal (on and around a highlight whose lobe is about as wide as that
error) a wrong normal gives a residual of the size of the highlight itself, spatially
structured, that no BRDF shared by a material can follow: the fit then buys a material for
the highlight (docs/results/measured-ball.md). This module carries that error in the noise instead.

Model. The normal used at observation i differs from the true one by a small tangential
error, isotropic with standard deviation sigma_n (radians) per tangential direction. To
first order the prediction moves by ``grad_t mu_i . dn``, so

    var_i = sigma_r^2 + sigma_n^2 g_i^2 = sigma_r^2 (1 + k g_i^2),     k = sigma_n^2 / sigma_r^2,

with ``g_i = |d mu_i / d n|`` the tangential gradient of the prediction. For Lambert plus one
energy-normalised Blinn lobe, ``mu = E (a <l.n> / pi + b N(g) <l.n> <h.n>^g)``, the gradient
is ``alpha l + beta h`` with ``alpha = E (a / pi + b N(g) <h.n>^g)``, ``beta = E b N(g) g
<l.n> <h.n>^(g-1)``, and its tangential part has

    g_i^2 = alpha^2 (1 - <l.n>^2) + beta^2 (1 - <h.n>^2) + 2 alpha beta (<l.h> - <l.n><h.n>).

The fit then uses the known scales ``s_i = sqrt(1 + k g_i^2)`` (:mod:`rjfit.data.noise`:
weighted least squares; each material keeps its own sigma_r^2, sampled).

The rule for g_i and k (the reference needs no segmentation). A per-pixel fit would absorb a
wrong normal (each pixel gets its own lobe, which bends to the wrong normal), so its
residuals do not show the error. Here every ``patch`` x ``patch`` pixel tile (default 5 x 5)
shares one Lambert + Blinn fit (:func:`rjfit.data.pixelfit.group_fit`): one lobe cannot
bend to 25 independent normal errors, so they stay in its residuals, while a tile is still
small enough to follow a surface of several materials. ``g_i`` is the tangential gradient of
the tile fit's prediction; k (with sigma_r^2) is the maximum-likelihood estimate of the
Gaussian ``r_i ~ N(0, sigma_r^2 + sigma_n^2 g_i^2 + q_i)`` on the tile fits' residuals r_i,
``q_i`` a known variance (quantisation), sigma_r^2 profiled out and k >= 0 found by a grid
over log k refined by golden section, k = 0 included. Observations of a tile with no fit
(fewer than 4 observations) get ``g_i = 0``.

Caveats. First order in the error: where the lobe is narrower than sigma_n the residual is
not linear in it, and k is what the linear model's likelihood prefers. Any misfit whose size
grows with ``g_i`` (a lobe of the wrong shape on the highlight) is read as normal error too:
sigma_n is then an upper bound on the normals' error, not a measurement of it. sigma_r^2 is
pooled over the whole surface; with materials of different noise k is a compromise.
"""
from __future__ import annotations

import numpy as np

from rjfit.data.footprint import (
    UNIFORM_OFFSET_VARIANCE,
    estimate_footprint_error,
    finite_squares,
    image_gradient_squared,
)
from rjfit.data.pixelfit import _golden_section, group_fit, patch_index
from rjfit.model.blinn import blinn_normalisation

__all__ = ["DEFAULT_PATCH", "patch_reference", "tangential_gradient_squared", "estimate_normal_error",
           "normal_error_noise", "misfit_tiles", "MISFIT_TILE_FACTOR"]

DEFAULT_PATCH = 5
#: a tile whose mean squared residual over the model's variance is this many times the median tile's is counted as
#: one the model does not describe (:func:`misfit_tiles`): a residual about three times a typical tile's
MISFIT_TILE_FACTOR = 10.0
_LOG_T_GRID = np.linspace(np.log(1e-8), np.log(1e8), 65)     # k * median(g^2): dimensionless


def patch_reference(observations, patch: int = DEFAULT_PATCH) -> dict:
    """The tile fits of ``patch`` x ``patch`` pixels: per observation the prediction, residual and g_i^2.

    Raises
    ------
    ValueError
        If ``patch < 1`` or the observations carry no ``cos_lh`` (build them from a Dataset or
        :func:`rjfit.data.observations.observations_from_stack` with ``cos_lh``).
    """
    if patch < 1:
        raise ValueError(f"patch must be at least 1 pixel, got {patch}")
    if observations.cos_lh is None:
        raise ValueError("the normal-error noise model needs <l.h> per observation (Observations.cos_lh); these "
                         "observations were built without it")
    tile, n_tiles = patch_index(observations, patch)
    result = group_fit(observations, tile, n_tiles)
    a, b, gamma = result["a"][tile], result["b"][tile], result["gamma"][tile]
    g2 = tangential_gradient_squared(observations, a, b, gamma)
    fitted = result["fitted"][tile]
    return {"residuals": result["residuals"], "g2": np.where(fitted, g2, 0.0), "fitted": fitted,
            "prediction": np.asarray(observations.y, float) - np.where(fitted, result["residuals"], 0.0),
            "patch": patch, "tiles_fitted": int(result["fitted"].sum()), "tile": tile, "n_tiles": n_tiles}


def misfit_tiles(residuals, variance, tile, n_tiles: int) -> dict:
    """The tiles whose fit misses their data far beyond the others' and their share of the estimate:
    ``{"factor", "tiles", "share"}``, the tiles whose mean of ``residuals^2 / variance`` (the model's variance per
    observation) is over :data:`MISFIT_TILE_FACTOR` times the median tile's, and their share of the sum of
    ``residuals^2 / variance`` over every tile (what sigma_r^2 is a mean of).

    Why: a tile across two materials (a paint's outline) has a residual of the size of the albedo step, which no
    normal error explains, and the estimate is a mean of squares. On the DiLiGenT ball with three painted discs
    (2 % of its pixels) 28 of 620 tiles held 84 % of the sum and sigma_r^2 came out nine times the plain ball's,
    where no tile is over 5.2 times the median (docs/results/2026-11-30-edge-reference.md). Leaving such tiles out
    was tried and not kept (psm-horse's own normal error went to 0 with them): the fit states the share instead.
    """
    finite = np.isfinite(residuals)
    ratio = np.where(finite, np.asarray(residuals, float) ** 2 / np.maximum(variance, 1e-300), 0.0)
    total = np.bincount(tile, ratio, minlength=n_tiles)
    count = np.bincount(tile, finite.astype(float), minlength=n_tiles)
    judged = count > 0
    if not np.any(judged) or total[judged].sum() <= 0:
        return {"factor": MISFIT_TILE_FACTOR, "tiles": 0, "share": 0.0}
    mean = total[judged] / count[judged]
    over = mean > MISFIT_TILE_FACTOR * float(np.median(mean))
    return {"factor": MISFIT_TILE_FACTOR, "tiles": int(over.sum()),
            "share": float(total[judged][over].sum() / total[judged].sum())}


def tangential_gradient_squared(observations, a, b, gamma) -> np.ndarray:
    """``|d mu_i / d n|^2`` (tangential part) of ``mu = E (a <l.n>/pi + b N(g) <l.n> <h.n>^g)`` per observation."""
    cos_ln = np.asarray(observations.cos_ln, float)
    cos_hn = np.clip(np.asarray(observations.cos_hn, float), 1e-12, 1.0)
    cos_lh = np.asarray(observations.cos_lh, float)
    irradiance = np.asarray(observations.irradiance, float)
    lobe = b * blinn_normalisation(gamma) * np.exp((gamma - 1.0) * np.log(cos_hn))      # b N <h.n>^(g-1)
    alpha = irradiance * (a / np.pi + lobe * cos_hn)
    beta = irradiance * lobe * gamma * cos_ln
    value = (alpha ** 2 * (1.0 - cos_ln ** 2) + beta ** 2 * (1.0 - cos_hn ** 2)
             + 2.0 * alpha * beta * (cos_lh - cos_ln * cos_hn))
    return np.maximum(value, 0.0)


def estimate_normal_error(residuals, g2, known_variance=None) -> dict:
    """Maximum-likelihood (sigma_r^2, sigma_n^2) of ``r_i ~ N(0, sigma_r^2 + sigma_n^2 g_i^2 + q_i)``.

    Parameters
    ----------
    residuals, g2 : ndarray (N,)
        Residuals and squared tangential gradients; non-finite residuals are left out.
    known_variance : ndarray (N,) or float, optional
        ``q_i``, a known variance added to each observation's (e.g. quantisation).

    Returns
    -------
    dict
        ``k`` (sigma_n^2 / sigma_r^2), ``sigma_r2``, ``sigma_n_deg`` (sigma_n in degrees),
        ``log_likelihood_gain`` (over k = 0), ``n``.

    Raises
    ------
    ValueError
        If fewer than 3 finite residuals remain.
    """
    r2, q, g2 = finite_squares(residuals, known_variance, g2)
    scale = float(np.median(g2[g2 > 0])) if np.any(g2 > 0) else 1.0

    def profile(k):
        """(negative log-likelihood, sigma_r^2) at k, sigma_r^2 profiled: q enters as q / sigma_r^2 fixed
        at the k = 0 level's sigma_r^2 (one pass; q is a floor far below the misfit where it is used)."""
        weight = 1.0 + k * g2 + q / base
        sigma_r2 = float(np.mean(r2 / weight))
        return 0.5 * r2.size * np.log(sigma_r2) + 0.5 * float(np.sum(np.log(weight))), sigma_r2

    base = max(float(np.mean(r2)), 1e-300)
    nll0, _ = profile(0.0)
    grid = np.array([profile(np.exp(t) / scale)[0] for t in _LOG_T_GRID])
    best = int(np.argmin(grid))
    k = 0.0
    if grid[best] < nll0:
        low, high = _LOG_T_GRID[max(best - 1, 0)], _LOG_T_GRID[min(best + 1, _LOG_T_GRID.size - 1)]
        log_t = float(_golden_section(lambda t: np.array([profile(np.exp(v) / scale)[0] for v in np.ravel(t)]),
                                      np.array([low]), np.array([high]), 30)[0])
        k = np.exp(log_t) / scale
    nll, sigma_r2 = profile(k)
    if nll > nll0:
        k, (nll, sigma_r2) = 0.0, profile(0.0)
    return {"k": float(k), "sigma_r2": sigma_r2, "sigma_n_deg": float(np.degrees(np.sqrt(k * sigma_r2))),
            "log_likelihood_gain": float(nll0 - nll), "n": int(r2.size)}


def normal_error_noise(observations, patch: int = DEFAULT_PATCH, known_variance=None,
                       footprint: bool = False) -> tuple[np.ndarray, dict]:
    """Known scales ``s_i = sqrt(1 + k g_i^2 (+ t f_i^2) + q_i / sigma_r^2)`` of the normal-error noise model, and its record.

    Parameters
    ----------
    observations : rjfit.data.observations.Observations
        With ``cos_lh``.
    patch : int
        Side of the reference fit's tiles in pixels.
    known_variance : ndarray (N,) or float, optional
        A known variance per observation (quantisation), in the units of ``y``.
    footprint : bool
        Add the footprint term ``t f_i^2`` (``--noise footprint``; :mod:`rjfit.data.footprint`):
        ``f_i^2`` the observed image's squared gradient over 12, k and t estimated jointly.
        False: the normals' term alone, as before.

    Returns
    -------
    scale : ndarray (N,)
    record : dict
        The estimate (:func:`estimate_normal_error` or
        :func:`rjfit.data.footprint.estimate_footprint_error`), the rule and its caveat, for summary.json.

    Raises
    ------
    ValueError
        As :func:`patch_reference` and :func:`estimate_normal_error`; for a joint colour stack with
        ``footprint``.
    """
    reference = patch_reference(observations, patch)
    q = 0.0 if known_variance is None else np.asarray(known_variance, float)
    if footprint:
        f2 = UNIFORM_OFFSET_VARIANCE * image_gradient_squared(observations)
        estimate = estimate_footprint_error(reference["residuals"], reference["g2"], f2, known_variance)
        scale = np.sqrt(1.0 + estimate["k"] * reference["g2"] + estimate["t"] * f2 + q / estimate["sigma_r2"])
        estimate["footprint_share"] = _footprint_share(estimate, reference["g2"], f2, reference["residuals"])
    else:
        estimate = estimate_normal_error(reference["residuals"], reference["g2"], known_variance)
        scale = np.sqrt(1.0 + estimate["k"] * reference["g2"] + q / estimate["sigma_r2"])
    variance = estimate["sigma_r2"] * scale ** 2
    record = {**estimate, "patch_px": patch, "tiles_fitted": reference["tiles_fitted"],
              "misfit_tiles": misfit_tiles(reference["residuals"], variance, reference["tile"], reference["n_tiles"]),
              "known_variance": None if known_variance is None else "quantisation",
              "rule": "var_i = sigma_r^2 (1 + k g_i^2) (+ q_i): g_i the tangential gradient of a Lambert + Blinn fit "
                      f"shared by each {patch} x {patch} pixel tile; k by maximum likelihood on those fits' residuals",
              "caveat": "first order in the normals' error; a lobe misfit that grows with the gradient is read as "
                        "normal error too, so sigma_n bounds the normals' error from above"}
    if footprint:
        record["rule"] = ("var_i = sigma_r^2 (1 + k g_i^2 + t f_i^2) (+ q_i): g_i as for --noise normals; f_i^2 = "
                          "|grad_x y_i|^2 / 12 of the observed image by central differences, its noise bias removed "
                          "per light; k and t by maximum likelihood on the tile fits' residuals")
        record["caveat"] += ("; the footprint term reads any misfit that grows with the image gradient (the limb, an "
                             "edge, a tile fit that straddles two materials) as footprint, and its noise-bias "
                             "correction is one variance per light")
    return scale, record


def _footprint_share(estimate, g2, f2, residuals) -> float:
    """The footprint term's share of the modelled variance, summed over the fitted observations."""
    keep = np.isfinite(residuals)
    normal = estimate["k"] * float(np.sum(g2[keep]))
    foot = estimate["t"] * float(np.sum(f2[keep]))
    return float(foot / (int(keep.sum()) + normal + foot))
