"""A damaged or hand-edited fit folder gets one line naming the file and the problem from each
of its readers (``rjfit report``, ``rjfit diagnose``, ``rjfit compare --fit``), never a traceback.

One real fit of a tiny data set (8 x 10 pixels, 10 iterations) is made per module; each case
breaks one file of a copy of it.
"""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from rjfit.cli import main
from rjfit.data.exr import read_exr, write_exr

from builders import HEIGHT, WIDTH, make_rjfit_folder


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """(data set, fit folder): ``rjfit fit`` of the tiny two-material data set of test_bad_input."""
    root = tmp_path_factory.mktemp("fit_folder")
    dataset = make_rjfit_folder(root / "dataset", full=True)
    result = CliRunner().invoke(main, ["fit", str(dataset), "--out", str(root / "fit"), "--allow-unvalidated",
                                       "--iterations", "10", "--chains", "1", "--max-u", "1", "--max-v", "1"])
    assert result.exit_code == 0, result.output
    return dataset, root / "fit"


@pytest.fixture
def copy(fitted, tmp_path, monkeypatch):
    """A copy of the fit folder to break, beside a copy of its data set (the summary names the data set relative
    to the fit folder), and the commands that read it (tracebacks off)."""
    monkeypatch.delenv("RJFIT_DEBUG", raising=False)
    dataset, fit = fitted
    shutil.copytree(fit, tmp_path / "fit")
    shutil.copytree(dataset, tmp_path / dataset.name)
    fit, dataset = tmp_path / "fit", tmp_path / dataset.name
    commands = {"report": ["report", str(fit)],
                "diagnose": ["diagnose", str(fit), "--max-steps", "0", "--no-simulate", "--out", str(tmp_path / "d")],
                "compare": ["compare", str(dataset), "--fit", str(fit), "--out", str(tmp_path / "c")]}
    return fit, commands


def one_error_line(command) -> str:
    """Run a command that must fail with one ``Error:`` line (a ClickException), and return it."""
    result = CliRunner().invoke(main, command)
    assert result.exit_code == 1 and isinstance(result.exception, SystemExit), (result.output, result.exception)
    assert "Traceback" not in result.output
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1 and result.output.rstrip().endswith(errors[0]), result.output
    return errors[0]


def edit_summary(edit):
    def damage(fit):
        path = fit / "summary.json"
        summary = json.loads(path.read_text())
        replaced = edit(summary)
        path.write_text(json.dumps(summary if replaced is None else replaced))
    return damage


def edit_labels(edit):
    def damage(fit):
        path = fit / "labels.exr"
        write_exr(path, {"labels": edit(read_exr(path)["labels"])})
    return damage


def on_object(value):
    """Labels with ``value`` at the first object pixel (row 0, column 3 of the disc mask)."""
    def edit(labels):
        assert labels[0, 3] >= 0 and (labels[0, :3] == -1).all()
        labels[0, 3] = value
        return labels
    return edit


