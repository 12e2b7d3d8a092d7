"""The extended closed form: eq. 2 with effects composed in stages (see effects/base.py).

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
"""
from __future__ import annotations

import numpy as np

from rjfit.diagnose.effects.base import STAGES
from rjfit.model.blinn import blinn_normalisation

__all__ = ["predict", "order_effects", "REGION_PARAMS"]

REGION_PARAMS = ("I0", "kd", "gamma", "sigma2")


def order_effects(effects):
    """Effects sorted by stage (stable within a stage)."""
    return tuple(sorted(effects, key=lambda e: STAGES.index(e.stage)))


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
    for effect, theta, feature in zip(effects, effect_thetas, features):
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
