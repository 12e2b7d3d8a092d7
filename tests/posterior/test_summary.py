"""Summaries of a fit on inputs with known answers: convergence warnings (chains with known
properties), the truth flags of a labelling, label accuracy after matching, region quantiles."""
import numpy as np
import pytest

from rjfit.posterior.summary import ESS_PER_CHAIN_MIN, RHAT_MAX, convergence_warnings, diagnostics

AGREE = [{"(1,1)": 0.97, "(1,2)": 0.03}] * 4


def _iid_chains(rng, n_chains=4, draws=1000):
    # 4 regions x 4 parameters, independent standard normal draws
    return [rng.normal(size=(draws, 4, 4)) for _ in range(n_chains)]


def test_well_mixed_chains_give_no_warning():
    # iid draws: ESS ~ 4000 >> 400; split R-hat of 4 x 1000 iid draws scatters about 1 by ~0.001
    # (sd of R-hat - 1 ~ 1 / n_draws), so 1.01 is some ten sd away for each of the 16 parameters.
    diag = diagnostics(_iid_chains(np.random.default_rng(0)))
    assert diag["rhat_max"] < RHAT_MAX and diag["ess_bulk_min"] > 4 * ESS_PER_CHAIN_MIN
    assert convergence_warnings(diag, AGREE, 4) == []


def test_a_shifted_chain_is_caught_by_rhat():
    chains = _iid_chains(np.random.default_rng(1))
    chains[2] = chains[2] + 1.0          # one chain one sd away: R-hat about 1.1
    warnings = convergence_warnings(diagnostics(chains), AGREE, 4)
    assert any(w.startswith("R-hat max") for w in warnings), warnings


def test_a_sticky_chain_is_caught_by_ess():
    rng = np.random.default_rng(2)
    chains = []
    for _ in range(4):
        # AR(1) with phi = 0.995: ESS per 1000 draws about 1000 (1 - phi) / (1 + phi) = 2.5 per chain
        x = np.empty((1000, 4, 4))
        x[0] = rng.normal(size=(4, 4))
        for t in range(1, 1000):
            x[t] = 0.995 * x[t - 1] + np.sqrt(1 - 0.995 ** 2) * rng.normal(size=(4, 4))
        chains.append(x)
    warnings = convergence_warnings(diagnostics(chains), AGREE, 4)
    assert any(w.startswith("ESS min") for w in warnings), warnings


def test_chains_in_different_models_are_named():
    rng = np.random.default_rng(3)
    chain_models = [{"(1,2)": 1.0}, {"(2,1)": 0.98, "(1,2)": 0.02}]
    # the MAP model's draws come from one chain only (the other never visits it)
    diag = diagnostics([rng.normal(size=(500, 6, 4)), np.empty((0, 6, 4))])
    warnings = convergence_warnings(diag, chain_models, 2)
    assert any("disagree" in w and "chain 0: (1,2) (1.00)" in w and "chain 1: (2,1) (0.98)" in w for w in warnings)
    assert any("only 1 of 2 chains" in w for w in warnings), warnings


def test_disagreeing_chains_say_which_sits_highest_in_the_target():
    """With each chain's mean log posterior the warning names the chain whose model the target
    favours and by how much (the DiLiGenT ball under --preset measured: chain 1 in K = 3 sat
    1,370 above the chains in K = 1, which the pooled posterior made the MAP)."""
    chain_models = [{"1": 0.9, "2": 0.1}, {"3": 1.0}, {"1": 1.0}]
    diag = diagnostics(_iid_chains(np.random.default_rng(6), n_chains=3))
    warnings = convergence_warnings(diag, chain_models, 3, [-165221.8, -163879.5, -165255.9])
    disagree = [w for w in warnings if "disagree" in w]
    assert len(disagree) == 1
    assert "chain 1's draws (model 3) have the highest mean log posterior, 1376 above chain 2's (model 1)" in disagree[0]
    # a chain without kept draws (NaN) leaves the comparison out rather than print a NaN
    plain = convergence_warnings(diag, chain_models, 3, [-1.0, float("nan"), -2.0])
    assert not any("highest mean log posterior" in w for w in plain) and any("disagree" in w for w in plain)


def test_chains_that_each_visit_both_models_do_not_disagree():
    # a genuinely bimodal model posterior: each chain's most frequent model is a coin flip,
    # but their frequencies agree (total variation 0.04 << 0.5)
    chain_models = [{"(1,1)": 0.52, "(1,2)": 0.48}, {"(1,2)": 0.50, "(1,1)": 0.50}, {"(1,1)": 0.54, "(1,2)": 0.46}]
    diag = diagnostics(_iid_chains(np.random.default_rng(5), n_chains=3))
    assert convergence_warnings(diag, chain_models, 3) == []


