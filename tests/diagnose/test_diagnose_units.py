"""Small, fast checks of the criticism building blocks."""
from __future__ import annotations

import numpy as np
import pytest

from rjfit.model.priors import LogitNormal, LogNormal, Normal


@pytest.mark.parametrize("prior, z", [(LogNormal(0.3, 1.2), 0.7), (LogitNormal(-1.0, 2.0), 1.3),
                                      (LogitNormal(-1.5, 2.0, low=0.01, high=1.0), -4.0), (Normal(0.0, 0.2), -0.1)])
def test_prior_density_in_unconstrained_coordinates_includes_jacobian(prior, z):
    theta = prior.to_constrained(z)
    assert np.isclose(prior.to_unconstrained(theta), z)
    lhs = prior.log_prob_unconstrained(z)
    assert np.isclose(lhs, prior.log_prob(theta) + prior.log_abs_det_jacobian(z))
    # numerical: density of theta = density of z / |d theta / d z|
    h = 1e-6
    dtheta = (prior.to_constrained(z + h) - prior.to_constrained(z - h)) / (2 * h)
    assert np.isclose(prior.log_prob(theta), lhs - np.log(abs(dtheta)), rtol=1e-6)


def test_blinn_lobe_albedo_is_one_at_normal_view_and_table_matches_quadrature():
    from rjfit.effects.ambient import lobe_albedo, lobe_albedo_quadrature

    for gamma in (1.0, 10.0, 100.0):
        assert abs(lobe_albedo_quadrature(gamma, [1.0], n_u=128, n_phi=128)[0] - 1.0) < 2e-3   # Giesen's claim
        exact = lobe_albedo_quadrature(gamma, [0.3, 0.7], n_u=128, n_phi=256)
        assert np.allclose(lobe_albedo([gamma, gamma], [0.3, 0.7]), exact, rtol=5e-3)


def test_the_shipped_albedo_table_is_the_quadratures_and_read_only():
    """ambient_albedo.npy holds albedo_table_quadrature() on the grid. Tolerance 1e-12 relative: the same sums, so
    only the libm's last bits (another machine's exp and cos) may differ; a changed grid or quadrature fails by far
    more."""
    from rjfit.effects.ambient import albedo_table, albedo_table_quadrature

    table = albedo_table()
    np.testing.assert_allclose(table, albedo_table_quadrature(), rtol=1e-12, atol=0.0,
                               err_msg="write rjfit/effects/ambient_albedo.npy again from albedo_table_quadrature()")
    assert not table.flags.writeable


def test_the_ambient_effect_interpolates_as_lobe_albedo():
    """The effect interpolates per region's gamma, then per view angle (separable bilinear):
    the same values as the table's bilinear interpolation per observation."""
    from types import SimpleNamespace

    from rjfit.effects.ambient import Ambient, lobe_albedo

    rng = np.random.default_rng(3)
    n, gammas = 5000, np.array([0.02, 0.7, 13.0, 480.0, 9000.0])     # beyond the table at both ends too
    ctx = SimpleNamespace(region=rng.integers(0, gammas.size, n), cos_vn=rng.uniform(-0.1, 1.1, n))
    terms = {"kd": rng.uniform(0, 1, n), "I0": rng.uniform(1, 2, n), "gamma_region": gammas,
             "gamma": gammas[ctx.region], "mu": np.zeros(n)}
    effect = Ambient()
    effect.apply(terms, np.array([0.5]), effect.prepare(ctx), ctx)
    expected = 0.5 * terms["I0"] * (terms["kd"] + (1 - terms["kd"]) * lobe_albedo(terms["gamma"], ctx.cos_vn))
    np.testing.assert_allclose(terms["mu"], expected, rtol=1e-12)


def test_srgb_curve_matches_colour_science():
    import colour

    from rjfit.effects.camera_srgb import srgb_encode

    x = np.linspace(0.0, 1.2, 101)
    assert np.allclose(srgb_encode(x), colour.cctf_encoding(x, function="sRGB"), atol=1e-9)


def test_helmert_basis_fixes_geometric_mean():
    from rjfit.effects.light_calibration import helmert_basis, light_scales

    basis = helmert_basis(7)
    assert np.allclose(basis.T @ basis, np.eye(6)) and np.allclose(basis.sum(axis=0), 0)
    scales = light_scales(np.random.default_rng(0).normal(size=6), 7)
    assert np.isclose(np.log(scales).mean(), 0.0)


