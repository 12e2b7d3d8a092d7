"""Sampler bookkeeping: incremental statistics vs the full-recompute oracle, change points, priors."""
import numpy as np
import pytest
from scipy import integrate
from threadpoolctl import threadpool_limits

from rjfit.data.synthetic import sphere_stack
from rjfit.sampler.forward import Problem
from rjfit.sampler.kernel import ChainContext, anneal_power, initial_state, make_state, step
from rjfit.sampler.likelihood import RegionData, oracle_log_likelihood, region_stats
from rjfit.sampler.regions.changepoints.birth_death import birth_probability, propose_birth, propose_death
from rjfit.sampler.regions.changepoints.birth_death_free import propose_birth_free, propose_death_free
from rjfit.sampler.moves.region_proposals import LAPLACE_COARSE_OBS, laplace_log_gamma
from rjfit.sampler.priors import ParamPrior, Prior, make_prior
from rjfit.sampler.regions.changepoints.grid import (
    Changepoints,
    log_prior_changepoints,
    model_from_number,
    model_number,
    obs_region_labels,
    pixel_region_labels,
)
from rjfit.sampler.state import ChainState, SamplerConfig, Work

from builders import laplace_objective, parabola_at_grid_max


@pytest.fixture(scope="module")
def small():
    obs, labels, truth = sphere_stack(20, n_lights=6, seed=3)
    problem = Problem.from_observations(obs)
    prior = make_prior("default", y=problem.y, diffuse_scale=problem.A)
    return problem, prior, labels, truth


@pytest.mark.parametrize("sampler,likelihood_power,noise", [("adaptive", 1.0, None), ("paper", 1.0, None),
                                                             ("adaptive", 0.3, None), ("adaptive", 0.3, "relative"),
                                                             ("paper", 1.0, "shot")])
def test_incremental_log_likelihood_equals_oracle_after_long_random_sequences(small, sampler, likelihood_power, noise):
    problem, prior, _, _ = small
    if likelihood_power != 1.0 or noise is not None:
        from rjfit.data.noise import noise_scale

        obs = sphere_stack(20, n_lights=6, seed=3)[0]
        scale = None if noise is None else noise_scale(obs, noise, 0.05)
        problem = Problem.from_observations(obs, likelihood_power=likelihood_power, noise_scale=scale)
    # refresh_every=0: no periodic recompute, so drift of the incremental updates would show.
    config = SamplerConfig.from_flat(max_u=2, max_v=2, sampler=sampler, burn_in=100, jump_prob=0.7, cp_uniform_prob=0.3,
                           refresh_every=0, split_scale=0.5)
    rng = np.random.default_rng(11)
    state = initial_state(problem, prior, config, rng, model=(1, 1))
    context = ChainContext()       # the chain's reusable work, as a fit's runner keeps it
    models = set()
    with threadpool_limits(1):
        for t in range(600):
            state, info = step(state, rng, problem, prior, config, context)
            if t % 25 == 12:
                # Force a birth or death (accepted whatever its ratio) so that the incremental
                # bookkeeping is exercised across changes of dimension.
                state = _forced_jump(state, rng, problem, prior, config)
            models.add(state.layout.model_key)
            if t % 50 == 49:
                labels = obs_region_labels(state.layout.u, state.layout.v, problem.row, problem.col)
                np.testing.assert_array_equal(state.labels, labels)
                # the oracle includes the known noise scales' constant; the chain's statistics leave it out
                oracle = oracle_log_likelihood(problem, state.labels, state.theta)
                assert state.total_log_lik + problem.log_likelihood_constant == pytest.approx(oracle, rel=1e-10,
                                                                                              abs=1e-7)
                fresh = region_stats(problem, state.labels, state.theta[:, 2], state.n_regions)
                np.testing.assert_allclose(state.stats, fresh, rtol=1e-9, atol=1e-8)
    assert len(models) >= 3, "the sequence should visit several models"


def _forced_jump(state, rng, problem, prior, config):
    regions = config.regions
    for _ in range(100):      # retry until the proposal is a valid state
        axis = "u" if rng.random() < 0.5 else "v"
        n, n_max = (state.layout.n_u, regions.max_u) if axis == "u" else (state.layout.n_v, regions.max_v)
        birth = rng.random() < birth_probability(n, n_max)
        free = rng.random() < 0.5
        work = Work(layout=state.layout, theta=state.theta.copy(), stats=state.stats.copy(),
                    log_lik=state.log_lik.copy(), labels=state.labels)
        propose = (propose_birth_free if birth else propose_death_free) if free else (propose_birth if birth
                                                                                       else propose_death)
        proposal = propose(work, rng, problem, prior, regions.birth_death, regions.proposals, regions.prior, n_max,
                           axis)
        if np.isfinite(proposal.log_ratio):
            break
    return ChainState(layout=proposal.layout, theta=proposal.theta, stats=proposal.stats, log_lik=proposal.log_lik,
                      labels=proposal.labels, log_g_scale=state.log_g_scale, iteration=state.iteration)


