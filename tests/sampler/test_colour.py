"""The joint colour fit (``--channel rgb``, :mod:`rjfit.sampler.colour`): exactness on tiny images.

- Enumeration: on :func:`builders.tiny_colour_problem`'s 2 x 2 image (3 lights x 3 channels,
  36 observations) the exact posterior of a partition is ``rho^K exp(-beta B) x prod over
  blocks of the block's evidence``, the evidence of a block a product over channels given
  one gamma: ``int p(gamma) prod_c [int p(I0_c) p(kd_c) p(sigma2_c) L_c] dgamma``
  (:class:`ColourQuadrature`: each channel's I0 and kd on the grid and sigma^2 analytically,
  gamma's axis shared). The chain's partition and K frequencies are compared with it by
  the ESS-scaled chi-square (level 0.001, fixed seed), pixel 0's material's gamma with
  its exact marginal by KS on draws thinned to about one per effective sample (level 0.001).
- The within-material moves alone (K fixed at 1): gamma against its exact marginal.
- Incremental statistics against a full recompute and the per-observation oracle after
  random move sequences (Gibbs sweeps, cluster moves, merges/splits) at a likelihood power.
- The compiled colour passes against their NumPy twins.
"""
import dataclasses

import numpy as np
import pytest
from scipy import stats
from test_exact_materials import canonical, exact_partition_posterior, k_test, partition_test
from threadpoolctl import threadpool_limits

from rjfit.data.synthetic import sphere_stack
from rjfit.sampler import reference
from rjfit.sampler.forward import Problem
from rjfit.sampler.kernel import ChainContext, initial_state, refresh, step
from rjfit.sampler.likelihood import RegionData, oracle_log_likelihood, region_stats
from rjfit.sampler.moves.colour_within import newton_log_gamma_colour
from rjfit.sampler.moves.gamma import ls_profile, ls_profile_nonnegative, newton_log_gamma
from rjfit.sampler.regions.materials.passes.labels import pixel_log_lik_colour, relabel_pixels_colour
from rjfit.sampler.state import SamplerConfig

from builders import Quadrature, tiny_colour_problem

LEVEL = 1e-3


class ColourQuadrature:
    """Evidence of a block of pixels under a shared gamma: per channel I0, kd (grid) and sigma^2 (analytic)."""

    def __init__(self, per_channel, prior, points=61):
        self.quads = [Quadrature(obs, prior, points=points) for obs in per_channel]
        q = self.quads[0]
        g0, g1, g2 = np.meshgrid(*q.axes, indexing="ij")
        phi = np.stack([g0, g1, g2, np.zeros_like(g0)], axis=-1)
        self.log_g_prior = prior.logpdf_phi_components(phi)[0, 0, :, 2]        # gamma's, once
        self.w01 = q.weights[0][:, None] * q.weights[1][None, :]
        self.w2 = q.weights[2]
        self._cache = {}

    def log_gamma_profile(self, pixels):
        """log [p(gamma) prod_c int p(I0_c) p(kd_c) p(sigma2_c) L_c] on the gamma axis."""
        total = self.log_g_prior.copy()
        for q in self.quads:
            f, _ = q._log_integrand(np.flatnonzero(np.isin(q.pixel, list(pixels))))
            f = f - self.log_g_prior[None, None, :]          # each channel's integrand without gamma's prior
            m = f.max()
            total += m + np.log(np.einsum("ijk,ij->k", np.exp(f - m), self.w01))
        return total

    def log_evidence(self, pixels):
        key = frozenset(int(p) for p in pixels)
        if not key:
            return 0.0
        if key not in self._cache:
            h = self.log_gamma_profile(key)
            m = h.max()
            self._cache[key] = float(m + np.log(np.sum(np.exp(h - m) * self.w2)))
        return self._cache[key]

    def gamma_cdf(self, pixels):
        """The CDF of gamma: the trapezoid rule's running integral of the log gamma density, linear between nodes."""
        h = self.log_gamma_profile(pixels)
        dens = np.exp(h - h.max())
        log_axis = self.quads[0].axes[2]
        cdf = np.concatenate([[0.0], np.cumsum(0.5 * (dens[1:] + dens[:-1]) * np.diff(log_axis))])
        cdf /= cdf[-1]
        return lambda x: np.interp(np.log(x), log_axis, cdf)


