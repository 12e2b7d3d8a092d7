"""A rough dielectric interface (GGX): the energy it transmits and reflects, as Mitsuba's ``roughplastic`` tabulates it.

- ``T(mu)``: the energy a GGX dielectric interface of roughness alpha and relative index eta transmits from
  outside at incidence cosine mu, ``E[(1 - F(<i.m>)) G1(t, m)]`` over the visible normals m of the direction i
  (Heitz and d'Eon 2014), t the refracted direction; tabulated at the 64 cosines ``max(1e-6, k / 63)``
  (:data:`TABLE_COSINES`) and read linearly between them (:func:`table_lookup`), as Mitsuba does;
- ``R_int``: its reflectance from inside, ``2 mean_k(rho(mu_k; 1/eta) mu_k)`` over the same 64 cosines, ``rho(mu;
  1/eta) = E[F(<i.m>; 1/eta) G1(r, m)]`` (r the reflected direction): Mitsuba's estimate of the hemispherical
  integral, kept as the definition.

The expectations are computed as Mitsuba computes them, written here from the papers: Gauss-Legendre product
rules over the unit square, mapped to the disk by Shirley and Chiu's concentric map and the disk to the visible
normals by Heitz's (2018) projection ("Sampling the GGX Distribution of Visible Normals", JCGT 7(4)). T with 32 x
32 nodes: the same nodes on the same normals as Mitsuba's table, equal to its float32 rounding (3e-6,
``tests/render/test_ext_plugin.py``). ``R_int``'s integrand has the kink of total internal reflection, so a rule
of fixed order is jagged in (alpha, eta) (Mitsuba's 128 x 128: second differences over eta steps of 1e-3 change
sign at 1e-5, a hundred times the smooth function's), which a finite-difference Hessian reads as curvature, and
converges slowly (128 against 1024 nodes: 1.5e-3 relative in ``1 - R_int`` at alpha 0.02, eta 2; 1e-4 at alpha
0.3, eta 1.5). So ``1 - R_int`` is a tensor Chebyshev series in (log alpha, eta) over :data:`SERIES_ALPHA` x
:data:`SERIES_ETA`, fitted to 512 x 512 rules by ``validation/rough_interface_fit.py``: within 3.7e-4 of such
rules at 24 random points, and within 1.3e-4 where alpha >= 0.1, where the rules themselves move by up to
3e-4 from 512 to 768 nodes at alpha < 0.08, eta > 1.8 (1e-5 elsewhere); checked in
``tests/model/test_rough_interface.py``. So it is smooth, and as close to the integral as Mitsuba's estimate.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["TABLE_COSINES", "SERIES_ALPHA", "SERIES_ETA", "ggx_visible_normal", "interface_transmittance",
           "interface_reflectance", "internal_transmission", "chebyshev_coordinates", "transmittance_table",
           "table_lookup"]

#: the domain of the series of 1 - R_int: GGX roughness from polished (0.02) to matte (1), and the index of
#: refraction of coatings, binders and glasses (rjfit.effects.coating)
SERIES_ALPHA, SERIES_ETA = (0.02, 1.0), (1.2, 2.0)
#: the cosines of roughplastic's transmittance table (its 64 entries, the first at 1e-6)
TABLE_COSINES = np.maximum(1e-6, np.arange(64) / 63.0)
#: Gauss-Legendre orders per axis: the transmittance, and the inside reflectance (total internal reflection)
TRANSMITTANCE_ORDER, INTERNAL_ORDER = 32, 128   # Mitsuba's

#: 1 - R_int as a Chebyshev series in chebyshev_coordinates(alpha, eta), degree (15, 9): fitted by
#: validation/rough_interface_fit.py (its header says how) to 512 x 512 rules at 20 x 13 Chebyshev points
INTERNAL_TRANSMISSION_SERIES = np.array([
    [5.5532417088e-01, -1.8928447205e-01, 3.3291017147e-02, -4.8079285757e-03, 5.8762040359e-04,
     -4.9761663926e-05, -1.4571938761e-06, 4.1324429292e-06, -2.3455722945e-06, 8.0969816859e-06],
    [2.2676569655e-01, 4.9188116835e-02, -1.6193425718e-02, 4.3024926898e-03, -1.0200248654e-03,
     2.1307650486e-04, -5.1739773733e-05, 1.6376595508e-05, -9.4076115566e-06, -1.0637230101e-05],
    [8.7787268892e-02, 3.3252185255e-02, -8.6158940639e-03, 1.8337281691e-03, -3.0843653445e-04,
     4.2105014642e-05, 2.5581269831e-06, -3.3568271599e-06, 3.6609452854e-06, 1.0365928991e-05],
    [9.0385277316e-03, 1.4216331006e-02, -2.1142305805e-03, 3.2940157603e-05, 1.0479839779e-04,
     -5.8765543263e-05, 1.8713417799e-05, -5.1831530456e-06, 3.0325619716e-07, -1.0185297768e-05],
    [-8.4377578152e-03, 2.0317234421e-03, 7.0433261274e-04, -4.3676827233e-04, 1.5472457363e-04,
     -4.0758016703e-05, 1.1506608715e-05, -4.8856887501e-06, 1.9819687311e-06, 5.3477107333e-06],
    [-4.4976259888e-03, -1.7298450413e-03, 8.3424674454e-04, -2.4674386723e-04, 4.7788425525e-05,
     -6.1660468625e-06, -1.8133533904e-06, 1.8704391227e-06, -3.9281787381e-07, -2.5793620637e-06],
    [-5.7185183806e-04, -1.2992196409e-03, 2.6548244583e-04, -1.2463930917e-05, -1.5833965905e-05,
     1.1535729241e-05, -3.8901007247e-06, 1.1052559726e-06, 1.8123029681e-07, 1.7095505638e-06],
    [3.8183789387e-04, -3.0645943642e-04, -5.2404136410e-05, 5.1375963463e-05, -1.9705155173e-05,
     7.0745318416e-06, -1.4795627912e-06, 1.1048058753e-06, -1.1067938430e-07, -1.8865463772e-06],
    [1.9787604122e-04, 8.2976782398e-05, -7.5525256081e-05, 2.7711948093e-05, -5.4401530947e-06,
     3.5702573687e-07, 5.7883713083e-07, 2.1146612470e-08, 5.2214532212e-07, 1.2925382744e-07],
    [3.0961491163e-05, 9.3419786709e-05, -2.3930474567e-05, 1.5188284003e-06, 2.8394150573e-06,
     -1.5034052819e-06, 5.7407789808e-07, 6.4084861918e-08, 5.0151031342e-07, 3.5465982390e-07],
    [-1.5599373237e-05, 2.3462887492e-05, 4.4784971793e-06, -4.8849641412e-06, 3.0490512552e-06,
     -3.5620616880e-07, 5.5485996323e-07, 2.6659732185e-07, 1.5565247287e-07, -1.0989723408e-07],
    [-9.8710829449e-06, -6.9053082629e-06, 6.7746604487e-06, -2.0121850340e-06, 6.9130305709e-07,
     9.4158154444e-07, 8.1142290705e-07, 1.1625030987e-06, 8.0124049995e-07, 5.0068889688e-07],
    [-3.1090133121e-08, -4.2367619149e-06, 2.2470672052e-06, 3.4111931826e-07, 3.9022084640e-08,
     9.6416561633e-07, 7.0137075026e-07, 1.1955678719e-06, 1.0457026544e-06, 6.0687507544e-07],
    [2.1370098165e-06, 4.6558750345e-07, -7.1296465819e-07, -5.4826221290e-07, -1.3213827988e-06,
     -1.9398342475e-07, 5.1835693972e-07, 8.7565096299e-07, 7.6488542208e-07, 2.6279258713e-07],
    [1.8503204386e-06, 7.6306081197e-07, -8.8172792413e-07, 4.1169965617e-08, -6.5167776574e-07,
     -4.1668359486e-07, 2.6577618877e-07, 5.5179711631e-07, -1.5067830529e-07, -6.7653452346e-07],
    [-6.6316693855e-06, -3.8269595092e-06, 2.2607037453e-08, -5.0646072423e-07, 3.1254616267e-08,
     -5.3181268213e-07, -8.0862072408e-07, -3.4196072388e-07, 9.0018376551e-08, -8.8376894754e-08],
])


def _unit_square(order):
    nodes, weights = np.polynomial.legendre.leggauss(order)
    return 0.5 * (nodes + 1.0), 0.5 * weights


#: the rules of the default orders, built once: NumPy's leggauss solves an eigenproblem per call, a fifth of a table's
#: time when a sampler builds one per proposed (alpha, eta)
_RULES = {order: _unit_square(order) for order in (TRANSMITTANCE_ORDER, INTERNAL_ORDER)}


def _rule(order):
    """``(nodes, weights)`` of the Gauss-Legendre rule of ``order`` on [0, 1]."""
    return _RULES[order] if order in _RULES else _unit_square(order)


@njit(cache=True, nogil=True)
def _concentric_disk(u1, u2):
    """Shirley and Chiu's (1997) area-preserving map of the unit square onto the unit disk (the one Mitsuba's
    visible-normal sampling uses, so that a product rule over the square samples the normals Mitsuba's does)."""
    a, b = 2.0 * u1 - 1.0, 2.0 * u2 - 1.0
    if a == 0.0 and b == 0.0:
        return 0.0, 0.0
    if abs(a) > abs(b):
        radius, phi = a, 0.25 * math.pi * (b / a)
    else:
        radius, phi = b, 0.5 * math.pi - 0.25 * math.pi * (a / b)
    return radius * math.cos(phi), radius * math.sin(phi)


