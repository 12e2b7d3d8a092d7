"""The effects a fit samples with the regions (issue 26): how each one enters the forward model.

Each class is an :class:`rjfit.sampler.forward.Effect` (parameters -> transformed columns),
built by the criticism's effect library (:mod:`rjfit.diagnose.effects`, whose
``sampler_effect`` supplies the priors, the starting values and the per-observation features)
so that the fit and the criticism share one statement of every effect's physics
(:mod:`rjfit.model.effects`) and priors. How each enters (the stages of
:data:`rjfit.model.effects.STAGES`, in that order):

=================  ========  ====================================================================
effect             stage     enters as
=================  ========  ====================================================================
fresnel            lobe      a factor on the lobe's C only: ``CB *= 1 + (1/F0 - 1)(1 - <h.v>)^5``
masking            lobe      a gamma-dependent factor on the lobe: ``(1 - w) + w G1(v) G1(l)``
cast_shadows       direct    a factor on C (and CB): ``1 - w (1 - V)``, V Mitsuba's shadow rays
interreflection    indirect  a known offset: ``y -> y - beta F`` (F Mitsuba's indirect light)
light_calibration  light     per-light gains on C, CB and the offset: ``exp(H h)[light]``
ambient            ambient   ``A += a`` (C += pi a) and a lobe term ``a alb(gamma, v) / N(gamma)``
camera_gamma       camera    ``y -> W (y / W)^k`` with log-Jacobian ``log k + (k - 1) log(y / W)``
camera_srgb        camera    ``y -> W sRGB^-1(y / W)`` with the log of the inverse's slope
=================  ========  ====================================================================

Each class keeps its features in the order of the observations it was built from
(:meth:`~rjfit.sampler.forward.Effect.in_order` sorts them as the problem is).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from rjfit.model.effects import helmert_basis, srgb_decode, srgb_decode_log_slope, srgb_encode
from rjfit.sampler.forward import Columns, Effect

__all__ = ["LobeFactor", "LobeMasking", "DirectFactor", "IndirectLight", "LightGains", "AmbientLight", "CameraCurve"]


def _take(values, order):
    return np.asarray(values)[order]


@dataclass(frozen=True, eq=False)
class LobeFactor(Effect):
    """Fresnel (Schlick): the lobe's C times ``1 + (1/F0 - 1) fresnel_term``, ``fresnel_term = (1 - <h.v>)^5``."""

    params: tuple
    fresnel_term: np.ndarray
    name: str = "fresnel"
    stage: str = "lobe"

    def apply(self, columns: Columns, theta) -> None:
        columns.CB = columns.CB * (1.0 + (1.0 / theta[0] - 1.0) * self.fresnel_term)

    def in_order(self, order):
        return replace(self, fresnel_term=_take(self.fresnel_term, order))


@dataclass(frozen=True, eq=False)
class LobeMasking(Effect):
    """Smith-Beckmann shadowing / masking of the lobe with weight w (:mod:`rjfit.sampler.passes.lobe`)."""

    params: tuple
    tan_v: np.ndarray
    tan_l: np.ndarray
    name: str = "masking"
    stage: str = "lobe"

    def apply(self, columns: Columns, theta) -> None:
        columns.mask_w = float(theta[0])
        columns.tan = (self.tan_v, self.tan_l)

    def in_order(self, order):
        return replace(self, tan_v=_take(self.tan_v, order), tan_l=_take(self.tan_l, order))


@dataclass(frozen=True, eq=False)
class DirectFactor(Effect):
    """Cast shadows: direct light (C and the lobe's C) times ``1 - w (1 - visibility)``."""

    params: tuple
    visibility: np.ndarray
    name: str = "cast_shadows"
    stage: str = "direct"

    def apply(self, columns: Columns, theta) -> None:
        factor = 1.0 - theta[0] * (1.0 - self.visibility)
        columns.C = columns.C * factor
        columns.CB = columns.CB * factor

    def in_order(self, order):
        return replace(self, visibility=_take(self.visibility, order))


@dataclass(frozen=True, eq=False)
class IndirectLight(Effect):
    """Interreflection: a known indirect radiance ``feature`` (a fixed feature per fit) times beta added to the mean."""

    params: tuple
    feature: np.ndarray
    name: str = "interreflection"
    stage: str = "indirect"

    def apply(self, columns: Columns, theta) -> None:
        columns.add_offset(theta[0] * self.feature)

    def in_order(self, order):
        return replace(self, feature=_take(self.feature, order))


@dataclass(frozen=True, eq=False)
class LightGains(Effect):
    """Per-light gains ``exp(H h)`` (H the Helmert basis: their geometric mean is 1) on all light of each image."""

    params: tuple
    n_lights: int
    name: str = "light_calibration"
    stage: str = "light"

    def gains(self, theta) -> np.ndarray:
        return np.exp(helmert_basis(self.n_lights) @ np.asarray(theta, dtype=float))

    def apply(self, columns: Columns, theta) -> None:
        columns.scale(self.gains(theta)[columns.light])


@dataclass(frozen=True, eq=False)
class AmbientLight(Effect):
    """Ambient light of radiance a: ``a I0 (kd + (1 - kd) alb(gamma, v))`` added to the mean.

    ``column`` and ``weight`` place each observation's view angle in the albedo table
    (:func:`rjfit.model.effects.cos_v_weights`); ``table`` and ``grid`` are the table and its
    log-gamma grid (lowest, highest, step).
    """

    params: tuple
    column: np.ndarray
    weight: np.ndarray
    table: np.ndarray
    grid: np.ndarray
    name: str = "ambient"
    stage: str = "ambient"

    def apply(self, columns: Columns, theta) -> None:
        columns.C = columns.C + np.pi * theta[0]
        columns.ambient = float(theta[0])
        columns.ambient_terms = (self.column, self.weight, self.table, self.grid)

    def in_order(self, order):
        return replace(self, column=_take(self.column, order), weight=_take(self.weight, order))


@dataclass(frozen=True, eq=False)
class CameraCurve(Effect):
    """A camera response ``y = f(mu)``, inverted on the data with its log-Jacobian.

    ``curve`` 'gamma': ``f(mu) = W (mu / W)^(1/k)`` with W the white level (fixed);
    'srgb': ``f(mu) = W sRGB(mu / W)``, ``W = white_rel x white_level``.

    Raises
    ------
    ValueError
        On :meth:`apply`, for the power law with values at or below 0 (its inverse has no
        finite slope there).
    """

    params: tuple
    curve_kind: str
    white_level: float
    name: str = "camera_gamma"
    stage: str = "camera"

    def _white(self, theta) -> float:
        return self.white_level * float(theta[0]) if self.curve_kind == "srgb" else self.white_level

    def apply(self, columns: Columns, theta) -> None:
        white = self._white(theta)
        x = columns.y / white
        if self.curve_kind == "srgb":
            columns.y = white * srgb_decode(x)
            columns.log_jacobian += float(np.sum(srgb_decode_log_slope(x)))
            columns.curve = lambda mu: white * srgb_encode(mu / white)
            return
        if np.any(x <= 0):
            raise ValueError(f"camera_gamma: {int(np.count_nonzero(x <= 0))} observations are <= 0, where the power "
                             "law's inverse has no finite slope; leave dark values out (a dark threshold) or use "
                             "camera_srgb")
        k = float(theta[0])
        columns.y = white * np.power(x, k)
        columns.log_jacobian += float(x.size * np.log(k) + (k - 1.0) * np.sum(np.log(x)))
        columns.curve = lambda mu: white * np.power(np.maximum(mu, 0.0) / white, 1.0 / k)