def test_one_chain_is_flagged():
    diag = diagnostics(_iid_chains(np.random.default_rng(4), n_chains=1))
    warnings = convergence_warnings(diag, AGREE[:1], 1)
    assert len(warnings) == 1 and warnings[0].startswith("one chain only")


def _recorder_on_a_small_sphere():
    from rjfit.data.synthetic import sphere_stack
    from rjfit.sampler.forward import Problem
    from rjfit.sampler.priors import make_prior
    from rjfit.sampler.runner import ChainRecorder, ChainSpec
    from rjfit.sampler.state import SamplerConfig

    obs, truth, _ = sphere_stack(24, n_lights=4, seed=1)
    problem = Problem.from_observations(obs)
    spec = ChainSpec(problem=problem, prior=make_prior("default"), config=SamplerConfig.from_flat(max_u=2, max_v=2), seed=0,
                     chain=0, n_chains=1, iterations=10, cp_thin=1, truth_labels=truth)
    return ChainRecorder(spec), problem, truth


def test_truth_flags_of_labellings_with_known_answers():
    """ChainRecorder.exact: exact partition, 'true regions' (one region per true region and
    >= 99 % agreement after matching) and the count of regions holding object pixels."""
    from rjfit.sampler.runner import TRUE_REGIONS_AGREEMENT

    recorder, problem, truth = _recorder_on_a_small_sphere()
    observed = np.zeros(truth.shape, bool)
    observed[problem.row, problem.col] = True
    object_pixels = np.argwhere(observed & (truth >= 0))

    def flags(pixel_labels):
        return recorder.exact(pixel_labels[problem.row, problem.col].astype(np.int8))

    renamed = np.where(truth >= 0, (truth + 2) % 4, 0)            # the truth under other region names
    assert flags(renamed) == (1, 1, 4)

    def with_wrong(fraction):
        labels = renamed.copy()
        count = int(fraction * len(object_pixels))
        for row, col in object_pixels[:count]:
            labels[row, col] = (labels[row, col] + 1) % 4
        return labels, count

    few, count = with_wrong(0.005)                                 # 99.5 % agree: not exact, true regions
    assert count >= 1 and flags(few) == (0, 1, 4)
    many, _ = with_wrong(2 * (1 - TRUE_REGIONS_AGREEMENT))         # 98 % agree: neither
    assert flags(many) == (0, 0, 4)
    extra = renamed.copy()
    row, col = object_pixels[0]
    extra[row, col] = 4                                            # a fifth region with one object pixel
    assert flags(extra) == (0, 0, 5)


def test_label_accuracy_matches_regions_before_counting():
    from rjfit.posterior.summary import label_accuracy

    truth = np.array([[0, 0, 1, 1], [2, 2, 3, 3], [-1, -1, -1, -1]])
    renamed = np.where(truth >= 0, 3 - truth, 7)                   # off-object labels do not count
    result = label_accuracy(renamed, truth)
    assert result["accuracy"] == 1.0 and result["matching"] == {3: 0, 2: 1, 1: 2, 0: 3}
    one_wrong = renamed.copy()
    one_wrong[0, 0] = 0
    assert label_accuracy(one_wrong, truth)["accuracy"] == 7 / 8


def test_region_summaries_are_the_pooled_draws_quantiles():
    from rjfit.posterior.summary import region_summaries

    rng = np.random.default_rng(3)
    chains = [rng.normal(size=(500, 2, 4)) + np.arange(4) for _ in range(3)]
    labels = np.array([[0, 0, 1], [1, 1, -1]])
    summaries = region_summaries(chains, labels)
    pooled = np.concatenate(chains)
    assert [s["pixels"] for s in summaries] == [2, 3]
    for r, summary in enumerate(summaries):
        for k, name in enumerate(("I0", "kd", "gamma", "sigma2")):
            values = pooled[:, r, k]
            assert summary[name]["mean"] == pytest.approx(values.mean(), rel=1e-12)
            assert summary[name]["sd"] == pytest.approx(values.std(ddof=1), rel=1e-6)
            assert summary[name]["q2.5"] == pytest.approx(np.quantile(values, 0.025), rel=1e-12)
            assert summary[name]["q97.5"] == pytest.approx(np.quantile(values, 0.975), rel=1e-12)


