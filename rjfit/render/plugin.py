"""The rjfit Mitsuba 3 BSDF: Lambert + Blinn-Phong with Giesen's normalisation.

    f(wi, wo) = scale * ( kd / pi + (1 - kd) * N(g) * <h.n>^g ),
    N(g)      = (g + 2)(g + 4) / (8 pi (2^(-g/2) + g)),     h = normalize(wi + wo),

the paper's eq. 2 (Lenoch et al. 2016) with ``ks = 1 - kd``. ``scale`` is per material, so
the paper's per-region ``I0`` is the light's intensity times ``scale``. Following Mitsuba's
convention, :meth:`eval` returns ``f * cos(theta_o)``; both ``wi`` and ``wo`` must lie above
the surface (front side only), otherwise the value is zero.

Usage (the caller chooses the variant first; registrations are per variant)::

    import mitsuba as mi
    mi.set_variant("llvm_ad_rgb")
    from rjfit.render.plugin import register, PLUGIN_NAME
    register()                                    # idempotent for the active variant
    bsdf = mi.load_dict({"type": PLUGIN_NAME, "kd": 0.5, "gamma": 5.0, "scale": 1.0})

Parameters (scene dictionary / XML properties):

``kd``    float in [0, 1], diffuse fraction (default 0.5); ``ks = 1 - kd``.
``gamma`` float > 0, Blinn-Phong exponent (default 10).
``scale`` float > 0, overall factor (default 1).

All three are exposed by ``traverse`` and may be changed with ``mi.traverse(scene)`` +
``params.update()``; they are kept opaque (``dr.make_opaque``) so a new value does not
recompile the kernel. (In the scalar variants they are Python floats, which Mitsuba's
``SceneParameters`` cannot write into: load a new scene there instead.)

Sampling: the diffuse lobe is chosen with probability ``kd`` (cosine-weighted hemisphere),
the specular lobe with ``1 - kd``: ``cos theta_h = u^(1/(g+1))`` gives the half-vector density
``(g+1)/(2 pi) cos^g theta_h``, ``wo`` is ``wi`` reflected about ``h``, and
``pdf(wo) = pdf_h / (4 <wo.h>)``. The returned pdf is the mixture of the two lobe pdfs and the
weight is ``eval / pdf``. The choice ``kd`` is each lobe's share of the albedo at normal
incidence (Giesen's factor makes the specular lobe's albedo exactly 1 there; it falls off at
oblique incidence), so the weights stay near ``scale``. Samples whose reflected ``wo`` falls
below the horizon get weight 0 (the lobe loses that energy; ``pdf`` integrates to <= 1).
If a ``BSDFContext`` disables one component (0 diffuse, 1 glossy) the other is sampled alone.
"""
from __future__ import annotations

import math

__all__ = ["PLUGIN_NAME", "register", "registered_variants"]

#: The stable plugin name used in scene dictionaries and XML (``{"type": "rjfit_blinn"}``).
PLUGIN_NAME = "rjfit_blinn"

_INV_PI = 1.0 / math.pi
_INV_TWO_PI = 0.5 / math.pi

# variant name -> the BSDF class registered for it
_REGISTERED: dict[str, type] = {}


def registered_variants() -> tuple[str, ...]:
    """The Mitsuba variants for which :func:`register` has registered the plugin."""
    return tuple(_REGISTERED)


def register(variant: str | None = None) -> type:
    """Register the ``rjfit_blinn`` BSDF with Mitsuba for one variant; return its class.

    Mitsuba keeps one plugin registry per variant, so call ``mi.set_variant(...)`` first and
    then ``register()``; ``variant`` defaults to the active variant. Calling it again for the
    same variant does nothing. It changes no global state besides that registration (it does
    not set or switch the variant).
    """
    import mitsuba as mi

    if variant is None:
        variant = mi.variant()
        if variant is None:
            raise RuntimeError(
                "No Mitsuba variant is active: call mi.set_variant(...) before register()."
            )
    if variant not in mi.variants():
        raise ValueError(f"Unknown Mitsuba variant {variant!r}; available: {mi.variants()}")
    cls = _REGISTERED.get(variant)
    if cls is None:
        module = getattr(mi, variant)  # the variant's own module: its types, whatever is active
        cls = _make_bsdf_class(module)
        module.register_bsdf(PLUGIN_NAME, lambda props: cls(props))
        _REGISTERED[variant] = cls
    return cls


