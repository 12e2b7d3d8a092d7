"""Shadowing / masking of the specular lobe: Smith's G for a Beckmann surface.

    spec *= (1 - w) + w G1(v) G1(l),   alpha = sqrt(2 / (gamma + 2))

``alpha`` is the Beckmann roughness whose lobe matches Blinn-Phong of exponent gamma (Walter
et al. 2007), so the roughness comes from the region's own gamma and the effect adds one
parameter, the weight w in [0, 1] (w = 0: the plain model). G1 is Walter's rational fit to
the Beckmann Smith term. Mitsuba side: plugin variant ``rjfit_blinn_ext`` with ``mask_w``.
"""
from __future__ import annotations

import numpy as np

from rjfit.diagnose.effects.base import Effect, MitsubaChange, Param
from rjfit.diagnose.priors import LogitNormal


def tangent(cos_theta):
    """tan theta from cos theta, cos clipped to [1e-6, 1] (grazing angles stay finite)."""
    cos_theta = np.clip(cos_theta, 1e-6, 1.0)
    return np.sqrt(np.maximum(1.0 - cos_theta ** 2, 0.0)) / cos_theta


def smith_g1(cos_theta, alpha):
    """Walter et al. (2007) rational approximation of Beckmann's Smith G1."""
    return smith_g1_tan(tangent(cos_theta), alpha)


def smith_g1_tan(tan_theta, alpha):
    """:func:`smith_g1` from tan theta (:func:`tangent`), which a refit computes once per observation."""
    a = 1.0 / np.maximum(alpha * tan_theta, 1e-12)
    g = (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a)
    return np.where(a >= 1.6, 1.0, g)


def beckmann_alpha(gamma):
    return np.sqrt(2.0 / (np.asarray(gamma, dtype=float) + 2.0))


class Masking(Effect):
    name = "masking"
    kind = "shadowing / masking"
    stage = "lobe"
    description = "Smith-Beckmann shadowing/masking G on the specular lobe, mixed with weight w"

    def params(self, ctx):
        return [Param("w_mask", LogitNormal(loc=0.0, scale=2.0), init=0.5, null=0.0)]

    def prepare(self, ctx):
        # the geometry's tangents: fixed, while alpha changes with every gamma a refit tries
        return tangent(ctx.cos_vn), tangent(ctx.cos_ln)

    def apply(self, terms, theta, features, ctx):
        alpha = beckmann_alpha(terms["gamma"])
        tan_v, tan_l = features
        g = smith_g1_tan(tan_v, alpha) * smith_g1_tan(tan_l, alpha)
        w = theta[0]
        terms["spec"] = terms["spec"] * ((1.0 - w) + w * g)

    def mitsuba_change(self, theta, ctx=None):
        return MitsubaChange(bsdf_params={"mask_w": float(theta[0])})
