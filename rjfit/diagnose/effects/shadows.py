"""Cast shadows missing from the valid mask: multiply direct light by Mitsuba's shadow rays.

    direct *= 1 - w (1 - V),   V = 1 where a shadow ray from the surface point reaches the light

V is computed with Mitsuba (``scene.ray_test`` from the pixel-centre intersection towards the
light; ``rjfit.render.mitsuba_scene.shadow_visibility``) on the data set's own mesh, whatever
the data set's ``visibility`` says. w = 1 is full occlusion, w = 0 the plain model.

Why multiply rather than drop the shadowed observations: evidence (Bayes factor, LOO) is only
comparable between models of the SAME observations. Dropping the shadowed ones would change
the data and make the two evidences incommensurable; multiplying keeps every observation and
lets the data decide how dark the shadows are. The Mitsuba side needs no change: the path
tracer always traces occlusion; the closed form with w = 1 reproduces it (the gate with the
plain closed form fails exactly on the shadowed observations).
"""
from __future__ import annotations

from rjfit.diagnose.effects.base import Effect, Param
from rjfit.model.priors import LogitNormal
from rjfit.render.effect_scenes import mitsuba_visibility
from rjfit.render.scene_change import MitsubaChange
from rjfit.sampler.effects import DirectFactor


class CastShadows(Effect):
    name = "cast_shadows"
    kind = "cast shadows"
    stage = "direct"
    needs_mitsuba = True
    description = "direct light times Mitsuba shadow-ray visibility (weight w; w = 0: none)"

    def params(self, ctx):
        return [Param("w_shadow", LogitNormal(loc=0.0, scale=2.0), init=0.5, null=0.0, physical_ends=(1.0,))]

    def prepare(self, ctx):
        visibility = ctx.feature("mitsuba_visibility", lambda: mitsuba_visibility(ctx.dataset))
        width = ctx.image_shape[1]
        return visibility[ctx.light, ctx.pixel // width, ctx.pixel % width].astype(float)

    def available(self, ctx):
        ok, why = super().available(ctx)
        if not ok:
            return ok, why
        return True, ""

    def apply(self, terms, theta, features, ctx):
        terms["direct"] = terms["direct"] * (1.0 - theta[0] * (1.0 - features))

    def mitsuba_change(self, theta, ctx=None):
        return MitsubaChange(notes=["Mitsuba traces occlusion always; the closed form matches it at w = 1"])

    def sampler_effect(self, ctx):
        """A factor on the direct light's C (:class:`rjfit.sampler.effects.DirectFactor`), Mitsuba's visibility."""
        return DirectFactor(params=self.fit_params(ctx), visibility=self.prepare(ctx))