def _make_bsdf_class(m):
    """Build the BSDF class against the variant module ``m`` (types bound at build time)."""
    import drjit as dr
    from mitsuba.mitsuba_ext import BSDFFlags, ParamFlags

    diffuse_flags = BSDFFlags.DiffuseReflection | BSDFFlags.FrontSide
    glossy_flags = BSDFFlags.GlossyReflection | BSDFFlags.FrontSide

    class RjfitBlinnBSDF(m.BSDF):
        """Lambert + Giesen-normalised Blinn-Phong (see the module docstring)."""

        def __init__(self, props):
            m.BSDF.__init__(self, props)
            kd, gamma, scale = _checked_properties(props)
            self.kd = m.Float(kd)
            self.gamma = m.Float(gamma)
            self.scale = m.Float(scale)
            dr.make_opaque(self.kd, self.gamma, self.scale)
            self.m_components = [diffuse_flags, glossy_flags]
            self.m_flags = diffuse_flags | glossy_flags

        # -- parameters -------------------------------------------------------------------
        def traverse(self, callback):
            callback.put("kd", self.kd, ParamFlags.Differentiable)
            callback.put("gamma", self.gamma, ParamFlags.Differentiable)
            callback.put("scale", self.scale, ParamFlags.Differentiable)

        def parameters_changed(self, keys=None):
            dr.make_opaque(self.kd, self.gamma, self.scale)

        # -- helpers ----------------------------------------------------------------------
        def _lobe_probabilities(self, ctx):
            return _lobe_probabilities(m, ctx, self.kd)

        def _eval_pdf(self, ctx, si, wo, active):
            """(f * cos theta_o as a Float, mixture pdf) for local directions."""
            return _value_and_pdf(m, self._lobe_probabilities(ctx), self.kd, self.gamma, self.scale, si.wi, wo, active)

        # -- the BSDF interface -----------------------------------------------------------
        def eval(self, ctx, si, wo, active=True):
            value, _ = self._eval_pdf(ctx, si, wo, active)
            return m.Spectrum(value)

        def pdf(self, ctx, si, wo, active=True):
            _, pdf = self._eval_pdf(ctx, si, wo, active)
            return pdf

        def eval_pdf(self, ctx, si, wo, active=True):
            value, pdf = self._eval_pdf(ctx, si, wo, active)
            return m.Spectrum(value), pdf

        def sample(self, ctx, si, sample1, sample2, active=True):
            has_diffuse, has_glossy, prob_d = self._lobe_probabilities(ctx)
            bs = dr.zeros(m.BSDFSample3f)
            if not (has_diffuse or has_glossy):
                return bs, m.Spectrum(0.0)
            active = active & (m.Frame3f.cos_theta(si.wi) > 0.0)
            choose_diffuse = sample1 < prob_d
            wo = dr.select(choose_diffuse, m.warp.square_to_cosine_hemisphere(sample2),
                           _reflected_about_sampled_half_vector(m, si.wi, sample2, self.gamma))
            bs.wo = wo
            bs.eta = 1.0
            bs.sampled_component = dr.select(choose_diffuse, m.UInt32(0), m.UInt32(1))
            bs.sampled_type = dr.select(choose_diffuse, m.UInt32(int(BSDFFlags.DiffuseReflection)),
                                        m.UInt32(int(BSDFFlags.GlossyReflection)))
            value, pdf = self._eval_pdf(ctx, si, wo, active)
            active = active & (pdf > 0.0)
            bs.pdf = dr.select(active, pdf, 0.0)
            weight = dr.select(active, value / dr.select(active, pdf, 1.0), 0.0)
            return bs, m.Spectrum(weight)

        def to_string(self):
            return f"RjfitBlinnBSDF[kd={self.kd}, gamma={self.gamma}, scale={self.scale}]"

    RjfitBlinnBSDF.__name__ = f"RjfitBlinnBSDF_{m.__name__.rsplit('.', 1)[-1]}"
    return RjfitBlinnBSDF


