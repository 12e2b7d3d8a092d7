"""The fit folder's standard files (issue 43, item 5): ArviZ reads chains.nc as it is, every file records
rjfit's version, the schema and the options, paths are relative to the folder, and ``rjfit.load_fit`` reads it.

Both region models, each a small real fit (2 chains of 200 iterations on a 16-pixel sphere, one process).
The change-point fit runs under the 'relative' noise model and a likelihood power of 0.5, so the check that
the pointwise log likelihood sums to the chains' own covers the tempering and the noise scales' constant.
"""
import json
import warnings

import numpy as np
import pytest

import rjfit
from rjfit.data.exr import read_exr, read_exr_attributes
from rjfit.data.synthetic import sphere_stack
from rjfit.errors import DatasetError, DatasetFileNotFoundError
from rjfit.pipeline.fit import fit
from rjfit.pipeline.fit_folder import SCHEMA_VERSION, read_summary, relative_paths, write_summary

SETTINGS = {"changepoints": {"regions": "changepoints", "noise": "relative", "likelihood_power": 0.5},
            "materials": {"regions": "materials"}}


@pytest.fixture(scope="module", params=sorted(SETTINGS))
def fitted(request, tmp_path_factory):
    obs, labels, _ = sphere_stack(16, n_lights=8, seed=4)
    out = tmp_path_factory.mktemp("fit") / "out"
    summary = fit(obs, out, seed=5, n_chains=2, iterations=200, processes=1, progress=False, figures=False,
                  truth_labels=labels, **SETTINGS[request.param])
    return out, summary


def _arviz():
    from rjfit.posterior.summary import _arviz as quiet

    return quiet()


def test_az_summary_has_no_nan_row_and_lp_is_a_sample_stat(fitted):
    out, summary = fitted
    idata = _arviz().from_netcdf(str(out / "chains.nc"))
    table = _arviz().summary(idata)
    # one row per parameter of the summarised model's regions (a material fit's: its segmentation's K), every one of
    # them a number (no padded region slot); R-hat too where every chain drew that model (on this 16-pixel sphere a
    # chain may hold 3 materials throughout: four of five other seeds, with or without component moves, and R-hat
    # is then undefined)
    per_chain = summary.get("chain_materials_posterior")
    k = str(summary.get("segmentation_materials", summary.get("map_materials")))
    every_chain = per_chain is None or all(chain.get(k, 0) > 0 for chain in per_chain)
    columns = [name for name in table.columns if name != "r_hat" or every_chain]
    assert len(table) == 4 * len(summary["regions"]) and not table[columns].isna().any(axis=None), table
    assert "lp" in idata.sample_stats and "lp" not in idata.posterior and "log_post" not in idata.posterior
    kept = summary["iterations"] - summary["burn_in"]
    assert idata.sample_stats["lp"].shape == (2, kept)
    model_keys = ("n_materials",) if summary["region_model"] == "materials" else ("n_u", "n_v", "model_number")
    assert all(key in idata.sample_stats for key in model_keys)


def test_the_log_likelihood_is_the_one_the_chains_used(fitted):
    """Summed over the pixel blocks, each draw's pointwise log likelihood is the chain's own (tempered, with the
    noise scales' constant). The chain sums its regions' sufficient statistics, the file sums every observation's
    residual: the same number in another order of float64 sums, equal to 1e-8 relative (the expanded quadratic
    form loses about Syy / SSR ~ 1e3 times the rounding, 1e-13)."""
    out, summary = fitted
    idata = _arviz().from_netcdf(str(out / "chains.nc"))
    log_lik = idata.log_likelihood["y"]
    assert log_lik.dims == ("chain", "draw", "pixel_block")
    attrs = idata.log_likelihood.attrs
    assert attrs["values"] == log_lik.size and attrs["likelihood_power"] == summary["likelihood_power"]
    assert summary["log_likelihood"]["points"] == log_lik.shape[2]
    totals = log_lik.sum("pixel_block").values
    iterations = idata.log_likelihood["iteration"].values
    chain_totals = idata.sample_stats["log_lik"].values[np.arange(2)[:, None], iterations - summary["burn_in"]]
    np.testing.assert_allclose(totals, chain_totals, rtol=1e-8)
    blocks = idata.constant_data["block_of_pixel"].values
    assert idata.constant_data["block_observations"].values.sum() == summary["n_observations"]
    assert blocks.max() + 1 == log_lik.shape[2]