def test_region_of_pixel_counts_change_points_left_and_above():
    u = np.array([[0.9], [2.2]])       # H = 2 rows, one u vector
    v = np.array([[0.4], [-1.0], [1.7]])  # W = 3 columns, one v vector
    labels = pixel_region_labels(u, v, (2, 3))
    # row 0: u at 0.9 -> pixels 1,2 (centres 1.5, 2.5) right of it; row 1: u at 2.2 -> pixel 2 only.
    # column 0: v at 0.4 -> both rows (centres 0.5, 1.5) below; column 1: v at -1 -> both below;
    # column 2: v at 1.7 -> neither.
    iu = np.array([[0, 1, 1], [0, 0, 1]])
    iv = np.array([[1, 1, 0], [1, 1, 0]])
    np.testing.assert_array_equal(labels, iu * 2 + iv)


def test_model_number_round_trip_and_changepoint_prior():
    for n_u in range(4):
        for n_v in range(3):
            assert model_from_number(model_number(n_u, n_v, 2), 2) == (n_u, n_v)
    assert model_number(1, 1, 5) == 8
    # order-statistics density of 2 uniforms on [-1, W+1] per row: 2 / (W+2)^2
    assert log_prior_changepoints(2, 0, (3, 5)) == pytest.approx(3 * (np.log(2) - 2 * np.log(7)))


@pytest.mark.parametrize("param,slot", [(ParamPrior("lognormal", 1.0, 0.7), 0), (ParamPrior("uniform", 0.0, 1.0), 1),
                                        (ParamPrior("beta", 2.0, 3.0), 1), (ParamPrior("invgamma", 3.0, 2.0), 3),
                                        (ParamPrior("uniform", 0.5, 40.0), 2)])
def test_phi_density_includes_the_transform_jacobian(param, slot):
    """Each phi component's density must integrate to one (it would not without the Jacobian)."""
    params = [ParamPrior("lognormal", 0.0, 1.0), ParamPrior("uniform", 0.0, 1.0), ParamPrior("lognormal", 0.0, 1.0),
              ParamPrior("lognormal", 0.0, 1.0)]
    params[slot] = param
    prior = Prior(params=tuple(params))

    def density(x):
        phi = np.zeros(4)
        phi[slot] = x
        return np.exp(prior.logpdf_phi_components(phi)[slot])

    total, _ = integrate.quad(density, -30, 30, limit=400, points=[-5, 0, 5])
    assert total == pytest.approx(1.0, rel=1e-6)


def test_make_state_rejects_wrong_region_count(small):
    problem = small[0]
    with pytest.raises(ValueError, match="regions"):
        make_state(problem, Changepoints(np.zeros((problem.height, 1)), np.zeros((problem.width, 0))),
                   np.ones((3, 4)) * 0.5)


def test_config_rejects_unknown_sampler():
    with pytest.raises(ValueError, match="sampler"):
        SamplerConfig.from_flat(sampler="nuts")


def test_annealed_warm_up_tempers_then_hands_over_the_plain_likelihood(small):
    """During the warm-up the cached statistics are the tempered ones; after it, the plain ones (oracle)."""
    problem, prior, _, _ = small
    config = SamplerConfig.from_flat(max_u=2, max_v=2, burn_in=40, anneal=30, jump_prob=0.5, refresh_every=0)
    rng = np.random.default_rng(5)
    state = initial_state(problem, prior, config, rng, model=(1, 1))
    context = ChainContext()       # the chain's reusable work, as a fit's runner keeps it
    assert anneal_power(config.kernel, 0) == pytest.approx(1e-3) and anneal_power(config.kernel, 30) == 1.0
    with threadpool_limits(1):
        for t in range(45):
            state, _ = step(state, rng, problem, prior, config, context)
            power = anneal_power(config.kernel, t)
            fresh = region_stats(problem, state.labels, state.theta[:, 2], state.n_regions)
            np.testing.assert_allclose(state.stats, power * fresh, rtol=1e-9, atol=1e-8 * power)
    assert state.total_log_lik == pytest.approx(oracle_log_likelihood(problem, state.labels, state.theta),
                                                rel=1e-10, abs=1e-7)


@pytest.mark.parametrize("region", [0, 3])
def test_laplace_fit_of_a_large_region_finds_the_full_data_mode(region):
    # The jump proposals' Laplace fit of log gamma locates the mode on a thinning of a large
    # region first, then refines it on the whole region. Reference: the same approximate
    # log marginal h evaluated on the whole region on a fine grid (parabola through the
    # best three points). The Newton iteration stops once a step is below 0.2 sd, so the
    # mean must agree within 0.2 sd; the sd is the curvature at that point (within 5 %).
    obs, truth_labels, _ = sphere_stack(128, seed=3)
    problem = Problem.from_observations(obs)
    prior = make_prior("default", y=problem.y, diffuse_scale=problem.A)
    labels = truth_labels.ravel()[problem.pixel]
    data = RegionData.gather(problem, np.flatnonzero(labels == region))
    assert data.n >= 2 * LAPLACE_COARSE_OBS          # the thinned path is the one under test
    mean, sd = laplace_log_gamma(data, prior)
    ref_mean, ref_sd = parabola_at_grid_max(laplace_objective(data, prior), mean, sd, 3.0, 61)
    assert abs(mean - ref_mean) < 0.2 * ref_sd
    assert abs(sd / ref_sd - 1.0) < 0.05
