"""Fresnel reflection at grazing angles: Schlick's F(<h.v>; F0) on the specular lobe.

    spec *= F(<h.v>) / F0 = 1 + (1/F0 - 1) (1 - <h.v>)^5,   F(c) = F0 + (1 - F0) (1 - c)^5

Dividing by F0 keeps the lobe's normal-incidence albedo (which I0 (1 - kd) already carries):
F0 = 1 is the plain model; a small F0 (0.04 for glass-like coatings) brightens the lobe where
light and view directions are far apart (<h.v> small: back lighting). F0 is kept above
``F0_MIN`` = 0.01, below every real dielectric's.

- physics: :func:`fresnel_term`, :func:`schlick_factor` (both forms use it);
- criticism: :class:`Fresnel` (the factor on ``spec``);
- fit: :class:`LobeFactor`, a factor on the lobe's own C only (``CB``);
- Mitsuba: the plugin variant ``rjfit_blinn_ext`` with parameter ``f0`` (the same factor in the
  BSDF, :mod:`rjfit.render.ext_plugin`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rjfit.effects.base import Columns, Effect, FitForm, Param, take
from rjfit.model.priors import LogitNormal
from rjfit.render.scene_change import MitsubaChange

__all__ = ["Fresnel", "LobeFactor", "fresnel_term", "schlick_factor", "F0_MIN"]

# The smallest normal-incidence reflectance of a real dielectric is about 0.02 (water, n = 1.33;
# ((n - 1) / (n + 1))^2); 0.01 (n = 1.22) stays below every coating, paint binder and glass.
F0_MIN = 0.01


def fresnel_term(cos_hv):
    """``(1 - <h.v>)^5``, the per-observation feature of Schlick's approximation."""
    return (1.0 - cos_hv) ** 5


def schlick_factor(term, f0):
    """``F(<h.v>) / F0 = 1 + (1/F0 - 1) term`` from :func:`fresnel_term`'s ``term``."""
    return 1.0 + (1.0 / f0 - 1.0) * term


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
        return [Param("F0", LogitNormal.centred_on(0.2, scale=2.0, low=F0_MIN, high=1.0), init=0.5, null=1.0)]

    def prepare(self, ctx):
        return fresnel_term(ctx.cos_hv)

    def apply(self, terms, theta, features, ctx):
        terms["spec"] = terms["spec"] * schlick_factor(features, theta[0])

    def mitsuba_change(self, theta, ctx=None):
        return MitsubaChange(bsdf_params={"f0": float(theta[0])})

    def fit_form(self, ctx):
        """A factor on the lobe's C only (:class:`LobeFactor`)."""
        return LobeFactor(params=self.fit_params(ctx), fresnel_term=self.prepare(ctx))


@dataclass(frozen=True, eq=False)
class LobeFactor(FitForm):
    """Fresnel (Schlick) in the fit: the lobe's C times :func:`schlick_factor` of ``fresnel_term``."""

    params: tuple
    fresnel_term: np.ndarray
    name: str = "fresnel"
    stage: str = "lobe"

    def apply(self, columns: Columns, theta) -> None:
        columns.CB = columns.CB * schlick_factor(self.fresnel_term, theta[0])

    def in_order(self, order):
        return take(self, order, "fresnel_term")
