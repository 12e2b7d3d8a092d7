"""Light intensity miscalibration: one unknown scale per light (image).

    mu_l *= s_l,   log s = H z,   z ~ N(0, 0.2^2 I_{L-1})

H (L x L-1) is an orthonormal basis of the vectors that sum to zero (Helmert), so the
geometric mean of the scales is fixed to 1: an overall scale is not identifiable apart from
the regions' I0. The prior is the iid log-normal N(0, 0.2^2) on log s conditioned on that
constraint (0.2: a 20 % error is one prior standard deviation).

- physics: :func:`helmert_basis`, :func:`light_scales` (both forms use them);
- criticism: :class:`LightCalibration` (each light's mean times its scale);
- fit: :class:`LightGains`, per-light gains on C, the lobe's C and the offset;
- Mitsuba: the emitters' intensities times s_l.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rjfit.effects.base import Columns, Effect, FitForm, Param
from rjfit.model.priors import Normal
from rjfit.render.scene_change import MitsubaChange

__all__ = ["LightCalibration", "LightGains", "helmert_basis", "light_scales", "PRIOR_SCALE"]

PRIOR_SCALE = 0.2


def helmert_basis(n):
    """(n, n-1) orthonormal columns, each orthogonal to the ones vector."""
    basis = np.zeros((n, n - 1))
    for j in range(1, n):
        basis[:j, j - 1] = 1.0
        basis[j, j - 1] = -j
        basis[:, j - 1] /= np.sqrt(j * (j + 1))
    return basis


def light_scales(theta, n_lights):
    """Per-light scales ``exp(H theta)`` (geometric mean 1) from the Helmert coordinates ``theta``."""
    return np.exp(helmert_basis(n_lights) @ np.asarray(theta, dtype=float))


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

    def fit_form(self, ctx):
        """Per-light gains on C (:class:`LightGains`)."""
        return LightGains(params=self.fit_params(ctx), n_lights=ctx.n_lights)


@dataclass(frozen=True, eq=False)
class LightGains(FitForm):
    """Light calibration in the fit: per-light gains :func:`light_scales` (their geometric mean 1) on all light of each image."""

    params: tuple
    n_lights: int
    name: str = "light_calibration"
    stage: str = "light"

    def gains(self, theta) -> np.ndarray:
        return light_scales(theta, self.n_lights)

    def apply(self, columns: Columns, theta) -> None:
        columns.scale(self.gains(theta)[columns.light])
