"""``rjfit fit --normals sample`` end to end, and its refusals.

- The option honoured: Mitsuba's paper_sphere at 48 x 48 (the session's render) whose geometry file's normals
  were turned by a known field (3 degrees sd per tangent direction, independent per pixel) is fitted through the
  command line with the paper's change points (2 chains x 300, seed 1), once with the given normals and once
  sampling them. The sampled fit writes the normals' maps and summary entry; its posterior mean tangent
  coordinates correlate with the true correction of each given normal (the true normal in the given one's frame)
  at r > 0.7 (measured 0.92, 2026-11-28: docs/results/2026-11-28-normals.md), and its MAP segmentation's accuracy
  against the truth is at least the fixed fit's less 0.01, and at least 0.95 (measured: fixed 0.73, the turned
  normals cost it; sampled 0.98). About two minutes.
- The refusals: with effects, with --channel rgb and with --noise footprint, one line naming the option, before
  any work; --normal-sd where the normals are fixed, and where they are sampled the prior's sd it sets.
- The follow-on commands, on a short sampled fit of the turned sphere (2 chains x 80, --normal-sd 3, --noise
  normals; about 10 s): `rjfit diagnose` criticises it at its posterior mean normals, with the fit's observations
  and noise scales; `rjfit refine` refuses it in one line before any work (its refits sample effects, which
  sampled normals cannot take).
"""
import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from rjfit.cli import main
from rjfit.data.exr import read_exr, write_exr
from rjfit.data.lights import tangent_frame
from rjfit.diagnose.document import NORMALS
from rjfit.errors import DatasetError
from rjfit.pipeline.diagnose import diagnose_fit, fit_mean_normals
from rjfit.pipeline.fit_power import MIN_NORMAL_SD_DEG, noise_and_power, normal_prior_sd
from rjfit.pipeline.options import FitOptions
from rjfit.pipeline.resolve import resolve_options
from rjfit.render.datasets import load_dataset

from builders import perturbed_normals

REFUSED = [(["--effects", "ambient"], "--effects"), (["--channel", "rgb", "--regions", "materials"], "--channel rgb"),
           (["--noise", "footprint"], "footprint")]


@pytest.mark.parametrize("flags, named", REFUSED, ids=[" ".join(f) for f, _ in REFUSED])
def test_sampled_normals_refuse_what_they_do_not_support_in_one_line(paper_sphere_small, tmp_path, flags, named):
    result = CliRunner().invoke(main, ["fit", str(paper_sphere_small), "--out", str(tmp_path / "fit"),
                                       "--allow-unvalidated", "--iterations", "20", "--normals", "sample", *flags])
    assert result.exit_code == 1, result.output
    message = result.output.strip()
    assert message.startswith("Error: ") and "--normals sample" in message and named in message, message
    assert "\n" not in message and "Traceback" not in result.output
    assert not (tmp_path / "fit" / "summary.json").exists()


def test_a_prior_sd_is_read_only_where_the_normals_are_sampled(paper_sphere_small, tmp_path):
    result = CliRunner().invoke(main, ["fit", str(paper_sphere_small), "--out", str(tmp_path / "fit"),
                                       "--allow-unvalidated", "--iterations", "20", "--normal-sd", "2"])
    assert result.exit_code == 1 and "--normal-sd is an option of --normals sample" in result.output
    assert "Traceback" not in result.output
    resolved = resolve_options(FitOptions(normals="sample", normal_sd=2.0))
    assert normal_prior_sd(resolved, {"sigma_n_deg": 0.0}) == pytest.approx(np.tan(np.radians(2.0)))
    estimated = resolve_options(FitOptions(normals="sample"))
    assert normal_prior_sd(estimated, {"sigma_n_deg": 0.0}) == pytest.approx(np.tan(np.radians(MIN_NORMAL_SD_DEG)))
    assert normal_prior_sd(resolve_options(FitOptions()), {"sigma_n_deg": 2.0}) is None
    with pytest.raises(ValueError, match="--normal-sd is in degrees"):
        FitOptions(normal_sd=90.0)


