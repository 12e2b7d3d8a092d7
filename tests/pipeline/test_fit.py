"""End to end: fit() on a small synthetic stack writes every result and finds the four regions."""
import json
from pathlib import Path

import numpy as np
import pytest

from rjfit.data.synthetic import sphere_stack
from rjfit.pipeline.fit import fit


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    out = tmp_path_factory.mktemp("fit")
    obs, labels, truth = sphere_stack(24, n_lights=8, seed=4)
    # Two chains in two spawned worker processes, started in model (1, 1) with straight change
    # points near the centre lines and no annealed warm-up: this file tests what a fit WRITES
    # and its parameter estimates at the truth's mode. The default path (dispersed starts,
    # annealing) is tested end to end in test_fit_default_path.py, over seeds in
    # validation/default_fit_seeds.py.
    start = [{"changepoints": (np.full(24, 10.7), np.full(24, 13.4))},
             {"changepoints": (np.full(24, 13.6), np.full(24, 10.2))}]
    summary = fit(obs, out, truth_labels=labels, truth_params=truth, seed=8, n_chains=2, iterations=1000,
                  burn_in=0.5, max_u=2, max_v=2, processes=2, progress=False, start=start, checkpoint_every=250,
                  anneal=0.0)
    return out, summary, labels


def test_fit_writes_summary_labels_chains_and_figures(fitted):
    out, summary, labels = fitted
    on_disk = json.loads((out / "summary.json").read_text())
    for key in ("model_posterior", "map_model", "regions", "rhat_max", "ess_min", "iterations", "seconds",
                "label_accuracy", "four_region_probability", "exact_truth_probability", "warnings"):
        assert key in on_disk, key
    assert on_disk["map_model"] == {"n_u": 1, "n_v": 1, "m": 5}
    assert abs(sum(on_disk["model_posterior"].values()) - 1.0) < 1e-9
    region = on_disk["regions"][0]
    assert {"pixels", "I0", "kd", "gamma", "sigma2"} <= set(region)
    assert {"mean", "sd", "q2.5", "q97.5"} <= set(region["kd"])
    from rjfit.data.exr import read_exr

    exr = read_exr(out / "labels.exr")["labels"]
    assert exr.shape == labels.shape and exr.dtype == np.float32
    import arviz as az

    idata = az.from_netcdf(out / "chains.nc")
    assert idata.posterior["theta"].dims == ("chain", "draw", "region", "parameter")
    assert idata.posterior.attrs["rjfit_fit_id"] == on_disk["fit_id"]
    # the MAP model's draws of every kept iteration (the chains start in it), every iteration's lp beside them
    assert idata.posterior["theta"].shape[:3] == (2, 500, 4)
    assert idata.sample_stats["lp"].shape == (2, 500) and idata.warmup_sample_stats["lp"].shape == (2, 500)
    for name in ("model_histogram", "traces", "changepoints", "reflectance"):
        assert (out / "figures" / f"{name}.png").stat().st_size > 1000
    # checkpoints (every 250 of 1000 iterations) are cleared once the results are written,
    # and so is their folder; the staging folder of the results is gone too
    assert not (out / "checkpoints").exists()
    assert not list(out.glob(".staging*"))
    assert on_disk["figures"]["traces"] == "figures/traces.png"      # relative to the fit folder, like "maps"
    assert len(on_disk["fit_id"]) == 16


def test_fit_recovers_the_truth_on_a_small_sphere(fitted):
    _, summary, _ = fitted
    assert summary["label_accuracy"] > 0.97
    # All 16 parameters within 4 posterior sd of the truth: for an exact posterior the chance
    # that any of 16 misses is 16 x P(|z| > 4) = 0.1 % (the Monte Carlo error of the means is
    # ~sd / sqrt(ESS), a few per cent of sd). Measured: |z| <= 2.72.
    _, _, truth = sphere_stack(24, n_lights=8, seed=4)
    for region, params in zip(summary["regions"], truth):
        for name in ("I0", "kd", "gamma", "sigma2"):
            z = (region[name]["mean"] - params[name]) / region[name]["sd"]
            assert abs(z) < 4.0, (region["region"] if "region" in region else None, name, z)


#: the beginnings of the caveats of a fit's own numbers (rjfit.posterior.caveats) and of R-hat's missing values
NUMBER_CAVEATS = ("lies at or above its prior's plausible range", "lies at or below its prior's plausible range",
                  "reaches its prior's bound",
                  "holds no pixel with observations", "the model cap binds", "outside its own 95 % interval",
                  "acceptance ratio was NaN", "R-hat not computable")


