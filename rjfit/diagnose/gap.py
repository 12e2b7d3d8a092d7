"""The gap: one number for how far the fitted model is from the data, used throughout.

Definition. With r_i = y_i - E[m_i] (observation minus the posterior mean of the model's
predicted value) and sigma_hat^2 a noise variance estimated from the data,

    gap = mean_i(r_i^2) / sigma_hat^2 - 1.

It is the excess mean squared standardised residual: about 0 for a model that explains the
data up to noise (sampling error ~ sqrt(2/N) plus the error of sigma_hat^2), and grows with
the squared size of what is missing (a gap of 3 means the misfit carries three times the
noise power). The same sigma_hat^2 is used for every model of a data set, so gaps before and
after adding an effect are comparable; per light, per region and per pixel the same ratio is
taken over that subset ("where disagreement concentrates").

Noise estimate. The model's misfit is smooth at pixel scale while the noise is white, so the
noise shows in second differences of the residual images: for three horizontally (or
vertically) adjacent valid observations of the same light and region,
d = r_c - (r_l + r_r)/2 has variance 1.5 sigma^2 plus a tiny share of the misfit's curvature.
A robust scale (1.4826 x median absolute deviation) ignores the few triples across a sharp
edge (a shadow boundary, a region border). The workflow computes it from the residuals of
its FINAL model (the one that leaves the smoothest misfit; the plain model's misfit can have
curvature at pixel scale, which inflates the estimate) and uses that one value for every gap
it reports, before and after every step. Heavy-tailed noise (e.g. Monte Carlo noise of a
low-spp render) is underestimated by the robust scale and shows up as a positive gap.
"""
from __future__ import annotations

import numpy as np

__all__ = ["noise_variance", "gap", "gap_breakdown"]


def noise_variance(ctx, residuals) -> float:
    """Robust noise variance from second differences of the residual images (see above)."""
    r = ctx.dense(residuals)                         # (L, H, W), NaN where not observed
    regions = np.where(ctx.labels >= 0, ctx.labels, -1).astype(float)
    regions[regions < 0] = np.nan
    diffs = []
    for axis in (1, 2):
        left = np.take(r, np.arange(0, r.shape[axis] - 2), axis=axis)
        centre = np.take(r, np.arange(1, r.shape[axis] - 1), axis=axis)
        right = np.take(r, np.arange(2, r.shape[axis]), axis=axis)
        reg_axis = axis - 1
        rl = np.take(regions, np.arange(0, regions.shape[reg_axis] - 2), axis=reg_axis)
        rc = np.take(regions, np.arange(1, regions.shape[reg_axis] - 1), axis=reg_axis)
        rr = np.take(regions, np.arange(2, regions.shape[reg_axis]), axis=reg_axis)
        same = (rl == rc) & (rc == rr)
        d = centre - 0.5 * (left + right)
        keep = np.isfinite(d) & same[None]
        diffs.append(d[keep])
    d = np.concatenate(diffs)
    if d.size < 20:
        raise ValueError("too few adjacent valid observations to estimate the noise")
    mad = np.median(np.abs(d - np.median(d)))
    return float((1.4826 * mad) ** 2 / 1.5)


def gap(residuals, sigma2_hat) -> float:
    """``mean(r^2) / sigma_hat^2 - 1`` (see the module docstring)."""
    residuals = np.asarray(residuals, dtype=float)
    return float(np.mean(residuals ** 2) / sigma2_hat - 1.0)


def gap_breakdown(ctx, residuals, sigma2_hat) -> dict:
    """The gap per light, per region, and per pixel (H, W map; NaN off the observations)."""
    r2 = np.asarray(residuals, dtype=float) ** 2 / sigma2_hat
    per_light = [float(r2[ctx.light == l].mean() - 1.0) if np.any(ctx.light == l) else None
                 for l in range(ctx.n_lights)]
    per_region = [float(r2[ctx.region == k].mean() - 1.0) for k in range(ctx.n_regions)]
    return {"per_light": per_light, "per_region": per_region, "per_pixel": ctx.per_pixel_mean(r2) - 1.0}
