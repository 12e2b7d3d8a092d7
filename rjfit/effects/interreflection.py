"""Interreflection: light that bounced off the object before reaching the surface point.

    mu += beta * L_ind,   L_ind = path(max_depth 8) - path(max_depth 2)

``L_ind`` is the indirect radiance of the FITTED model (the current fit's region parameters in
rjfit's plugin), path-traced by Mitsuba along the data set's own pixel-centre rays for every
light. Direct light from a point or directional emitter is deterministic in Mitsuba, so the
difference carries only the Monte Carlo noise of the indirect paths. beta = 1 is the physical
value; beta = 0 the plain model. Needs the data set's mesh.

- physics: the rendered feature (:func:`rjfit.effects.scenes.indirect_radiance`, the render-side
  twin, :func:`rjfit.render.effect_scenes.render_indirect`);
- criticism: :class:`Interreflection` (``beta F`` added to the indirect term);
- fit: :class:`IndirectLight`, a known offset ``y -> y - beta F``;
- Mitsuba: the path integrator's max_depth (8 instead of the direct-only 2).

Samples per pixel. beta is a regression coefficient on a feature measured with Monte Carlo
noise: errors in variables attenuate it by the factor ``v_signal / (v_signal + v_mc)``, i.e.
a share ``v_mc / (v_mc + v_signal)`` of beta is lost, where ``v_mc`` is the feature's Monte
Carlo variance per observation (from its independent batches; it falls as 1 / spp) and
``v_signal`` the variance of the indirect light across the observations of a region (what
tells beta from the region's own parameters). The share does not depend on the resolution
(both are per pixel). Measured on dented_plaster at its true materials and segmentation
(2026-11-26; 64 x 64 x 8 lights, and 128 x 128 x 12): 9.4 % (9.7) at 32 spp, 5.0 % (5.1) at
64, 2.6 % (2.6) at 128, 1.3 % (1.3) at 256; ``v_mc`` 0.036 at 32 spp against the data's noise
variance 0.1. Hence:

- ``INDIRECT_SPP`` (the diagnosis' candidate test and its final model): share <= 5 %; what is
  decided there is whether interreflection is there (log Bayes factors in the thousands) and
  the materials once the indirect light is out of them, whose error from a 5 % shorter beta
  is 5 % of the indirect light (~14 % of the radiance on that object), under 1 %;
- ``FEATURE_SPP`` (the refit's feature, rendered once per fit and sampled with the
  segmentation): share <= 2 %, so that the fit's beta and the regions' albedos it frees are
  within 2 % of the indirect light.

Seconds per render (LLVM, 2 shared cores, load 2 to 3): 64 x 64 x 8 lights 4.5 (32 spp), 6.7
(64), 9.5 (128), 13.7 (256); 128 x 128 x 12 lights 11.9, 20.4, 34.8, 48.5. :func:`feature_record`
measures the share on the feature a refit renders (its summary records it: on an over-segmented
fit's regions the per-region signal variance is smaller and the share larger, 4 % measured).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rjfit.effects.base import Columns, Effect, FitForm, Param, take
from rjfit.effects.scenes import indirect_radiance
from rjfit.model.priors import LogNormal
from rjfit.render.scene_change import MitsubaChange

__all__ = ["Interreflection", "IndirectLight", "INDIRECT_SPP", "FEATURE_SPP", "INDIRECT_DEPTH", "feature_key",
           "feature_record"]

INDIRECT_SPP = 64      # the diagnosis' feature: beta attenuated <= 5 % (module docstring)
FEATURE_SPP = 256      # the refit's feature: beta attenuated <= 2 % (module docstring)
INDIRECT_DEPTH = 8


class Interreflection(Effect):
    name = "interreflection"
    kind = "interreflection"
    stage = "indirect"
    needs_mitsuba = True
    renders_fitted_model = True
    description = "beta x Mitsuba path-traced indirect radiance of the fitted model (depth 8 minus direct)"

    def params(self, ctx):
        return [Param("beta", LogNormal(loc=0.0, scale=1.0), init=1.0, null=0.0)]

    def prepare(self, ctx):
        """The indirect light at each observation of ``ctx``, rendered at ``ctx.features['indirect_spp']``
        (default ``INDIRECT_SPP``; a refit's context: ``FEATURE_SPP``) samples per pixel for the region
        parameters ``ctx.features['fit_region_params']`` (cached in ``ctx`` per both; its Monte Carlo
        error beside it, and in ``ctx.features['indirect_se']`` for the gate).

        Raises
        ------
        RuntimeError
            If ``ctx.features`` holds no region parameters.
        """
        region_params = ctx.features.get("fit_region_params")
        if region_params is None:
            raise RuntimeError("interreflection needs the current fit's region parameters in "
                               "ctx.features['fit_region_params'] (the workflow sets them)")
        spp = int(ctx.features.get("indirect_spp", INDIRECT_SPP))
        key = feature_key(region_params, spp)
        se_key = ("indirect_se",) + key[1:]
        if key not in ctx.features:
            ctx.features[key] = indirect_radiance(ctx, region_params, spp=spp, max_depth=INDIRECT_DEPTH)
            ctx.features[se_key] = ctx.features["indirect_se"]
        if se_key in ctx.features:      # the error of the feature last used
            ctx.features["indirect_se"] = ctx.features[se_key]
        width = ctx.image_shape[1]
        return ctx.features[key][ctx.light, ctx.pixel // width, ctx.pixel % width]

    def apply(self, terms, theta, features, ctx):
        terms["indirect"] = terms["indirect"] + theta[0] * features

    def mitsuba_change(self, theta, ctx=None):
        return MitsubaChange(max_depth=INDIRECT_DEPTH, stochastic=True)

    def fit_form(self, ctx):
        """A known offset ``beta F`` (:class:`IndirectLight`): F the indirect light
        (:meth:`prepare`; a refit sets ``ctx.features['indirect_spp']`` to ``FEATURE_SPP``) of the fitted
        model whose region parameters ``ctx.features['fit_region_params']`` holds, a fixed feature of the fit."""
        return IndirectLight(params=self.fit_params(ctx), feature=self.prepare(ctx))


@dataclass(frozen=True, eq=False)
class IndirectLight(FitForm):
    """Interreflection in the fit: a known indirect radiance ``feature`` (a fixed feature per fit) times beta added to the mean."""

    params: tuple
    feature: np.ndarray
    name: str = "interreflection"
    stage: str = "indirect"

    def apply(self, columns: Columns, theta) -> None:
        columns.add_offset(theta[0] * self.feature)

    def in_order(self, order):
        return take(self, order, "feature")


def feature_key(region_params, spp) -> tuple:
    """The key of the indirect light rendered at ``spp`` for ``region_params`` in a context's feature cache."""
    return ("indirect", int(spp), np.asarray(region_params, dtype=float).tobytes())


def feature_record(ctx) -> dict:
    """What the summary records of the feature :meth:`Interreflection.prepare` gives on ``ctx``:
    ``feature_spp``, its Monte Carlo variance per observation and the share by which that attenuates
    beta, ``v_mc / (v_mc + v_signal)`` (module docstring)."""
    feature = Interreflection().prepare(ctx)
    spp = int(ctx.features.get("indirect_spp", INDIRECT_SPP))
    width = ctx.image_shape[1]
    v_mc = float(np.mean(ctx.features["indirect_se"][ctx.light, ctx.pixel // width, ctx.pixel % width] ** 2))
    centred = feature.copy()
    for region in range(ctx.n_regions):
        centred[ctx.region == region] -= centred[ctx.region == region].mean()
    v_signal = max(float(centred.var()) - v_mc, 0.0)
    share = v_mc / (v_mc + v_signal) if v_mc + v_signal > 0 else None
    return {"feature_spp": int(spp), "feature_mc_variance": v_mc, "feature_signal_variance": v_signal,
            "beta_attenuation_share": share}
