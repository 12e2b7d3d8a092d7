"""A pixel's footprint as noise: the misfit where the signal changes fast across the image.

Hypothesis (docs/results/measured-data.md, "The footprint term"; measured there, not assumed). A pixel
integrates the surface over its footprint, while the model is evaluated at the pixel's centre
(its normal, its material). Where the prediction changes fast across the image - along the
limb of a sphere, where the normal turns by degrees within one pixel, or on the edge between
two paints, where a pixel holds some of each - the pixel's value differs from the centre's
model by about ``grad_x(mu) . dx``, with ``dx`` an unknown offset within the pixel (uniform over
it: variance 1/12 px^2 per axis). No BRDF shared by a material fits such a pixel, and a fit
then buys a material for the band of such pixels (the DiLiGenT ball's limb, 1-2 pixel
materials on the paint edges of the synthetic layouts: docs/results/materials.md). Carried as noise,

    var_i = sigma_r^2 + sigma_n^2 g_i^2 + c f_i^2,       f_i^2 = |grad_x y_i|^2 / 12,

with ``g_i`` the normals' term of :mod:`rjfit.data.normal_error` and ``c >= 0`` a scale found by
maximum likelihood with ``k = sigma_n^2 / sigma_r^2`` (c = 1 if the offsets were exactly uniform
over the pixel and the model had no other error there).

Which gradient. ``f_i`` is the image-space gradient of the OBSERVED image of observation i's
light, by central differences over its valid 4-neighbours (one-sided, over one pixel, where one
neighbour is missing: the limb, the mask's edge; 0 where both are). The observed image carries
both causes (the limb's turn of the normal and a paint edge, which no segmentation-free
prediction shows). Its own noise inflates it: with pixel noise of variance v, a central
difference's square is biased by v / 2 (by 2 v one-sided). The bias is subtracted with v
measured per light from the image itself, robustly, as the median of squared second
differences along rows and columns divided by 6 x 0.4549 (a second difference of white noise
has variance 6 v; 0.4549 is the median of chi^2_1), which a smooth signal and the few edges do
not move; each axis' term is clipped at 0. Caveat: v is one value per light, so where the
noise grows with the signal (shot noise) bright pixels keep part of the bias and dark ones
lose part of their gradient; on a smooth surface with little noise f_i is then small, not 0.

Measured (docs/results/measured-data.md, "The footprint term"): on the DiLiGenT ball the term carries
part of the limb band's misfit (c about 0.5; the band halves but stays in 2 of 4 chains under
``--preset measured --noise footprint``); on psm-rock it replaces the normals' term (c about
4) and 3 of 4 chains (two seeds) lost the large pebble, so the preset does not use it. The synthetic renders have
no footprint (pixel-centre rays): there c is read from tile fits that straddle two paints.
"""
from __future__ import annotations

import numpy as np

from rjfit.data.pixelfit import _golden_section

__all__ = ["UNIFORM_OFFSET_VARIANCE", "image_gradient_squared", "finite_squares", "light_noise_variance",
           "estimate_footprint_error"]

UNIFORM_OFFSET_VARIANCE = 1.0 / 12.0          # var of an offset uniform over one pixel, per axis (px^2)
_CHI2_1_MEDIAN = 0.454936                      # median of chi^2 with one degree of freedom
_LOG_GRID = np.linspace(np.log(1e-6), np.log(1e6), 25)   # k median(g^2) and t median(f^2): dimensionless
_REFINE_ROUNDS = 3


def _neighbours(images, axis):
    """The values at -1 and +1 along ``axis`` (1 rows, 2 columns) of each pixel, NaN beyond the image."""
    before, after = np.full_like(images, np.nan), np.full_like(images, np.nan)
    inner = [slice(None)] * 3
    inner[axis] = slice(1, None)
    outer = [slice(None)] * 3
    outer[axis] = slice(None, -1)
    before[tuple(inner)] = images[tuple(outer)]
    after[tuple(outer)] = images[tuple(inner)]
    return before, after


def light_noise_variance(observations) -> np.ndarray:
    """Per light, the pixel noise variance v from squared second differences (module docstring); 0 where none."""
    images = observations.dense()
    squares = []
    for axis in (1, 2):
        before, after = _neighbours(images, axis)
        second = (before - 2.0 * images + after).reshape(images.shape[0], -1)
        squares.append(second ** 2)
    squares = np.concatenate(squares, axis=1)
    variance = np.zeros(images.shape[0])
    for light, row in enumerate(squares):
        finite = row[np.isfinite(row)]
        if finite.size:
            variance[light] = float(np.median(finite)) / (6.0 * _CHI2_1_MEDIAN)
    return variance


