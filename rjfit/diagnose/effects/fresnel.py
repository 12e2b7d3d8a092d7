"""Fresnel reflection at grazing angles: Schlick's F(<h.v>; F0) on the specular lobe.

    spec *= F(<h.v>) / F0,   F(c) = F0 + (1 - F0) (1 - c)^5

Dividing by F0 keeps the lobe's normal-incidence albedo (which I0 (1 - kd) already carries):
F0 = 1 is the plain model; a small F0 (0.04 for glass-like coatings) brightens the lobe where
light and view directions are far apart (<h.v> small: back lighting). F0 is kept above
``F0_MIN`` = 0.01, below every real dielectric's. Mitsuba side: the
plugin variant ``rjfit_blinn_ext`` with parameter ``f0`` (the same factor in the BSDF).
"""
from __future__ import annotations

import numpy as np

from rjfit.diagnose.effects.base import Effect, Param
from rjfit.model.priors import LogitNormal
from rjfit.render.scene_change import MitsubaChange

# The smallest normal-incidence reflectance of a real dielectric is about 0.02 (water, n = 1.33;
# ((n - 1) / (n + 1))^2); 0.01 (n = 1.22) stays below every coating, paint binder and glass.
F0_MIN = 0.01


def schlick_ratio(cos_hv, f0):
    """``F(<h.v>) / F0`` of Schlick's approximation."""
    return 1.0 + (1.0 / f0 - 1.0) * (1.0 - np.clip(cos_hv, 0.0, 1.0)) ** 5


class Fresnel(Effect):
    name = "fresnel"
    kind = "Fresnel reflection"
    stage = "lobe"
    description = "Schlick Fresnel factor F(h.v; F0)/F0 on the specular lobe (F0 = 1: none)"

    def params(self, ctx):
        # F0 ~ logit-normal on (F0_MIN, 1) centred on 0.2, broad (covers dielectrics ~0.04 and
        # metals ~0.9). The floor is physical: without it, a fit could take F0 -> 0, where the
        # factor (1/F0 - 1) (1 - <h.v>)^5 stops being Fresnel and becomes a free per-light gain
        # of the lobe (on the measured ball F0 went to 0.0000 and was named on that ground).
        centre = (0.2 - F0_MIN) / (1.0 - F0_MIN)
        return [Param("F0", LogitNormal(loc=float(np.log(centre / (1.0 - centre))), scale=2.0, low=F0_MIN, high=1.0),
                      init=0.5, null=1.0)]

    def prepare(self, ctx):
        return (1.0 - ctx.cos_hv) ** 5

    def apply(self, terms, theta, features, ctx):
        f0 = theta[0]
        terms["spec"] = terms["spec"] * (1.0 + (1.0 / f0 - 1.0) * features)

    def mitsuba_change(self, theta, ctx=None):
        return MitsubaChange(bsdf_params={"f0": float(theta[0])})