@pytest.fixture(scope="module")
def colour_square():
    per_channel, obs, prior = tiny_colour_problem()
    return prior, Problem.from_observations(obs), ColourQuadrature(per_channel, prior, points=81)


def test_colour_partitions_k_and_gamma_match_enumeration(colour_square):
    """All 15 partitions of the 2 x 2 colour image, K_max 4, every label and jump move (3000 iterations, ~40 s)."""
    prior, problem, quad = colour_square
    beta, rho = 1.0, 1.0
    exact = exact_partition_posterior(quad, (2, 2), beta, rho)
    config = SamplerConfig.from_flat(region_model="materials", burn_in=0, cluster_moves=2, potts_beta=beta,
                                     potts_rho=rho, max_materials=4, merge_split_moves=1)
    rng = np.random.default_rng(3)
    state = initial_state(problem, prior, config, rng)
    context = ChainContext()       # the chain's reusable work, as a fit's runner keeps it
    parts, gamma0 = [], []
    with threadpool_limits(1):
        for _ in range(3000):
            state, _ = step(state, rng, problem, prior, config, context)
            z = state.layout.pixels.ravel()
            parts.append(canonical(z))
            gamma0.append(state.theta[3 * z[0], 2])
    parts, gamma0 = parts[300:], np.array(gamma0[300:])
    p_part, details = partition_test(parts, exact)
    p_k, k_details = k_test(parts, exact)
    print(p_part, details, p_k, k_details)
    assert np.sort(k_details["exact"])[-2] > 0.05, "the exact posterior should spread over K for the test to bite"
    assert p_part > LEVEL, details
    assert p_k > LEVEL, k_details
    import arviz as az

    blocks = {}
    for part, prob in exact.items():
        block = tuple(np.flatnonzero(np.array(part) == part[0]))
        blocks[block] = blocks.get(block, 0.0) + prob
    mixture = [(prob, quad.gamma_cdf(block)) for block, prob in blocks.items()]
    ess = float(az.ess(gamma0[None], method="bulk"))
    draws = gamma0[::max(1, int(np.ceil(len(gamma0) / ess)))]
    p_gamma = stats.kstest(draws, lambda x: sum(p * cdf(x) for p, cdf in mixture)).pvalue
    print("gamma KS", p_gamma, len(draws))
    assert p_gamma > LEVEL


