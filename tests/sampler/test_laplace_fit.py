"""The region proposals' Laplace fit of log gamma on the constrained (a, b >= 0) profile.

``h(l)`` (:func:`~rjfit.sampler.moves.region_proposals.laplace_log_gamma`) takes its
``SSR_min`` from the least squares over ``a, b >= 0``; its Newton steps use that profile's
closed-form derivatives (:func:`~rjfit.sampler.moves.gamma.ls_profile_nonnegative`). Each
region here: 2,000 pixels x 12 lights (24,000 observations, so the thinned path runs too),
``I0 = 10``, noise variance 0.05; the whole file takes about 5 s.
"""
import math

import numpy as np
import pytest

from rjfit.data.observations import Observations
from rjfit.model.blinn import radiance
from rjfit.sampler.forward import Problem
from rjfit.sampler.likelihood import RegionData
from rjfit.sampler.moves import region_proposals
from rjfit.sampler.moves.ab_conditional import ab_conditional
from rjfit.sampler.moves.gamma import ls_profile, ls_profile_nonnegative
from rjfit.sampler.moves.region_proposals import (
    LAPLACE_COARSE_OBS,
    LAPLACE_GRID,
    laplace_log_gamma,
    sigma2_prior_as_invgamma,
    ssr_min,
)
from rjfit.sampler.priors import ParamPrior, Prior

from builders import laplace_objective, parabola_at_grid_max

PRIOR = Prior(params=(ParamPrior("lognormal", math.log(10.0), 1.0), ParamPrior("uniform", 0.0, 1.0),
                      ParamPrior("lognormal", math.log(8.0), 1.5), ParamPrior("invgamma", 2.0, 0.1)))


def _region(kd, gamma, n_pix=2000, n_lights=12, seed=0):
    """One region's data: the radiance of (10, kd, gamma) plus noise; kd < 0 or > 1 puts the optimum on a face."""
    rng = np.random.default_rng(seed)
    pixel = np.repeat(np.arange(n_pix), n_lights).astype(np.int64)
    cos_ln, cos_hn = rng.uniform(0.1, 1.0, pixel.size), rng.uniform(0.3, 1.0, pixel.size)
    irradiance = np.ones(pixel.size)
    y = radiance(10.0, kd, gamma, cos_ln, cos_hn, irradiance) + rng.normal(0.0, math.sqrt(0.05), pixel.size)
    obs = Observations(image_shape=(1, n_pix), n_lights=n_lights, pixel=pixel,
                       light=np.tile(np.arange(n_lights), n_pix).astype(np.int32), y=y, cos_ln=cos_ln, cos_hn=cos_hn,
                       irradiance=irradiance, object_mask=np.ones((1, n_pix), bool))
    problem = Problem.from_observations(obs)
    data = RegionData.gather(problem, np.arange(problem.n_obs))
    assert data.n >= 2 * LAPLACE_COARSE_OBS
    return data


def _objective(data, count_of=None):
    return laplace_objective(data, PRIOR, count_of)


def _face_at(data, ell):
    return ls_profile_nonnegative(data.fixed[2], data.fixed[3], data.b_sums_newton(math.exp(ell)), math.exp(ell))[6]


def _no_fallback(monkeypatch):
    def refuse(*args):
        raise AssertionError("the finite-difference fallback ran")
    monkeypatch.setattr(region_proposals, "_laplace_finite_differences", refuse)


@pytest.mark.parametrize("kd,gamma,face", [(0.5, 5.0, 0), (-0.03, 5.0, 1), (1.05, 5.0, 2)])
def test_constrained_profile_derivatives_match_finite_differences_of_ssr_min(kd, gamma, face):
    # f = Syy - SSR_min as ssr_min computes it; f' and f'' against central differences with
    # step 1e-4 in l: truncation (third derivative times step^2 / 6, measured ~1e-6
    # relative) and rounding of f (1e-16 |f| / step^2 in f'') are far below the tolerances;
    # a wrong term is of the order of f' or f''.
    data = _region(kd, gamma)
    syy = data.fixed[1]
    ell, step = math.log(gamma), 1e-4

    def f(e):
        return syy - ssr_min(data.stats_at(math.exp(e)))[0]

    profile = ls_profile_nonnegative(data.fixed[2], data.fixed[3], data.b_sums_newton(gamma), gamma)
    assert profile[6] == face
    f1_ref = (f(ell + step) - f(ell - step)) / (2 * step)
    f2_ref = (f(ell + step) - 2 * f(ell) + f(ell - step)) / step ** 2
    assert profile[0] == pytest.approx(f(ell), rel=1e-12)
    assert abs(profile[1] - f1_ref) <= 1e-6 * (abs(profile[1]) + abs(profile[2]))
    assert abs(profile[2] - f2_ref) <= 1e-5 * abs(profile[2]) + 1e-14 * abs(profile[0]) / step ** 2
    if face == 0:       # inside, the unconstrained profile itself, bit for bit
        assert profile[:6] == ls_profile(data.fixed[2], data.fixed[3], data.b_sums_newton(gamma), gamma)[:6]


