"""Cast shadows missing from the valid mask: multiply direct light by Mitsuba's shadow rays.

    direct *= 1 - w (1 - V),   V = 1 where a shadow ray from the surface point reaches the light

V is computed with Mitsuba (``scene.ray_test`` from the pixel-centre intersection towards the
light; :func:`rjfit.render.effect_scenes.mitsuba_visibility`, the render-side twin) on the
data set's own mesh, whatever the data set's ``visibility`` says. w = 1 is full occlusion,
w = 0 the plain model.

Why multiply rather than drop the shadowed observations: evidence (Bayes factor, LOO) is only
comparable between models of the SAME observations. Dropping the shadowed ones would change
the data and make the two evidences incommensurable; multiplying keeps every observation and
lets the data decide how dark the shadows are. The Mitsuba side needs no change: the path
tracer always traces occlusion; the closed form with w = 1 reproduces it (the gate with the
plain closed form fails exactly on the shadowed observations).

- physics: :func:`shadow_factor` (both forms use it);
- criticism: :class:`CastShadows` (the factor on the direct light);
- fit: :class:`DirectFactor`, a factor on C and the lobe's C.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rjfit.effects.base import Columns, Effect, FitForm, Param, take
from rjfit.model.priors import LogitNormal
from rjfit.render.effect_scenes import mitsuba_visibility
from rjfit.render.scene_change import MitsubaChange

__all__ = ["CastShadows", "DirectFactor", "shadow_factor"]


def shadow_factor(visibility, w):
    """``1 - w (1 - V)``: the direct light's factor at shadow weight ``w``."""
    return 1.0 - w * (1.0 - visibility)


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

    def apply(self, terms, theta, features, ctx):
        terms["direct"] = terms["direct"] * shadow_factor(features, theta[0])

    def mitsuba_change(self, theta, ctx=None):
        return MitsubaChange(notes=["Mitsuba traces occlusion always; the closed form matches it at w = 1"])

    def fit_form(self, ctx):
        """A factor on the direct light's C (:class:`DirectFactor`), Mitsuba's visibility."""
        return DirectFactor(params=self.fit_params(ctx), visibility=self.prepare(ctx))


@dataclass(frozen=True, eq=False)
class DirectFactor(FitForm):
    """Cast shadows in the fit: direct light (C and the lobe's C) times :func:`shadow_factor`."""

    params: tuple
    visibility: np.ndarray
    name: str = "cast_shadows"
    stage: str = "direct"

    def apply(self, columns: Columns, theta) -> None:
        # scale(): C, CB and what else carries direct light (a second lobe); no offset exists at this stage yet
        columns.scale(shadow_factor(self.visibility, theta[0]))

    def in_order(self, order):
        return take(self, order, "visibility")