@njit(cache=True, nogil=True)
def _visible_normal_on_disk(cos_i, alpha, t1, t2):
    """The microfacet normal of Heitz's (2018, listing 1) projection of the disk point ``(t1, t2)`` (module
    docstring), for the direction ``(sin_i, 0, cos_i)`` and GGX roughness ``alpha``."""
    sin_i = math.sqrt(max(1.0 - cos_i * cos_i, 0.0))
    # the view stretched to the hemisphere configuration (its y is 0, so T1 = (0, 1, 0), T2 = (-vz, 0, vx))
    vx, vz = alpha * sin_i, cos_i
    norm = math.sqrt(vx * vx + vz * vz)
    vx, vz = vx / norm, vz / norm
    s = 0.5 * (1.0 + vz)
    t2 = (1.0 - s) * math.sqrt(max(1.0 - t1 * t1, 0.0)) + s * t2
    t3 = math.sqrt(max(0.0, 1.0 - t1 * t1 - t2 * t2))
    # Mitsuba's frame: its disk's x along -y (the tables do not see the mirror; the normals then are its own)
    mx, my, mz = alpha * (t3 * vx - t2 * vz), -alpha * t1, max(t2 * vx + t3 * vz, 0.0)
    length = math.sqrt(mx * mx + my * my + mz * mz)
    return mx / length, my / length, mz / length