def test_trace_limits_span_the_kept_draws_not_the_burn_in():
    """traces.png scales each panel to the kept draws: a wild burn-in no longer flattens them."""
    from rjfit.posterior.figures import kept_draw_limits

    rng = np.random.default_rng(3)
    burn = 100
    chains = [np.concatenate([rng.normal(0, 50, burn), rng.normal(0.5, 0.01, 200)]) for _ in range(2)]
    chains[1][150:170] = np.nan                               # iterations in another model
    low, high = kept_draw_limits(chains, burn)
    kept = np.concatenate([c[burn:] for c in chains])
    kept = kept[np.isfinite(kept)]
    span = kept.max() - kept.min()
    assert low < kept.min() and high > kept.max()              # no kept draw is cut off
    assert np.isclose(low, kept.min() - 0.1 * span) and np.isclose(high, kept.max() + 0.1 * span)
    assert high - low < 0.01 * (np.nanmax(chains[0]) - np.nanmin(chains[0]))   # the burn-in is what is cut
    constant = kept_draw_limits([np.full(10, 2.0)], 5)
    assert constant[0] < 2.0 < constant[1]
    assert kept_draw_limits([np.full(10, np.nan)], 5) is None
    assert kept_draw_limits([np.arange(10.0)], 10) is None       # nothing kept


def _cp_record(x_u, draws, height=4, width=6, iterations=20, burn=10):
    """A chain record in model (1, 0) whose one u vector stands straight at column position x_u."""
    from types import SimpleNamespace

    snapshots = np.arange(burn, iterations)
    return SimpleNamespace(n_u=np.ones(iterations, int), n_v=np.zeros(iterations, int), cp_iteration=snapshots,
                           cp_u=np.full((len(snapshots), height, 1), float(x_u)),
                           cp_v=np.zeros((len(snapshots), width, 0)), theta=None, draws=draws)


def test_chain_region_summaries_keep_each_chain_s_mode_apart():
    """Two chains in different modes: pooled, region 0 is a mixture; per chain, each its own pixels and values."""
    from rjfit.posterior.summary import chain_region_summaries, region_summaries

    rng = np.random.default_rng(5)
    draws = [rng.normal(size=(300, 2, 4)) * 0.01 + 1.0, rng.normal(size=(300, 2, 4)) * 0.01 + 5.0,
             rng.normal(size=(1, 2, 4))]                           # the third: too few draws to summarise
    records = [_cp_record(2.0, draws[0]), _cp_record(4.0, draws[1]), _cp_record(3.0, draws[2])]
    per_chain = chain_region_summaries(records, draws, 10, (1, 0), (4, 6))
    assert [c["chain"] for c in per_chain] == [0, 1] and [c["draws"] for c in per_chain] == [300, 300]
    assert [r["pixels"] for r in per_chain[0]["regions"]] == [8, 16]     # cut after column 1
    assert [r["pixels"] for r in per_chain[1]["regions"]] == [16, 8]     # cut after column 3
    for chain in (0, 1):                                                # the chain's own draws, summarised alone
        own = region_summaries([draws[chain]])
        for r in range(2):
            assert all(per_chain[chain]["regions"][r][p] == own[r][p] for p in ("I0", "kd", "gamma", "sigma2"))
    pooled = region_summaries(draws[:2])[0]["kd"]
    assert pooled["sd"] > 1.5 and all(c["regions"][0]["kd"]["sd"] < 0.02 for c in per_chain)


def test_the_report_shows_each_chain_s_regions_only_when_the_chains_have_not_mixed(tmp_path):
    import json

    from rjfit.pipeline.report import build_report

    def region(kd):
        return {"region": 0, "pixels": 7, **{p: {"mean": kd, "sd": 0.01, "q2.5": kd - 0.02, "q97.5": kd + 0.02}
                                              for p in ("I0", "kd", "gamma", "sigma2")}}

    chains = [{"chain": 0, "draws": 800, "regions": [region(0.123)]},
              {"chain": 1, "draws": 600, "regions": [region(0.789)]}]
    for rhat, shown in ((3.6, True), (None, True), (1.004, False)):
        (tmp_path / "summary.json").write_text(json.dumps({"regions": [region(0.456)], "rhat_max": rhat,
                                                           "chain_regions": chains}))
        page = build_report(tmp_path).read_text()
        assert "0.456" in page
        assert ("chain 1 (600 draws in the MAP model)" in page) == shown
        assert ("0.789" in page) == shown and ("0.123" in page) == shown


