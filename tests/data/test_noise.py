"""Heteroscedastic noise with known scales (weighted least squares): density, scales, posterior coverage."""
import dataclasses

import numpy as np
import pytest
from scipy import stats
from threadpoolctl import threadpool_limits

from rjfit.data.noise import noise_scale, reference_signal, weighted_observations
from rjfit.data.synthetic import sphere_stack
from rjfit.model.blinn import radiance
from rjfit.sampler.forward import Problem
from rjfit.sampler.kernel import ChainContext, initial_state, step
from rjfit.sampler.likelihood import RegionData, log_likelihood_from_stats, oracle_log_likelihood, region_stats
from rjfit.sampler.priors import make_prior
from rjfit.sampler.regions.changepoints.grid import obs_region_labels
from rjfit.sampler.state import SamplerConfig


@pytest.fixture(scope="module")
def stack():
    return sphere_stack(16, n_lights=6, seed=2)


def _quadrant_changepoints(height, width):
    return np.full((height, 1), width / 2.0), np.full((width, 1), height / 2.0)


@pytest.mark.parametrize("power", [1.0, 0.4])
def test_weighted_likelihood_equals_the_heteroscedastic_gaussian_density(stack, power):
    obs, _, _ = stack
    rng = np.random.default_rng(0)
    scale = np.exp(rng.normal(0.0, 0.7, obs.n_obs))           # known scales, far from 1
    problem = Problem.from_observations(obs, likelihood_power=power, noise_scale=scale)
    u, v = _quadrant_changepoints(*obs.image_shape)
    labels = obs_region_labels(u, v, problem.row, problem.col)
    theta = np.array([[90.0, 0.4, 4.0, 0.3], [110.0, 0.8, 12.0, 0.05], [100.0, 0.6, 2.0, 1.5], [95.0, 0.3, 30.0, 0.2]])
    gammas = theta[:, 2]
    incremental = float(np.sum(log_likelihood_from_stats(region_stats(problem, labels, gammas, 4), theta)))
    incremental += problem.log_likelihood_constant
    # the same density evaluated directly from the float64 observations, in their own order
    obs_labels = obs_region_labels(u, v, obs.row.astype(np.int64), obs.col.astype(np.int64))
    t = theta[obs_labels]
    mu = radiance(t[:, 0], t[:, 1], t[:, 2], obs.cos_ln, obs.cos_hn, obs.irradiance)
    direct = power * float(np.sum(stats.norm.logpdf(obs.y, mu, np.sqrt(t[:, 3]) * scale)))
    assert incremental == pytest.approx(direct, rel=1e-6)
    assert oracle_log_likelihood(problem, labels, theta) == pytest.approx(incremental, rel=1e-10, abs=1e-7)
    assert problem.log_likelihood_constant == pytest.approx(-power * np.sum(np.log(scale)), rel=1e-6)
    # per-region gathered sums agree with the streamed ones
    for r in range(4):
        data = RegionData.gather(problem, np.flatnonzero(labels == r))
        np.testing.assert_allclose(data.stats_at(gammas[r]), region_stats(problem, labels, gammas, 4)[r], rtol=1e-10)


def test_unit_scales_give_the_homoscedastic_problem(stack):
    obs, _, _ = stack
    plain = Problem.from_observations(obs)
    unit = Problem.from_observations(obs, noise_scale=np.ones(obs.n_obs))
    np.testing.assert_array_equal(plain.y, unit.y)
    np.testing.assert_array_equal(plain.C, unit.C)
    assert plain.noise_scale is None and plain.log_likelihood_constant == 0.0
    assert unit.noise_scale.dtype == np.float32 and unit.log_likelihood_constant == 0.0


def test_problem_rejects_bad_noise_scales(stack):
    obs, _, _ = stack
    with pytest.raises(ValueError, match="one value per observation"):
        Problem.from_observations(obs, noise_scale=np.ones(obs.n_obs - 1))
    for bad in (0.0, -1.0, np.nan, np.inf):
        scale = np.ones(obs.n_obs)
        scale[3] = bad
        with pytest.raises(ValueError, match="finite and positive"):
            Problem.from_observations(obs, noise_scale=scale)