@njit(cache=True, nogil=True)
def ggx_visible_normal(cos_i, alpha, u1, u2):
    """The microfacet normal ``(mx, my, mz)`` of a GGX surface of roughness ``alpha`` seen from the direction
    ``(sin_i, 0, cos_i)``, mapped from the point ``(u1, u2)`` of the unit square (Heitz 2018, listing 1, with
    the concentric disk)."""
    t1, t2 = _concentric_disk(u1, u2)
    return _visible_normal_on_disk(cos_i, alpha, t1, t2)


@njit(cache=True, nogil=True)
def _fresnel_any_side(cos_i, eta):
    """Unpolarised Fresnel reflectance at incidence cosine ``cos_i`` for a relative index ``eta`` (below 1 from
    inside: 1 beyond the critical angle), and the refracted cosine (0 there)."""
    c = min(max(cos_i, 0.0), 1.0)
    sin2_t = (1.0 - c * c) / (eta * eta)
    if sin2_t >= 1.0:
        return 1.0, 0.0
    cos_t = math.sqrt(1.0 - sin2_t)
    r_s = (c - eta * cos_t) / (c + eta * cos_t)
    r_p = (eta * c - cos_t) / (eta * c + cos_t)
    return 0.5 * (r_s * r_s + r_p * r_p), cos_t


@njit(cache=True, nogil=True)
def _smith_g1(cos_theta, alpha):
    cos2 = cos_theta * cos_theta
    return 2.0 / (1.0 + math.sqrt(1.0 + alpha * alpha * max(1.0 - cos2, 0.0) / cos2))