def test_a_clean_fit_has_none_of_the_number_caveats(fitted):
    _, summary, _ = fitted
    assert not [w for w in summary["warnings"] if any(c in w for c in NUMBER_CAVEATS)], summary["warnings"]
    assert summary["rhat_reason"] is None and np.isfinite(summary["rhat_max"])
    counts = summary["acceptance_counts"]
    assert set(counts) == set(summary["acceptance"]) and all(c["nan_rejected"] == 0 for c in counts.values())
    assert all(summary["acceptance"][k] == c["accepted"] / c["proposed"] for k, c in counts.items())


def test_a_region_without_data_and_a_binding_cap_are_warned(tmp_path):
    """A fixed segmentation whose first u vector lies left of every pixel: region 0 holds no
    observation. A fit capped at (1, 1) on the four-region sphere: the posterior sits on the cap."""
    obs, _, _ = sphere_stack(12, n_lights=4, seed=2)
    empty = fit(obs, tmp_path / "empty", n_chains=1, iterations=20, max_u=1, max_v=0, processes=1, progress=False,
                figures=False, fixed_segmentation=(np.full((12, 1), -0.9), np.zeros((12, 0))))
    assert any(w.startswith("region 0 of the MAP model holds no pixel with observations") for w in empty["warnings"])
    assert not any("the model cap binds" in w for w in empty["warnings"])     # a fixed segmentation cannot move
    capped = fit(obs, tmp_path / "capped", n_chains=1, iterations=40, max_u=1, max_v=1, processes=1, progress=False,
                 figures=False, start=[{"model": (1, 1)}])
    assert capped["model_posterior"].get("(1,1)", 0.0) > 0.05
    assert any(w.startswith("the model cap binds: ") and "n_u = 1" in w and "--max-u 2" in w
               for w in capped["warnings"]), capped["warnings"]


def test_an_interrupted_fit_leaves_the_previous_results_whole(tmp_path):
    """Interrupted while it writes its results, a fit into a folder that holds an earlier fit
    must leave that fit as it was, not one run's labels beside another run's summary."""
    obs, _, _ = sphere_stack(12, n_lights=4, seed=2)
    options = dict(n_chains=1, iterations=20, max_u=1, max_v=1, processes=1, progress=False)
    first = fit(obs, tmp_path, seed=1, **options)
    (tmp_path / "report.html").write_text("report of the first fit")
    before = {path.relative_to(tmp_path): path.read_bytes() for path in tmp_path.rglob("*") if path.is_file()}

    def interrupt(staging, summary):
        assert (staging / "labels.exr").is_file() and summary["seed"] == 2
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        fit(obs, tmp_path, seed=2, before_publish=interrupt, **options)
    after = {path.relative_to(tmp_path): path.read_bytes() for path in tmp_path.rglob("*") if path.is_file()}
    # the previous results as they were; beside them only the interrupted run's sampled chain (its
    # final checkpoint), which running it again publishes
    kept = Path("checkpoints") / "chain_0.pkl"
    assert kept in after and {name: data for name, data in after.items() if name != kept} == before
    (tmp_path / ".staging.killed" / "figures").mkdir(parents=True)     # what SIGKILL would leave
    # a finished second fit replaces every result, and drops the report of the first
    second = fit(obs, tmp_path, seed=2, **options)
    assert json.loads((tmp_path / "summary.json").read_text())["seed"] == 2
    assert second["chain_resumed_from"] == [[20]]          # the kept chain, published without sampling again
    assert second["fit_id"] != first["fit_id"] and not (tmp_path / "report.html").exists()
    assert not list(tmp_path.glob(".staging*")) and not (tmp_path / "checkpoints").exists()


def test_fit_rejects_bad_arguments(tmp_path):
    obs, _, _ = sphere_stack(8, n_lights=3, seed=1)
    with pytest.raises(ValueError, match="burn_in"):
        fit(obs, tmp_path, burn_in=1.5, progress=False)
    with pytest.raises(ValueError, match="prior"):
        fit(obs, tmp_path, prior="flat", progress=False)


