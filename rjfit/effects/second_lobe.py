"""A second specular lobe of another family: a GGX microfacet lobe of global weight and roughness.

    direct += I0 E <l.n> v f_GGX(alpha2),   i.e.   f = I0 (kd/pi + (1 - kd) spec + v f_GGX(alpha2))

``f_GGX`` is :mod:`rjfit.effects.ggx`'s microfacet BRDF (GGX D, Smith-GGX shadowing,
``1 / (4 cos cos)``, Fresnel 1), Mitsuba's ``roughconductor`` (material "none", "ggx"). The
weight ``v`` is relative to the material's albedo ``I0``, not to its specular part ``I0 (1 -
kd)``: a layer or a blend of two BSDFs (Mitsuba's ``blendbsdf`` of a base and a
``roughconductor`` at weight t is exactly this model with ``I0' = (1 - t) I0`` and ``v = t /
(1 - t)``) reflects its lobe whatever the base's diffuse share, so one global ``v`` serves
regions of different kd. v = 0 is the plain model.

Priors: ``v ~ LogNormal(log 0.25, 1.5)`` (95 % between 0.013 and 4.7: from a trace of a
second lobe to one several times the first's albedo; the null v = 0 is approached as a
limit, as ambient light's); ``alpha2`` logit-normal on (0.02, 1) centred on 0.2 with scale
1.5 (GGX roughnesses of real glossy surfaces, from polished, ~0.02, to matte, 1; 0.2 a
typical coating's). Where v is near 0 the data say nothing of alpha2 and its prior holds.

How it enters the fit: the mean is linear in the region's amplitudes ``a = I0 kd`` and ``b =
I0 (1 - kd) N(g)`` given gamma, since ``I0 = a + b / N(g)``: the diffuse column gains ``C v
f_GGX`` (``C *= 1 + pi v f_GGX``, as ambient light's ``C += pi a``) and the lobe column ``C v
f_GGX / N(g)`` (:mod:`rjfit.sampler.passes.lobe`). It is direct light: cast shadows and light
gains scale it (:meth:`rjfit.effects.base.Columns.scale`); it runs first in the direct stage
(``order_in_stage``), before the factors on direct light.

- physics: :func:`rjfit.effects.ggx.ggx_lobe`;
- criticism: :class:`SecondLobe` (the term added to ``direct``);
- fit: :class:`SecondLobeTerm`;
- Mitsuba: the plugin variant ``rjfit_blinn_ext`` with ``lobe2_v`` and ``lobe2_alpha``
  (:mod:`rjfit.render.ext_plugin`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rjfit.effects.base import Columns, Effect, FitForm, Param, take
from rjfit.effects.ggx import ggx_features, ggx_lobe
from rjfit.model.priors import LogitNormal, LogNormal
from rjfit.render.scene_change import MitsubaChange

__all__ = ["SecondLobe", "SecondLobeTerm", "ALPHA2_MIN"]

#: the smallest second-lobe roughness: below it a GGX lobe is a mirror the pixels cannot resolve
ALPHA2_MIN = 0.02


def _alpha2_prior():
    return LogitNormal.centred_on(0.2, scale=1.5, low=ALPHA2_MIN, high=1.0)


class SecondLobe(Effect):
    name = "second_lobe"
    kind = "lobe shape"
    stage = "direct"
    order_in_stage = -1       # direct light added before the factors on direct light (cast shadows)
    description = "a second specular lobe, GGX of global weight v (relative to the albedo) and roughness alpha2"

    def params(self, ctx):
        return [Param("v", LogNormal(loc=float(np.log(0.25)), scale=1.5), init=0.25, null=0.0),
                Param("alpha2", _alpha2_prior(), init=0.2)]

    def prepare(self, ctx):
        irradiance_cos = np.asarray(ctx.irradiance, dtype=float) * np.maximum(ctx.cos_ln, 0.0)
        return ggx_features(ctx) + (irradiance_cos,)

    def apply(self, terms, theta, features, ctx):
        cos2_h, tan_v, tan_l, irradiance_cos = features
        v, alpha2 = theta[0], theta[1]
        terms["direct"] = terms["direct"] + terms["I0"] * irradiance_cos * (v * ggx_lobe(cos2_h, tan_v, tan_l, alpha2))

    def mitsuba_change(self, theta, ctx=None):
        return MitsubaChange(bsdf_params={"lobe2_v": float(theta[0]), "lobe2_alpha": float(theta[1])})

    def fit_form(self, ctx):
        """A term on both columns (:class:`SecondLobeTerm`)."""
        cos2_h, tan_v, tan_l = ggx_features(ctx)
        return SecondLobeTerm(params=self.fit_params(ctx), cos2_h=cos2_h, tan_v=tan_v, tan_l=tan_l)


@dataclass(frozen=True, eq=False)
class SecondLobeTerm(FitForm):
    """The second lobe in the fit: ``C *= 1 + pi v f_GGX`` (the diffuse column gains ``C v f_GGX``) and the
    lobe column's term ``C v f_GGX`` (before the factor, divided by N(g) in the passes)."""

    params: tuple
    cos2_h: np.ndarray
    tan_v: np.ndarray
    tan_l: np.ndarray
    name: str = "second_lobe"
    stage: str = "direct"
    order_in_stage = -1

    def apply(self, columns: Columns, theta) -> None:
        lobe = theta[0] * ggx_lobe(self.cos2_h, self.tan_v, self.tan_l, theta[1])
        term = columns.C * lobe
        columns.second_lobe = term if columns.second_lobe is None else columns.second_lobe + term
        columns.C = columns.C + math.pi * term        # CB, the first lobe's, is left as it is

    def in_order(self, order):
        return take(self, order, "cos2_h", "tan_v", "tan_l")