@pytest.fixture(scope="module")
def turned_sphere(paper_sphere_small, tmp_path_factory):
    """A copy of paper_sphere_small whose geometry file holds normals turned by 3 degrees (sd per direction)."""
    folder = tmp_path_factory.mktemp("turned") / "dataset"
    shutil.copytree(paper_sphere_small, folder)
    dataset = load_dataset(folder)
    turned = perturbed_normals(dataset.normals, dataset.object_mask, 3.0, 1)
    geometry = folder / dataset.meta["geometry"]
    channels = read_exr(geometry)
    for k, axis in enumerate("XYZ"):
        channels[f"N.{axis}"] = turned[..., k].astype(np.float32)
    write_exr(geometry, channels)
    return folder, dataset.normals, turned, dataset.object_mask


def run_fit(folder, out, *flags):
    result = CliRunner().invoke(main, ["fit", str(folder), "--out", str(out), "--allow-unvalidated", "--chains", "2",
                                       "--iterations", "300", "--seed", "1", *flags])
    assert result.exit_code == 0, result.output
    return json.loads((out / "summary.json").read_text())


def test_sampled_normals_find_a_known_turn_and_keep_the_segmentation(turned_sphere, tmp_path):
    folder, true, given, mask = turned_sphere
    fixed = run_fit(folder, tmp_path / "fixed")
    sampled = run_fit(folder, tmp_path / "sampled", "--normals", "sample")
    assert "normals" not in fixed and sampled["normals"]["mode"] == "sample"
    maps = read_exr(tmp_path / "sampled" / "maps.exr")
    estimate = np.stack([maps["normal_dx"], maps["normal_dy"]], -1)
    seen = mask & np.isfinite(estimate[..., 0])
    t1, t2 = tangent_frame(given[seen])
    true, given = true[seen], given[seen]       # the true normal's tangent coordinates in the given one's frame:
    correction = np.stack([np.sum(true * t1, -1), np.sum(true * t2, -1)], -1) / np.sum(true * given, -1)[:, None]
    assert np.corrcoef(correction.ravel(), estimate[seen].ravel())[0, 1] > 0.7
    assert np.all(np.isfinite(maps["normal_shift_deg"][seen])) and np.all(maps["normal_sd_deg"][seen] >= 0)
    # the segmentation is kept (the turned normals cost the fixed fit accuracy: 0.73 measured, the sampled 0.98)
    assert sampled["label_accuracy"] >= max(fixed["label_accuracy"] - 0.01, 0.95)


def test_sampled_normals_keep_the_normal_error_inflation(paper_sphere_small):
    """Under --noise normals the sampled normals' fit keeps the fixed fit's noise scales 1 + k g^2 and power (the
    ball's control, docs/results/2026-11-28-normals.md: dropping them, k = 0, split a one-material object)."""
    observations = load_dataset(paper_sphere_small).observations(tangents=True)
    fixed = noise_and_power(observations, resolve_options(FitOptions(noise="normals")))
    sampled = noise_and_power(observations, resolve_options(FitOptions(noise="normals", normals="sample")))
    assert fixed[3]["k"] > 0 and np.max(fixed[0]) > 1.0        # the clean render reads ~0.6 deg: an inflation to keep
    np.testing.assert_allclose(sampled[0], fixed[0], rtol=1e-12)
    assert sampled[2] == pytest.approx(fixed[2], rel=1e-12)


@pytest.fixture(scope="module")
def short_sampled_fit(turned_sphere, tmp_path_factory):
    """A short fit of the turned sphere that samples its normals (prior sd 3 degrees, the turn's) under --noise
    normals: its folder and summary."""
    folder = turned_sphere[0]
    out = tmp_path_factory.mktemp("sampled") / "fit"
    result = CliRunner().invoke(main, ["fit", str(folder), "--out", str(out), "--allow-unvalidated", "--chains", "2",
                                       "--iterations", "80", "--seed", "1", "--normals", "sample", "--normal-sd", "3",
                                       "--noise", "normals"])
    assert result.exit_code == 0, result.output
    return out, json.loads((out / "summary.json").read_text())