def test_az_loo_plot_rank_and_plot_trace_accept_the_file(fitted):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out, _ = fitted
    az = _arviz()
    idata = az.from_netcdf(str(out / "chains.nc"))
    with warnings.catch_warnings():     # Pareto k above 0.7 at a few boundary pixels: ArviZ warns, and may
        warnings.simplefilter("ignore")  # do so here; the estimate is still made
        loo = az.loo(idata, reff=idata.log_likelihood.attrs["reff"])
        plain = az.loo(idata)
    assert np.isfinite(loo.elpd_loo) and np.isfinite(plain.elpd_loo)
    assert loo.n_data_points == idata.log_likelihood["y"].shape[2]
    az.plot_rank(idata, var_names=["theta"])
    az.plot_trace(idata, var_names=["theta"])
    plt.close("all")


def test_every_file_records_the_version_schema_and_options(fitted):
    out, summary = fitted
    on_disk = json.loads((out / "summary.json").read_text())
    assert on_disk["rjfit_version"] == rjfit.__version__ and on_disk["schema_version"] == SCHEMA_VERSION
    options = json.dumps(on_disk["fit_options"], sort_keys=True)
    idata = _arviz().from_netcdf(str(out / "chains.nc"))
    for group in idata.groups():
        attrs = idata[group].attrs
        assert attrs["rjfit_version"] == rjfit.__version__ and attrs["rjfit_schema_version"] == str(SCHEMA_VERSION)
        assert attrs["rjfit_fit_options"] == options and attrs["rjfit_fit_id"] == summary["fit_id"], group
    for name in ("labels.exr", "maps.exr"):
        header = read_exr_attributes(out / name, "rjfit_")
        assert header["rjfit_fit_options"] == options and header["rjfit_version"] == rjfit.__version__, name
    snapshots = "materials.npz" if summary["region_model"] == "materials" else "changepoints.npz"
    with np.load(out / snapshots) as arrays:
        assert str(arrays["rjfit_schema_version"]) == str(SCHEMA_VERSION)
        assert str(arrays["rjfit_fit_options"]) == options


def test_load_fit_round_trips(fitted):
    out, summary = fitted
    loaded = rjfit.load_fit(out)
    assert loaded.summary == read_summary(out) and loaded.summary["fit_id"] == summary["fit_id"]
    theta = _arviz().from_netcdf(str(out / "chains.nc")).posterior["theta"]
    np.testing.assert_array_equal(loaded.inference_data.posterior["theta"].values, theta.values)
    maps = read_exr(out / "maps.exr")
    assert set(loaded.maps) == set(maps) and np.array_equal(loaded.maps["I0"], maps["I0"], equal_nan=True)
    assert loaded.labels.shape == maps["label"].shape and loaded.labels.max() == len(summary["regions"]) - 1


def test_load_fit_of_a_folder_that_is_not_a_fit_is_one_line(fitted, tmp_path):
    with pytest.raises(DatasetFileNotFoundError, match="not a fit folder") as error:
        rjfit.load_fit(tmp_path)
    assert "\n" not in str(error.value)
    out, _ = fitted
    copy = tmp_path / "copy"
    copy.mkdir()
    (copy / "summary.json").write_text((out / "summary.json").read_text())
    with pytest.raises(DatasetFileNotFoundError, match="chains.nc: missing"):
        rjfit.load_fit(copy)
    (copy / "chains.nc").write_text("not netCDF")
    (copy / "maps.exr").write_bytes((out / "maps.exr").read_bytes())
    with pytest.raises(DatasetError, match="chains.nc: not a readable netCDF"):
        rjfit.load_fit(copy)


def test_paths_are_stored_relative_and_read_back_absolute(tmp_path):
    """A summary's data set and validation paths are written relative to the fit folder and read back
    absolute; a summary written before (schema 1, absolute paths) reads as it was."""
    data = tmp_path / "data" / "ball"
    (data / "validation").mkdir(parents=True)
    fit_dir = tmp_path / "fits" / "ball"
    fit_dir.mkdir(parents=True)
    summary = {"dataset": str(data), "validation": {"passed": True, "path": str(data / "validation" / "v.json")}}
    summary = relative_paths(summary, fit_dir)
    assert summary == {"dataset": "../../data/ball", "validation": {"passed": True,
                                                                    "path": "../../data/ball/validation/v.json"}}
    write_summary(fit_dir / "summary.json", summary)
    read = read_summary(fit_dir)
    assert read["dataset"] == str(data.resolve()) and read["validation"]["path"] == str(data.resolve() / "validation"
                                                                                       / "v.json")
    moved = tmp_path / "moved"          # the data and its fits moved together: the paths follow them
    moved.mkdir()
    for name in ("data", "fits"):
        (tmp_path / name).rename(moved / name)
    fit_dir = moved / "fits" / "ball"
    assert read_summary(fit_dir)["dataset"] == str((moved / "data" / "ball").resolve())
    old_style = {"dataset": "/somewhere/ball", "validation": {"path": "/somewhere/ball/validation/validation.json"}}
    write_summary(fit_dir / "summary.json", old_style)
    assert read_summary(fit_dir) == old_style
