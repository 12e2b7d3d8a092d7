"""Ambient or stray light: a constant environment radiance around the object.

    mu += a * I0 * ( kd + (1 - kd) * A_g(theta_v) )

``a`` is the environment's radiance relative to the reference intensity (Mitsuba: a
``constant`` emitter of radiance a x reference_intensity). For a white constant environment
the reflected radiance is the BRDF's directional albedo: kd for the Lambert part, and for the
normalised Blinn lobe ``A_g(theta_v) = int N(g) <h.n>^g <l.n> dl`` over the hemisphere, which
depends on gamma and the view angle (Giesen's normalisation makes it ~1 at normal view). It is
tabulated once by quadrature over the half vector (Gauss-Legendre in u = cos^(g+1) theta_h,
uniform in phi) and interpolated; exact for a convex object, where nothing occludes the sky.
"""
from __future__ import annotations

import functools

import numpy as np

from rjfit.diagnose.effects.base import Effect, Param
from rjfit.model.blinn import blinn_normalisation
from rjfit.model.priors import LogNormal
from rjfit.render.scene_change import MitsubaChange

_LOG_G = np.linspace(np.log(0.05), np.log(5000.0), 48)
_COS_V = np.linspace(0.0, 1.0, 41)


def lobe_albedo_quadrature(gamma, cos_v, n_u=64, n_phi=96):
    """``A_g`` at one gamma for an array of cos theta_v, by quadrature (module docstring)."""
    cos_v = np.atleast_1d(np.asarray(cos_v, dtype=float))
    nodes, weights = np.polynomial.legendre.leggauss(n_u)
    u = 0.5 * (nodes + 1.0)
    wu = 0.5 * weights
    phi = (np.arange(n_phi) + 0.5) * (2.0 * np.pi / n_phi)
    cos_h = u ** (1.0 / (gamma + 1.0))
    sin_h = np.sqrt(np.maximum(1.0 - cos_h ** 2, 0.0))
    sin_v = np.sqrt(np.maximum(1.0 - cos_v ** 2, 0.0))[:, None, None]
    cv = cos_v[:, None, None]
    v_dot_h = sin_v * sin_h[None, :, None] * np.cos(phi)[None, None] + cv * cos_h[None, :, None]
    cos_i = 2.0 * v_dot_h * cos_h[None, :, None] - cv
    integrand = np.where((v_dot_h > 0) & (cos_i > 0), cos_i * 4.0 * v_dot_h, 0.0)
    total = np.einsum("u,vup->v", wu, integrand) * (2.0 * np.pi / n_phi)
    return blinn_normalisation(gamma) / (gamma + 1.0) * total


@functools.lru_cache(maxsize=1)
def _table():
    return np.stack([lobe_albedo_quadrature(float(np.exp(lg)), _COS_V, n_u=48, n_phi=64) for lg in _LOG_G])


def lobe_albedo(gamma, cos_v):
    """``A_g(theta_v)``, bilinear in (log gamma, cos theta_v) from the table (vectorised)."""
    table = _table()
    gamma, cos_v = np.broadcast_arrays(np.asarray(gamma, dtype=float), np.asarray(cos_v, dtype=float))
    i, fx = gamma_weights(gamma)
    j, fy = cos_v_weights(cos_v)
    return ((1 - fx) * (1 - fy) * table[i, j] + fx * (1 - fy) * table[i + 1, j]
            + (1 - fx) * fy * table[i, j + 1] + fx * fy * table[i + 1, j + 1])


def gamma_weights(gamma):
    """The table row ``i`` below each gamma (linear in log gamma, clipped to the table) and the weight ``fx`` of row ``i + 1``."""
    x = (np.clip(np.log(np.asarray(gamma, dtype=float)), _LOG_G[0], _LOG_G[-1]) - _LOG_G[0]) / (_LOG_G[1] - _LOG_G[0])
    i = np.minimum(x.astype(int), _LOG_G.size - 2)
    return i, x - i


def cos_v_weights(cos_v):
    """The table column ``j`` below each cos theta_v and the weight ``fy`` of column ``j + 1``."""
    y = np.clip(np.asarray(cos_v, dtype=float), 0.0, 1.0) / (_COS_V[1] - _COS_V[0])
    j = np.minimum(y.astype(int), _COS_V.size - 2)
    return j, y - j


def albedo_rows(gammas):
    """The table interpolated at each of ``gammas`` (linear in log gamma): (len(gammas), n_cos_v)."""
    table = _table()
    i, fx = gamma_weights(gammas)
    return (1 - fx[:, None]) * table[i] + fx[:, None] * table[i + 1]


class Ambient(Effect):
    name = "ambient"
    kind = "ambient or stray light"
    stage = "ambient"
    description = "constant environment radiance a (relative to the reference intensity) x the BRDF's albedo"

    def params(self, ctx):
        return [Param("ambient", LogNormal(loc=float(np.log(0.01)), scale=2.5), init=0.01, null=0.0)]

    def prepare(self, ctx):
        # Bilinear interpolation is separable: the view angle's column and weight are fixed per
        # observation, so a refit's evaluation interpolates in gamma once per region (a row of
        # the table) and gathers from those rows (as lobe_albedo, 15x faster on the ball)
        j, fy = cos_v_weights(ctx.cos_vn)
        return ctx.region * _COS_V.size + j, fy

    def apply(self, terms, theta, features, ctx):
        kd = terms["kd"]
        index, fy = features
        rows = albedo_rows(terms["gamma_region"]).ravel()
        albedo = (1.0 - fy) * rows[index] + fy * rows[index + 1]
        terms["mu"] = terms["mu"] + theta[0] * terms["I0"] * (kd + (1.0 - kd) * albedo)

    def mitsuba_change(self, theta, ctx):
        radiance = float(theta[0]) * ctx.reference_intensity
        return MitsubaChange(extra={"ambient": {"type": "constant", "radiance": {"type": "rgb", "value": [radiance] * 3}}},
                             stochastic=True,
                             notes=["exact for a convex object: nothing occludes the environment"])