def test_colour_incremental_statistics_match_full_recompute():
    """After 300 iterations of every move at likelihood power 0.7 on a 2 x 5 colour image (~5 s): statistics
    and log-likelihoods equal a full recompute and the per-observation oracle to 1e-9 relative."""
    _, obs, prior = tiny_colour_problem(seed=8, width=5)
    problem = Problem.from_observations(obs, likelihood_power=0.7)
    config = SamplerConfig.from_flat(region_model="materials", burn_in=50, cluster_moves=3, potts_beta=0.5,
                                     max_materials=5, merge_split_moves=2, refresh_every=0)
    rng = np.random.default_rng(11)
    state = initial_state(problem, prior, config, rng)
    context = ChainContext()       # the chain's reusable work, as a fit's runner keeps it
    seen_k = set()
    for _ in range(300):
        state, _ = step(state, rng, problem, prior, config, context)
        seen_k.add(state.layout.n_materials)
        assert state.theta.shape[0] == 3 * state.layout.n_materials
        rows = state.theta.reshape(-1, 3, 4)
        assert np.all(rows[:, :, 2] == rows[:, :1, 2]), "a material's channels must share gamma"
    fresh = refresh(problem, state)
    scale = np.abs(fresh.stats).max()
    np.testing.assert_allclose(state.stats, fresh.stats, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(state.log_lik, fresh.log_lik, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(state.total_log_lik, oracle_log_likelihood(problem, state.labels, state.theta),
                               rtol=1e-9)
    assert len(seen_k) > 1, "the chain should change its number of materials"


def test_colour_passes_match_numpy_twins():
    """pixel_log_lik_colour against its twin, and relabel_pixels_colour against a full recompute (~2 s)."""
    _, obs, _ = tiny_colour_problem(seed=9, width=4)
    problem = Problem.from_observations(obs, likelihood_power=0.6)
    rng = np.random.default_rng(0)
    K = 3
    theta = np.column_stack([rng.uniform(5, 15, 3 * K), rng.uniform(0.2, 0.8, 3 * K),
                             np.repeat(rng.uniform(2, 30, K), 3), rng.uniform(0.1, 1.0, 3 * K)])
    n_pix = problem.height * problem.width
    got = pixel_log_lik_colour(problem.y, problem.C, problem.log_cos_hn, problem.channel_start, theta, 3, n_pix)
    np.testing.assert_allclose(got, reference.pixel_log_lik_colour(problem, theta), rtol=1e-10)
    pixels = rng.integers(0, K, n_pix)
    labels = np.repeat(pixels, np.diff(problem.pixel_start)) * 3 + problem.channel
    stats_now = region_stats(problem, labels, theta[:, 2], 3 * K)
    moved = np.array([0, 3, 5], np.int64)
    new = (pixels[moved] + 1) % K
    obs_labels = labels.astype(np.int64)
    relabel_pixels_colour(problem.y, problem.C, problem.log_cos_hn, problem.pixel_start, problem.channel, 3, moved,
                          pixels[moved].astype(np.int64), new.astype(np.int64), theta[:, 2].copy(), stats_now,
                          float(problem.likelihood_power), obs_labels)
    pixels[moved] = new
    expected_labels = np.repeat(pixels, np.diff(problem.pixel_start)) * 3 + problem.channel
    np.testing.assert_array_equal(obs_labels, expected_labels)
    np.testing.assert_allclose(stats_now, region_stats(problem, expected_labels, theta[:, 2], 3 * K), rtol=1e-10,
                               atol=1e-10)


def test_colour_within_moves_match_quadrature_on_one_material(colour_square):
    """K fixed at 1 on the 2 x 2 colour image (the within-material moves alone, 12000 iterations, ~20 s): gamma's
    draws against its exact marginal (KS on draws thinned to about one per effective sample, level 0.001).

    Sharper than the enumeration's gamma test (about 2900 effective draws, one block). Measured once by hand (not
    a test: the control is not a switch of the code): with gamma's prior counted once per channel instead of once
    per material (the correction in ``move_gamma_colour`` dropped) this test gives p = 1.8e-4, rejected at the
    level but not by far; the right code p = 0.26."""
    import arviz as az

    prior, problem, quad = colour_square
    config = SamplerConfig.from_flat(region_model="materials", burn_in=0, max_materials=1, update_labels=False,
                                     jumps=False)
    rng = np.random.default_rng(21)
    state = initial_state(problem, prior, config, rng, n_materials=1)
    context = ChainContext()       # the chain's reusable work, as a fit's runner keeps it
    gamma = np.empty(12000)
    with threadpool_limits(1):
        for t in range(gamma.size):
            state, _ = step(state, rng, problem, prior, config, context)
            gamma[t] = state.theta[0, 2]
    gamma = gamma[500:]
    ess = float(az.ess(gamma[None], method="bulk"))
    draws = gamma[::max(1, int(np.ceil(len(gamma) / ess)))]
    p_value = stats.kstest(draws, quad.gamma_cdf(range(4))).pvalue
    print("gamma KS", p_value, len(draws))
    assert p_value > LEVEL


def test_the_colour_newton_proposal_of_one_row_is_the_single_channels_where_kd_would_be_negative():
    """A colour material's Newton proposal of log gamma sums its rows' bounded profiles (least squares over a, b >= 0),
    the single channel's rule: with one row it is that rule's proposal, bit for bit. The data are a lobe of exponent 8
    less a small diffuse part (the unbounded least-squares a is -0.05 at gamma 8, a channel with kd at 0 as the
    DiLiGenT ball's red one), where the unbounded profile's slope differs (checked) and its proposals missed the
    posterior (accepted 0.1 % on the ball)."""
    obs, _, _ = sphere_stack(24, n_lights=6, seed=5)
    problem = Problem.from_observations(obs)
    C = problem.C.astype(float)
    y = 2.0 * C * np.exp(8.0 * problem.log_cos_hn.astype(float)) - 0.05 * C / np.pi
    data = RegionData.gather(dataclasses.replace(problem, y=y.astype(problem.y.dtype)), np.arange(problem.y.size))
    for g in (6.0, 8.0):
        stats_r, sums = data.stats_at(g), data.b_sums_newton(g)
        unbounded, bounded = (f(stats_r[2], stats_r[3], sums, g) for f in (ls_profile, ls_profile_nonnegative))
        assert unbounded[1] != bounded[1]
        single = newton_log_gamma(stats_r, sums, g, 1e-4, 1.0)
        assert single is not None
        assert newton_log_gamma_colour([stats_r], [sums], g, [1e-4], 1.0) == single
