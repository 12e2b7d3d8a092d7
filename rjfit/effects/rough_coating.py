"""A dielectric coating with a rough interface: Mitsuba's ``roughplastic`` (GGX, ``nonlinear = false``).

    diffuse *= (1 - w) + w T(<l.n>) T(<v.n>) / (eta^2 (1 - R_int))
    spec    *= (1 - w) + w F(<h.v>) / F(1)

:mod:`rjfit.effects.coating` transmits the diffuse part through a SMOOTH interface (``T = 1 - F``);
``roughplastic`` transmits it through the rough one its lobe is the reflection of, and that changes the
diffuse part's shape: at eta 1.5 and GGX roughness 0.41 to 0.82 the rough interface transmits 4 to 19 %
less at 45 to 70 degrees and 17 to 73 % more beyond 80 (docs/results/2026-11-28-coating.md). Here the
interface has its own GGX roughness ``alpha_coat``, one for the model (``roughplastic`` ties it to each
material's lobe; one roughness keeps the diffuse column independent of the regions' gamma, which every
statistic of the sampler assumes).

The interface is ``roughplastic``'s (:mod:`rjfit.model.rough_interface`): ``T`` its transmittance over
the incidence cosine (a table of 64 entries, read linearly) and ``R_int`` its reflectance from inside, both
for a GGX interface of roughness ``alpha_coat``. The table costs about 3 ms (compiled), once per change of
(alpha, eta).

At alpha -> 0 the interface is smooth and ``T -> 1 - F``: the smooth coating, up to Mitsuba's estimate of
``R_int`` (a constant, which the regions' kd absorb). The lobe part is the smooth coating's, and so is
the meaning of w (a share of the surface coated) and eta's prior; ``alpha_coat`` has a logit-normal prior
on (0.02, 1) centred on 0.3, GGX roughnesses from polished to matte.

- physics: :mod:`rjfit.model.rough_interface`, :func:`rough_coating_factors`;
- criticism: :class:`RoughCoating`;
- fit: :class:`RoughCoatingFactors` (the same seams as the smooth coating's);
- Mitsuba: the plugin variant ``rjfit_blinn_ext`` with ``coat_w``, ``coat_eta`` and ``coat_alpha``, whose
  table Mitsuba's own microfacet sampling, Fresnel and Smith terms compute (:mod:`rjfit.render.ext_plugin`);
  it is ``roughplastic``'s diffuse part up to the ratio of the two ``1 - R_int``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rjfit.effects.base import Param
from rjfit.effects.coating import Coating, CoatingFactors, coating_lobe_factor
from rjfit.model.priors import LogitNormal
from rjfit.model.rough_interface import SERIES_ALPHA, table_lookup, transmittance_table
from rjfit.render.scene_change import MitsubaChange

__all__ = ["RoughCoating", "RoughCoatingFactors", "rough_coating_factors", "ALPHA_MIN", "ALPHA_MAX"]

#: the interface's GGX roughness: from polished (0.02) to matte (1), the domain of its internal reflectance's series
ALPHA_MIN, ALPHA_MAX = SERIES_ALPHA


def rough_coating_factors(cos_l, cos_v, cos_hv, w, eta, alpha, table=None):
    """The factors on the diffuse part and on the lobe per observation (module docstring); ``table``, when given, is
    :func:`transmittance_table` of (alpha, eta), so a caller that holds it does not compute it again."""
    transmittance, scale = transmittance_table(alpha, eta) if table is None else table
    transmitted = table_lookup(cos_l, transmittance) * table_lookup(cos_v, transmittance)
    return (1.0 - w) + w * (transmitted / scale), coating_lobe_factor(cos_hv, w, eta)


def _alpha_prior():
    return LogitNormal.centred_on(0.3, scale=1.5, low=ALPHA_MIN, high=ALPHA_MAX)


class _TableMemo:
    """The last (alpha, eta) and its table, held by one context's features or one fit form: a chain's or an
    optimiser's moves change w more often than the two. The pair is replaced whole, so threads sharing it read a
    key with its own table."""

    def __init__(self):
        self._entry = (None, None)

    def get(self, alpha, eta):
        key = (float(alpha), float(eta))
        entry = self._entry
        if entry[0] != key:
            entry = (key, transmittance_table(*key))
            self._entry = entry
        return entry[1]


class RoughCoating(Coating):
    """The smooth coating's seams and lobe factor (:class:`rjfit.effects.coating.Coating`), with the rough
    interface's transmission on the diffuse part."""

    name = "rough_coating"
    description = ("a dielectric coating of index eta with a rough interface (roughness alpha_coat, share w): "
                   "exact Fresnel F(h.v)/F(1) on the lobe, the rough interface's transmission on the diffuse part "
                   "(Mitsuba's roughplastic)")

    def params(self, ctx):
        return super().params(ctx) + [Param("alpha_coat", _alpha_prior(), init=0.3)]

    def prepare(self, ctx):
        return super().prepare(ctx) + (_TableMemo(),)

    def factors(self, theta, features):
        cos_l, cos_v, cos_hv, _, memo = features
        w, eta, alpha = theta
        return rough_coating_factors(cos_l, cos_v, cos_hv, w, eta, alpha, memo.get(alpha, eta))

    def mitsuba_change(self, theta, ctx=None):
        change = super().mitsuba_change(theta, ctx)
        return MitsubaChange(bsdf_params={**change.bsdf_params, "coat_alpha": float(theta[2])})

    def fit_form(self, ctx):
        """Factors on the diffuse column and the lobe (:class:`RoughCoatingFactors`)."""
        return RoughCoatingFactors(params=self.fit_params(ctx), cos_l=np.asarray(ctx.cos_ln, dtype=float),
                                   cos_v=np.asarray(ctx.cos_vn, dtype=float), cos_hv=np.asarray(ctx.cos_hv, dtype=float))


@dataclass(frozen=True, eq=False)
class RoughCoatingFactors(CoatingFactors):
    """The rough coating in the fit: the smooth coating's seams (``C -> (C - pi second) D + pi second``, ``CB *= L``,
    :class:`rjfit.effects.coating.CoatingFactors`) with (D, L) of :func:`rough_coating_factors`."""

    name: str = "rough_coating"

    def __post_init__(self):
        # not a field: what a form is (its fingerprint, its copies' equality) is its parameters and features
        object.__setattr__(self, "_memo", _TableMemo())

    def factors(self, theta):
        w, eta, alpha = theta
        return rough_coating_factors(self.cos_l, self.cos_v, self.cos_hv, w, eta, alpha, self._memo.get(alpha, eta))
