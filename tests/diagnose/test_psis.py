"""The vectorised PSIS-LOO against ArviZ's ``az.loo`` / ``az.psislw`` and an exact leave-one-out."""
from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from rjfit.diagnose.psis import psis_loo, psis_smooth


def _arviz_loo(log_lik):
    import arviz as az

    idata = az.from_dict(posterior={"z": np.zeros((1, log_lik.shape[0]))}, log_likelihood={"y": log_lik[None]})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")          # its k-hat warning: the heavy tails below are on purpose
        return az.loo(idata, pointwise=True)


def _heavy_tailed_log_lik(n_draws, n_obs, seed):
    """A location-scale model's draws against Student-t data: k-hats from about 0 to far above 0.7."""
    rng = np.random.default_rng(seed)
    z = rng.standard_normal((n_draws, 1))
    y = rng.standard_t(3, n_obs)
    log_scale = 0.2 * z
    return -0.5 * math.log(2 * math.pi) - log_scale - 0.5 * (y[None] - 0.3 * z) ** 2 / np.exp(2 * log_scale)


@pytest.mark.parametrize("n_draws", [100, 37])
def test_psis_loo_equals_arviz(n_draws):
    # Same estimator, vectorised: agreement to rounding (1e-9 nat per observation), over
    # observations whose k-hat ranges from about 0 to beyond 1 (the smoothing then matters).
    log_lik = _heavy_tailed_log_lik(n_draws, 3000, seed=3)
    ours = psis_loo(log_lik, block_size=700)            # several blocks, the last one short
    theirs = _arviz_loo(log_lik)
    k_theirs = np.asarray(theirs.pareto_k)
    assert k_theirs.min() < 0.3 and k_theirs.max() > 1.0
    np.testing.assert_allclose(ours.pointwise, np.asarray(theirs.loo_i), rtol=0, atol=1e-9)
    np.testing.assert_allclose(ours.pareto_k, k_theirs, rtol=0, atol=1e-9)
    assert ours.elpd == pytest.approx(float(theirs.elpd_loo), abs=1e-7)
    assert ours.se == pytest.approx(float(theirs.se), rel=1e-9)


def test_ties_at_the_cutoff_shorten_the_tail_as_in_arviz():
    # 14 distinct draws repeated 7 times (98 draws): the 20-draw tail's cutoff sits inside a
    # run of 7 ties, so only the 14 draws strictly above it are smoothed, as az.psislw does.
    import arviz as az

    log_lik = np.repeat(_heavy_tailed_log_lik(14, 400, seed=5), 7, axis=0)
    weights, khat, order = psis_smooth(-log_lik.T)
    ref_weights, ref_khat = az.psislw(-log_lik.T)
    np.testing.assert_allclose(khat, np.asarray(ref_khat), rtol=0, atol=1e-9)
    # tied ratios get different smoothed weights in an order that may differ from ArviZ's;
    # the weights as a multiset (and hence every weighted sum over tied draws) agree
    np.testing.assert_allclose(np.sort(weights, axis=1), np.sort(np.asarray(ref_weights), axis=1), rtol=0, atol=1e-9)
    ours, theirs = psis_loo(log_lik), _arviz_loo(log_lik)
    np.testing.assert_allclose(ours.pointwise, np.asarray(theirs.loo_i), rtol=0, atol=1e-9)


def test_a_coarsened_posterior_leaves_out_with_the_likelihood_to_its_power():
    # Oracle: ArviZ's smoothing of the ratios p^-zeta, then the weighted predictive density.
    import arviz as az
    from scipy.special import logsumexp

    log_lik = _heavy_tailed_log_lik(100, 500, seed=7)
    zeta = 0.3
    log_weights, _ = az.psislw(-zeta * log_lik.T)
    expected = logsumexp(np.asarray(log_weights) + log_lik.T, axis=1)
    ours = psis_loo(log_lik, likelihood_power=zeta)
    np.testing.assert_allclose(ours.pointwise, expected, rtol=0, atol=1e-9)
    # and it is not the plain estimator
    assert np.max(np.abs(ours.pointwise - psis_loo(log_lik).pointwise)) > 1e-3


def test_psis_loo_matches_the_exact_leave_one_out_of_a_conjugate_model():
    # y_i ~ N(mu, 1), mu ~ N(0, 10^2): exact posterior draws of mu, and the exact LOO predictive
    # density N(y_i | m_-i, 1 + v_-i) in closed form. Tolerance: 4 delta-method standard errors
    # of each self-normalised importance-sampling estimate (computed from its own weights),
    # so a false alarm somewhere among the 40 observations has probability below 0.3 %.
    rng = np.random.default_rng(11)
    n, n_draws, prior_var = 40, 4000, 100.0
    y = rng.normal(1.5, 1.0, n)
    y[0] = 6.0                                  # one influential observation
    post_var = 1.0 / (1.0 / prior_var + n)
    mu = rng.normal(post_var * y.sum(), math.sqrt(post_var), n_draws)
    log_lik = -0.5 * math.log(2 * math.pi) - 0.5 * (y[None] - mu[:, None]) ** 2
    var_loo = 1.0 / (1.0 / prior_var + n - 1)
    mean_loo = var_loo * (y.sum() - y)
    exact = -0.5 * np.log(2 * math.pi * (1.0 + var_loo)) - 0.5 * (y - mean_loo) ** 2 / (1.0 + var_loo)

    loo = psis_loo(log_lik)
    weights, _, order = psis_smooth(-log_lik.T)
    density = np.exp(np.take_along_axis(log_lik.T, order, axis=1) - loo.pointwise[:, None])
    se = np.sqrt(np.sum(np.exp(2 * weights) * (density - 1.0) ** 2, axis=1))
    assert np.all(np.abs(loo.pointwise - exact) < 4 * se), np.max(np.abs(loo.pointwise - exact) / se)
    assert np.all(loo.pareto_k < 0.7)
    # negative control: the in-sample density (no leaving out) misses the influential one
    in_sample = np.log(np.mean(np.exp(log_lik), axis=0))
    assert abs(in_sample[0] - exact[0]) > 10 * se[0]


@pytest.mark.parametrize("log_lik, power, message", [
    (np.zeros((4, 10)), 1.0, "at least 5 draws"),
    (np.zeros(10), 1.0, "at least 5 draws"),
    (np.full((10, 3), np.nan), 1.0, "non-finite"),
    (np.zeros((10, 3)), 0.0, "likelihood_power"),
])
def test_psis_loo_refuses_what_it_cannot_estimate(log_lik, power, message):
    with pytest.raises(ValueError, match=message):
        psis_loo(log_lik, likelihood_power=power)
