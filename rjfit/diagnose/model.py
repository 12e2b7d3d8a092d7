"""The extended closed form: eq. 2 with effects composed in stages (:mod:`rjfit.effects.base`).

Eq. 2 itself is :mod:`rjfit.model.blinn`'s: Giesen's normalisation is its
``blinn_normalisation``, and the lobe ``<h.n>^g`` is its ``log_cos_power`` bit for bit. What
is written out here, and why:

- ``log <h.n>`` is taken once per context (``ctx.feature``) and the lobe computed as
  ``exp(g log <h.n>)`` from it, where ``log_cos_power(<h.n>, g)`` would take the logarithm
  again at every one of a refit's thousands of evaluations. The values are the same bits
  (the same exp of the same product where <h.n> > 0; exp(-inf) = 0 elsewhere, as the
  ``where`` of ``log_cos_power`` gives for g > 0).
- The direct term ``I0 (E max(<l.n>, 0)) (kd/pi + (1 - kd) spec)`` is eq. 2, but not
  :func:`rjfit.model.blinn.radiance`: the lobe-stage effects (Fresnel, masking) change the
  lobe between ``N(g) <h.n>^g`` and the BRDF's sum, which ``brdf`` does not let in, and
  ``radiance`` multiplies in another order (``((I0 E) brdf) <l.n>``), which changes the last
  bits of every prediction and so of every diagnosis. Both equalities are tested
  (``tests/diagnose/test_diagnose_units.py``: the lobe bit for bit, the plain prediction to
  rounding).

:func:`fit_prediction` is the same mean as the FIT computes it with the effects inside its
likelihood (issue 26): the sampler's forward model (:mod:`rjfit.sampler.forward`, built by
each effect's ``fit_form``) transforms the problem, and the mean is ``f(offset + a A +
b B(gamma))`` on the data's scale. It equals :func:`predict` to float32 rounding
(``tests/diagnose/test_effects_in_fit.py``, per effect); the gate
(:func:`rjfit.diagnose.gate.gate`) checks it against Mitsuba as well.
"""
from __future__ import annotations

import numpy as np

from rjfit.data.observations import Observations
from rjfit.effects.base import STAGES, stage_key
from rjfit.model.blinn import blinn_normalisation
from rjfit.sampler.forward import LambertBlinnPhong, transformed
from rjfit.sampler.likelihood import ab_from_theta, lobe_column

__all__ = ["predict", "fit_prediction", "order_effects", "REGION_PARAMS"]

REGION_PARAMS = ("I0", "kd", "gamma", "sigma2")


def order_effects(effects):
    """Effects sorted by stage and their order in it (:func:`rjfit.effects.base.stage_key`; stable)."""
    return tuple(sorted(effects, key=stage_key))


def _geometry(ctx):
    """What every prediction of a context reuses: log <h.n> (-inf where <h.n> <= 0, so that the
    lobe's power is 0 there for every gamma > 0) and E max(<l.n>, 0)."""
    positive = ctx.cos_hn > 0
    with np.errstate(divide="ignore"):
        log_cos = np.where(positive, np.log(np.where(positive, ctx.cos_hn, 1.0)), -np.inf)
    return log_cos, ctx.irradiance * np.maximum(ctx.cos_ln, 0.0)


def predict(ctx, effects, region_params, effect_thetas, features):
    """Expected value of every observation of ``ctx``.

    Parameters
    ----------
    region_params : ndarray (R, >=3)
        Constrained I0, kd, gamma per region (sigma2 may follow, unused here).
    effect_thetas : list of ndarray
        Constrained parameters of each effect, in the order of ``effects``.
    features : list
        ``effect.prepare(ctx)`` of each effect.
    """
    region_params = np.asarray(region_params, dtype=float)
    I0 = region_params[ctx.region, 0]
    kd = region_params[ctx.region, 1]
    gamma_r = region_params[:, 2]
    gamma = gamma_r[ctx.region]
    log_cos, irradiance_cos = ctx.feature("predict_geometry", lambda: _geometry(ctx))
    lobe = blinn_normalisation(gamma_r)[ctx.region] * np.exp(gamma * log_cos)     # 0 where <h.n> <= 0
    terms = {"I0": I0, "kd": kd, "gamma": gamma, "gamma_region": gamma_r, "spec": lobe}
    by_stage = {stage: [] for stage in STAGES}
    for effect, theta, feature in sorted(zip(effects, effect_thetas, features), key=lambda t: stage_key(t[0])):
        by_stage[effect.stage].append((effect, theta, feature))

    def run(stage):
        for effect, theta, feature in by_stage[stage]:
            effect.apply(terms, theta, feature, ctx)

    run("lobe")
    terms["direct"] = I0 * irradiance_cos * (kd / np.pi + (1.0 - kd) * terms["spec"])
    run("direct")
    terms["indirect"] = np.zeros_like(terms["direct"])
    run("indirect")
    terms["mu"] = terms["direct"] + terms["indirect"]
    run("light")
    run("ambient")
    run("camera")
    return terms["mu"]


def fit_prediction(ctx, effects, region_params, effect_thetas):
    """Expected value of every observation of ``ctx`` as the fit's forward model computes it.

    The arguments as :func:`predict`'s (without features: each effect's ``fit_form``
    computes its own). The fit's problem of the context's observations (with the context's
    noise scales) is transformed at the effects' parameters; the mean ``a A + b B(gamma)``
    of the transformed problem, times the noise scale, goes through the camera response
    with the known offsets (:meth:`rjfit.effects.base.Columns.data_scale`). The data do
    not enter a mean: the problem is built with every value 1 (a camera's inverse needs
    positive values).
    """
    ones = np.ones(ctx.n_obs)
    observations = Observations(image_shape=ctx.image_shape, n_lights=ctx.n_lights, pixel=ctx.pixel, light=ctx.light,
                                y=ones, cos_ln=ctx.cos_ln, cos_hn=ctx.cos_hn, irradiance=ctx.irradiance,
                                object_mask=ctx.labels >= 0)
    model = LambertBlinnPhong([effect.fit_form(ctx) for effect in effects])
    problem = model.problem(observations, noise_scale=ctx.noise_scale)
    theta_of = {effect.name: np.atleast_1d(np.asarray(theta, dtype=float)) for effect, theta in zip(effects, effect_thetas)}
    # a parameter at its physical end (w = 1: full shadows) is +-inf unconstrained, and maps back exactly
    with np.errstate(divide="ignore"):
        z = np.concatenate([[float(p.prior.to_unconstrained(v)) for p, v in zip(e.params, theta_of[e.name])]
                            for e in problem.effects.effects])
    draw, _ = transformed(problem, z)
    order = np.argsort(ctx.pixel, kind="stable")      # the problem's order (sorted by pixel)
    theta = np.asarray(region_params, dtype=float)[ctx.region[order]]
    a, b = ab_from_theta(theta)
    mean = a * draw.C.astype(np.float64) / np.pi + b * lobe_column(draw, slice(None), theta[:, 2])
    scale = 1.0 if problem.effects.scale is None else problem.effects.scale
    out = np.empty(ctx.n_obs)
    out[order] = problem.effects.columns(z).data_scale(mean * scale)
    return out
