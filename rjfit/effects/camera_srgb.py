"""A nonlinear camera response, sRGB: the stored values are sRGB-encoded radiance.

    y = W sRGB(mu / W)

with the IEC 61966-2-1 curve and a free white level W (relative to the largest valid value);
as W grows the curve tends to its linear toe, so the plain model is the limit W -> infinity
(I0 absorbs the toe's slope 12.92). Applied last (the camera stage). Of the kind "camera
response", with :mod:`rjfit.effects.camera_gamma`; a fit takes one response.

- physics: :func:`srgb_encode`, its inverse :func:`srgb_decode` with the inverse's log slope
  (:func:`srgb_decode_log_slope`), :func:`srgb_curve` and its inverse :func:`srgb_inverse`
  (both forms use them);
- criticism: :class:`CameraSRGB` (the curve on the mean; the likelihood on the linear scale
  with the inverse's slope: the noise is added before the curve, :class:`CameraResponse`);
- fit: :class:`SRGBCurve`, a data transform: ``y -> W sRGB^-1(y / W)`` with the log of the
  inverse's slope;
- Mitsuba: the same curve as a post-process of the path-traced images.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rjfit.effects.base import CameraResponse, Columns, FitForm, Param
from rjfit.model.priors import LogNormal

__all__ = ["CameraSRGB", "SRGBCurve", "srgb_encode", "srgb_decode", "srgb_decode_log_slope", "srgb_curve",
           "srgb_inverse", "SRGB_KNEE"]

#: the encoded value below which the sRGB curve is its linear toe (12.92 x 0.0031308)
SRGB_KNEE = 12.92 * 0.0031308


def srgb_encode(x):
    """IEC 61966-2-1 sRGB encoding, extended linearly below 0 (as colour-science does)."""
    x = np.asarray(x, dtype=float)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(np.maximum(x, 0.0031308), 1.0 / 2.4) - 0.055)


def srgb_decode(v):
    """The inverse of :func:`srgb_encode` (linear below the knee, so for every real ``v``)."""
    v = np.asarray(v, dtype=float)
    return np.where(v <= SRGB_KNEE, v / 12.92, np.power((np.maximum(v, SRGB_KNEE) + 0.055) / 1.055, 2.4))


def srgb_decode_log_slope(v):
    """``log d srgb_decode / dv`` at ``v``."""
    v = np.asarray(v, dtype=float)
    upper = np.log(2.4 / 1.055) + 1.4 * np.log((np.maximum(v, SRGB_KNEE) + 0.055) / 1.055)
    return np.where(v <= SRGB_KNEE, -np.log(12.92), upper)


def srgb_curve(mu, white):
    """``W sRGB(mu / W)``: linear radiance ``mu`` as a camera of white level ``white`` stores it."""
    return white * srgb_encode(mu / white)


def srgb_inverse(y, white):
    """``W sRGB^-1(y / W)``: stored values ``y`` on the linear scale (the inverse of :func:`srgb_curve`;
    its log slope is :func:`srgb_decode_log_slope` of ``y / W``: the white level cancels)."""
    return white * srgb_decode(np.asarray(y, dtype=float) / white)


class CameraSRGB(CameraResponse):
    name = "camera_srgb"
    description = "sRGB-encoded values y = W sRGB(mu/W) with a free white level W"

    def params(self, ctx):
        return [Param("white_rel", LogNormal(loc=0.0, scale=1.0), init=1.0, null=float("inf"))]

    def curve(self, mu, theta, white_level):
        return srgb_curve(mu, theta[0] * white_level)

    def inverse(self, values, theta, white_level):
        return srgb_inverse(values, theta[0] * white_level)

    def inverse_log_slope(self, values, theta, white_level):
        return srgb_decode_log_slope(np.asarray(values, dtype=float) / (theta[0] * white_level))

    def fit_form(self, ctx):
        """The data linearised by the curve's inverse, with its log-Jacobian (:class:`SRGBCurve`)."""
        return SRGBCurve(params=self.fit_params(ctx), white_level=ctx.white_level)


@dataclass(frozen=True, eq=False)
class SRGBCurve(FitForm):
    """The sRGB response in the fit: ``y = W sRGB(mu / W)``, ``W = white_rel x white_level``,
    inverted on the data with its log-Jacobian."""

    params: tuple
    white_level: float
    name: str = "camera_srgb"
    stage: str = "camera"

    def apply(self, columns: Columns, theta) -> None:
        white = self.white_level * float(theta[0])
        columns.log_jacobian += float(np.sum(srgb_decode_log_slope(columns.y / white)))
        columns.y = srgb_inverse(columns.y, white)
        columns.curve = lambda mu: srgb_curve(mu, white)
