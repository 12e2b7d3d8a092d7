"""``rjfit_blinn_ext``: rjfit's plugin (:mod:`rjfit.render.plugin`) with more parameters on the
specular lobe, implemented separately from the NumPy closed form of the criticism's effects
(drjit, in the BSDF):

    f = scale ( kd/pi K_d + (1 - kd) ((1 - u) N(g) <h.n>^g + u f_GGX(alpha)) F(<h.v>)/F0 ((1 - w) + w G1(v) G1(l)) K_s
                + v2 f_GGX(alpha2) )
    K_d = (1 - c) + c (1 - F_eta(<l.n>)) (1 - F_eta(<v.n>)) / (1 - R(eta)),   K_s = (1 - c) + c F_eta(<h.v>) / F_eta(1)

with ``alpha = sqrt(2 / (g + 2))`` and ``f_GGX(a) = D_a(h) G1_a(v) G1_a(l) / (4 <v.n> <l.n>)``
the GGX microfacet BRDF with Fresnel 1 (Mitsuba's ``roughconductor``, material "none",
distribution "ggx": ``tests/render/test_ext_plugin.py`` checks the two against each other).
Parameters, traverse-able and opaque: ``f0`` (default 1: no Fresnel), ``mask_w`` (default 0:
no Beckmann masking), ``ggx_w`` (u, default 0: no GGX in the lobe), ``lobe2_v`` (v2, default
0: no second lobe), ``lobe2_alpha`` (alpha2, default 0.2), ``coat_w`` (c, default 0: no coating) and
``coat_eta`` (eta, default 1.5): a dielectric coating (:mod:`rjfit.effects.coating`), ``F_eta`` the exact
unpolarised Fresnel reflectance written here in drjit and ``R(eta) = 2 int F_eta(mu) mu dmu`` summed
by the midpoint rule (2048 nodes) when the parameters change. ``coat_alpha`` (default 0: a smooth
interface) gives the coating's interface a GGX roughness (:mod:`rjfit.effects.rough_coating`): ``K_d``'s
transmission is then ``roughplastic``'s, ``T(<l.n>) T(<v.n>) / (eta^2 (1 - R_int))``, its table over 64
cosines computed when the parameters change with Mitsuba's own visible-normal sampling, ``fresnel`` and
``refract`` and Smith G1 (Gauss-Legendre 32 x 32 over the sample space, as ``roughplastic``) and read by
linear interpolation as ``roughplastic`` reads its own; ``1 - R_int`` is the smooth series of
:mod:`rjfit.model.rough_interface` (``roughplastic``'s 128 x 128 estimate is jagged in the parameters, and
differs from it by a constant factor, under 2e-3). Sampling is the plugin's (the
Blinn importance sampling stays valid: its density is positive wherever the lobes are; only
its efficiency changes). ``N(g)`` is Giesen's normalisation written in drjit, the twin of
:func:`rjfit.model.blinn.blinn_normalisation` (drjit cannot call NumPy inside a kernel); the
gate of the lobe effects (``tests/diagnose/test_diagnose_gate.py``) checks this BSDF against
that closed form.
"""
from __future__ import annotations

import math
from functools import partial

__all__ = ["EXT_PLUGIN_NAME", "register_ext"]

EXT_PLUGIN_NAME = "rjfit_blinn_ext"
# variant name -> the BSDF class registered for it: Mitsuba's plugin registry is per variant
# and process-wide, and registering twice is refused, so this mirrors that registry (as
# rjfit.render.plugin does for rjfit_blinn)
_REGISTERED: dict = {}


def _beckmann_smith_g1(dr, cos_theta, alpha):
    """Walter et al.'s rational fit of Beckmann's Smith G1, in drjit."""
    cos_theta = dr.clip(cos_theta, 1e-6, 1.0)
    tan_theta = dr.safe_sqrt(1.0 - cos_theta * cos_theta) / cos_theta
    a = 1.0 / dr.maximum(alpha * tan_theta, 1e-12)
    g = (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a)
    return dr.select(a >= 1.6, 1.0, g)


