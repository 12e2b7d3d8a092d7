"""A nonlinear camera response: the stored values are not linear in radiance.

Two candidate curves (both of the kind "camera response"), applied last:

``camera_gamma``: y = W (mu / W)^(1/k), W = the largest valid value (fixed: with a pure power
    law W only rescales I0, so it is not a free parameter); k = 1 is linear.
``camera_srgb``:  y = W sRGB(mu / W) with the IEC 61966-2-1 curve and a free white level W
    (relative to the largest valid value); as W grows the curve tends to its linear toe, so the
    plain model is the limit W -> infinity (I0 absorbs the toe's slope 12.92).

Mitsuba side: the same curve as a post-process of the path-traced images.
"""
from __future__ import annotations

import numpy as np

from rjfit.diagnose.effects.base import Effect, Param
from rjfit.model.effects import srgb_encode
from rjfit.model.priors import LogNormal
from rjfit.render.scene_change import MitsubaChange
from rjfit.sampler.effects import CameraCurve

__all__ = ["CameraGamma", "CameraSRGB", "srgb_encode"]


class CameraGamma(Effect):
    name = "camera_gamma"
    kind = "camera response"
    stage = "camera"
    description = "power-law response y = W (mu/W)^(1/k) with W the data's white level"

    def params(self, ctx):
        return [Param("k", LogNormal(loc=0.0, scale=1.0), init=1.2, null=1.0)]

    def prepare(self, ctx):
        return ctx.white_level

    def curve(self, mu, theta, white):
        return white * np.power(np.maximum(mu, 0.0) / white, 1.0 / theta[0])

    def apply(self, terms, theta, features, ctx):
        terms["mu"] = self.curve(terms["mu"], theta, features)

    def mitsuba_change(self, theta, ctx):
        white = ctx.white_level
        return MitsubaChange(post_process=lambda images: self.curve(images, theta, white))

    def sampler_effect(self, ctx):
        """The data linearised by the curve's inverse, with its log-Jacobian (:class:`rjfit.sampler.effects.CameraCurve`)."""
        return CameraCurve(params=self.fit_params(ctx), curve_kind="gamma", white_level=ctx.white_level, name=self.name)


class CameraSRGB(Effect):
    name = "camera_srgb"
    kind = "camera response"
    stage = "camera"
    description = "sRGB-encoded values y = W sRGB(mu/W) with a free white level W"

    def params(self, ctx):
        return [Param("white_rel", LogNormal(loc=0.0, scale=1.0), init=1.0, null=float("inf"))]

    def prepare(self, ctx):
        return ctx.white_level

    def curve(self, mu, theta, white_level):
        white = theta[0] * white_level
        return white * srgb_encode(mu / white)

    def apply(self, terms, theta, features, ctx):
        terms["mu"] = self.curve(terms["mu"], theta, features)

    def mitsuba_change(self, theta, ctx):
        white = ctx.white_level
        return MitsubaChange(post_process=lambda images: self.curve(images, theta, white))

    def sampler_effect(self, ctx):
        """The data linearised by the curve's inverse, with its log-Jacobian (:class:`rjfit.sampler.effects.CameraCurve`)."""
        return CameraCurve(params=self.fit_params(ctx), curve_kind="srgb", white_level=ctx.white_level, name=self.name)