def test_noise_models_follow_their_formulas(stack):
    obs, _, _ = stack
    ybar = float(np.mean(obs.y))
    reference = np.linspace(0.0, 3.0 * ybar, obs.n_obs)
    assert noise_scale(obs, "constant") is None
    shot = noise_scale(obs, "shot", 0.1, reference=reference)
    relative = noise_scale(obs, "relative", 0.1, reference=reference)
    np.testing.assert_allclose(shot ** 2, (reference + 0.1 * ybar) / ybar)
    np.testing.assert_allclose(relative, (reference + 0.1 * ybar) / ybar)
    # the default reference is the per-pixel fit's prediction: closer to the noise-free
    # signal than the data are. A least-squares fit of ~3 parameters (a, b, gamma on a grid)
    # to k <= 6 observations predicts with error variance about 3 / k sigma^2, so its RMS
    # error is about 0.71 sigma (0.67 measured over 447 observations, MC sd ~0.03): 0.85
    # sigma is 5 sd away. Pixels with fewer than 4 observations fall back to y itself.
    _, labels, truth = stack
    region = labels.ravel()[obs.pixel]
    params = np.array([[t["I0"], t["kd"], t["gamma"]] for t in truth])[region]
    mu = radiance(params[:, 0], params[:, 1], params[:, 2], obs.cos_ln, obs.cos_hn, obs.irradiance)
    signal = reference_signal(obs)
    assert signal.shape == obs.y.shape and np.all(signal >= 0)
    fitted = np.bincount(obs.pixel)[obs.pixel] >= 4
    assert fitted.sum() > 300
    assert np.sqrt(np.mean((signal - mu)[fitted] ** 2)) < 0.85 * np.sqrt(truth[0]["sigma2"])
    np.testing.assert_array_equal(signal[~fitted], np.maximum(obs.y[~fitted], 0.0))
    weighted = weighted_observations(obs, relative)
    np.testing.assert_allclose(weighted.y * relative, obs.y)
    np.testing.assert_allclose(weighted.irradiance * relative, obs.irradiance)


@pytest.mark.parametrize("kwargs,match", [({"model": "poisson"}, "unknown noise model"),
                                          ({"model": "shot", "floor": 0.0}, "floor"),
                                          ({"model": "relative", "floor": -0.1}, "floor"),
                                          ({"model": "shot", "reference": np.ones(3)}, "one value per observation"),
                                          ({"model": "relative", "reference": "negative"}, "non-negative")])
def test_noise_scale_rejects_bad_input(stack, kwargs, match):
    obs, _, _ = stack
    if isinstance(kwargs.get("reference"), str):
        kwargs = dict(kwargs, reference=np.full(obs.n_obs, -1.0))
    with pytest.raises(ValueError, match=match):
        noise_scale(obs, **kwargs)


def _posterior(problem, seed, iterations=1200, burn=400):
    height, width = problem.image_shape
    prior = make_prior("default", y=problem.y, diffuse_scale=problem.A)
    config = SamplerConfig.from_flat(max_u=1, max_v=1, burn_in=burn, update_changepoints=False, jumps=False)
    rng = np.random.default_rng(seed)
    state = initial_state(problem, prior, config, rng, changepoints=_quadrant_changepoints(height, width))
    context = ChainContext()       # the chain's reusable work, as a fit's runner keeps it
    draws = []
    with threadpool_limits(1):
        for t in range(iterations):
            state, _ = step(state, rng, problem, prior, config, context)
            if t >= burn:
                draws.append(state.theta.copy())
    return state, np.array(draws)


def test_weighted_fit_covers_the_truth_of_heteroscedastic_data():
    """Noise sd proportional to the signal: the weighted posterior covers every true parameter,
    the homoscedastic one cannot (its sigma^2 is an average over very different variances)."""
    obs, truth_labels, _ = sphere_stack(24, n_lights=8, seed=4)
    truth = np.array([[100.0, 0.5, 5.0, 0.004], [100.0, 0.9, 10.0, 0.004],
                      [100.0, 0.6, 5.0, 0.004], [100.0, 0.4, 1.0, 0.004]])
    region = truth_labels.ravel()[obs.pixel]
    t = truth[region]
    mu = radiance(t[:, 0], t[:, 1], t[:, 2], obs.cos_ln, obs.cos_hn, obs.irradiance)
    scale = (mu + 0.05 * mu.mean()) / mu.mean()          # known scales (relative model, true signal)
    rng = np.random.default_rng(12)
    y = mu + np.sqrt(t[:, 3]) * scale * rng.standard_normal(obs.n_obs)
    data = dataclasses.replace(obs, y=y)
    weighted = Problem.from_observations(data, noise_scale=scale)
    state, draws = _posterior(weighted, seed=3)
    labels = state.labels
    # sampler region -> true region (by majority of observations)
    true_of_obs = truth_labels.ravel()[weighted.pixel]
    mapping = [int(np.bincount(true_of_obs[labels == r], minlength=4).argmax()) for r in range(4)]
    assert sorted(mapping) == [0, 1, 2, 3]
    # 99.5 % central intervals: under an exact posterior all 16 cover their truth with
    # probability about 0.995^16 = 92 % (fixed seeds; one miss would be a 1-in-12 event)
    lo, hi = np.quantile(draws, [0.0025, 0.9975], axis=0)
    for r, k in enumerate(mapping):
        inside = (lo[r] <= truth[k]) & (truth[k] <= hi[r])
        assert inside.all(), (r, k, truth[k], lo[r], hi[r])
    # the same data without the weights: every sigma^2 interval misses the truth (what the weights fix).
    # Unweighted, sigma^2 absorbs the varying variance (truth x mean(scale^2) = 1.76 to 2.17 per
    # region) and part of the misfit: measured posterior means 1.40 to 2.36 x truth, lowest 0.25 %
    # quantile 1.17 x truth; the closest region's mean lies about 5 posterior sd above the truth.
    _, plain_draws = _posterior(Problem.from_observations(data), seed=3, iterations=500, burn=200)
    plain_lo = np.quantile(plain_draws[:, :, 3], 0.0025, axis=0)
    assert np.all(plain_lo > truth[0, 3])