def _ggx(dr, cos_h, cos_i, cos_o, alpha):
    """``D G1(i) G1(o) / (4 cos_i cos_o)`` of GGX in drjit, written from the definitions (Walter et al.
    2007, eqs. 33-34), for cos_i, cos_o > 0."""
    a2 = alpha * alpha
    denom = (cos_h * cos_h) * (a2 - 1.0) + 1.0
    d = dr.select(cos_h > 0.0, a2 / (math.pi * denom * denom), 0.0)

    def g1(cos_theta):
        cos2 = cos_theta * cos_theta
        return 2.0 / (1.0 + dr.sqrt(1.0 + a2 * (1.0 - cos2) / cos2))
    return d * g1(cos_i) * g1(cos_o) / (4.0 * cos_i * cos_o)


def _dielectric_fresnel(dr, cos_i, eta):
    """Unpolarised Fresnel reflectance from outside on a dielectric of index eta > 1, in drjit, from the definitions."""
    c = dr.clip(cos_i, 0.0, 1.0)
    cos_t = dr.safe_sqrt(1.0 - (1.0 - c * c) / (eta * eta))
    r_s = (c - eta * cos_t) / (c + eta * cos_t)
    r_p = (eta * c - cos_t) / (eta * c + cos_t)
    return 0.5 * (r_s * r_s + r_p * r_p)


#: nodes of the midpoint rule of the coating's diffuse reflectance R(eta) (error ~1e-8)
COAT_NODES = 2048


def _diffuse_reflectance(dr, m, eta):
    """``R(eta) = 2 int_0^1 F(mu) mu dmu`` by the midpoint rule, as a Float of width 1."""
    mu = (dr.arange(m.Float, COAT_NODES) + 0.5) / COAT_NODES
    return m.Float(dr.sum(_dielectric_fresnel(dr, mu, eta) * mu)) * (2.0 / COAT_NODES)


#: the Gauss-Legendre order per axis of the rough interface's table (roughplastic's; its cosines are
#: rjfit.model.rough_interface.TABLE_COSINES, roughplastic's 64)
ROUGH_ORDER = 32


def _over_visible_normals(dr, m, alpha: float, order: int, quantity):
    """``E[quantity(wi, m, distribution)]`` over the visible normals of GGX (roughness alpha) of each table cosine, by
    Mitsuba's sampling of them on a Gauss-Legendre product rule over its sample space: an array of the table's size."""
    import mitsuba as mi
    import numpy as np

    from rjfit.model.rough_interface import TABLE_COSINES

    nodes, weights = (np.asarray(values, dtype=float) for values in m.quad.gauss_legendre(order))
    mu, u1, u2 = (grid.ravel() for grid in np.meshgrid(TABLE_COSINES, 0.5 * nodes + 0.5, 0.5 * nodes + 0.5,
                                                           indexing="ij"))
    weight = 0.25 * np.outer(weights, weights).ravel()
    distribution = m.MicrofacetDistribution(mi.MicrofacetType.GGX, alpha, True)
    wi = m.Vector3f(m.Float(np.sqrt(1.0 - mu * mu)), m.Float(np.zeros_like(mu)), m.Float(mu))
    normal = distribution.sample(wi, m.Point2f(m.Float(u1), m.Float(u2)))[0]
    values = np.asarray(quantity(wi, normal, distribution), dtype=float).reshape(TABLE_COSINES.size, -1)
    return values @ weight


def _rough_interface_table(dr, m, alpha: float, eta: float):
    """``roughplastic``'s transmittance table of a GGX interface (roughness alpha, index eta), with Mitsuba's
    microfacet sampling, Fresnel and Smith terms, and ``eta^2 (1 - R_int)`` (module docstring): ``(table, scale)``."""
    from rjfit.model.rough_interface import internal_transmission

    def transmitted(wi, normal, distribution):
        fresnel, cos_t, _, eta_ti = m.fresnel(dr.dot(wi, normal), m.Float(eta))
        through = m.refract(wi, normal, cos_t, eta_ti)
        return dr.select(through.z < 0.0, distribution.smith_g1(through, normal) * (1.0 - fresnel), 0.0)

    table = _over_visible_normals(dr, m, alpha, ROUGH_ORDER, transmitted)
    return table, eta * eta * internal_transmission(alpha, eta)