def test_fit_records_the_noise_model_and_rejects_an_unknown_one(tmp_path):
    obs, _, _ = sphere_stack(16, n_lights=6, seed=1)
    summary = fit(obs, tmp_path / "rel", seed=1, n_chains=1, iterations=30, max_u=1, max_v=1, processes=1,
                  progress=False, figures=False, noise="relative", noise_floor=0.1, likelihood_power="auto")
    on_disk = json.loads((tmp_path / "rel" / "summary.json").read_text())
    assert on_disk["noise"]["model"] == "relative" and on_disk["noise"]["floor"] == 0.1
    assert "c = floor * ybar" in on_disk["noise"]["formula"]
    assert 0 < on_disk["noise"]["scale_min"] <= on_disk["noise"]["scale_median"] <= on_disk["noise"]["scale_max"]
    assert 0 < summary["likelihood_power"] <= 1
    plain = fit(obs, tmp_path / "plain", seed=1, n_chains=1, iterations=30, max_u=1, max_v=1, processes=1,
                progress=False, figures=False)
    assert plain["noise"] == {"model": "constant", "formula": "var_i = sigma_r^2", "floor": None, "reference": None}
    with pytest.raises(ValueError, match="unknown noise model"):
        fit(obs, tmp_path / "bad", n_chains=1, iterations=30, processes=1, progress=False, noise="poisson")


def test_parameter_maps_at_the_true_parameters(tmp_path):
    """write_parameter_maps with the truth as 'posterior means': each pixel carries its
    region's values, and the standardised residuals are the noise itself, so the squared
    per-pixel RMS weighted by the pixel's observation count, chi2_N / N over all N
    observations, is 1 within its Monte Carlo error (sd sqrt(2 / N); tolerance 5 sd)."""
    from rjfit.data.exr import read_exr, write_exr
    from rjfit.pipeline.fit import write_parameter_maps

    obs, labels, truth = sphere_stack(24, n_lights=8, seed=4)
    write_exr(tmp_path / "labels.exr", {"labels": labels.astype(np.float32)})
    names = ("I0", "kd", "gamma", "sigma2")
    summary = {"regions": [{"region": r, **{name: {"mean": params[name], "sd": 0.01 * (r + 1)} for name in names}}
                           for r, params in enumerate(truth)]}
    assert write_parameter_maps(obs, summary, tmp_path) == "maps.exr"
    maps = read_exr(tmp_path / "maps.exr")
    for r, params in enumerate(truth):
        where = labels == r
        np.testing.assert_array_equal(maps["label"][where], r)
        for name in names:
            np.testing.assert_allclose(maps[name][where], params[name], rtol=1e-6)
            np.testing.assert_allclose(maps[f"{name}_sd"][where], 0.01 * (r + 1), rtol=1e-6)
    assert np.all(np.isnan(maps["I0"][labels < 0]))
    counts = np.bincount(obs.pixel, minlength=labels.size).reshape(labels.shape)
    np.testing.assert_array_equal(maps["valid_images"], counts)
    mean_square = np.nansum(maps["residual_rms"] ** 2 * counts) / counts.sum()
    assert abs(mean_square - 1.0) < 5 * np.sqrt(2.0 / counts.sum())


def test_summary_json_is_strict_json_even_without_rhat(tmp_path):
    """One chain: R-hat cannot be computed (NaN in memory); the file says null, which any JSON parser reads."""
    obs, _, _ = sphere_stack(12, n_lights=4, seed=2)
    summary = fit(obs, tmp_path, n_chains=1, iterations=20, max_u=1, max_v=1, processes=1, progress=False,
                  figures=False)
    assert np.isnan(summary["rhat_max"]) and summary["rhat_reason"].startswith("one chain: R-hat compares chains")
    text = (tmp_path / "summary.json").read_text()
    assert "NaN" not in text and "Infinity" not in text
    on_disk = json.loads(text, parse_constant=lambda name: pytest.fail(f"non-JSON constant {name}"))
    assert on_disk["rhat_max"] is None


@pytest.mark.parametrize("preset, table", [("paper-synthetic", 1), ("paper-real", 3)])
def test_a_fit_with_a_placeholder_paper_preset_says_so(tmp_path, preset, table):
    """The paper presets' numbers could not be read: a fit with one records that in its prior and warns."""
    obs, _, _ = sphere_stack(12, n_lights=4, seed=2)
    summary = fit(obs, tmp_path, n_chains=1, iterations=10, max_u=1, max_v=1, processes=1, progress=False,
                  figures=False, prior=preset)
    on_disk = json.loads((tmp_path / "summary.json").read_text())
    assert f"Table {table} could not be read" in on_disk["prior"]["caveat"]
    assert on_disk["prior"]["caveat"] in summary["warnings"]
    default = fit(obs, tmp_path / "default", n_chains=1, iterations=10, max_u=1, max_v=1, processes=1,
                  progress=False, figures=False)
    assert default["prior"]["caveat"] is None
    assert not any("placeholder" in w for w in default["warnings"])
