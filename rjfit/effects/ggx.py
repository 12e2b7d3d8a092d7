"""The lobe's shape: a GGX (Trowbridge-Reitz) microfacet lobe mixed into the Blinn-Phong lobe.

    spec = (1 - w) N(g) <h.n>^g + w f_GGX(alpha),   alpha = sqrt(2 / (gamma + 2))
    f_GGX = D(h) G1(v) G1(l) / (4 <v.n> <l.n>)
    D(h) = alpha^2 / (pi (1 + <h.n>^2 (alpha^2 - 1))^2),   G1(x) = 2 / (1 + sqrt(1 + alpha^2 tan^2 x))

``f_GGX`` is a true microfacet BRDF with Fresnel 1 (Walter et al. 2007, eqs. 33 and 34: the
GGX distribution and its exact separable Smith term): Mitsuba's built-in ``roughconductor``
with ``material = "none"``, ``distribution = "ggx"`` is its twin, term for term. ``alpha``
comes from the region's own gamma by the Blinn-Phong <-> microfacet roughness match of
Walter et al. (2007, sec. 5.2: ``alpha_p = 2 alpha_b^-2 - 2``, i.e. ``alpha = sqrt(2 / (gamma
+ 2))``), the relation :mod:`rjfit.effects.masking` uses, so the two lobes have the same
width at the peak and differ in their tails and at grazing angles; the effect adds one
parameter, the weight w in [0, 1] (w = 0: the plain model; w = 1: a GGX lobe whose roughness
the region's gamma sets). The GGX part carries its own Smith-GGX shadowing and
``1 / (4 cos cos)``; lobe factors applied after it (Fresnel, masking) multiply the whole mix,
so this effect runs first in its stage (``order_in_stage``).

- physics: :func:`ggx_lobe` (NumPy), :func:`ggx_scalar` (compiled, the same operations in the
  same order), :func:`ggx_features` (a context's per-observation geometry);
- criticism: :class:`GGX` (the mix on ``spec``);
- fit: :class:`LobeGGX`, a gamma-dependent lobe term (the compiled passes of
  :mod:`rjfit.sampler.passes.lobe` evaluate it with :func:`ggx_scalar`);
- Mitsuba: the plugin variant ``rjfit_blinn_ext`` with ``ggx_w`` (:mod:`rjfit.render.ext_plugin`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from rjfit.effects.base import Columns, Effect, FitForm, Param, take
from rjfit.effects.masking import beckmann_alpha, tangent
from rjfit.model.blinn import blinn_normalisation
from rjfit.model.priors import LogitNormal
from rjfit.render.scene_change import MitsubaChange

__all__ = ["GGX", "LobeGGX", "ggx_lobe", "ggx_scalar", "ggx_features", "ggx_over_norm", "LOG_COS_H_ZERO"]

#: log <h.n> at and below which the half vector counts as below the surface (the fit stores
#: log max(<h.n>, 1e-300), so a GGX D, which is alpha^2 / pi at <h.n> = 0, must be cut there)
LOG_COS_H_ZERO = math.log(1e-299)


def ggx_lobe(cos2_h, tan_v, tan_l, alpha):
    """``D G1(v) G1(l) / (4 <v.n> <l.n>)`` of the GGX distribution (module docstring), 0 where ``cos2_h`` is 0.

    ``cos2_h`` is <h.n>^2 (0 where <h.n> <= 0), ``tan_v``, ``tan_l`` the tangents of the view and light
    angles (:func:`rjfit.effects.masking.tangent`; ``1 / cos = sqrt(1 + tan^2)``).
    """
    a2 = np.asarray(alpha, dtype=float) ** 2
    denom = 1.0 + cos2_h * (a2 - 1.0)
    d = a2 / (math.pi * denom * denom)
    g_v = 2.0 / (1.0 + np.sqrt(1.0 + a2 * (tan_v * tan_v)))
    g_l = 2.0 / (1.0 + np.sqrt(1.0 + a2 * (tan_l * tan_l)))
    inverse_cos = np.sqrt(1.0 + tan_v * tan_v) * np.sqrt(1.0 + tan_l * tan_l)
    return np.where(cos2_h > 0.0, 0.25 * d * g_v * g_l * inverse_cos, 0.0)


@njit(inline="always")
def ggx_scalar(cos2_h, tan_v, tan_l, alpha):
    """:func:`ggx_lobe` of one observation, compiled: the same operations in the same order."""
    if cos2_h <= 0.0:
        return 0.0
    a2 = alpha * alpha
    denom = 1.0 + cos2_h * (a2 - 1.0)
    d = a2 / (math.pi * denom * denom)
    g_v = 2.0 / (1.0 + math.sqrt(1.0 + a2 * (tan_v * tan_v)))
    g_l = 2.0 / (1.0 + math.sqrt(1.0 + a2 * (tan_l * tan_l)))
    inverse_cos = math.sqrt(1.0 + tan_v * tan_v) * math.sqrt(1.0 + tan_l * tan_l)
    return 0.25 * d * g_v * g_l * inverse_cos


def ggx_features(ctx):
    """A context's GGX geometry: (<h.n>^2, 0 where <h.n> <= 0; tan view; tan light)."""
    cos_hn = np.asarray(ctx.cos_hn, dtype=float)
    return np.where(cos_hn > 0.0, cos_hn * cos_hn, 0.0), tangent(ctx.cos_vn), tangent(ctx.cos_ln)