def _quadrant_record(problem, theta, x_u, y_v, iterations=40, burn=20, thin=2):
    """A chain record that sits at (u, v) = (x_u, y_v) in model (1, 1) with constant parameters ``theta``."""
    from types import SimpleNamespace

    height, width = problem.image_shape
    snapshots = np.arange(0, iterations, thin)
    return SimpleNamespace(n_u=np.ones(iterations, int), n_v=np.ones(iterations, int), cp_iteration=snapshots,
                           cp_u=np.full((len(snapshots), height, 1), float(x_u), np.float32),
                           cp_v=np.full((len(snapshots), width, 1), float(y_v), np.float32),
                           theta=np.broadcast_to(np.asarray(theta, float), (iterations, 4, 4)))


def test_posterior_mean_prediction_at_the_truth_is_the_noise_free_radiance():
    """Draws at the true segmentation and parameters: E[mu] is the noise-free radiance and the standardised
    residuals are the noise, so the count-weighted mean of residual_rms^2 (chi2_N / N) is 1 within its
    Monte Carlo error (sd sqrt(2 / N); tolerance 5 sd)."""
    from rjfit.data.synthetic import sphere_stack
    from rjfit.model.blinn import radiance
    from rjfit.posterior.summary import posterior_mean_prediction
    from rjfit.sampler.forward import Problem

    obs, labels, truth = sphere_stack(24, n_lights=8, seed=4)
    problem = Problem.from_observations(obs)
    theta = [[t["I0"], t["kd"], t["gamma"], t["sigma2"]] for t in truth]
    prediction = posterior_mean_prediction([_quadrant_record(problem, theta, 12.0, 12.0)], 20, problem)
    assert prediction["draws"] == 10
    region = labels.ravel()[obs.pixel]
    table = np.asarray(theta)
    mu = radiance(table[region, 0], table[region, 1], table[region, 2], obs.cos_ln, obs.cos_hn, obs.irradiance)
    count = np.bincount(obs.pixel, minlength=labels.size)
    expected = np.bincount(obs.pixel, weights=mu, minlength=labels.size) / np.maximum(count, 1)
    seen = count > 0
    np.testing.assert_allclose(prediction["radiance"].ravel()[seen], expected[seen], rtol=1e-5)
    assert np.all(np.isnan(prediction["radiance"].ravel()[~seen]))
    observed = np.bincount(obs.pixel, weights=obs.y, minlength=labels.size) / np.maximum(count, 1)
    np.testing.assert_allclose(prediction["observed"].ravel()[seen], observed[seen], rtol=1e-5)
    mean_square = np.nansum(prediction["residual_rms"].ravel() ** 2 * count) / count.sum()
    assert abs(mean_square - 1.0) < 5 * np.sqrt(2.0 / count.sum())


def test_posterior_mean_prediction_averages_each_chain_s_own_segmentation():
    """Two chains in different modes: the prediction is the mean of each chain's own, not radiance at mixed means."""
    from rjfit.data.synthetic import sphere_stack
    from rjfit.posterior.summary import posterior_mean_prediction
    from rjfit.sampler.forward import Problem

    obs, _, _ = sphere_stack(16, n_lights=6, seed=2)
    problem = Problem.from_observations(obs)
    theta_a = [[100.0, 0.5, 5.0, 0.1], [100.0, 0.9, 10.0, 0.1], [100.0, 0.6, 5.0, 0.1], [100.0, 0.4, 1.0, 0.1]]
    theta_b = [[60.0, 0.2, 40.0, 0.3]] * 4
    chain_a, chain_b = _quadrant_record(problem, theta_a, 5.0, 9.0), _quadrant_record(problem, theta_b, 11.0, 4.0)
    alone_a = posterior_mean_prediction([chain_a], 20, problem)["radiance"]
    alone_b = posterior_mean_prediction([chain_b], 20, problem)["radiance"]
    both = posterior_mean_prediction([chain_a, chain_b], 20, problem)
    assert both["draws"] == 20
    np.testing.assert_allclose(both["radiance"], (alone_a + alone_b) / 2, rtol=1e-12)
    mixed = _quadrant_record(problem, (np.asarray(theta_a) + np.asarray(theta_b)) / 2, 5.0, 9.0)
    plug_in = posterior_mean_prediction([mixed], 20, problem)["radiance"]
    assert np.nanmax(np.abs(plug_in - both["radiance"]) / both["radiance"]) > 0.1
    with pytest.raises(ValueError, match="no change-point snapshot after burn-in"):
        posterior_mean_prediction([chain_a], 40, problem)
