"""The physics of the effects (issue 26) as pure functions: defined once, used by the criticism's
closed form (:mod:`rjfit.diagnose.effects`) and by the fit's forward model
(:mod:`rjfit.sampler.effects`, :mod:`rjfit.sampler.passes.lobe`).

- the stages in which effects extend eq. 2: :data:`STAGES`;
- light gains: :func:`helmert_basis`, :func:`light_scales` (log gains with a fixed geometric mean);
- camera responses: :func:`srgb_encode` and its inverse :func:`srgb_decode` with the inverse's
  derivative (:func:`srgb_decode_log_slope`); the power law is written where it is used;
- Fresnel: :func:`schlick_ratio`;
- Smith-Beckmann shadowing / masking: :func:`tangent`, :func:`smith_g1_tan` (NumPy),
  :func:`g1_tan` (compiled, the same operations in the same order: the same bits),
  :func:`beckmann_alpha`;
- the normalised Blinn lobe's directional albedo (ambient light): :func:`lobe_albedo_quadrature`,
  its table (:func:`albedo_table`, :data:`ALBEDO_LOG_GAMMA`, :data:`ALBEDO_COS_V`) and the table's
  bilinear interpolation (:func:`gamma_weights`, :func:`cos_v_weights`, :func:`albedo_rows`,
  :func:`lobe_albedo`).
"""
from __future__ import annotations

import functools

import numpy as np
from numba import njit

from rjfit.model.blinn import blinn_normalisation

__all__ = ["STAGES", "helmert_basis", "light_scales", "srgb_encode", "srgb_decode", "srgb_decode_log_slope", "SRGB_KNEE",
           "schlick_ratio", "tangent", "smith_g1", "smith_g1_tan", "g1_tan", "beckmann_alpha",
           "lobe_albedo_quadrature", "albedo_table", "gamma_weights", "cos_v_weights", "albedo_rows", "lobe_albedo",
           "ALBEDO_LOG_GAMMA", "ALBEDO_COS_V"]


#: the order in which effects extend eq. 2 (``rjfit.diagnose.effects.base`` describes each stage)
STAGES = ("lobe", "direct", "indirect", "light", "ambient", "camera")


# -- light gains ---------------------------------------------------------------------------
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


# -- camera responses ----------------------------------------------------------------------
#: the encoded value below which the sRGB curve is its linear toe (12.92 x 0.0031308)
SRGB_KNEE = 12.92 * 0.0031308


def srgb_encode(x):
    """IEC 61966-2-1 sRGB encoding, extended linearly below 0 (as colour-science does)."""
    x = np.asarray(x, dtype=float)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(np.maximum(x, 0.0031308), 1.0 / 2.4) - 0.055)


def srgb_decode(v):
    """The inverse of :func:`srgb_encode` (linear below the knee, so for every real ``v``)."""
    v = np.asarray(v, dtype=float)
    return np.where(v <= SRGB_KNEE, v / 12.92, np.power((np.maximum(v, SRGB_KNEE) + 0.055) / 1.055, 2.4))


def srgb_decode_log_slope(v):
    """``log d srgb_decode / dv`` at ``v``."""
    v = np.asarray(v, dtype=float)
    upper = np.log(2.4 / 1.055) + 1.4 * np.log((np.maximum(v, SRGB_KNEE) + 0.055) / 1.055)
    return np.where(v <= SRGB_KNEE, -np.log(12.92), upper)


# -- Fresnel -------------------------------------------------------------------------------
def schlick_ratio(cos_hv, f0):
    """``F(<h.v>) / F0`` of Schlick's approximation."""
    return 1.0 + (1.0 / f0 - 1.0) * (1.0 - np.clip(cos_hv, 0.0, 1.0)) ** 5


# -- Smith-Beckmann shadowing / masking ----------------------------------------------------
def tangent(cos_theta):
    """tan theta from cos theta, cos clipped to [1e-6, 1] (grazing angles stay finite)."""
    cos_theta = np.clip(cos_theta, 1e-6, 1.0)
    return np.sqrt(np.maximum(1.0 - cos_theta ** 2, 0.0)) / cos_theta


