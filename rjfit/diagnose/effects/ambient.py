"""Ambient or stray light: a constant environment radiance around the object.

    mu += a * I0 * ( kd + (1 - kd) * A_g(theta_v) )

``a`` is the environment's radiance relative to the reference intensity (Mitsuba: a
``constant`` emitter of radiance a x reference_intensity). For a white constant environment
the reflected radiance is the BRDF's directional albedo: kd for the Lambert part, and for the
normalised Blinn lobe ``A_g(theta_v) = int N(g) <h.n>^g <l.n> dl`` over the hemisphere, which
depends on gamma and the view angle (Giesen's normalisation makes it ~1 at normal view). It is
tabulated once by quadrature over the half vector (Gauss-Legendre in u = cos^(g+1) theta_h,
uniform in phi) and interpolated; exact for a convex object, where nothing occludes the sky.
"""
from __future__ import annotations

import numpy as np

from rjfit.diagnose.effects.base import Effect, Param
from rjfit.model.effects import (
    ALBEDO_COS_V,
    ALBEDO_LOG_GAMMA,
    albedo_rows,
    albedo_table,
    cos_v_weights,
    gamma_weights,
    lobe_albedo,
    lobe_albedo_quadrature,
)
from rjfit.model.priors import LogNormal
from rjfit.render.scene_change import MitsubaChange
from rjfit.sampler.effects import AmbientLight

__all__ = ["Ambient", "lobe_albedo", "lobe_albedo_quadrature", "albedo_rows", "albedo_table", "gamma_weights",
           "cos_v_weights"]


class Ambient(Effect):
    name = "ambient"
    kind = "ambient or stray light"
    stage = "ambient"
    description = "constant environment radiance a (relative to the reference intensity) x the BRDF's albedo"

    def params(self, ctx):
        return [Param("ambient", LogNormal(loc=float(np.log(0.01)), scale=2.5), init=0.01, null=0.0)]

    def prepare(self, ctx):
        # Bilinear interpolation is separable: the view angle's column and weight are fixed per
        # observation, so a refit's evaluation interpolates in gamma once per region (a row of
        # the table) and gathers from those rows (as lobe_albedo, 15x faster on the ball)
        j, fy = cos_v_weights(ctx.cos_vn)
        return ctx.region * ALBEDO_COS_V.size + j, fy

    def apply(self, terms, theta, features, ctx):
        kd = terms["kd"]
        index, fy = features
        rows = albedo_rows(terms["gamma_region"]).ravel()
        albedo = (1.0 - fy) * rows[index] + fy * rows[index + 1]
        terms["mu"] = terms["mu"] + theta[0] * terms["I0"] * (kd + (1.0 - kd) * albedo)

    def mitsuba_change(self, theta, ctx):
        radiance = float(theta[0]) * ctx.reference_intensity
        return MitsubaChange(extra={"ambient": {"type": "constant", "radiance": {"type": "rgb", "value": [radiance] * 3}}},
                             stochastic=True,
                             notes=["exact for a convex object: nothing occludes the environment"])

    def sampler_effect(self, ctx):
        """``A += a`` and the lobe's ambient term (:class:`rjfit.sampler.effects.AmbientLight`)."""
        column, weight = cos_v_weights(ctx.cos_vn)
        grid = np.array([ALBEDO_LOG_GAMMA[0], ALBEDO_LOG_GAMMA[-1], ALBEDO_LOG_GAMMA[1] - ALBEDO_LOG_GAMMA[0]])
        return AmbientLight(params=self.fit_params(ctx), column=column.astype(np.int32), weight=weight,
                            table=albedo_table(), grid=grid)
