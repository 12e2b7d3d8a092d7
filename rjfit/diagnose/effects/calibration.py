"""Light intensity miscalibration: one unknown scale per light (image).

    mu_l *= s_l,   log s = H z,   z ~ N(0, 0.2^2 I_{L-1})

H (L x L-1) is an orthonormal basis of the vectors that sum to zero (Helmert), so the
geometric mean of the scales is fixed to 1: an overall scale is not identifiable apart from
the regions' I0. The prior is the iid log-normal N(0, 0.2^2) on log s conditioned on that
constraint (0.2: a 20 % error is one prior standard deviation). Mitsuba side: the emitters'
intensities times s_l.
"""
from __future__ import annotations

import numpy as np

from rjfit.diagnose.effects.base import Effect, Param
from rjfit.model.effects import helmert_basis, light_scales
from rjfit.model.priors import Normal
from rjfit.render.scene_change import MitsubaChange
from rjfit.sampler.effects import LightGains

__all__ = ["LightCalibration", "helmert_basis", "light_scales", "PRIOR_SCALE"]

PRIOR_SCALE = 0.2


class LightCalibration(Effect):
    name = "light_calibration"
    kind = "light intensity miscalibration"
    stage = "light"
    description = "per-light intensity scales, log-normal prior (sd 0.2), geometric mean fixed to 1"

    def params(self, ctx):
        return [Param(f"h{j}", Normal(loc=0.0, scale=PRIOR_SCALE), init=0.0, null=0.0)
                for j in range(1, ctx.n_lights)]

    def available(self, ctx):
        if ctx.n_lights < 2:
            return False, "one light: a per-light scale is the regions' I0"
        return True, ""

    def prepare(self, ctx):
        return helmert_basis(ctx.n_lights)

    def apply(self, terms, theta, features, ctx):
        self.apply_light_values(terms, features @ np.asarray(theta, dtype=float), ctx)

    def light_basis(self, ctx):
        """log s = H theta: each light's log scale (see Effect.light_basis)."""
        return helmert_basis(ctx.n_lights)

    def apply_light_values(self, terms, log_scales, ctx):
        terms["mu"] = terms["mu"] * np.exp(np.asarray(log_scales, dtype=float))[ctx.light]

    def scales(self, theta, ctx):
        return light_scales(theta, ctx.n_lights)

    def mitsuba_change(self, theta, ctx):
        return MitsubaChange(light_scales=light_scales(theta, ctx.n_lights))

    def sampler_effect(self, ctx):
        """Per-light gains on C (:class:`rjfit.sampler.effects.LightGains`)."""
        return LightGains(params=self.fit_params(ctx), n_lights=ctx.n_lights)