def truncate(fit):
    text = (fit / "summary.json").read_text()
    (fit / "summary.json").write_text(text[: len(text) // 2])


def test_the_unbroken_fit_folder_is_read_by_every_reader(copy):
    """Every failure below is due to the one thing broken."""
    fit, commands = copy
    for name, command in commands.items():
        result = CliRunner().invoke(main, command)
        assert result.exit_code == 0, (name, result.output)


def test_a_fit_folder_of_schema_1_with_absolute_paths_is_read_by_every_reader(copy):
    """Fit folders written before paths became relative (schema 1) name their data set by its absolute path."""
    fit, commands = copy
    summary = json.loads((fit / "summary.json").read_text())
    assert not summary["dataset"].startswith("/") and summary["schema_version"] == 2
    summary["dataset"] = str((fit / summary["dataset"]).resolve())
    for key in ("schema_version", "rjfit_version", "log_likelihood"):
        summary.pop(key)
    (fit / "summary.json").write_text(json.dumps(summary))
    for name, command in commands.items():
        result = CliRunner().invoke(main, command)
        assert result.exit_code == 0, (name, result.output)


AGAIN = "run `rjfit fit DATASET --out {fit}` again"
SUMMARY = "{fit}/summary.json: not a summary `rjfit fit` wrote ({problem}); " + AGAIN


@pytest.mark.parametrize("damage, problem", [
    (edit_summary(lambda s: [s]), "a JSON list, not an object"),
    (edit_summary(lambda s: s.update(regions={"0": {}})), "'regions' is {'0': {}}, not a list"),
    (edit_summary(lambda s: s.update(map_model=[1, 0])), "'map_model' is [1, 0], not an object"),
    (edit_summary(lambda s: s.update(fit_id=12)), "'fit_id' is 12, not a string"),
    (edit_summary(lambda s: s.update(dataset=["x"])), "'dataset' is ['x'], not a string"),
    (edit_summary(lambda s: s.update(regions=[{}, "red"])), "'regions' entry 1 is 'red', not an object"),
    (edit_summary(lambda s: s.update(warnings=["R-hat", 3])), "'warnings' entry 1 is 3, not a string"),
    (edit_summary(lambda s: s.update(model_posterior={"(1,0)": "high"})),
     "'model_posterior' entry '(1,0)' is 'high', not a number"),
    (edit_summary(lambda s: s.update(channel="red")), "'channel' is 'red', not one of mean, R, G, B, luminance, rgb"),
    (edit_summary(lambda s: s.update(likelihood_power=2)), "'likelihood_power' is 2, not a number in (0, 1]"),
    (edit_summary(lambda s: s["noise"].update(model="loud")),
     "'noise' entry 'model' is 'loud', not one of constant, shot, relative, normals, footprint"),
    (edit_summary(lambda s: s["noise"].update(model="shot", floor=-1)), "'noise' entry 'floor' is -1, not a positive number"),
], ids=["list", "regions", "map_model", "fit_id", "dataset", "region", "warning", "model_posterior", "channel",
        "likelihood_power", "noise_model", "noise_floor"])
def test_a_summary_of_the_wrong_shape_is_named_by_every_reader(copy, damage, problem):
    fit, commands = copy
    damage(fit)
    for command in commands.values():
        assert one_error_line(command) == "Error: " + SUMMARY.format(fit=fit, problem=problem)


def test_diagnose_weighs_the_likelihood_as_the_fit_did(copy, tmp_path):
    """A coarsened fit's power (summary.json's likelihood_power) is the diagnosis' default;
    --likelihood-power overrides it, and the refits' evidence changes with it."""
    fit, commands = copy
    edit_summary(lambda s: s.update(likelihood_power=0.25))(fit)
    evidence = {}
    for option, expected in (([], 0.25), (["--likelihood-power", "1"], 1.0)):
        result = CliRunner().invoke(main, commands["diagnose"] + option)
        assert result.exit_code == 0, result.output
        diagnosis = json.loads((tmp_path / "d" / "diagnosis.json").read_text())
        assert diagnosis["likelihood_power"] == expected
        evidence[expected] = diagnosis["plain_model"]["log_evidence"]
        markdown = (tmp_path / "d" / "diagnosis.md").read_text()
        assert ("Likelihood power: 0.25" in markdown) == (expected == 0.25)
        # what that power asks of a candidate, in plain log-likelihood: ln 100 / 0.25 = 18.4
        assert ("over zeta, 18 nats" in markdown) == (expected == 0.25)
    # the refits weigh the likelihood by the power (test_diagnose_units checks how); unweighted,
    # both would give the same evidence
    assert abs(evidence[0.25] - evidence[1.0]) > 1.0, evidence
    result = CliRunner().invoke(main, commands["diagnose"] + ["--likelihood-power", "0"])
    assert result.exit_code == 2 and "'--likelihood-power': 0.0 is not in the range 0.0<x<=1.0" in result.output


def test_diagnose_weighs_the_observations_by_the_fit_s_noise_model(copy, tmp_path):
    """A fit made with --noise relative is diagnosed with the same known scales (summary.json's
    noise record, its floor included); --noise constant overrides it."""
    fit, commands = copy
    edit_summary(lambda s: s["noise"].update(model="relative", floor=0.1))(fit)
    for option, expected in (([], "relative"), (["--noise", "constant"], "constant")):
        result = CliRunner().invoke(main, commands["diagnose"] + option)
        assert result.exit_code == 0, result.output
        diagnosis = json.loads((tmp_path / "d" / "diagnosis.json").read_text())
        assert diagnosis["noise"]["model"] == expected
        assert diagnosis["noise"]["floor"] == (0.1 if expected == "relative" else None)
        # the scales were computed (their range is recorded) for the relative model only;
        # test_diagnose_units checks how they enter the refits
        assert ("sum_log_scale" in diagnosis["noise"]) == (expected == "relative")
        assert ("Noise model: relative" in (tmp_path / "d" / "diagnosis.md").read_text()) == (expected == "relative")


def test_a_truncated_summary_is_named_by_every_reader(copy):
    fit, commands = copy
    truncate(fit)
    for command in commands.values():
        line = one_error_line(command)
        assert line.startswith(f"Error: {fit}/summary.json: not valid JSON (")
        assert line.endswith(f"was it truncated or edited by hand? Run `rjfit fit DATASET --out {fit}` again to "
                             f"rewrite it.")


def test_a_missing_summary_or_dataset_entry(copy):
    fit, commands = copy
    summary = json.loads((fit / "summary.json").read_text())
    dataset = (fit / summary.pop("dataset")).resolve()       # stored relative to the fit folder
    (fit / "summary.json").write_text(json.dumps(summary))
    assert one_error_line(commands["diagnose"]) == (f"Error: {fit}/summary.json: no 'dataset' entry; pass the data "
                                                    f"set (--dataset DIR)")
    assert one_error_line(commands["compare"]) == (f"Error: {fit}: is a fit of an unknown data set (summary.json has "
                                                   f"no 'dataset' entry), not of {dataset}; compare a data set with "
                                                   f"its own fit")
    (fit / "summary.json").unlink()
    for name in ("report", "diagnose"):
        assert one_error_line(commands[name]) == (f"Error: {fit}: not a fit folder (no summary.json); give the folder "
                                                  f"that `rjfit fit DATASET --out FOLDER` wrote, or run it again if it "
                                                  f"was interrupted")


@pytest.mark.parametrize("damage, message", [
    (lambda fit: (fit / "labels.exr").unlink(),
     "{fit}: no MAP segmentation (looked for map_labels.exr, labels.exr); give the folder that `rjfit fit` wrote, "
     "or " + AGAIN),
    (lambda fit: (fit / "labels.exr").write_text("not an image"),
     "{fit}/labels.exr: not a readable EXR file (Unable to open '{fit}/labels.exr' for read); " + AGAIN),
    (lambda fit: write_exr(fit / "labels.exr", {"label": np.zeros((HEIGHT, WIDTH))}),
     "{fit}/labels.exr: needs a channel 'labels' (the MAP labels), has label; " + AGAIN),
    (edit_labels(lambda labels: labels[:, :-1]),
     f"{{fit}}/labels.exr: labels are {WIDTH - 1} x {HEIGHT} (width x height) but the data set's images are "
     f"{WIDTH} x {HEIGHT}; give the fit of this data set (the data set it was run on), or " + AGAIN),
    (edit_labels(on_object(np.nan)),
     f"{{fit}}/labels.exr: the labels on the object must be region indices (whole numbers from -1 to "
     f"{HEIGHT * WIDTH - 1}); 1 pixel is not (the first at row 0, column 3: nan); " + AGAIN),
    (edit_labels(on_object(np.inf)), "column 3: inf); "),
    (edit_labels(on_object(0.5)), "column 3: 0.5); "),
    (edit_labels(on_object(1e9)), "column 3: 1e+09); "),
    (edit_labels(on_object(-2)), "column 3: -2); "),
], ids=["missing", "not_exr", "no_channel", "size", "nan", "inf", "fraction", "huge", "negative"])
def test_bad_map_labels_are_named_by_their_readers(copy, damage, message):
    fit, commands = copy
    damage(fit)
    for name in ("diagnose", "compare"):
        line = one_error_line(commands[name])
        if message.startswith("{fit}"):
            assert line == "Error: " + message.format(fit=fit)
        else:
            assert line.startswith(f"Error: {fit}/labels.exr: the labels on the object must be region indices")
            assert message in line
    # the report shows the summary only: its labels are none of its business
    assert CliRunner().invoke(main, commands["report"]).exit_code == 0


def test_labels_off_the_object_may_be_nan(copy):
    """-1 or NaN off the object both mean "no region" (as compare has always read them)."""
    fit, commands = copy
    edit_labels(lambda labels: np.where(labels < 0, np.nan, labels).astype(np.float32))(fit)
    assert CliRunner().invoke(main, commands["compare"]).exit_code == 0
