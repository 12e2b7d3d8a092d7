"""Where the sampler's numbers could overflow or turn NaN, each case measured on real stacks or built to hit it,
evaluated with floating-point warnings as errors (pyproject.toml): a defined result, never inf - inf."""
import math

import numpy as np
import pytest

from rjfit.data.synthetic import sphere_stack
from rjfit.sampler.forward import Problem
from rjfit.sampler.likelihood import AB_PLAIN_MAX, RegionData, log_lik_large_ab, log_likelihood_from_stats
from rjfit.sampler.moves.ab_conditional import ab_conditional, draw_ab
from rjfit.sampler.moves.gamma import ls_profile, newton_log_gamma
from rjfit.sampler.moves.region_terms import giesen_norm, region_log_lik
from rjfit.sampler.regions.changepoints.passes import paths

# ls_profile's arguments where it overflowed, recorded in a psm-rock fit (4 chains x 1000, seed 0,
# likelihood power auto): gamma 838, the region's lobe sums subnormal (SBB 8.8e-322)
ROCK_SYA, ROCK_SAA, ROCK_GAMMA = 35.74065477632946, 0.0878976996439143, 838.2511561010754
ROCK_SUMS = np.array([2.1600695432237646e-160, 6.254114971266015e-163, 8.84e-322, -9.454783470290118e-161,
                      -2.7374721817229197e-163, -3.85e-322, 4.138428355258325e-161, 1.19821173421599e-163, 1.7e-322])


def test_the_profile_of_a_vanished_lobe_is_none():
    """The old profile gave b = -4e160 and overflowed (f'); the lobe has vanished there: no Newton step."""
    assert ls_profile(ROCK_SYA, ROCK_SAA, ROCK_SUMS, ROCK_GAMMA) is None
    stats = np.array([100.0, 2e4, ROCK_SYA, ROCK_SAA, *ROCK_SUMS[:3]])
    assert newton_log_gamma(stats, ROCK_SUMS, ROCK_GAMMA, 250.0, 1.0) is None


@pytest.fixture(scope="module")
def far_region():
    """The sphere's observations far from the highlight (<h.n> < 0.9), as one region."""
    obs, _, _ = sphere_stack(24, n_lights=6, seed=5)
    problem = Problem.from_observations(obs)
    far = np.flatnonzero(problem.log_cos_hn < math.log(0.9))
    return problem, RegionData.gather(problem, far)


def test_the_profile_where_the_lobe_is_present_is_unchanged(far_region):
    """At gamma 10 the lobe is there: a finite profile, the same as the plain formula's."""
    _, data = far_region
    stats = data.stats_at(10.0)
    profile = ls_profile(stats[2], stats[3], data.b_sums_newton(10.0), 10.0)
    assert profile is not None and all(math.isfinite(v) for v in profile)


def test_amplitudes_from_a_vanished_lobe_have_a_finite_likelihood(far_region):
    """At a gamma where <h.n>^gamma is ~1e-150 over the region, SBB is ~1e-300 and the (a, b)
    conditional draws b ~1e150: b^2 overflows float64, b^2 SBB does not. The likelihood is
    finite, the same from the array and the scalar form, and the plain sum's where both apply."""
    _, data = far_region
    closest = float(np.max(data.log_cos_hn))               # the region's <h.n> nearest 1
    gamma = -345.0 / closest                                # <h.n>^gamma <= e^-345 = 1e-150
    stats = data.stats_at(gamma)
    assert 0 < stats[6] < 1e-290
    s2 = 0.5 * float(np.var(data.y))
    cond = ab_conditional(stats, s2)
    a, b = draw_ab(cond, np.random.default_rng(0))
    b = abs(b)
    assert b > AB_PLAIN_MAX
    I0 = a + b / giesen_norm(gamma)
    theta = np.array([[I0, a / I0, gamma, s2]])
    array_form = log_likelihood_from_stats(stats[None], theta)[0]
    assert math.isfinite(array_form)
    assert region_log_lik(stats, *theta[0]) == pytest.approx(array_form, rel=1e-9)
    # the scaled sum against the plain one where the plain one does not overflow
    ordinary = data.stats_at(10.0)
    plain = log_likelihood_from_stats(ordinary[None], np.array([[2.0, 0.5, 10.0, s2]]))[0]
    a2, b2 = 1.0, 1.0 * giesen_norm(10.0)
    assert log_lik_large_ab(ordinary, a2, b2, s2) == pytest.approx(plain, rel=1e-9)