def _lobe_probabilities(m, ctx, kd):
    """``(diffuse enabled, glossy enabled, probability of sampling the diffuse lobe)`` under the BSDF context
    ``ctx`` (component 0 diffuse, 1 glossy): ``kd`` when both are, else the enabled one's."""
    from mitsuba.mitsuba_ext import BSDFFlags

    has_diffuse = ctx.is_enabled(BSDFFlags.DiffuseReflection, 0)
    has_glossy = ctx.is_enabled(BSDFFlags.GlossyReflection, 1)
    if has_diffuse and has_glossy:
        return has_diffuse, has_glossy, m.Float(kd)
    return has_diffuse, has_glossy, m.Float(1.0 if has_diffuse else 0.0)


def _value_and_pdf(m, lobes, kd, g, scale, wi, wo, active):
    """``(f * cos theta_o, mixture pdf)`` for local directions ``wi``, ``wo`` (the module docstring's BSDF and
    sampling densities), zero unless both lie above the surface; ``lobes`` as :func:`_lobe_probabilities` gives
    them."""
    import drjit as dr

    has_diffuse, has_glossy, prob_d = lobes
    cos_o = m.Frame3f.cos_theta(wo)
    active = active & (m.Frame3f.cos_theta(wi) > 0.0) & (cos_o > 0.0)
    h = dr.normalize(wi + wo)
    cos_h_pow_g = dr.power(dr.maximum(m.Frame3f.cos_theta(h), 0.0), g)
    value = m.Float(0.0)
    pdf = m.Float(0.0)
    if has_diffuse:
        value += kd * _INV_PI
        pdf += prob_d * cos_o * _INV_PI
    if has_glossy:
        norm = (g + 2.0) * (g + 4.0) / ((8.0 * math.pi) * (dr.exp2(-0.5 * g) + g))
        value += (1.0 - kd) * norm * cos_h_pow_g
        pdf_h = (g + 1.0) * _INV_TWO_PI * cos_h_pow_g
        wo_dot_h = dr.dot(wo, h)
        pdf += (1.0 - prob_d) * dr.select(wo_dot_h > 0.0, pdf_h / (4.0 * wo_dot_h), 0.0)
    value = scale * value * cos_o
    return dr.select(active, value, 0.0), dr.select(active, pdf, 0.0)


def _reflected_about_sampled_half_vector(m, wi, sample2, gamma):
    """The specular lobe's sample: ``wi`` reflected about a half vector h of density (g+1)/(2 pi) cos^g theta_h
    (``cos theta_h = u^(1/(g+1))``)."""
    import drjit as dr

    cos_th = dr.power(sample2.x, 1.0 / (gamma + 1.0))
    sin_th = dr.safe_sqrt(1.0 - cos_th * cos_th)
    sin_phi, cos_phi = dr.sincos((2.0 * math.pi) * sample2.y)
    h = m.Vector3f(sin_th * cos_phi, sin_th * sin_phi, cos_th)
    return 2.0 * dr.dot(wi, h) * h - wi


def _checked_properties(props) -> tuple:
    """``(kd, gamma, scale)`` of a scene's properties (defaults 0.5, 10, 1), checked by :func:`_check`."""
    kd, gamma, scale = (float(props.get(name, default)) for name, default in (("kd", 0.5), ("gamma", 10.0),
                                                                               ("scale", 1.0)))
    _check(kd, gamma, scale)
    return kd, gamma, scale


def _check(kd: float, gamma: float, scale: float) -> None:
    if not (0.0 <= kd <= 1.0):
        raise ValueError(f"{PLUGIN_NAME}: kd must lie in [0, 1], got {kd}")
    if not gamma > 0.0:
        raise ValueError(f"{PLUGIN_NAME}: gamma must be > 0, got {gamma}")
    if not scale > 0.0:
        raise ValueError(f"{PLUGIN_NAME}: scale must be > 0, got {scale}")