def smith_g1(cos_theta, alpha):
    """Walter et al. (2007) rational approximation of Beckmann's Smith G1."""
    return smith_g1_tan(tangent(cos_theta), alpha)


def smith_g1_tan(tan_theta, alpha):
    """:func:`smith_g1` from tan theta (:func:`tangent`), which a refit computes once per observation."""
    a = 1.0 / np.maximum(alpha * tan_theta, 1e-12)
    g = (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a)
    return np.where(a >= 1.6, 1.0, g)


@njit(inline="always")
def g1_tan(tan_theta, alpha):
    """:func:`smith_g1_tan` of one value, compiled: the same operations, in the same order (the same bits)."""
    a = 1.0 / max(alpha * tan_theta, 1e-12)
    if a >= 1.6:
        return 1.0
    return (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a)


def beckmann_alpha(gamma):
    """The Beckmann roughness whose lobe matches Blinn-Phong of exponent gamma (Walter et al. 2007)."""
    return np.sqrt(2.0 / (np.asarray(gamma, dtype=float) + 2.0))


# -- the directional albedo of the normalised Blinn lobe -----------------------------------
#: the table's rows: log gamma from log 0.05 to log 5000; its columns: cos theta_v from 0 to 1
ALBEDO_LOG_GAMMA = np.linspace(np.log(0.05), np.log(5000.0), 48)
ALBEDO_COS_V = np.linspace(0.0, 1.0, 41)


def lobe_albedo_quadrature(gamma, cos_v, n_u=64, n_phi=96):
    """``A_g(theta_v) = int N(g) <h.n>^g <l.n> dl`` at one gamma for an array of cos theta_v, by
    quadrature over the half vector (Gauss-Legendre in u = cos^(g+1) theta_h, uniform in phi)."""
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
def albedo_table() -> np.ndarray:
    """``A_g(theta_v)`` on the grid (:data:`ALBEDO_LOG_GAMMA` x :data:`ALBEDO_COS_V`), by quadrature.

    A constant of the model, computed once per process (0.3 s) and never written to.
    """
    table = np.stack([lobe_albedo_quadrature(float(np.exp(lg)), ALBEDO_COS_V, n_u=48, n_phi=64)
                      for lg in ALBEDO_LOG_GAMMA])
    table.setflags(write=False)
    return table


def gamma_weights(gamma):
    """The table row ``i`` below each gamma (linear in log gamma, clipped to the table) and the weight ``fx`` of row ``i + 1``."""
    grid = ALBEDO_LOG_GAMMA
    x = (np.clip(np.log(np.asarray(gamma, dtype=float)), grid[0], grid[-1]) - grid[0]) / (grid[1] - grid[0])
    i = np.minimum(x.astype(int), grid.size - 2)
    return i, x - i


def cos_v_weights(cos_v):
    """The table column ``j`` below each cos theta_v and the weight ``fy`` of column ``j + 1``."""
    y = np.clip(np.asarray(cos_v, dtype=float), 0.0, 1.0) / (ALBEDO_COS_V[1] - ALBEDO_COS_V[0])
    j = np.minimum(y.astype(int), ALBEDO_COS_V.size - 2)
    return j, y - j


def albedo_rows(gammas):
    """The table interpolated at each of ``gammas`` (linear in log gamma): (len(gammas), n_cos_v)."""
    table = albedo_table()
    i, fx = gamma_weights(gammas)
    return (1 - fx[:, None]) * table[i] + fx[:, None] * table[i + 1]


def lobe_albedo(gamma, cos_v):
    """``A_g(theta_v)``, bilinear in (log gamma, cos theta_v) from the table (vectorised)."""
    table = albedo_table()
    gamma, cos_v = np.broadcast_arrays(np.asarray(gamma, dtype=float), np.asarray(cos_v, dtype=float))
    i, fx = gamma_weights(gamma)
    j, fy = cos_v_weights(cos_v)
    return ((1 - fx) * (1 - fy) * table[i, j] + fx * (1 - fy) * table[i + 1, j]
            + (1 - fx) * fy * table[i, j + 1] + fx * fy * table[i + 1, j + 1])
