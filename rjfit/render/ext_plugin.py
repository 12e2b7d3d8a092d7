"""``rjfit_blinn_ext``: rjfit's plugin (:mod:`rjfit.render.plugin`) with two more parameters on
the specular lobe, implemented separately from the NumPy closed form of the criticism's
effects (drjit, in the BSDF):

    f = scale ( kd/pi + (1 - kd) N(g) <h.n>^g F(<h.v>)/F0 ((1 - w) + w G1(v) G1(l)) )

``f0`` (default 1: no Fresnel) and ``mask_w`` (default 0: no masking), both traverse-able and
opaque. Sampling is the plugin's (the lobe factors are <= 1/F0 and smooth, so the Blinn
importance sampling stays valid; only its efficiency changes). ``N(g)`` is Giesen's
normalisation written in drjit, the twin of :func:`rjfit.model.blinn.blinn_normalisation`
(drjit cannot call NumPy inside a kernel); the gate of the Fresnel and masking effects
(``tests/diagnose/test_diagnose_gate.py``) checks this BSDF against that closed form.
"""
from __future__ import annotations

import math

__all__ = ["EXT_PLUGIN_NAME", "register_ext"]

EXT_PLUGIN_NAME = "rjfit_blinn_ext"
# variant name -> the BSDF class registered for it: Mitsuba's plugin registry is per variant
# and process-wide, and registering twice is refused, so this mirrors that registry (as
# rjfit.render.plugin does for rjfit_blinn)
_REGISTERED: dict = {}


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

    def smith_g1(cos_theta, alpha):
        cos_theta = dr.clip(cos_theta, 1e-6, 1.0)
        tan_theta = dr.safe_sqrt(1.0 - cos_theta * cos_theta) / cos_theta
        a = 1.0 / dr.maximum(alpha * tan_theta, 1e-12)
        g = (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a)
        return dr.select(a >= 1.6, 1.0, g)

    class RjfitBlinnExtBSDF(base):
        def __init__(self, props):
            base.__init__(self, props)
            f0 = float(props.get("f0", 1.0))
            mask_w = float(props.get("mask_w", 0.0))
            if not (0.0 < f0 <= 1.0) or not (0.0 <= mask_w <= 1.0):
                raise ValueError(f"{EXT_PLUGIN_NAME}: need 0 < f0 <= 1 and 0 <= mask_w <= 1, got {f0}, {mask_w}")
            self.f0 = m.Float(f0)
            self.mask_w = m.Float(mask_w)
            dr.make_opaque(self.f0, self.mask_w)

        def traverse(self, callback):
            base.traverse(self, callback)
            callback.put("f0", self.f0, ParamFlags.Differentiable)
            callback.put("mask_w", self.mask_w, ParamFlags.Differentiable)

        def parameters_changed(self, keys=None):
            base.parameters_changed(self, keys)
            dr.make_opaque(self.f0, self.mask_w)

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
            if has_diffuse:
                value += self.kd * inv_pi
                pdf += prob_d * cos_o * inv_pi
            if has_glossy:
                norm = (g + 2.0) * (g + 4.0) / ((8.0 * math.pi) * (dr.exp2(-0.5 * g) + g))
                cos_hv = dr.clip(dr.dot(h, si.wi), 0.0, 1.0)
                one_minus = 1.0 - cos_hv
                fresnel = 1.0 + (1.0 / self.f0 - 1.0) * (one_minus * one_minus) * (one_minus * one_minus) * one_minus
                alpha = dr.sqrt(2.0 / (g + 2.0))
                masking = (1.0 - self.mask_w) + self.mask_w * smith_g1(cos_i, alpha) * smith_g1(cos_o, alpha)
                value += (1.0 - self.kd) * norm * cos_h_pow_g * fresnel * masking
                pdf_h = (g + 1.0) * (0.5 / math.pi) * cos_h_pow_g
                wo_dot_h = dr.dot(wo, h)
                pdf += (1.0 - prob_d) * dr.select(wo_dot_h > 0.0, pdf_h / (4.0 * wo_dot_h), 0.0)
            value = self.scale * value * cos_o
            return dr.select(active, value, 0.0), dr.select(active, pdf, 0.0)

    m.register_bsdf(EXT_PLUGIN_NAME, lambda props: RjfitBlinnExtBSDF(props))
    _REGISTERED[variant] = RjfitBlinnExtBSDF
    return RjfitBlinnExtBSDF
