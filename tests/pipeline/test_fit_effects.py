"""``rjfit fit --effects`` / ``--effects-from`` end to end: the effects sampled, recorded, reported (issue 26).

A 12 x 12 hidden-ambient stack (:func:`rjfit.render.hidden.render_hidden`, Mitsuba's constant
emitter), one short chain with ambient light named: the summary records the effect's
posterior in its schema, ``chains.nc`` its draws, the report shows it. The chain is short
(60 iterations): what is checked is the plumbing, not the posterior (the exactness tests
are in ``tests/sampler/test_effects_exact.py``; the hidden-effect measurements in
``validation/effects_in_fit.py``). Cost: one small render and about 10 s of fitting.
"""
from __future__ import annotations

import json
import math

import pytest
from click.testing import CliRunner

from rjfit.errors import DatasetError
from rjfit.pipeline.fit import fit
from rjfit.pipeline.fit_dataset import fit_dataset
from rjfit.pipeline.options import FitOptions


@pytest.fixture(scope="module")
def ambient(tmp_path_factory):
    from rjfit.render.hidden import render_hidden

    return render_hidden("ambient", tmp_path_factory.mktemp("ambient") / "dataset", resolution=12)


@pytest.fixture(scope="module")
def fitted(ambient, tmp_path_factory):
    out = tmp_path_factory.mktemp("fit_effects")
    summary = fit_dataset(ambient, out, allow_unvalidated=True, effects=("ambient",), n_chains=1, iterations=60,
                          figures=False, progress=False, seed=1)
    return out, summary


def test_the_summary_records_each_effect_s_posterior(fitted):
    out, summary = fitted
    on_disk = json.loads((out / "summary.json").read_text())
    assert on_disk["fit_id"] == summary["fit_id"]
    (effect,) = on_disk["effects"]
    assert effect["name"] == "ambient" and effect["stage"] == "ambient"
    (param,) = effect["parameters"]
    assert param["name"] == "ambient" and "LogNormal" in param["prior"]
    assert all(math.isfinite(param[key]) for key in ("mean", "sd", "q2.5", "q97.5"))
    assert 0 < param["q2.5"] <= param["mean"] <= param["q97.5"]
    assert effect["source"]["requested_by"] == "--effects"
    assert on_disk["acceptance"]["effect_ambient"] >= 0


def test_chains_nc_holds_the_effect_draws_and_the_report_shows_them(fitted):
    import arviz as az

    from rjfit.pipeline.report import build_report

    out, summary = fitted
    idata = az.from_netcdf(str(out / "chains.nc"))
    assert list(idata.posterior["effects"].coords["effect_parameter"].values) == ["ambient.ambient"]
    draws = idata.posterior["effects"].values       # at the MAP model's kept draws, beside their regions
    kept = summary["iterations"] - summary["burn_in"]
    assert draws.shape[0] == 1 and 0 < draws.shape[1] <= kept and (draws > 0).all()
    assert idata.sample_stats["lp"].shape == (1, kept)
    assert idata.warmup_sample_stats["lp"].shape == (1, summary["burn_in"])
    # no pointwise log likelihood for a fit with effects (their per-observation transform is not recorded)
    assert "log_likelihood" not in idata.groups() and "note" in summary["log_likelihood"]
    page = build_report(out).read_text()
    assert "Effects sampled with the regions" in page and "ambient" in page


def test_effects_need_the_data_set_and_a_diagnosis_where_they_say_so(ambient, tmp_path):
    from rjfit.render.datasets import load_dataset

    observations = load_dataset(ambient).observations()
    with pytest.raises(ValueError, match="need the data set"):
        fit(observations, tmp_path / "a", effects=("ambient",))
    with pytest.raises(DatasetError, match="no diagnosis.json"):
        fit_dataset(ambient, tmp_path / "b", allow_unvalidated=True, effects_from=tmp_path)
    with pytest.raises(ValueError, match="--effects-from"):
        fit_dataset(ambient, tmp_path / "c", allow_unvalidated=True, effects=("interreflection",))
    with pytest.raises(ValueError, match="unknown effect"):
        FitOptions(effects="ambient,glare")


def test_the_command_line_takes_effects_as_a_comma_separated_list(monkeypatch, ambient, tmp_path):
    from rjfit import cli

    seen = {}

    def record(datasets, out_dir, options=None, **keywords):
        seen["options"] = options
        return []
    monkeypatch.setattr("rjfit.pipeline.fit_dataset.fit_datasets", record)
    outcome = CliRunner().invoke(cli.main, ["fit", str(ambient), "--out", str(tmp_path / "o"), "--effects",
                                            "ambient, camera_srgb", "--effect-every", "2"])
    assert outcome.exit_code == 0, outcome.output
    assert seen["options"].effects == ("ambient", "camera_srgb") and seen["options"].effect_every == 2


def test_an_effects_uncertain_parameters_make_one_warning():
    """light_calibration has a parameter per light: 95 flagged parameters are one line that says how many and
    their R-hat and ESS spans, not 95 lines; one flagged parameter keeps its own line; none, no line."""
    from rjfit.pipeline.fit import effect_warnings

    # h1 settled; h2 to h96 with R-hat 1.22 to 2.16 and bulk ESS 6.02 to 6.96
    gains = {"name": "light_calibration", "parameters": [{"name": "h1", "rhat": 1.01, "ess_bulk": 399.0}] + [
        {"name": f"h{k}", "rhat": 1.2 + k / 100, "ess_bulk": 6.0 + k / 100} for k in range(2, 97)]}
    ambient_effect = {"name": "ambient", "parameters": [{"name": "L_amb", "rhat": 1.02, "ess_bulk": 42.0}]}
    settled = {"name": "coating", "parameters": [{"name": "w_coat", "rhat": 1.01, "ess_bulk": 900.0}]}
    warnings = effect_warnings([gains, ambient_effect, settled])
    assert warnings == [
        "effect light_calibration: 95 of its 96 parameters (h2, h3, h4, h5, ...) have R-hat 1.220 to 2.160 and bulk "
        "ESS 6 to 7: their posterior summaries are uncertain; run longer",
        "effect ambient: its parameter L_amb has R-hat 1.020 and bulk ESS 42: its posterior summary is uncertain; "
        "run longer"]
