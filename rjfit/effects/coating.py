"""A dielectric coating over the material: a smooth interface of index eta on top of the diffuse base.

    diffuse *= (1 - w) + w T(<l.n>, <v.n>),   T = (1 - F(<l.n>)) (1 - F(<v.n>)) / (1 - R(eta))
    spec    *= (1 - w) + w F(<h.v>) / F(1)

``F(c) = F(c; eta)`` is the exact unpolarised Fresnel reflectance of a dielectric of relative
index eta (light from outside), ``F(1) = ((eta - 1) / (eta + 1))^2`` its value at normal
incidence, and ``R(eta) = 2 int_0^1 F(mu) mu dmu`` its hemispherical (diffuse) reflectance from
outside. The diffuse part is the light the interface transmits to the base and back out,
divided by the interface's internal reflection: a base of albedo kd under the coating,
whose light bounces between the base and the interface's underside (internal reflectance
``R_int`` for light from inside), reflects ``kd / (1 - R_int)`` (to first order in kd, Mitsuba's
``nonlinear = false``) spread over the eta^2 larger solid angle inside, ``kd (1 - F(i)) (1 -
F(o)) / (pi eta^2 (1 - R_int))``: Mitsuba's ``plastic`` term for term. Since light crossing
the interface either way has the same reflectance, ``1 - R_int = (1 - R(eta)) / eta^2``
(light inside beyond the critical angle reflects totally), which gives ``T``; the
coated base's directional albedo is then ``kd (1 - F(<l.n>))``. The lobe is the interface's
own reflection: its Fresnel factor divided by F(1), as :mod:`rjfit.effects.fresnel` divides
Schlick's, so the lobe keeps its normal-incidence albedo. One eta sets both.

The weight w mixes the coated and uncoated BSDFs (a coating over a share w of the surface;
w = 1 the coated material): w = 0 is the plain model. eta has a physical range: the
coatings, binders, varnishes and glasses of real objects, 1.2 to 2.0 (water 1.33, lacquer
and glass 1.45-1.55, dense glass 1.8), LogitNormal on (1.2, 2.0) centred on 1.5.

Relation to Mitsuba's ``roughplastic`` (GGX or Beckmann, ``nonlinear = false``): the lobe
``specular_reflectance F(<h.v>) D G / (4 cos cos)`` is this coating's over a GGX lobe
(:mod:`rjfit.effects.ggx` at w = 1), exactly; roughplastic's diffuse part uses the ROUGH
interface's transmittance, a table over the incidence cosine computed from the microfacet
distribution of the region's roughness, and its internal reflectance, where this coating
uses the smooth interface's (Mitsuba's ``plastic``). The rough transmittance depends on the
region's roughness, so on gamma, which would make the diffuse column gamma-dependent; the
smooth one keeps it fixed. At eta 1.5 and the roughnesses 0.41 to 0.82 of the rendered stacks the
two differ by a factor per region (0.43 to 0.60 for GGX, 0.57 to 0.78 for Beckmann; the region's
kd absorbs it) and in shape: the rough interface transmits relatively less at 45 to 70 degrees and
more beyond 80 (docs/results/2026-11-28-coating.md).

How it enters the fit: a factor on direct light's diffuse part and on its lobe, both fixed
per observation given (w, eta), so the mean stays linear in (a, b) given gamma: ``C -> (C -
pi second) ((1 - w) + w T) + pi second`` (a second lobe's share of C, added just before in
the stage, is not under the coating) and ``CB *= (1 - w) + w F(<h.v>) / F(1)``. It runs in the
direct stage after the second lobe and before the factors on all direct light (cast
shadows, which commute with it).

- physics: :func:`dielectric_fresnel`, :func:`diffuse_fresnel_reflectance`,
  :func:`coating_factors`;
- criticism: :class:`Coating` (its change to ``direct``);
- fit: :class:`CoatingFactors`;
- Mitsuba: the plugin variant ``rjfit_blinn_ext`` with ``coat_w`` and ``coat_eta``
  (:mod:`rjfit.render.ext_plugin`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rjfit.effects.base import Columns, Effect, FitForm, Param, take
from rjfit.model.priors import LogitNormal
from rjfit.render.scene_change import MitsubaChange

__all__ = ["Coating", "CoatingFactors", "dielectric_fresnel", "diffuse_fresnel_reflectance", "coating_factors",
           "coating_lobe_factor", "ETA_MIN", "ETA_MAX"]

#: the coating's index of refraction: from below water's (1.33) to dense glass (1.8) and beyond
ETA_MIN, ETA_MAX = 1.2, 2.0
_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(64)


def dielectric_fresnel(cos_i, eta):
    """The unpolarised Fresnel reflectance of light from outside at incidence cosine ``cos_i`` (clipped to
    [0, 1]) on a dielectric of relative index ``eta`` > 1: the mean of the s and p reflectances."""
    c = np.clip(np.asarray(cos_i, dtype=float), 0.0, 1.0)
    cos_t = np.sqrt(1.0 - (1.0 - c * c) / (eta * eta))
    r_s = (c - eta * cos_t) / (c + eta * cos_t)
    r_p = (eta * c - cos_t) / (eta * c + cos_t)
    return 0.5 * (r_s * r_s + r_p * r_p)


def diffuse_fresnel_reflectance(eta):
    """``R(eta) = 2 int_0^1 F(mu) mu dmu``: the reflectance from outside under uniform light (Gauss-Legendre,
    64 nodes; the integrand is smooth on [0, 1], so the rule is exact to rounding)."""
    mu = 0.5 * (_NODES + 1.0)
    return float(np.sum(_WEIGHTS * dielectric_fresnel(mu, eta) * mu))


def coating_lobe_factor(cos_hv, w, eta):
    """The factor on the lobe per observation, ``(1 - w) + w F(<h.v>) / F(1)`` (module docstring)."""
    f_normal = ((eta - 1.0) / (eta + 1.0)) ** 2
    return (1.0 - w) + w * (dielectric_fresnel(cos_hv, eta) / f_normal)


def coating_factors(cos_l, cos_v, cos_hv, w, eta):
    """The factors on the diffuse part and on the lobe per observation (module docstring): weight w, index eta."""
    transmitted = (1.0 - dielectric_fresnel(cos_l, eta)) * (1.0 - dielectric_fresnel(cos_v, eta))
    diffuse = (1.0 - w) + w * (transmitted / (1.0 - diffuse_fresnel_reflectance(eta)))
    return diffuse, coating_lobe_factor(cos_hv, w, eta)


def _eta_prior():
    return LogitNormal.centred_on(1.5, scale=1.5, low=ETA_MIN, high=ETA_MAX)


class Coating(Effect):
    name = "coating"
    # the kind of `fresnel`: both put the interface's Fresnel reflection on the lobe, so a model holds one of the
    # two (both would apply it twice); the search tries no candidate of a kind present, and a revisit swaps one
    # for the other on the Laplace evidence (rjfit.diagnose.revisit)
    kind = "Fresnel reflection"
    stage = "direct"
    order_in_stage = -0.5     # after a second lobe (not under the coating), before the factors on all direct light
    description = ("a dielectric coating of index eta (share w): exact Fresnel F(h.v)/F(1) on the lobe, the "
                   "interface's transmission in and out on the diffuse part (roughplastic's physics)")

    def params(self, ctx):
        return [Param("w_coat", LogitNormal(loc=0.0, scale=2.0), init=0.5, null=0.0, physical_ends=(1.0,)),
                Param("eta", _eta_prior(), init=1.5)]

    def prepare(self, ctx):
        irradiance_cos = np.asarray(ctx.irradiance, dtype=float) * np.maximum(ctx.cos_ln, 0.0)
        return ctx.cos_ln, ctx.cos_vn, ctx.cos_hv, irradiance_cos

    def factors(self, theta, features):
        """The factors on the diffuse part and on the lobe of the observations (``features``: :meth:`prepare`'s)."""
        cos_l, cos_v, cos_hv = features[:3]
        return coating_factors(cos_l, cos_v, cos_hv, theta[0], theta[1])

    def apply(self, terms, theta, features, ctx):
        diffuse, lobe = self.factors(theta, features)
        irradiance_cos = features[3]
        kd = terms["kd"]
        change = kd / np.pi * (diffuse - 1.0) + (1.0 - kd) * terms["spec"] * (lobe - 1.0)
        terms["direct"] = terms["direct"] + terms["I0"] * irradiance_cos * change

    def mitsuba_change(self, theta, ctx=None):
        return MitsubaChange(bsdf_params={"coat_w": float(theta[0]), "coat_eta": float(theta[1])})

    def fit_form(self, ctx):
        """Factors on the diffuse column and the lobe (:class:`CoatingFactors`)."""
        return CoatingFactors(params=self.fit_params(ctx), cos_l=np.asarray(ctx.cos_ln, dtype=float),
                              cos_v=np.asarray(ctx.cos_vn, dtype=float), cos_hv=np.asarray(ctx.cos_hv, dtype=float))


@dataclass(frozen=True, eq=False)
class CoatingFactors(FitForm):
    """The coating in the fit: ``C -> (C - pi second) D + pi second`` and ``CB *= L`` with (D, L) of
    :func:`coating_factors` (``second``: a second lobe's term, which C holds as ``pi second``)."""

    params: tuple
    cos_l: np.ndarray
    cos_v: np.ndarray
    cos_hv: np.ndarray
    name: str = "coating"
    stage: str = "direct"
    order_in_stage = -0.5

    def factors(self, theta):
        """The factors on the diffuse column and on the lobe column of the observations."""
        return coating_factors(self.cos_l, self.cos_v, self.cos_hv, theta[0], theta[1])

    def apply(self, columns: Columns, theta) -> None:
        diffuse, lobe = self.factors(theta)
        if columns.second_lobe is None:
            columns.C = columns.C * diffuse
        else:
            added = math.pi * columns.second_lobe
            columns.C = (columns.C - added) * diffuse + added
        columns.CB = columns.CB * lobe

    def in_order(self, order):
        return take(self, order, "cos_l", "cos_v", "cos_hv")