def test_noise_estimate_ignores_smooth_misfit():
    from types import SimpleNamespace

    from rjfit.diagnose.context import Context
    from rjfit.diagnose.gap import gap, noise_variance

    rng = np.random.default_rng(1)
    L, H, W = 3, 40, 40
    yy, xx = np.mgrid[0:H, 0:W]
    valid = np.ones((L, H, W), bool)
    light, rows, cols = np.nonzero(valid)
    smooth = np.sin(xx / 7.0) + (yy / 20.0) ** 2
    residuals = 2.0 * smooth[rows, cols] + rng.normal(0, 0.3, rows.size)
    ctx = Context(dataset=SimpleNamespace(), labels=np.zeros((H, W), int), n_regions=1, region=np.zeros(rows.size, int),
                  light=light, pixel=rows * W + cols, y=residuals, cos_ln=None, cos_hn=None, irradiance=None,
                  cos_vn=None, cos_hv=None, valid=valid)
    s2 = noise_variance(ctx, residuals)
    # over 200 seeds the estimate's relative error has mean 0.002 and sd 0.032 (the smooth
    # misfit, 7 times the noise variance, does not leak in): 0.1 is 3 sd
    assert abs(s2 / 0.09 - 1) < 0.1
    # gap of pure noise: mean(r^2) / sigma^2 - 1 has sd sqrt(2 / 5000) = 0.02, so 0.1 is 5 sd
    assert abs(gap(rng.normal(0, 0.3, 5000), 0.09)) < 0.1


def test_laplace_evidence_agrees_with_importance_sampling(tmp_path):
    """The Bayes factors rest on the Laplace evidence: on a small rendered data set its value
    must agree with an importance-sampling estimate (proposal: the inflated Laplace Gaussian)
    to within 0.5 nat, for the plain model and for one with an extra effect."""
    from rjfit.diagnose.context import build_context
    from rjfit.effects import EFFECTS
    from rjfit.diagnose.evidence import evidence_by_importance_sampling
    from rjfit.diagnose.refit import refit
    from rjfit.render.datasets import load_dataset
    from rjfit.render.render import render_dataset

    dataset = load_dataset(render_dataset("paper_sphere", tmp_path / "d", resolution=24))
    ctx = build_context(dataset, dataset.truth_labels)
    plain = refit(ctx, ())
    for fit in (plain, refit(ctx, (EFFECTS["fresnel"],), start=plain)):
        log_z, se, ess = evidence_by_importance_sampling(fit, n_draws=3000)
        assert ess > 100, ess
        # 0.5 nat is about a ninth of the ln 100 threshold the Bayes factors are read against:
        # the accuracy the decision needs. The estimate's own error must be far smaller, so
        # that it cannot mask a larger gap (measured: differences 0.02 and 0.04, se 0.02-0.03).
        assert se < 0.1, se
        assert abs(log_z - fit.log_evidence) < 0.5, (log_z, fit.log_evidence, se)


def test_the_hessian_skips_only_pairs_that_never_meet(tmp_path):
    """The refit's Hessian leaves out pairs of parameters of two different regions: computed
    anyway (the full finite-difference Hessian), they are 0 up to the differences' rounding,
    while the pairs it keeps are not, for the plain model and with effects of every stage
    that shares parameters across regions (light calibration) or not (Fresnel)."""
    from rjfit.diagnose.context import build_context
    from rjfit.effects import EFFECTS
    from rjfit.diagnose.hessian import coupled_pairs, finite_difference_hessian
    from rjfit.diagnose.refit import refit
    from rjfit.render.datasets import load_dataset
    from rjfit.render.render import render_dataset

    dataset = load_dataset(render_dataset("paper_sphere", tmp_path / "d", resolution=24))
    ctx = build_context(dataset, dataset.truth_labels)
    plain = refit(ctx, ())
    for fit in (plain, refit(ctx, (EFFECTS["fresnel"], EFFECTS["light_calibration"]), start=plain)):
        problem = fit.objective
        coupled = coupled_pairs(problem)
        assert (~coupled).sum() == 16 * 4 * 3          # 4 x 4 parameters of each region with another's
        steps = np.minimum(0.05 / np.sqrt(np.diag(fit.hessian)), 0.05)
        full, _, _ = finite_difference_hessian(problem.f, fit.z, steps)
        correlation = np.abs(full) / np.sqrt(np.outer(np.diag(full), np.diag(full)))
        # rounding of f (about 1e-16 of |f|, over steps^2) gives 1e-7-sized correlations;
        # a real cross term between two regions would be of order 1 (kd-gamma: 0.9)
        assert correlation[~coupled].max() < 1e-4, correlation[~coupled].max()
        assert np.median(correlation[coupled & ~np.eye(problem.P, dtype=bool)]) > 1e-3
        # the refit's own steps differ from these (measured: 2e-5 apart at most)
        np.testing.assert_allclose(fit.hessian[coupled], full[coupled], rtol=1e-3, atol=1e-9 * np.abs(full).max())
        assert np.all(fit.hessian[~coupled] == 0.0)
        # the least-squares Jacobian differences the same parameter of every region in one
        # evaluation: it must equal the one-column-at-a-time forward differences (rows of
        # different regions never overlap, so to rounding)
        zm = fit.z[problem.mean_index]
        grouped = problem.mean_jacobian(zm, fit.z)
        per_light = sum(index.size for index, _ in problem.per_light_effects().values())
        assert len(problem.jacobian_groups()) == 3 + zm.size - 12 - per_light
        problem.jacobian_groups = lambda: [[position] for position in range(zm.size)]
        single = problem.mean_jacobian(zm, fit.z)
        np.testing.assert_allclose(grouped, single, rtol=1e-12, atol=1e-12 * np.abs(single).max())