def _old_newton(data, ell, k, b0, prior_part, max_steps=8, eps=1e-3):
    """The Newton iteration of commit 12fe60e (the unconstrained profile, None unless a, b > 0 at the end)."""
    syy, sya, saa = data.fixed[1], data.fixed[2], data.fixed[3]
    for _ in range(max_steps):
        g = math.exp(ell)
        profile = ls_profile(sya, saa, data.b_sums_newton(g), g)
        if profile is None:
            return None
        f, f1, f2, det, det1, det2, ca, cb = profile
        q = 0.5 * (syy - f) + b0
        p0, pp, pm = prior_part(ell), prior_part(ell + eps), prior_part(ell - eps)
        h1 = k * f1 / (2.0 * q) - 0.5 * det1 / det + (pp - pm) / (2.0 * eps)
        h2 = (k * f2 / (2.0 * q) + k * f1 * f1 / (4.0 * q * q) - 0.5 * (det2 / det - (det1 / det) ** 2)
              + (pp - 2.0 * p0 + pm) / eps ** 2)
        if not (math.isfinite(h1) and math.isfinite(h2) and h2 < 0 and q > 0):
            return None
        sd = 1.0 / math.sqrt(-h2)
        step = min(max(-h1 / h2, -0.5), 0.5)
        ell += step
        if abs(step) < 0.2 * sd:
            return (ell, min(max(sd, 1e-4), 2.0)) if ca > 0 and cb > 0 else None
    return None


@pytest.mark.parametrize("kd,gamma", [(0.5, 5.0), (0.3, 20.0), (0.8, 2.0)])
def test_interior_optimum_gives_the_old_newton_result_bit_for_bit(kd, gamma, monkeypatch):
    # Where the unconstrained least-squares point stays inside a, b > 0 the constrained
    # profile is the unconstrained one, so the fit is the old Newton's, every bit.
    data = _region(kd, gamma)
    _no_fallback(monkeypatch)
    mean, sd = laplace_log_gamma(data, PRIOR)
    assert _face_at(data, mean) == 0
    a0, b0 = sigma2_prior_as_invgamma(PRIOR)
    k = 0.5 * data.n * data.weight - 1.0 + a0

    def prior_part(ell):
        return PRIOR.params[2].logpdf_scalar(math.exp(ell)) + ell

    coarse = region_proposals._thinned(data, LAPLACE_COARSE_OBS)
    grid_values = [_objective(coarse, data)(e) for e in LAPLACE_GRID]     # the thinning's sums, the region's n
    start = LAPLACE_GRID[int(np.argmax(grid_values))]
    coarse_mode = _old_newton(coarse, start, k, b0, prior_part)
    old = _old_newton(data, start if coarse_mode is None else coarse_mode[0], k, b0, prior_part)
    assert old is not None
    assert (mean, sd) == old


@pytest.mark.parametrize("gamma", [5.0, 20.0])
def test_optimum_on_a_face_matches_a_dense_grid_and_the_finite_differences(gamma, monkeypatch):
    # kd < 0: the unconstrained a is negative at the mode, the constrained optimum lies on
    # a = 0. Reference: h on a fine grid around the result (parabola through the best three
    # of 241 points, 0.05 sd apart). Newton stops once a step is below 0.2 sd, so the mean
    # must agree within 0.2 sd and the sd (the curvature there) within 5 %. The old
    # fallback (finite differences on the whole region) must land within its own last
    # spacing (a ninth of the grid's step) and its sd within 25 % (a secant curvature over
    # that spacing, tens of sds here).
    data = _region(-0.03, gamma)
    h = _objective(data)
    old_start = LAPLACE_GRID[int(np.argmax([h(e) for e in LAPLACE_GRID]))]      # the old fallback's: the whole region's grid
    fd = region_proposals._laplace_finite_differences(h, old_start, LAPLACE_GRID[1] - LAPLACE_GRID[0])
    _no_fallback(monkeypatch)
    mean, sd = laplace_log_gamma(data, PRIOR)
    assert _face_at(data, mean) == 1
    ref_mean, ref_sd = parabola_at_grid_max(h, mean, sd, 6.0, 241)
    assert abs(mean - ref_mean) < 0.2 * ref_sd
    assert abs(sd / ref_sd - 1.0) < 0.05
    assert abs(mean - fd[0]) < (LAPLACE_GRID[1] - LAPLACE_GRID[0]) / 9
    assert abs(fd[1] / sd - 1.0) < 0.25