def _derive_constants(dr, m, bsdf) -> None:
    """A plugin's coating constants, 1 / (1 - R(eta)) and 1 / F(1), and with a rough interface its table and
    1 / (eta^2 (1 - R_int)), from its parameters; every one made opaque (a kernel reads them, they are not baked
    into it)."""
    bsdf.coat_inv_transmitted = 1.0 / (1.0 - _diffuse_reflectance(dr, m, bsdf.coat_eta))
    bsdf.coat_inv_f_normal = 1.0 / _dielectric_fresnel(dr, m.Float(1.0), bsdf.coat_eta)
    alpha, eta = float(bsdf.coat_alpha[0]), float(bsdf.coat_eta[0])
    bsdf.coat_rough = alpha > 0.0      # a Python switch: the kernel traced with or without the table
    table, scale = _rough_interface_table(dr, m, alpha, eta) if bsdf.coat_rough else ([1.0, 1.0], 1.0)
    bsdf.coat_table, bsdf.coat_inv_scale = m.Float(table), m.Float(1.0 / scale)
    dr.make_opaque(*(getattr(bsdf, key) for key in LOBE_DEFAULTS), bsdf.coat_inv_transmitted, bsdf.coat_inv_f_normal,
                   bsdf.coat_table, bsdf.coat_inv_scale)


def _table_lookup(dr, m, table, cos_theta):
    """``table`` at ``cos_theta``, linear between its entries (``roughplastic``'s ``lerp_gather``)."""
    size = dr.width(table)
    x = dr.clip(cos_theta, 0.0, 1.0) * (size - 1.0)
    index = dr.minimum(m.UInt32(x), size - 2)
    weight = x - m.Float(index)
    return (1.0 - weight) * dr.gather(m.Float, table, index) + weight * dr.gather(m.Float, table, index + 1)


#: the plugin's lobe parameters and their defaults (each one's null: no such term)
LOBE_DEFAULTS = {"f0": 1.0, "mask_w": 0.0, "ggx_w": 0.0, "lobe2_v": 0.0, "lobe2_alpha": 0.2, "coat_w": 0.0,
                 "coat_eta": 1.5, "coat_alpha": 0.0}


def _lobe_parameters(props) -> dict:
    """The lobe parameters of a plugin's properties (defaults where absent), checked.

    Raises
    ------
    ValueError
        For a value out of its range, naming the parameter.
    """
    values = {key: float(props.get(key, default)) for key, default in LOBE_DEFAULTS.items()}
    f0, mask_w, ggx_w, lobe2_v, lobe2_alpha, coat_w, coat_eta, coat_alpha = values.values()
    if not (0.0 < f0 <= 1.0) or not (0.0 <= mask_w <= 1.0) or not (0.0 <= ggx_w <= 1.0):
        raise ValueError(f"{EXT_PLUGIN_NAME}: need 0 < f0 <= 1, 0 <= mask_w <= 1 and 0 <= ggx_w <= 1, "
                         f"got {f0}, {mask_w}, {ggx_w}")
    if not (lobe2_v >= 0.0) or not (0.0 < lobe2_alpha <= 1.0):
        raise ValueError(f"{EXT_PLUGIN_NAME}: need lobe2_v >= 0 and 0 < lobe2_alpha <= 1, got {lobe2_v}, {lobe2_alpha}")
    if not (0.0 <= coat_w <= 1.0) or not (coat_eta > 1.0):
        raise ValueError(f"{EXT_PLUGIN_NAME}: need 0 <= coat_w <= 1 and coat_eta > 1, got {coat_w}, {coat_eta}")
    if coat_alpha != 0.0 and not (0.02 <= coat_alpha <= 1.0 and 1.2 <= coat_eta <= 2.0):
        raise ValueError(f"{EXT_PLUGIN_NAME}: need coat_alpha 0 (a smooth interface) or in [0.02, 1] with coat_eta in "
                         f"[1.2, 2] (the rough interface's domain), got {coat_alpha}, {coat_eta}")
    return values