def test_a_coarsened_refit_weighs_the_likelihood_by_its_power(tmp_path):
    """With likelihood power zeta the refit's objective is -zeta log L - log prior, so its
    Laplace Hessian is zeta times the data's part plus the prior's, and its evidence still
    agrees with importance sampling of the same (tempered) target."""
    from rjfit.diagnose.context import build_context
    from rjfit.diagnose.evidence import evidence_by_importance_sampling
    from rjfit.diagnose.refit import refit
    from rjfit.render.datasets import load_dataset
    from rjfit.render.render import render_dataset

    dataset = load_dataset(render_dataset("paper_sphere", tmp_path / "d", resolution=24))
    plain = refit(build_context(dataset, dataset.truth_labels))
    zeta = 0.25
    coarse = refit(build_context(dataset, dataset.truth_labels, likelihood_power=zeta))
    problem = coarse.objective
    z = coarse.z
    assert np.isclose(problem.f(z), -zeta * np.sum(problem.log_lik_pointwise(z)) - problem.log_prior(z), rtol=1e-12)
    # The priors are normal in the unconstrained coordinates: their Hessian is diag(1 / scale^2).
    # Predicted from the plain fit, H_zeta = zeta (H_1 - P) + P. Both are finite-difference
    # Hessians at slightly different MAPs (measured: 0.09 % apart); 1 % leaves room for that
    # and fails by far if the power is dropped anywhere (H_1 itself is 300 % away).
    prior_hessian = np.diag(1.0 / problem.scale ** 2)
    predicted = zeta * (plain.hessian - prior_hessian) + prior_hessian
    assert np.linalg.norm(coarse.hessian - predicted) < 0.01 * np.linalg.norm(predicted)
    # the same 0.5 nat as test_laplace_evidence_agrees_with_importance_sampling (measured: 0.08)
    log_z, se, ess = evidence_by_importance_sampling(coarse, n_draws=3000)
    assert ess > 100 and se < 0.1, (ess, se)
    assert abs(log_z - coarse.log_evidence) < 0.5, (log_z, coarse.log_evidence)
    with pytest.raises(ValueError, match=r"likelihood_power is 0; it must be in \(0, 1\]"):
        build_context(dataset, dataset.truth_labels, likelihood_power=0)


def test_a_refit_weighs_each_observation_by_the_noise_model_s_scale(tmp_path):
    """With known scales s_i the refit's likelihood is prod N(y_i | mu_i, sigma_r^2 s_i^2): on
    data whose noise follows the scales it recovers sigma_r^2 and its evidence beats the
    constant-noise model's; on homoscedastic data the constant model wins (negative control)."""
    import math
    from dataclasses import replace

    from rjfit.diagnose.context import build_context
    from rjfit.diagnose.refit import predictions, refit
    from rjfit.render.datasets import load_dataset
    from rjfit.render.render import render_dataset

    dataset = load_dataset(render_dataset("paper_sphere", tmp_path / "d", resolution=24, noise_variance=0.0))
    base = build_context(dataset, dataset.truth_labels)
    mu = predictions(refit(base), draws=False)               # a smooth "true" signal
    rng = np.random.default_rng(4)
    scale = np.exp(rng.uniform(np.log(0.3), np.log(3.0), base.n_obs))     # mean s^2 about 2
    sigma2 = 0.05
    noise = rng.standard_normal(base.n_obs) * math.sqrt(sigma2)
    evidence = {}
    for data, y in (("heteroscedastic", mu + scale * noise), ("homoscedastic", mu + noise)):
        for model, s in (("weighted", scale), ("constant", None)):
            ctx = replace(base, y=y, noise_scale=s, features={})
            fit = refit(ctx)
            problem = fit.objective
            # the objective is exactly the weighted Gaussian log density (+ its -log s_i)
            residuals = y - predictions(fit, draws=False)
            s2 = fit.region_params()[ctx.region, 3]
            variance = s2 * (1.0 if s is None else s ** 2)
            expected = -0.5 * np.sum(np.log(2 * math.pi * variance) + residuals ** 2 / variance)
            assert np.isclose(np.sum(problem.log_lik_pointwise(fit.z)), expected, rtol=1e-12)
            evidence[data, model] = fit.log_evidence
            # the inner solves optimise f itself: at fixed sigma^2 the least-squares cost differs
            # from f by a constant, and the sigma^2 update is f's minimum over log sigma^2
            # (a slip there would still end near the MAP after the Newton polish, only slower)
            z_other = fit.z.copy()
            z_other[problem.mean_index] += 0.01 * rng.standard_normal(problem.mean_index.size)
            offsets = [0.5 * np.sum(problem.mean_residuals(z[problem.mean_index], z) ** 2) - problem.f(z)
                       for z in (fit.z, z_other)]
            assert np.isclose(offsets[0], offsets[1], rtol=0, atol=1e-8 * abs(problem.f(fit.z))), offsets
            z_sigma = problem.update_sigma(z_other.copy())
            for index in problem.sigma_index:
                step = np.zeros(problem.P)
                step[index] = 1e-4
                slope = (problem.f(z_sigma + step) - problem.f(z_sigma - step)) / 2e-4
                assert abs(slope) < 1e-3, slope        # about 1 per unit z of a poor sigma^2 update
            if data == "heteroscedastic" and model == "weighted":
                # sigma^2's posterior sd is about sigma^2 sqrt(2 / n_r) (n_r about 900): 4 sd
                n_r = np.bincount(ctx.region)
                assert np.all(np.abs(fit.region_params()[:, 3] - sigma2) < 4 * sigma2 * np.sqrt(2.0 / n_r)), \
                    fit.region_params()[:, 3]
    assert evidence["heteroscedastic", "weighted"] - evidence["heteroscedastic", "constant"] > math.log(100), evidence
    assert evidence["homoscedastic", "constant"] - evidence["homoscedastic", "weighted"] > math.log(100), evidence


