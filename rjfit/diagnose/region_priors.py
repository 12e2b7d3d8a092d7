"""The region parameters' start and priors of the criticism refits, centred on the data.

Every model of one context (the plain one and each extension) shares these priors: they are
computed once per context (:func:`rjfit.diagnose.refit.refit` keeps them in ``ctx.features``),
so they cancel in the Bayes factors between models, which then compare only the effects.
"""
from __future__ import annotations

import math

import numpy as np

from rjfit.model.blinn import blinn_normalisation, log_cos_power
from rjfit.model.priors import LogitNormal, LogNormal

__all__ = ["initial_region_params", "region_priors", "INITIAL_GAMMAS"]

# the exponents the initial linear fit tries per region
INITIAL_GAMMAS = (1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0, 128.0)


def initial_region_params(ctx):
    """Per region ``(I0, kd, gamma, sigma2)`` from linear least squares on a gamma grid.

    For each gamma of :data:`INITIAL_GAMMAS`, y on the columns E <l.n> / pi and E <l.n> N(g)
    <h.n>^g (weighted by the noise model's scales: y and the columns divided by s_i), the
    coefficients clipped to at least 1e-3 of the largest; the gamma with the smallest residual
    sum of squares is kept, I0 = a_d + a_s, kd = a_d / I0 clipped to [0.02, 0.98], sigma2 =
    the mean squared residual.

    Not :func:`rjfit.data.pixelfit.per_pixel_residuals`, which also fits a gamma grid: that
    one fits every pixel (2 x 2 normal equations from per-pixel sums, unconstrained
    coefficients, 16 exponents from 0.5 to 500) to get residuals free of any segmentation;
    this one fits every region (``numpy.linalg.lstsq``, clipped positive coefficients, these 8
    exponents) to get a start and the priors' centres. One function for both would change
    the numbers of one of them (another solver, grid and clipping), and with them the
    diagnoses or the fits' noise models.
    """
    out = np.zeros((ctx.n_regions, 4))
    y_all = ctx.standardise(ctx.y)
    base_all = ctx.standardise(ctx.irradiance * np.maximum(ctx.cos_ln, 0.0))
    for r in range(ctx.n_regions):
        sel = ctx.region == r
        y, base = y_all[sel], base_all[sel]
        best = None
        for gamma in INITIAL_GAMMAS:
            design = np.stack([base / np.pi, base * blinn_normalisation(gamma) * log_cos_power(ctx.cos_hn[sel], gamma)], 1)
            coef, *_ = np.linalg.lstsq(design, y, rcond=None)
            coef = np.maximum(coef, 1e-3 * max(abs(coef).max(), 1e-9))
            ss = float(np.sum((y - design @ coef) ** 2))
            if best is None or ss < best[0]:
                best = (ss, coef, gamma)
        ss, (a_d, a_s), gamma = best
        I0 = a_d + a_s
        out[r] = (I0, np.clip(a_d / I0, 0.02, 0.98), gamma, max(ss / max(sel.sum(), 1), 1e-8))
    return out


def region_priors(init):
    """The priors of one region's ``(I0, kd, gamma, sigma2)``, from :func:`initial_region_params`'s ``init``:

    log I0 ~ N(log median I0_init, 2^2), logit kd ~ N(0, 2^2), log gamma ~ N(log 10, 1.5^2),
    log sigma^2 ~ N(log median sigma2_init, 2^2).

    How they differ from the fit's priors (:func:`rjfit.sampler.priors.make_prior`,
    ``default`` preset), and why:

    - Family: every one is Gaussian in its unconstrained coordinate
      (:mod:`rjfit.model.priors`). The Laplace evidence needs that: the least squares carry
      the prior as residual rows (z - loc) / scale, and the Hessian adds the prior's
      curvature diag(1 / scale^2) in closed form. The fit's ``kd ~ Uniform(0, 1)`` is not
      Gaussian in logit kd (and the paper presets' uniform priors have hard bounds, where a
      Laplace approximation fails); the sampler needs no such form.
    - kd: logit kd ~ N(0, 2^2) instead of Uniform(0, 1): nearly flat over kd in (0.1, 0.9),
      thinner towards 0 and 1.
    - I0: centred on the median of the regions' initial I0 with sd 2 in log I0, where the fit
      centres on the median of y / (E <l.n> / pi) over the observations with sd 1.5: a
      region's linear fit is the nearer start, and the wider sd keeps the prior weak around it.
    - sigma2: centred on the median of the regions' initial mean squared residual with sd 2,
      where the fit centres on 1e-3 var(y) with sd 3: the criticism's regions are the fit's
      MAP segmentation, whose residuals the linear fit already measures.
    - gamma: the same, log gamma ~ N(log 10, 1.5^2).
    - The effects' parameters have priors only here (each effect states its own).

    So a criticism's log evidence is not a fit's: its Bayes factors compare effects on the
    fit's segmentation under these priors, not numbers of regions under the fit's.
    """
    I0_centre = float(np.median(init[:, 0]))
    s2_centre = float(np.median(init[:, 3]))
    return [LogNormal(math.log(I0_centre), 2.0), LogitNormal(0.0, 2.0), LogNormal(math.log(10.0), 1.5),
            LogNormal(math.log(s2_centre), 2.0)]