def register_ext():
    """Register ``rjfit_blinn_ext`` for the active variant (idempotent); return its class."""
    import drjit as dr
    import mitsuba as mi
    from mitsuba.mitsuba_ext import ParamFlags

    from rjfit.render.plugin import register

    variant = mi.variant()
    if variant in _REGISTERED:
        return _REGISTERED[variant]
    base = register()
    m = getattr(mi, variant)
    inv_pi = 1.0 / math.pi

    smith_g1 = partial(_beckmann_smith_g1, dr)
    ggx = partial(_ggx, dr)
    fresnel = partial(_dielectric_fresnel, dr)

    class RjfitBlinnExtBSDF(base):
        def __init__(self, props):
            base.__init__(self, props)
            for key, value in _lobe_parameters(props).items():
                setattr(self, key, m.Float(value))
            _derive_constants(dr, m, self)

        def traverse(self, callback):
            base.traverse(self, callback)
            for key in LOBE_DEFAULTS:
                callback.put(key, getattr(self, key), ParamFlags.Differentiable)

        def parameters_changed(self, keys=None):
            base.parameters_changed(self, keys)
            _derive_constants(dr, m, self)

        def _eval_pdf(self, ctx, si, wo, active):
            has_diffuse, has_glossy, prob_d = self._lobe_probabilities(ctx)
            cos_i = m.Frame3f.cos_theta(si.wi)
            cos_o = m.Frame3f.cos_theta(wo)
            active = active & (cos_i > 0.0) & (cos_o > 0.0)
            h = dr.normalize(si.wi + wo)
            cos_h = dr.maximum(m.Frame3f.cos_theta(h), 0.0)
            g = self.gamma
            cos_h_pow_g = dr.power(cos_h, g)
            value = m.Float(0.0)
            pdf = m.Float(0.0)
            coat = self.coat_w
            if has_diffuse:
                # with coat_w = 0 the factor is (1 - 0) + 0 = 1 exactly: the values it had before
                if self.coat_rough:
                    transmitted = (_table_lookup(dr, m, self.coat_table, cos_i) * _table_lookup(dr, m, self.coat_table, cos_o)
                                   * self.coat_inv_scale)
                else:
                    transmitted = ((1.0 - fresnel(cos_i, self.coat_eta)) * (1.0 - fresnel(cos_o, self.coat_eta))
                                   * self.coat_inv_transmitted)
                value += self.kd * inv_pi * ((1.0 - coat) + coat * transmitted)
                pdf += prob_d * cos_o * inv_pi
            if has_glossy:
                norm = (g + 2.0) * (g + 4.0) / ((8.0 * math.pi) * (dr.exp2(-0.5 * g) + g))
                cos_hv = dr.clip(dr.dot(h, si.wi), 0.0, 1.0)
                one_minus = 1.0 - cos_hv
                schlick = 1.0 + (1.0 / self.f0 - 1.0) * (one_minus * one_minus) * (one_minus * one_minus) * one_minus
                alpha = dr.sqrt(2.0 / (g + 2.0))
                masking = (1.0 - self.mask_w) + self.mask_w * smith_g1(cos_i, alpha) * smith_g1(cos_o, alpha)
                # with ggx_w = lobe2_v = 0 the same products in the same order as before they existed
                blinn = (1.0 - self.kd) * ((1.0 - self.ggx_w) * norm) * cos_h_pow_g
                mixed = blinn + (1.0 - self.kd) * self.ggx_w * ggx(cos_h, cos_i, cos_o, alpha)
                second = self.lobe2_v * ggx(cos_h, cos_i, cos_o, self.lobe2_alpha)
                coating = (1.0 - coat) + coat * fresnel(cos_hv, self.coat_eta) * self.coat_inv_f_normal
                value += mixed * schlick * masking * coating + second
                pdf_h = (g + 1.0) * (0.5 / math.pi) * cos_h_pow_g
                wo_dot_h = dr.dot(wo, h)
                pdf += (1.0 - prob_d) * dr.select(wo_dot_h > 0.0, pdf_h / (4.0 * wo_dot_h), 0.0)
            value = self.scale * value * cos_o
            return dr.select(active, value, 0.0), dr.select(active, pdf, 0.0)

    m.register_bsdf(EXT_PLUGIN_NAME, lambda props: RjfitBlinnExtBSDF(props))
    _REGISTERED[variant] = RjfitBlinnExtBSDF
    return RjfitBlinnExtBSDF