def test_hidden_ambient_is_added_before_the_camera_response():
    """With both hidden, ambient light enters the sensor's response curve (it was once dropped)."""
    from rjfit.render.hidden import hidden_post_process

    rng = np.random.default_rng(0)
    images = rng.uniform(0.0, 10.0, (2, 4, 5, 1))
    ambient = rng.uniform(0.0, 1.0, (4, 5))
    np.testing.assert_allclose(hidden_post_process(ambient, None, images), images + ambient[None, :, :, None])
    both = hidden_post_process(ambient, (np.random.default_rng(1), 0.0), images)
    camera_of_sum = hidden_post_process(None, (np.random.default_rng(1), 0.0), images + ambient[None, :, :, None])
    np.testing.assert_allclose(both, camera_of_sum)
    assert not np.allclose(both, hidden_post_process(None, (np.random.default_rng(1), 0.0), images))


def test_a_per_light_effect_is_differenced_over_its_light_values(tmp_path):
    """Light calibration acts through one value per light (log s = H theta): the refit's Hessian
    and least-squares Jacobian difference those L values, whose pairs never meet, instead of
    every pair of its L - 1 parameters. Both must equal the plain finite differences in z: the
    block Hessian the all-pairs one (measured: within 1.1e-7 of sqrt(H_ii H_jj); a pair summed
    over the wrong blocks or a missing chain-rule factor B would be of order 1, so 1e-5 holds
    only the two schemes' truncation error), its evaluations 1 + 2T + 2T(T - 1) for T types of
    parameters whatever the number of lights, and the Jacobian's calibration columns the
    one-column forward differences (measured: 2.5e-8 of the column's largest entry, both being
    forward differences with sqrt(eps) steps, whose error is of that order; 1e-5 would still
    catch a wrong light's row or a missing factor of B). The normal equations the least
    squares solve, formed from per-light sums, equal the dense Jacobian's J'J and J'r."""
    from rjfit.diagnose.context import build_context
    from rjfit.effects import EFFECTS
    from rjfit.diagnose.hessian import block_hessian, finite_difference_hessian
    from rjfit.diagnose.refit import refit
    from rjfit.render.datasets import load_dataset
    from rjfit.render.render import render_dataset

    dataset = load_dataset(render_dataset("paper_sphere", tmp_path / "d", resolution=24))
    ctx = build_context(dataset, dataset.truth_labels)
    plain = refit(ctx, ())
    fit = refit(ctx, (EFFECTS["fresnel"], EFFECTS["ambient"], EFFECTS["light_calibration"]), start=plain)
    problem = fit.objective
    steps = np.minimum(0.05 / np.sqrt(np.diag(fit.hessian)), 0.05)
    full, _, f_full = finite_difference_hessian(problem.f, fit.z, steps)
    evaluations = []
    pointwise = problem.log_lik_pointwise
    problem.log_lik_pointwise = lambda *args: evaluations.append(1) or pointwise(*args)
    block, _, f_block = block_hessian(problem, fit.z, steps)
    problem.log_lik_pointwise = pointwise
    scale = np.sqrt(np.outer(np.diag(full), np.diag(full)))
    assert np.abs(block - full).max() / scale.max() < 1e-5
    assert (np.abs(block - full) / scale).max() < 1e-5, (np.abs(block - full) / scale).max()
    types = 4 + 2 + 1             # the region parameters, Fresnel's and ambient's, the light values
    assert len(evaluations) == 1 + 2 * types + 2 * types * (types - 1) + 1     # + f(z) itself
    assert f_block == f_full
    # the Jacobian's calibration columns against one-column forward differences in z
    zm = fit.z[problem.mean_index]
    grouped = problem.mean_jacobian(zm, fit.z)
    (index, _), = problem.per_light_effects().values()
    columns = [int(np.flatnonzero(problem.mean_index == i)[0]) for i in index]
    r0 = problem.mean_residuals(zm, fit.z)
    eps_step = np.sqrt(np.finfo(float).eps)
    for column in columns[:: max(1, len(columns) // 4)]:
        shifted = zm.copy()
        shifted[column] += eps_step * max(1.0, abs(zm[column]))
        single = (problem.mean_residuals(shifted, fit.z) - r0) / (shifted[column] - zm[column])
        difference = np.abs(grouped[:, column] - single).max() / np.abs(single).max()
        assert difference < 1e-5, (problem.names[problem.mean_index[column]], difference)
    # the least squares' normal equations, formed without the calibration's dense columns,
    # equal the dense Jacobian's products to rounding
    normal, gradient = problem.mean_normal_equations(zm, r0, fit.z)
    np.testing.assert_allclose(normal, grouped.T @ grouped, rtol=1e-9, atol=1e-12 * np.abs(normal).max())
    np.testing.assert_allclose(gradient, grouped.T @ r0, rtol=1e-9, atol=1e-12 * np.abs(gradient).max())


def test_a_fit_s_loo_and_mean_prediction_are_computed_once_and_keep_no_draw_arrays(tmp_path):
    """The diagnosis' candidate threads all ask for the current model's LOO: it is computed
    once (the pointwise log-likelihood of the draws evaluated once per draw, counted) and the
    same result returned to every thread; afterwards the fit keeps no (draws, observations)
    array (1.1 GB each on the measured ball). The mean prediction, summed draw by draw, equals
    the mean of the stacked predictions exactly (the same additions in the same order)."""
    from concurrent.futures import ThreadPoolExecutor

    from rjfit.diagnose.context import build_context
    from rjfit.diagnose.loo import refit_loo
    from rjfit.diagnose.refit import posterior_mean_prediction, predictions, refit
    from rjfit.render.datasets import load_dataset
    from rjfit.render.render import render_dataset

    dataset = load_dataset(render_dataset("paper_sphere", tmp_path / "d", resolution=24))
    fit = refit(build_context(dataset, dataset.truth_labels), (), n_draws=20)
    problem = fit.objective
    calls = []
    evaluate = problem.log_lik_pointwise
    problem.log_lik_pointwise = lambda z: calls.append(1) or evaluate(z)
    with ThreadPoolExecutor(max_workers=4) as pool:
        results = list(pool.map(lambda _: refit_loo(fit), range(4)))
    assert len(calls) == len(fit.draws)
    assert all(result is results[0] for result in results)
    n_obs = problem.ctx.y.size
    held = [key for key, value in fit._cache.items() if isinstance(value, np.ndarray) and value.size >= 2 * n_obs]
    assert not held, held
    # two code paths (a running sum draw by draw; NumPy's mean of the stacked draws): each is a sum of
    # S = 20 non-negative predictions, within (S - 1) u of the exact one (u = eps / 2), then one division
    np.testing.assert_allclose(posterior_mean_prediction(fit), predictions(fit).mean(axis=0),
                               rtol=len(fit.draws) * np.finfo(float).eps, atol=0)


def test_loo_difference_reports_the_share_of_observations_with_an_unreliable_k_hat(tmp_path):
    """The threshold is ArviZ's ``good_k`` for the number of draws (0.5 for 100, 0.7 from
    10^(10/3) draws up); an observation counts as unreliable where either model's k-hat
    exceeds it. On a measured stack many may (the ball's highlight peak): the report says how many."""
    import arviz as az

    from rjfit.diagnose.context import build_context
    from rjfit.effects import EFFECTS
    from rjfit.diagnose.loo import loo_difference, refit_loo
    from rjfit.diagnose.psis import good_k_threshold
    from rjfit.diagnose.refit import refit
    from rjfit.render.datasets import load_dataset
    from rjfit.render.render import render_dataset

    rng = np.random.default_rng(0)
    for n_draws in (100, 400, 4000):
        log_lik = rng.normal(size=(1, n_draws, 30))
        data = az.from_dict(posterior={"x": rng.normal(size=(1, n_draws))}, log_likelihood={"y": log_lik})
        assert np.isclose(good_k_threshold(n_draws), az.loo(data, pointwise=True).good_k)
    assert np.isclose(good_k_threshold(100), 0.5)

    dataset = load_dataset(render_dataset("paper_sphere", tmp_path / "d", resolution=24))
    ctx = build_context(dataset, dataset.truth_labels)
    plain = refit(ctx, ())
    fresnel = refit(ctx, (EFFECTS["fresnel"],), start=plain)
    delta, se, max_khat, unreliable, delta_reliable, se_reliable = loo_difference(fresnel, plain)
    khat = np.maximum(refit_loo(fresnel).pareto_k, refit_loo(plain).pareto_k)
    assert max_khat == khat.max()
    assert unreliable == np.mean(khat > 0.5)
    assert np.isclose(delta, refit_loo(fresnel).elpd - refit_loo(plain).elpd)
    # the same sum and SE over the observations where neither k-hat exceeds the threshold (a trial's support)
    diff, reliable = refit_loo(fresnel).pointwise - refit_loo(plain).pointwise, khat <= 0.5
    assert np.isclose(delta_reliable, diff[reliable].sum())
    assert np.isclose(se_reliable, np.sqrt(reliable.sum()) * diff[reliable].std())

    # decisive: 4 SE over all observations; supported (a possible trial): a positive gain over the reliable ones
    from rjfit.diagnose.candidates import judged_fields

    def judged(loo):
        fields = judged_fields(fresnel, plain, ("fresnel",), loo, -np.inf, 4.0)     # every log BF passes the bar
        return fields["decisive"], fields["supported"]

    assert judged((21.0, 5.0, 3.0, 0.1, 21.0, 5.0)) == (True, True)
    assert judged((10.0, 5.0, 3.0, 0.1, 1.0, 4.0)) == (False, True)
    assert judged((11.0, 5.0, 3.0, 0.1, -1.0, 4.0)) == (False, False)     # 2.2 SE over all, negative where reliable


def test_a_bounded_logit_normal_stays_within_its_bounds():
    """Fresnel's F0 lives on (0.01, 1): however far the data pull its coordinate, F0 stays
    above the floor (on the measured ball an unbounded F0 went to 0.0000)."""
    from rjfit.effects.fresnel import F0_MIN, Fresnel

    (param,) = Fresnel().params(None)
    z = np.array([-40.0, -10.0, 0.0, 10.0, 40.0])
    f0 = param.prior.to_constrained(z)
    assert np.all(f0 >= F0_MIN) and np.all(f0 <= 1.0) and np.all(np.diff(f0) >= 0)
    assert np.isclose(param.prior.to_constrained(param.prior.loc), 0.2)        # centred on F0 = 0.2
    assert np.isclose(param.prior.to_unconstrained(0.04), param.prior.to_unconstrained(np.array([0.04]))[0])


def test_prior_data_conflicts_are_the_effect_parameters_beyond_3_prior_sd_away_from_the_null():
    """Flagged: an effect parameter more than 3 prior sd from its prior's centre, unless it lies
    on the way to the parameter's null (an ambient term at 2e-6 says "no ambient", not that it
    stands in for another effect); a parameter whose null is only a limit is flagged either way."""
    from types import SimpleNamespace

    from rjfit.diagnose.candidates import PRIOR_CONFLICT_SD, prior_conflicts
    from rjfit.diagnose.document import candidate_line, prior_conflict_text
    from rjfit.effects.base import Param

    fresnel = [Param("F0", LogitNormal(-1.0, 2.0), init=0.5, null=1.0),          # null at z = +inf
               Param("far_side", LogitNormal(-1.0, 2.0), init=0.5, null=1.0),
               Param("near", LogNormal(1.0, 0.5), init=1.0, null=None),
               Param("limit_only", LogNormal(0.0, 1.0), init=1.0, null=None)]
    ambient = [Param("ambient", LogNormal(-4.6, 2.0), init=0.01, null=0.0)]      # null at z = -inf
    z = np.array([9.0, 0, 0, 0,                      # one region's I0, kd, gamma, sigma2: never flagged
                  -1.0 - 2.0 * 3.5,                 # F0: 3.5 sd towards 0, away from its null
                  -1.0 + 2.0 * 3.5,                 # 3.5 sd towards its null F0 = 1: not flagged
                  1.0 + 0.5 * 2.5,                  # 2.5 sd: not flagged
                  -4.0,                             # 4 sd, null only a limit: flagged
                  -4.6 - 2.0 * 5.0])                # ambient 5 sd towards its null 0: not flagged
    effects = [SimpleNamespace(name="fresnel"), SimpleNamespace(name="ambient")]
    conflicts = prior_conflicts(z, 1, effects, [fresnel, ambient], "fresnel")
    assert PRIOR_CONFLICT_SD == 3.0
    assert [c["param"] for c in conflicts] == ["fresnel.F0", "fresnel.limit_only"]
    assert np.allclose([c["prior_sd_from_centre"] for c in conflicts], [3.5, 4.0])
    assert np.isclose(conflicts[0]["map"], fresnel[0].prior.to_constrained(z[4]))
    assert prior_conflicts(z, 1, effects, [fresnel, ambient], "ambient") == []
    row = {"step": 0, "effect": "fresnel", "log_bayes_factor": 12.0, "loo_skipped": "x", "prior_conflict": conflicts}
    assert prior_conflict_text(conflicts[0]) in candidate_line(row)
    assert "3.5 prior sd" in candidate_line(row)


def test_diagnosis_md_warns_of_prior_conflicts_and_unreliable_loo():
    from rjfit.diagnose.document import markdown

    conflict = {"param": "fresnel.F0", "map": 0.0101, "prior_sd_from_centre": 4.2}
    row = {"step": 0, "effect": "fresnel", "kind": "Fresnel reflection", "log_bayes_factor": 50.0,
           "delta_elpd_loo": 80.0, "delta_elpd_loo_se": 9.0, "max_khat": 0.9, "khat_unreliable_fraction": 0.031,
           "signature_score": 0.2, "gap_with_effect": 1.5, "decisive": True, "prior_conflict": [conflict]}
    step = {"effect": "fresnel", "evidence": {"log_bayes_factor": 50.0, "delta_elpd_loo": 80.0, "delta_elpd_loo_se": 9.0},
            "gap_before": 2.0, "gap_after": 1.5, "prior_conflict": [conflict]}
    result = {"dataset": "d", "named_effects": ["fresnel"], "gap_definition": "g", "decision_rule": "r",
              "gap_plain": 2.0, "gap_final": 1.5, "noise_variance_estimate": 1.0, "steps": [step], "candidates": [row],
              "search": {"stopped": "x"}, "per_region_gap": {"plain": [2.0], "final": [1.5]},
              "thresholds": {"prior_conflict_sd": 3.0}}
    text = markdown(result)
    assert "**Warning**, prior-data conflict: fresnel.F0 = 0.0101 lies 4.2 prior sd from its prior's centre" in text
    assert "more than 3.0 prior sd" in text and "- step 1, fresnel (decisive): prior-data conflict" in text
    assert "| 0.90 | 3.1 % |" in text and "for up to 3.1 % of them (step 1, fresnel)" in text


def test_compiled_shadowing_masking_equals_the_numpy_smith_terms_bit_for_bit():
    """The masking effect's compiled pass (one per refit evaluation) against the NumPy form it
    replaced, over tangents from 0 (a = inf, G1 = 1) to grazing, both branches of Walter's fit
    (a < 1.6 and a >= 1.6) and roughnesses of sharp and broad lobes."""
    from rjfit.effects.masking import beckmann_alpha, shadowing_masking, smith_g1_tan, tangent

    rng = np.random.default_rng(5)
    n = 20000
    cos_v, cos_l = rng.uniform(-0.05, 1.0, n), rng.uniform(0.0, 1.0, n)
    cos_v[:3] = (1.0, 0.0, 1e-9)
    tan_v, tan_l = tangent(cos_v), tangent(cos_l)
    alpha_region = beckmann_alpha(np.array([0.2, 3.0, 80.0, 2000.0]))
    region = rng.integers(0, 4, n)
    alpha = alpha_region[region]
    expected = smith_g1_tan(tan_v, alpha) * smith_g1_tan(tan_l, alpha)
    a = 1.0 / np.maximum(alpha * tan_v, 1e-12)
    assert (a < 1.6).sum() > 1000 and (a >= 1.6).sum() > 1000       # both branches exercised
    np.testing.assert_array_equal(shadowing_masking(tan_v, tan_l, alpha_region, region), expected)


def test_the_plain_prediction_is_eq_2_of_the_model_layer():
    """The extended closed form with no effect is rjfit.model.blinn's eq. 2: its lobe N(g) <h.n>^g
    (from log <h.n> cached per context) equals blinn_normalisation times log_cos_power to the last
    bit, over <h.n> from negative (lobe 0) through 0 to 1 and exponents from 0.4 to 900; its
    prediction equals radiance() to rounding (rtol 1e-14: the same products in another order,
    a few ulps; rjfit/diagnose/model.py says why it is written out). 4,000 random observations,
    no rendering: a fraction of a second."""
    from types import SimpleNamespace

    from rjfit.diagnose.context import Context
    from rjfit.diagnose.model import predict
    from rjfit.model.blinn import blinn_normalisation, log_cos_power, radiance

    rng = np.random.default_rng(7)
    n = 4000
    region = rng.integers(0, 3, n)
    cos_hn, cos_ln = rng.uniform(-0.2, 1.0, n), rng.uniform(-0.2, 1.0, n)
    cos_hn[:5] = (0.0, 1.0, -0.0, 1e-300, 0.5)
    irradiance = rng.uniform(0.5, 2.0, n)
    params = np.array([[50.0, 0.3, 12.0, 1.0], [20.0, 0.8, 0.4, 1.0], [80.0, 0.05, 900.0, 1.0]])
    ctx = Context(dataset=SimpleNamespace(), labels=np.zeros((40, 100), int), n_regions=3, region=region,
                  light=np.zeros(n, int), pixel=np.arange(n), y=np.zeros(n), cos_ln=cos_ln, cos_hn=cos_hn,
                  irradiance=irradiance, cos_vn=None, cos_hv=None, valid=np.ones((1, 40, 100), bool))
    lobes = []
    recorder = SimpleNamespace(stage="lobe", apply=lambda terms, theta, features, ctx: lobes.append(terms["spec"].copy()))
    mu = predict(ctx, [recorder], params, [np.zeros(0)], [None])
    gamma = params[region, 2]
    expected_lobe = blinn_normalisation(params[:, 2])[region] * log_cos_power(cos_hn, gamma)
    assert (expected_lobe == 0).sum() > 100 and (expected_lobe > 0).sum() > 1000      # both branches
    np.testing.assert_array_equal(lobes[0], expected_lobe)
    expected = radiance(params[region, 0], params[region, 1], gamma, cos_ln, cos_hn, irradiance)
    np.testing.assert_allclose(mu, expected, rtol=1e-14, atol=0)
    np.testing.assert_array_equal(predict(ctx, [], params, [], []), mu)


def test_a_weight_at_its_physical_end_is_not_a_prior_data_conflict():
    """cast_shadows w = 1 (full occlusion) and masking w = 0.999 are physical values: far out on the
    logit scale of their LogitNormal(0, 2) priors (w = 0.999 is 3.45 sd) but no conflict; the same
    distance towards an end that is not physical (Fresnel's floor F0_MIN) still is one."""
    from types import SimpleNamespace

    from rjfit.diagnose.candidates import prior_conflicts
    from rjfit.effects import get_effect

    ctx = SimpleNamespace(n_lights=3)
    shadows, masking, fresnel = (get_effect(name).params(ctx) for name in ("cast_shadows", "masking", "fresnel"))
    effects = [SimpleNamespace(name=name) for name in ("cast_shadows", "masking", "fresnel")]
    to_z = [p.prior.to_unconstrained for p in (shadows[0], masking[0], fresnel[0])]
    f0_floor = float(fresnel[0].prior.to_constrained(fresnel[0].prior.loc - 4.0 * fresnel[0].prior.scale))
    z = np.array([0.0, 0, 0, 0, to_z[0](1.0 - 1e-9), to_z[1](0.999), to_z[2](f0_floor)])
    params = [shadows, masking, fresnel]
    assert abs(z[5] - masking[0].prior.loc) / masking[0].prior.scale > 3.0       # beyond the 3-sd rule
    assert prior_conflicts(z, 1, effects, params, "cast_shadows") == []
    assert prior_conflicts(z, 1, effects, params, "masking") == []
    assert [c["param"] for c in prior_conflicts(z, 1, effects, params, "fresnel")] == ["fresnel.F0"]


def test_the_misfit_description_says_so_when_the_fit_left_the_rim_out(tmp_path):
    """Under the rim rule (--max-view-angle, --preset measured) a diagnosis sees no grazing
    observation: the description says the rim was left out instead of printing 'n/a vs ...'."""
    import dataclasses

    from rjfit.diagnose.context import build_context
    from rjfit.diagnose.misfit import describe_misfit
    from rjfit.render.datasets import load_dataset
    from rjfit.render.render import render_dataset

    dataset = load_dataset(render_dataset("paper_sphere", tmp_path / "d", resolution=12))
    for max_view_angle, rim_seen in ((None, True), (72.5, False)):
        seen = dataset if max_view_angle is None else dataclasses.replace(dataset, max_view_angle=max_view_angle)
        ctx = build_context(seen, seen.truth_labels)
        residuals = np.random.default_rng(0).normal(size=ctx.y.shape)
        described = describe_misfit(ctx, residuals, 1.0)
        assert (described["rim"] is not None) == rim_seen
        assert ("n/a" in described["text"]) is False
        assert ("the rim left out of the fit" in described["text"]) == (not rim_seen)