@njit(cache=True, nogil=True)
def _interface_energy(mu, alpha, eta, disk, weights, transmitted):
    """``E[(1 - F) G1(t, m)]`` (``transmitted``) or ``E[F G1(r, m)]`` over the visible normals m of incidence cosine
    ``mu``, by the product rule of ``weights`` on the unit square's nodes (``disk``: their concentric-map points,
    (n, n, 2)); t refracted, r reflected through m."""
    sin_i = math.sqrt(1.0 - mu * mu)
    total = 0.0
    for i in range(weights.size):
        for j in range(weights.size):
            mx, _, mz = _visible_normal_on_disk(mu, alpha, disk[i, j, 0], disk[i, j, 1])
            cos_im = sin_i * mx + mu * mz
            fresnel, cos_t = _fresnel_any_side(cos_im, eta)
            if transmitted:
                out_z = -mu / eta + (cos_im / eta - cos_t) * mz     # Snell's law through m
                value = (1.0 - fresnel) * _smith_g1(out_z, alpha) if out_z < 0.0 else 0.0
            else:
                out_z = 2.0 * cos_im * mz - mu
                value = fresnel * _smith_g1(out_z, alpha) if out_z > 0.0 else 0.0
            total += weights[i] * weights[j] * value
    return total


@njit(cache=True, nogil=True)
def _over_cosines(cosines, alpha, eta, nodes, weights, transmitted):
    disk = np.empty((nodes.size, nodes.size, 2))
    for i in range(nodes.size):
        for j in range(nodes.size):
            disk[i, j, 0], disk[i, j, 1] = _concentric_disk(nodes[i], nodes[j])
    out = np.empty(cosines.size)
    for k in range(cosines.size):
        out[k] = _interface_energy(cosines[k], alpha, eta, disk, weights, transmitted)
    return out


def interface_transmittance(mu, alpha, eta, order=TRANSMITTANCE_ORDER):
    """``T(mu) = E[(1 - F(<i.m>)) G1(t, m)]``: the energy a GGX interface of roughness alpha and relative index eta
    transmits at the incidence cosines ``mu`` (1-D), t the refracted direction (module docstring)."""
    nodes, weights = _rule(order)
    return _over_cosines(np.asarray(mu, dtype=float), float(alpha), float(eta), nodes, weights, True)


def interface_reflectance(mu, alpha, eta, order=INTERNAL_ORDER):
    """``rho(mu) = E[F(<i.m>) G1(r, m)]``: the energy a GGX interface reflects at the incidence cosines ``mu``
    (1-D), r the reflected direction; ``eta`` < 1 for light from inside."""
    nodes, weights = _rule(order)
    return _over_cosines(np.asarray(mu, dtype=float), float(alpha), float(eta), nodes, weights, False)


def chebyshev_coordinates(alpha, eta):
    """(log alpha, eta) over :data:`SERIES_ALPHA` x :data:`SERIES_ETA` mapped to [-1, 1]^2: the coordinates of the
    series of ``1 - R_int``."""
    (a_low, a_high), (e_low, e_high) = SERIES_ALPHA, SERIES_ETA
    x = 2.0 * (np.log(alpha) - math.log(a_low)) / (math.log(a_high) - math.log(a_low)) - 1.0
    y = 2.0 * (eta - e_low) / (e_high - e_low) - 1.0
    return x, y


def internal_transmission(alpha, eta):
    """``1 - R_int`` of the interface (module docstring), from the Chebyshev series.

    Raises
    ------
    ValueError
        For (alpha, eta) outside the series' domain, :data:`SERIES_ALPHA` x :data:`SERIES_ETA`.
    """
    if not (SERIES_ALPHA[0] <= alpha <= SERIES_ALPHA[1] and SERIES_ETA[0] <= eta <= SERIES_ETA[1]):
        raise ValueError(f"rough interface: alpha {alpha} and eta {eta} must lie in {SERIES_ALPHA} and {SERIES_ETA}, "
                         "the domain of the series of its internal reflectance")
    x, y = chebyshev_coordinates(alpha, eta)
    return float(np.polynomial.chebyshev.chebval2d(x, y, INTERNAL_TRANSMISSION_SERIES))


def transmittance_table(alpha, eta):
    """roughplastic's table, ``T`` at :data:`TABLE_COSINES`, and ``eta^2 (1 - R_int)`` (module docstring)."""
    return interface_transmittance(TABLE_COSINES, alpha, eta), eta * eta * internal_transmission(alpha, eta)


def table_lookup(cos_theta, table):
    """The table's value at ``cos_theta`` (clipped to [0, 1]), linear between its entries as Mitsuba's
    ``lerp_gather`` (the last interval extended to 1)."""
    x = np.clip(np.asarray(cos_theta, dtype=float), 0.0, 1.0) * (len(table) - 1)
    index = np.minimum(x.astype(np.int64), len(table) - 2)
    weight = x - index
    return (1.0 - weight) * table[index] + weight * table[index + 1]


