"""The rough dielectric interface of Mitsuba's ``roughplastic`` (rjfit/model/rough_interface.py).

- The visible normals: Heitz's projection with the concentric disk gives the normals Mitsuba's own
  ``MicrofacetDistribution.sample`` gives for the same point of the unit square (float32), and the density they
  sample is ``D_i(m) = G1(i) max(0, <i.m>) D(m) / <i.n>``: expectations of smooth functions of m by the map agree
  with the plain integral over the hemisphere.
- The series of ``1 - R_int`` against 512 x 512 rules at random points of its domain (fixed seed): within 5e-4
  (its fit's own check: 3.7e-4 at most, at alpha < 0.08, where the rules themselves move by up to 3e-4 from 512
  to 768 nodes; 1.3e-4 for alpha >= 0.1; a series of the smooth interface's 1 - R(eta) is off by 10 to 50 %),
  and smooth where the rules are jagged (second differences over eta steps of 1e-3 below 2e-6, its curvature;
  Mitsuba's 128 x 128 rule's reach 1.5e-5, measured).
- Out of the series' domain: a ValueError naming it.
"""
from __future__ import annotations

import numpy as np
import pytest

from rjfit.model.rough_interface import (SERIES_ALPHA, SERIES_ETA, TABLE_COSINES, ggx_visible_normal,
                                         interface_reflectance, internal_transmission)


def _smith_g1(cos_theta, alpha):
    return 2.0 / (1.0 + np.sqrt(1.0 + alpha ** 2 * (1.0 - cos_theta ** 2) / cos_theta ** 2))


def _direct_expectation(h, cos_i, alpha, n_theta=2048, n_phi=1024):
    """``E[h(m)]`` over the visible normals of direction (sin_i, 0, cos_i) as a plain integral over the hemisphere,
    ``int G1(i) max(0, <i.m>) D(m) h(m) / cos_i dm`` with GGX's D, by the midpoint rule in (theta_m, phi) (the kink
    of max(0, .) limits it to about 1e-4)."""
    theta = ((np.arange(n_theta) + 0.5) * 0.5 * np.pi / n_theta)[:, None]
    phi = (np.arange(n_phi) + 0.5) * 2.0 * np.pi / n_phi
    mx, my, mz = np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta) + 0.0 * phi
    a2 = alpha * alpha
    d = a2 / (np.pi * (mz * mz * (a2 - 1.0) + 1.0) ** 2)
    cos_im = np.sqrt(1.0 - cos_i ** 2) * mx + cos_i * mz
    density = _smith_g1(cos_i, alpha) * np.maximum(cos_im, 0.0) * d / cos_i * np.sin(theta)
    cell = (0.5 * np.pi / n_theta) * (2.0 * np.pi / n_phi)
    return float(np.sum(density * h(mx, my, mz)) * cell)


@pytest.mark.parametrize("alpha", [0.3, 0.9])
@pytest.mark.parametrize("cos_i", [0.1, 0.5, 0.999])
def test_visible_normals_have_the_visible_normal_density(alpha, cos_i):
    """The map's product rule (64 x 64 nodes) and the plain integral agree on smooth functions of m and on 1 (5e-4: the
    plain rule's kink); an unstretched view, or the view's own angle instead of the stretched one, is off by percents."""
    nodes, weights = np.polynomial.legendre.leggauss(64)
    u, w = 0.5 * (nodes + 1.0), 0.5 * weights
    normals = np.array([[ggx_visible_normal(cos_i, alpha, a, b) for b in u] for a in u])
    weight = np.outer(w, w)[..., None]
    for h in (lambda x, y, z: 1.0 + 0.0 * x, lambda x, y, z: x * x, lambda x, y, z: z, lambda x, y, z: x + y * y):
        by_map = float(np.sum(weight[..., 0] * h(normals[..., 0], normals[..., 1], normals[..., 2])))
        assert by_map == pytest.approx(_direct_expectation(h, cos_i, alpha), abs=5e-4)


def test_visible_normals_are_mitsubas():
    mi = pytest.importorskip("mitsuba")
    from rjfit.render.mitsuba_scene import activate

    activate("llvm_ad_rgb")
    rng = np.random.default_rng(0)
    for alpha in (0.05, 0.4, 1.0):
        distribution = mi.MicrofacetDistribution(mi.MicrofacetType.GGX, alpha, True)
        cos_i, u1, u2 = rng.uniform(0.02, 1.0, 200), rng.random(200), rng.random(200)
        sin_i = np.sqrt(1.0 - cos_i ** 2)
        wi = mi.Vector3f(mi.Float(sin_i), mi.Float(np.zeros(200)), mi.Float(cos_i))
        theirs = np.array(distribution.sample(wi, mi.Point2f(mi.Float(u1), mi.Float(u2)))[0], dtype=float)
        ours = np.array([ggx_visible_normal(c, alpha, a, b) for c, a, b in zip(cos_i, u1, u2)]).T
        np.testing.assert_allclose(ours, theirs, atol=2e-5)


def _quadrature(alpha, eta, order):
    return 1.0 - 2.0 * float(np.mean(interface_reflectance(TABLE_COSINES, alpha, 1.0 / eta, order) * TABLE_COSINES))


def test_the_series_is_the_quadrature_and_smooth():
    rng = np.random.default_rng(7)
    for _ in range(3):
        alpha = float(np.exp(rng.uniform(*np.log(SERIES_ALPHA))))
        eta = float(rng.uniform(*SERIES_ETA))
        assert internal_transmission(alpha, eta) == pytest.approx(_quadrature(alpha, eta, 512), rel=5e-4)
    etas = 1.5 + 1e-3 * np.arange(-3, 4)
    series = np.array([internal_transmission(0.16, eta) for eta in etas])
    assert np.abs(np.diff(series, 2)).max() < 2e-6         # the function's own curvature: measured 1.2e-6
    rule = np.array([_quadrature(0.16, eta, 128) for eta in etas])
    assert np.abs(np.diff(rule, 2)).max() > 5 * np.abs(np.diff(series, 2)).max()   # what the series is there for


@pytest.mark.parametrize("alpha, eta", [(0.01, 1.5), (0.3, 2.5), (1.2, 1.5)])
def test_out_of_the_domain_is_refused(alpha, eta):
    with pytest.raises(ValueError, match="domain"):
        internal_transmission(alpha, eta)