def test_a_sampled_fit_is_diagnosed_at_its_posterior_mean_normals(short_sampled_fit, turned_sphere, tmp_path):
    fit_dir, summary = short_sampled_fit
    settings = dict(max_steps=0, simulate=False, make_figures=False)
    mean = diagnose_fit(fit_dir, tmp_path / "mean", **settings)
    given = diagnose_fit(fit_dir, tmp_path / "given", normals=None, **settings)     # the data set's normals
    assert mean["normals"] == NORMALS[True] and given["normals"] == NORMALS[False]
    assert "Normals: the fit's posterior mean normals" in (tmp_path / "mean" / "diagnosis.md").read_text()
    # the normals the diagnosis turns the given ones to are the fit's posterior mean: their angle from the given
    # normal is the fit's normal_shift_deg (written as float32: 1e-4 degrees)
    maps = read_exr(fit_dir / "maps.exr")
    given_normals = load_dataset(turned_sphere[0]).normals
    mean_normals = fit_mean_normals(fit_dir, summary, given_normals)
    seen = np.isfinite(maps["normal_shift_deg"])
    angle = np.degrees(np.arctan2(np.linalg.norm(np.cross(mean_normals, given_normals), axis=-1),
                                  np.sum(mean_normals * given_normals, axis=-1)))
    np.testing.assert_allclose(angle[seen], maps["normal_shift_deg"][seen], atol=1e-4)
    np.testing.assert_array_equal(mean_normals[~seen], given_normals[~seen])
    # the plain refit at the mean normals leaves much less misfit than at the turned given ones (measured noise
    # variance estimate 0.022 vs 0.106, log evidence -2367 vs -8020, 2026-11-28): half is a wide margin
    assert mean["noise_variance_estimate"] < 0.5 * given["noise_variance_estimate"]
    assert mean["plain_model"]["log_evidence"] > given["plain_model"]["log_evidence"]
    # the fit's observations and its noise scales (1 + k g^2 at the given normals, held while the normals moved):
    # the same function on the same observations, gathered by the fit and by the diagnosis (rel 1e-9)
    assert mean["n_observations"] == given["n_observations"]
    assert mean["noise"]["sum_log_scale"] == pytest.approx(summary["noise"]["sum_log_scale"], rel=1e-9)


def test_a_sampled_fit_without_its_normal_maps_is_refused_in_one_line(short_sampled_fit, tmp_path):
    fit_dir = tmp_path / "fit"
    shutil.copytree(short_sampled_fit[0], fit_dir)
    maps = read_exr(fit_dir / "maps.exr")
    write_exr(fit_dir / "maps.exr", {name: values for name, values in maps.items() if name != "normal_dx"})
    with pytest.raises(DatasetError, match=r"maps.exr: no normal_dx / normal_dy channels"):
        diagnose_fit(fit_dir, tmp_path / "diagnosis", max_steps=0, simulate=False, make_figures=False)


def test_refine_refuses_a_sampled_normals_fit_before_any_work(short_sampled_fit, tmp_path):
    """Its refits sample the effects a diagnosis names, which a fit refuses with sampled normals: refused up front,
    not after a diagnosis."""
    out = tmp_path / "refine"
    result = CliRunner().invoke(main, ["refine", str(short_sampled_fit[0]), "--out", str(out), "--no-simulate"])
    assert result.exit_code == 1, result.output
    message = result.output.strip()
    assert message.startswith("Error: ") and "\n" not in message and "Traceback" not in result.output
    assert "--normals sample" in message and "--normals fixed" in message, message
    assert not out.exists()