def test_mode_at_the_kink_gets_the_kinked_moments(monkeypatch):
    # gamma 0.5, kd < 0: the constraint a >= 0 starts to bind right at the mode, where the
    # curvature jumps about a hundredfold. Newton alone would cycle across the kink; the
    # kink is found and the fit is the mean and sd of the quadratic expansions on its two
    # sides. The reference: mean and sd of exp(h) on a dense grid. A proposal's sd is
    # inflated by 1.5 (birth_gamma_inflation) to cover such a misfit, so: mean within 1 sd,
    # sd within a factor 1.5.
    data = _region(-0.03, 0.5)
    _no_fallback(monkeypatch)
    mean, sd = laplace_log_gamma(data, PRIOR)
    h = _objective(data)
    grid = mean + sd * np.linspace(-10.0, 10.0, 801)
    values = np.array([h(e) for e in grid])
    weights = np.exp(values - values.max())
    weights /= weights.sum()
    ref_mean = float(np.sum(weights * grid))
    ref_sd = math.sqrt(float(np.sum(weights * (grid - ref_mean) ** 2)))
    mode = grid[int(np.argmax(values))]
    assert _face_at(data, mode - 0.1 * ref_sd) != _face_at(data, mode + 0.1 * ref_sd)     # a kink at the mode
    assert abs(mean - ref_mean) < ref_sd
    assert 1 / 1.5 < sd / ref_sd < 1.5


@pytest.mark.parametrize("slope,curv_below,curv_above", [(0.0, -4.0, -1 / 9), (-26.0, -1.1e4, -29.0),
                                                         (3.0, -50.0, -2.0), (0.0, -1.0, -1.0)])
def test_kinked_moments_match_numerical_integration(slope, curv_below, curv_above):
    # exp(slope t + curv t^2 / 2) with one curvature below 0 and another above, integrated
    # on a grid of 2 million points over +-12 of the wider side's sd: 1e-6 relative.
    width = 12.0 / math.sqrt(-max(curv_below, curv_above)) + abs(slope) / min(-curv_below, -curv_above)
    t = np.linspace(-width, width, 2_000_001)
    log_density = slope * t + 0.5 * np.where(t < 0, curv_below, curv_above) * t * t
    density = np.exp(log_density - log_density.max())
    density /= density.sum()
    mean = float(np.sum(density * t))
    sd = math.sqrt(float(np.sum(density * (t - mean) ** 2)))
    got = region_proposals._kinked_moments(0.0, slope, curv_below, curv_above)
    assert got[0] == pytest.approx(mean, rel=1e-6, abs=1e-9 * sd) and got[1] == pytest.approx(sd, rel=1e-6)


@pytest.mark.parametrize("kd", [0.5, -0.03, 1.05])
def test_ssr_min_rows_is_ssr_min_of_each_row(kd):
    """The compiled rows (a Laplace fit's nine coarse points; ssr_min is their one-row case) against the SSR at the
    centre of ab_conditional's (a, b) conditional, row by row: the interior and both faces (kd outside [0, 1] puts
    the optimum on one), and rows it refuses (singular, not finite, SSR <= 0) as NaN. Same operations in the same
    order; the tolerance (1e-14 relative) allows a compiler's rounding."""

    def reference(row):      # from the conditional's Python floats
        cond = ab_conditional(row, 1.0)
        if cond is None:
            return None
        ma, mb = cond.ma, cond.mb
        ssr = (row[1] - 2.0 * (ma * row[2] + mb * row[4]) + ma * ma * cond.saa + 2.0 * ma * mb * cond.sab
               + mb * mb * cond.sbb)
        return (ssr, cond.det) if ssr > 0 else None

    data = _region(kd, 5.0)
    stats = data.stats_at_many(np.exp(LAPLACE_GRID))
    refused = np.array([[10.0, 5.0, 1.0, 0.0, 1.0, 0.0, 1.0],            # SAA 0: singular
                        [10.0, 5.0, 1.0, 2.0, 1.0, 2.0, 2.0],            # det 0
                        [10.0, 0.0, 1.0, 1.0, 1.0, 0.0, 1.0],            # SSR below 0
                        [10.0, 5.0, np.nan, 2.0, 1.0, 1.0, 3.0]])
    rows = np.vstack([stats, refused])
    ssr, det = region_proposals.ssr_min_rows(rows)
    for row, s, d in zip(rows, ssr, det):
        expected = reference(row)
        if expected is None:
            assert np.isnan(s) and np.isnan(d), row
        else:
            assert s == pytest.approx(expected[0], rel=1e-14) and d == pytest.approx(expected[1], rel=1e-14), row
    assert np.isfinite(ssr[:len(stats)]).all() and np.isnan(ssr[len(stats):]).all()