def image_gradient_squared(observations, noise_variance=None) -> np.ndarray:
    """Per observation, ``|grad_x y|^2`` of its light's image (px^-2), its noise bias removed per axis.

    Parameters
    ----------
    observations : rjfit.data.observations.Observations
        One channel (``channel`` None).
    noise_variance : ndarray (L,), optional
        Pixel noise variance per light (default :func:`light_noise_variance`); zeros keep the bias.

    Raises
    ------
    ValueError
        For a joint colour stack (its observations of one pixel and light are one per channel).
    """
    if observations.channel is not None:
        raise ValueError("the footprint term measures one channel's image gradient: split a joint colour stack into "
                         "its channels first (rjfit.pipeline.fit_power.channel_normal_error_noise does)")
    images = observations.dense()
    v = light_noise_variance(observations) if noise_variance is None else np.asarray(noise_variance, float)
    v = v[:, None, None]
    total = np.zeros_like(images)
    for axis in (1, 2):
        before, after = _neighbours(images, axis)
        has_before, has_after = np.isfinite(before), np.isfinite(after)
        central = ((after - before) / 2.0) ** 2 - v / 2.0
        forward = (after - images) ** 2 - 2.0 * v
        backward = (images - before) ** 2 - 2.0 * v
        term = np.where(has_before & has_after, central,
                        np.where(has_after, forward, np.where(has_before, backward, 0.0)))
        total += np.maximum(np.nan_to_num(term, nan=0.0), 0.0)
    return _at_observations(total, observations)


def _at_observations(images, observations) -> np.ndarray:
    """Values of images (L, H, W) at the observations' light and pixel."""
    pixel = np.asarray(observations.pixel, np.int64)
    width = observations.image_shape[1]
    return images[np.asarray(observations.light, np.int64), pixel // width, pixel % width]


def finite_squares(residuals, known_variance, *columns):
    """``(r^2, q, *columns)`` over the finite residuals: the inputs of the noise models' maximum likelihood.

    Raises
    ------
    ValueError
        If fewer than 3 finite residuals remain.
    """
    r = np.asarray(residuals, float)
    keep = np.isfinite(r)
    if int(keep.sum()) < 3:
        raise ValueError("need at least 3 finite residuals to estimate the normal (and footprint) error")
    r2 = r[keep] ** 2
    q = np.zeros_like(r2) if known_variance is None else np.broadcast_to(np.asarray(known_variance, float),
                                                                       keep.shape)[keep]
    return (r2, q, *(np.asarray(column, float)[keep] for column in columns))


def estimate_footprint_error(residuals, g2, f2, known_variance=None) -> dict:
    """Maximum-likelihood ``(sigma_r^2, k, t)`` of ``r_i ~ N(0, sigma_r^2 (1 + k g_i^2 + t f_i^2) + q_i)``.

    ``k = sigma_n^2 / sigma_r^2`` (the normals' term, :func:`rjfit.data.normal_error.estimate_normal_error`)
    and ``t = c / sigma_r^2`` (the footprint's), both >= 0; sigma_r^2 profiled out. Search: a
    grid over (log k, log t), each with 0 included, then alternating golden-section steps on
    each log scale between the best grid point's neighbours (a parameter at 0 stays 0).

    Parameters
    ----------
    residuals, g2, f2 : ndarray (N,)
        Residuals, squared tangential gradients and footprint terms ``f_i^2``; non-finite
        residuals are left out.
    known_variance : ndarray (N,) or float, optional
        ``q_i`` (quantisation), entered as ``q_i / sigma_r^2`` at the k = t = 0 level.

    Returns
    -------
    dict
        ``k``, ``t``, ``c`` (= t sigma_r^2), ``sigma_r2``, ``sigma_n_deg``, ``log_likelihood_gain``
        (over k = t = 0), ``n``.

    Raises
    ------
    ValueError
        If fewer than 3 finite residuals remain.
    """
    r2, q, g2, f2 = finite_squares(residuals, known_variance, g2, f2)
    base = max(float(np.mean(r2)), 1e-300)
    scale_g = float(np.median(g2[g2 > 0])) if np.any(g2 > 0) else 1.0
    scale_f = float(np.median(f2[f2 > 0])) if np.any(f2 > 0) else 1.0

    def cost(log_k, log_t):
        """Negative profile log-likelihood and sigma_r^2; ``-inf`` on a log scale means 0."""
        weight = 1.0 + np.exp(log_k) / scale_g * g2 + np.exp(log_t) / scale_f * f2 + q / base
        sigma_r2 = float(np.mean(r2 / weight))
        return 0.5 * r2.size * np.log(sigma_r2) + 0.5 * float(np.sum(np.log(weight))), sigma_r2

    axis = np.concatenate([[-np.inf], _LOG_GRID])
    grid = np.array([[cost(lk, lt)[0] for lt in axis] for lk in axis])
    i, j = np.unravel_index(int(np.argmin(grid)), grid.shape)
    best = [axis[i], axis[j]]
    for _ in range(_REFINE_ROUNDS):
        for which, index in ((0, i), (1, j)):
            if index == 0:
                continue             # at 0: the grid's smallest positive value was no better
            low, high = axis[max(index - 1, 1)], axis[min(index + 1, axis.size - 1)]

            def along(values, which=which):
                return np.array([cost(*(v if w == which else best[w] for w in (0, 1)))[0] for v in np.ravel(values)])

            candidate = float(_golden_section(along, np.array([low]), np.array([high]), 30)[0])
            trial = list(best)
            trial[which] = candidate
            if cost(*trial)[0] <= cost(*best)[0]:
                best = trial
    nll0 = cost(-np.inf, -np.inf)[0]
    nll, sigma_r2 = cost(*best)
    k, t = np.exp(best[0]) / scale_g, np.exp(best[1]) / scale_f
    return {"k": float(k), "t": float(t), "c": float(t * sigma_r2), "sigma_r2": sigma_r2,
            "sigma_n_deg": float(np.degrees(np.sqrt(k * sigma_r2))), "log_likelihood_gain": float(nll0 - nll),
            "n": int(r2.size)}