def test_a_density_beyond_float64_is_minus_infinity_not_nan():
    stats = np.array([10.0, 5.0, 1.0, 2.0, 1.0, 1.0, 3.0])
    assert log_lik_large_ab(stats, 1e200, 1.0, 0.1) == -math.inf          # its mean's norm is 1.4e200
    assert log_lik_large_ab(stats, math.nan, 1.0, 0.1) == -math.inf
    empty_lobe = np.array([10.0, 5.0, 1.0, 2.0, 0.0, 0.0, 0.0])            # B all zero: b does not enter
    assert math.isfinite(log_lik_large_ab(empty_lobe, 1.0, 1e200, 0.1))


def test_a_backward_draw_at_a_dead_end_marks_the_line():
    """Three lines of four cells; line 1's only reachable cell is 0, line 2 sits at cell 3 and the
    steps reach one cell: from line 2 no cell of line 1 is in reach. The draw marks line 1 with -1."""
    alpha = np.full((3, 4), -np.inf)
    alpha[0, 0] = alpha[1, 0] = alpha[2, 3] = 0.0
    log_kernel = np.zeros(3)                               # steps -1, 0, 1
    path = paths.cell_backward_sample(alpha, log_kernel, np.full(3, 0.5))
    assert path[2] == 3 and path[1] == -1


# The statistics of two observations that (I0, kd, gamma) = (3000, 0.7, 5) fits exactly (a colour material's channel
# with two observations of a rim pixel): their SSR expansion rounds to about -1e-9, below the true 0
EXACT_FIT_STATS = np.array([2.0, 6651516.658547751, 2847.2113478222345, 1.2337752756956057, 1542.859528361211,
                            0.5880801049433155, 0.7065024319087959])


def test_an_exact_fit_gives_a_likelihood_bounded_as_sigma2_falls():
    """A sum of squares is never negative; its expansion's rounding can be, and the likelihood then grew without bound
    as sigma^2 fell (a colour fit of psm-horse reached a log posterior of 1.7e156). Every form of the region
    likelihood from statistics stays at or below its supremum, the density at SSR = 0 (to 1e-12 relative)."""
    I0, kd, g = 3000.0, 0.7, 5.0
    a, b = I0 * kd, I0 * (1.0 - kd) * giesen_norm(g)
    n, syy, sya, saa, syb, sab, sbb = (float(x) for x in EXACT_FIT_STATS)
    assert syy - 2.0 * a * sya - 2.0 * b * syb + a * a * saa + 2.0 * a * b * sab + b * b * sbb < 0.0   # the case
    for s2 in (1.0, 1e-12, 1e-200):
        supremum = -0.5 * n * (math.log(2.0 * math.pi) + math.log(s2))
        forms = {"scalar": region_log_lik(EXACT_FIT_STATS, I0, kd, g, s2),
                 "compiled rows": float(log_likelihood_from_stats(EXACT_FIT_STATS[None], np.array([[I0, kd, g, s2]]))[0]),
                 "array": float(log_likelihood_from_stats(EXACT_FIT_STATS, np.array([I0, kd, g, s2]))),
                 "large amplitudes": log_lik_large_ab(EXACT_FIT_STATS, a, b, s2)}
        for form, value in forms.items():
            assert value <= supremum + 1e-12 * abs(supremum), (form, s2, value, supremum)
