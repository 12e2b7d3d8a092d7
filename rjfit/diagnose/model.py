"""The extended closed form: eq. 2 with effects composed in stages (see effects/base.py)."""
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
