"""Interreflection: light that bounced off the object before reaching the surface point.

    mu += beta * L_ind,   L_ind = path(max_depth 8) - path(max_depth 2)

``L_ind`` is the indirect radiance of the FITTED model (the current fit's region parameters in
rjfit's plugin), path-traced by Mitsuba along the data set's own pixel-centre rays for every
light. Direct light from a point or directional emitter is deterministic in Mitsuba, so the
difference carries only the Monte Carlo noise of the indirect paths. beta = 1 is the physical
value; beta = 0 the plain model. Mitsuba side: the path integrator's max_depth (8 instead of
the direct-only 2). Needs the data set's mesh.
"""
from __future__ import annotations

import numpy as np

from rjfit.diagnose.effects.base import Effect, Param
from rjfit.diagnose.scenes import indirect_radiance
from rjfit.model.priors import LogNormal
from rjfit.render.scene_change import MitsubaChange
from rjfit.sampler.effects import IndirectLight

INDIRECT_SPP = 32
INDIRECT_DEPTH = 8


class Interreflection(Effect):
    name = "interreflection"
    kind = "interreflection"
    stage = "indirect"
    needs_mitsuba = True
    description = "beta x Mitsuba path-traced indirect radiance of the fitted model (depth 8 minus direct)"

    def params(self, ctx):
        return [Param("beta", LogNormal(loc=0.0, scale=1.0), init=1.0, null=0.0)]

    def prepare(self, ctx):
        region_params = ctx.features.get("fit_region_params")
        if region_params is None:
            raise RuntimeError("interreflection needs the current fit's region parameters in "
                               "ctx.features['fit_region_params'] (the workflow sets them)")
        indirect = ctx.feature(("indirect", np.asarray(region_params).tobytes()),
                               lambda: indirect_radiance(ctx, region_params, spp=INDIRECT_SPP,
                                                         max_depth=INDIRECT_DEPTH))
        width = ctx.image_shape[1]
        return indirect[ctx.light, ctx.pixel // width, ctx.pixel % width]

    def apply(self, terms, theta, features, ctx):
        terms["indirect"] = terms["indirect"] + theta[0] * features

    def mitsuba_change(self, theta, ctx=None):
        return MitsubaChange(max_depth=INDIRECT_DEPTH, stochastic=True)

    def sampler_effect(self, ctx):
        """A known offset ``beta F`` (:class:`rjfit.sampler.effects.IndirectLight`): F the indirect light of the
        fitted model whose region parameters ``ctx.features['fit_region_params']`` holds, a fixed feature of the fit."""
        return IndirectLight(params=self.fit_params(ctx), feature=self.prepare(ctx))
