"""Shadowing / masking of the specular lobe: Smith's G for a Beckmann surface.

    spec *= (1 - w) + w G1(v) G1(l),   alpha = sqrt(2 / (gamma + 2))

``alpha`` is the Beckmann roughness whose lobe matches Blinn-Phong of exponent gamma (Walter
et al. 2007), so the roughness comes from the region's own gamma and the effect adds one
parameter, the weight w in [0, 1] (w = 0: the plain model). G1 is Walter's rational fit to
the Beckmann Smith term.

- physics: :func:`tangent`, :func:`smith_g1_tan` (NumPy), :func:`g1_tan` (compiled, the same
  operations in the same order: the same bits), :func:`smith_g1`, :func:`beckmann_alpha`,
  :func:`shadowing_masking` (both tangents at once, compiled);
- criticism: :class:`Masking` (the factor on ``spec``);
- fit: :class:`LobeMasking`, a gamma-dependent lobe term (the compiled passes of
  :mod:`rjfit.sampler.passes.lobe` evaluate it with :func:`g1_tan`);
- Mitsuba: the plugin variant ``rjfit_blinn_ext`` with ``mask_w`` (:mod:`rjfit.render.ext_plugin`,
  which writes G1 in Dr.Jit).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from rjfit.effects.base import Columns, Effect, FitForm, Param, take
from rjfit.model.priors import LogitNormal
from rjfit.render.scene_change import MitsubaChange

__all__ = ["Masking", "LobeMasking", "shadowing_masking", "tangent", "smith_g1", "smith_g1_tan", "g1_tan",
           "beckmann_alpha"]


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


@njit(inline="always")
def g1_tan(tan_theta, alpha):
    """:func:`smith_g1_tan` of one value, compiled: the same operations, in the same order (the same bits)."""
    a = 1.0 / max(alpha * tan_theta, 1e-12)
    if a >= 1.6:
        return 1.0
    return (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a)


def beckmann_alpha(gamma):
    """The Beckmann roughness whose lobe matches Blinn-Phong of exponent gamma (Walter et al. 2007)."""
    return np.sqrt(2.0 / (np.asarray(gamma, dtype=float) + 2.0))


@njit(cache=True, nogil=True)
def shadowing_masking(tan_v, tan_l, alpha_region, region):
    """``G1(v) G1(l)`` per observation with the roughness of its region, in one compiled pass.

    Equal to ``smith_g1_tan(tan_v, alpha) * smith_g1_tan(tan_l, alpha)`` with ``alpha =
    alpha_region[region]`` to the last bit; NumPy's form made five temporaries of N floats
    per call, which took a third of a refit's time on the measured ball (14 ms per G1 over
    1.4 million observations, two per evaluation). Releases the GIL, so candidate refits on
    threads run it side by side.
    """
    out = np.empty(tan_v.size)
    for i in range(tan_v.size):
        alpha = alpha_region[region[i]]
        out[i] = g1_tan(tan_v[i], alpha) * g1_tan(tan_l[i], alpha)
    return out


class Masking(Effect):
    name = "masking"
    kind = "shadowing / masking"
    stage = "lobe"
    description = "Smith-Beckmann shadowing/masking G on the specular lobe, mixed with weight w"

    def params(self, ctx):
        return [Param("w_mask", LogitNormal(loc=0.0, scale=2.0), init=0.5, null=0.0, physical_ends=(1.0,))]

    def prepare(self, ctx):
        # the geometry's tangents: fixed, while alpha changes with every gamma a refit tries
        return tangent(ctx.cos_vn), tangent(ctx.cos_ln)

    def apply(self, terms, theta, features, ctx):
        tan_v, tan_l = features
        g = shadowing_masking(tan_v, tan_l, beckmann_alpha(terms["gamma_region"]), ctx.region)
        w = theta[0]
        terms["spec"] = terms["spec"] * ((1.0 - w) + w * g)

    def mitsuba_change(self, theta, ctx=None):
        return MitsubaChange(bsdf_params={"mask_w": float(theta[0])})

    def fit_form(self, ctx):
        """A gamma-dependent lobe factor (:class:`LobeMasking`)."""
        tan_v, tan_l = self.prepare(ctx)
        return LobeMasking(params=self.fit_params(ctx), tan_v=tan_v, tan_l=tan_l)


@dataclass(frozen=True, eq=False)
class LobeMasking(FitForm):
    """Masking in the fit: the weight w and the tangents, which the lobe column's compiled
    passes (:mod:`rjfit.sampler.passes.lobe`) turn into ``(1 - w) + w G1(v) G1(l)`` per gamma."""

    params: tuple
    tan_v: np.ndarray
    tan_l: np.ndarray
    name: str = "masking"
    stage: str = "lobe"

    def apply(self, columns: Columns, theta) -> None:
        columns.mask_w = float(theta[0])
        columns.tan = (self.tan_v, self.tan_l)

    def in_order(self, order):
        return take(self, order, "tan_v", "tan_l")