class GGX(Effect):
    name = "ggx"
    kind = "lobe shape"
    stage = "lobe"
    order_in_stage = -1       # the lobe's distribution: the stage's factors multiply the mix
    description = ("a GGX microfacet lobe (Smith-GGX shadowing, roughness from the region's gamma) mixed into "
                   "the Blinn-Phong lobe with weight w")

    def params(self, ctx):
        # as masking's weight: centred on an even mix, broad on the logit scale; w = 1 (all GGX) is physical
        return [Param("w_ggx", LogitNormal(loc=0.0, scale=2.0), init=0.5, null=0.0, physical_ends=(1.0,))]

    def prepare(self, ctx):
        return ggx_features(ctx)

    def apply(self, terms, theta, features, ctx):
        cos2_h, tan_v, tan_l = features
        gamma_region = terms["gamma_region"]
        ggx = ggx_lobe(cos2_h, tan_v, tan_l, beckmann_alpha(gamma_region)[ctx.region])
        w = theta[0]
        terms["spec"] = (1.0 - w) * terms["spec"] + w * ggx

    def mitsuba_change(self, theta, ctx=None):
        return MitsubaChange(bsdf_params={"ggx_w": float(theta[0])})

    def fit_form(self, ctx):
        """A gamma-dependent lobe term (:class:`LobeGGX`)."""
        _, tan_v, tan_l = self.prepare(ctx)
        return LobeGGX(params=self.fit_params(ctx), tan_v=tan_v, tan_l=tan_l)


@dataclass(frozen=True, eq=False)
class LobeGGX(FitForm):
    """The GGX mix in the fit: the weight w and the tangents; the lobe column's compiled passes
    (:mod:`rjfit.sampler.passes.lobe`) make ``CB ((1 - w) <h.n>^g + w f_GGX(alpha(g)) / N(g))``
    per gamma, with <h.n>^2 from the problem's log <h.n>."""

    params: tuple
    tan_v: np.ndarray
    tan_l: np.ndarray
    name: str = "ggx"
    stage: str = "lobe"
    order_in_stage = -1

    def apply(self, columns: Columns, theta) -> None:
        columns.ggx_w = float(theta[0])
        columns.tan = (self.tan_v, self.tan_l)

    def in_order(self, order):
        return take(self, order, "tan_v", "tan_l")


def ggx_over_norm(cos2_h, tan_v, tan_l, gamma):
    """``f_GGX(alpha(g)) / N(g)``: the GGX part of the fit's lobe column per unit ``CB`` (NumPy; the passes' twin)."""
    return ggx_lobe(cos2_h, tan_v, tan_l, beckmann_alpha(gamma)) / blinn_normalisation(gamma)
