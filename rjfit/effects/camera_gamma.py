"""A nonlinear camera response, the power law: the stored values are not linear in radiance.

    y = W (mu / W)^(1/k)

W = the largest valid value (fixed: with a pure power law W only rescales I0, so it is not a
free parameter); k = 1 is linear. Applied last (the camera stage). Of the kind "camera
response", with :mod:`rjfit.effects.camera_srgb`; a fit takes one response.

- physics: :func:`gamma_curve`, its inverse :func:`gamma_inverse` and the inverse's log slope
  :func:`gamma_inverse_log_slope` (both forms use them);
- criticism: :class:`CameraGamma` (the curve on the mean; the likelihood on the linear scale
  with the inverse's slope: the noise is added before the curve, :class:`CameraResponse`);
- fit: :class:`GammaCurve`, a data transform: the data linearised by the curve's inverse
  ``y -> W (y / W)^k`` with its log-Jacobian ``log k + (k - 1) log(y / W)``;
- Mitsuba: the same curve as a post-process of the path-traced images.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rjfit.effects.base import CameraResponse, Columns, FitForm, Param
from rjfit.model.priors import LogNormal

__all__ = ["CameraGamma", "GammaCurve", "gamma_curve", "gamma_inverse", "gamma_inverse_log_slope"]


def gamma_curve(mu, k, white):
    """``W (max(mu, 0) / W)^(1/k)``: linear radiance ``mu`` as the power-law camera stores it."""
    return white * np.power(np.maximum(mu, 0.0) / white, 1.0 / k)


def gamma_inverse(y, k, white):
    """``W (max(y, 0) / W)^k``: stored values ``y`` on the linear scale (the inverse of :func:`gamma_curve`)."""
    return white * np.power(np.maximum(y, 0.0) / white, k)


def gamma_inverse_log_slope(y, k, white):
    """``log (f^-1)'(y) = log k + (k - 1) log(y / W)`` of :func:`gamma_inverse`.

    Raises
    ------
    ValueError
        For values at or below 0 (the inverse has no finite log slope there).
    """
    x = np.asarray(y, dtype=float) / white
    if np.any(x <= 0):
        raise ValueError(f"camera_gamma: {int(np.count_nonzero(x <= 0))} observations are <= 0, where the power "
                         "law's inverse has no finite slope; leave dark values out (a dark threshold) or use "
                         "camera_srgb")
    return np.log(k) + (k - 1.0) * np.log(x)


class CameraGamma(CameraResponse):
    name = "camera_gamma"
    description = "power-law response y = W (mu/W)^(1/k) with W the data's white level"

    def params(self, ctx):
        return [Param("k", LogNormal(loc=0.0, scale=1.0), init=1.2, null=1.0)]

    def available(self, ctx):
        """Not on values at or below 0: a power law with the noise before it never stores them (its
        inverse has no finite log slope there: :func:`gamma_inverse_log_slope`)."""
        nonpositive = int(np.count_nonzero(np.asarray(ctx.y) <= 0))
        if nonpositive:
            return False, (f"{nonpositive} observations are <= 0, which a power-law camera (its noise before the "
                           f"curve) never stores; a dark threshold leaves them out")
        return super().available(ctx)

    def curve(self, mu, theta, white):
        return gamma_curve(mu, theta[0], white)

    def inverse(self, values, theta, white):
        return gamma_inverse(values, theta[0], white)

    def inverse_log_slope(self, values, theta, white):
        return gamma_inverse_log_slope(values, theta[0], white)

    def fit_form(self, ctx):
        """The data linearised by the curve's inverse, with its log-Jacobian (:class:`GammaCurve`)."""
        return GammaCurve(params=self.fit_params(ctx), white_level=ctx.white_level)


@dataclass(frozen=True, eq=False)
class GammaCurve(FitForm):
    """The power-law response in the fit: ``y = W (mu / W)^(1/k)`` inverted on the data with its log-Jacobian.

    Raises
    ------
    ValueError
        On :meth:`apply`, for values at or below 0 (the inverse has no finite slope there).
    """

    params: tuple
    white_level: float
    name: str = "camera_gamma"
    stage: str = "camera"

    def apply(self, columns: Columns, theta) -> None:
        white, k = self.white_level, float(theta[0])
        columns.log_jacobian += float(np.sum(gamma_inverse_log_slope(columns.y, k, white)))
        columns.y = gamma_inverse(columns.y, k, white)
        columns.curve = lambda mu: gamma_curve(mu, k, white)
