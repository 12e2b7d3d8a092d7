"""What ``rjfit diagnose`` prints agrees with what it writes (real Mitsuba renders, real data).

- every gap printed (while searching, the per-step lines and the summary) is one of the gaps
  of diagnosis.json, written the same way: one noise estimate, one definition;
- candidates whose PSIS-LOO was not computed say "skipped", never "nan";
- ``--max-steps 0`` says the search was skipped instead of "no missing effect found";
- candidates that cannot be tried on a data set (measured data: no mesh) are printed as
  skipped, with the reason.
"""
from __future__ import annotations

import json
import re

import numpy as np
import pytest
from click.testing import CliRunner

from rjfit.cli import main
from rjfit.diagnose.document import gap_text
from rjfit.render.datasets import load_dataset

from builders import SHARED_DATA, hidden_data_sets, truth_fit_folder

BALL = SHARED_DATA / "diligent-ball"
NUMBER = r"-?\d+(?:\.\d+)?(?:e[+-]?\d+)?"


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    return hidden_data_sets(tmp_path_factory, resolution=32)


def _diagnose(fit_dir, out_dir, *options):
    outcome = CliRunner().invoke(main, ["diagnose", str(fit_dir), "--out", str(out_dir), "--no-simulate", *options])
    return outcome


def test_printed_gaps_are_those_of_diagnosis_json(rendered, tmp_path):
    """Interreflection hidden in the dented plaster: it is named, and its step line, the
    summary and diagnosis.json give the same gaps (they used to differ: 2.466 -> 0.409 printed,
    2.383 -> 0.375 written, the printed ones from the plain model's noise estimate)."""
    fit_dir = truth_fit_folder(rendered("interreflection"), tmp_path / "fit")
    outcome = _diagnose(fit_dir, tmp_path / "out", "--max-steps", "2")
    assert outcome.exit_code == 0, outcome.output
    output = outcome.output
    result = json.loads((tmp_path / "out" / "diagnosis.json").read_text())
    assert result["named_effects"][:1] == ["interreflection"], output
    written = {gap_text(result["gap_plain"]), gap_text(result["gap_final"])}
    for step in result["steps"]:
        written |= {gap_text(step["gap_before"]), gap_text(step["gap_after"])}
        line = f"+ {step['effect']}: gap {gap_text(step['gap_before'])} -> {gap_text(step['gap_after'])}"
        assert line in output, output
    assert f"gap: plain {gap_text(result['gap_plain'])} -> final {gap_text(result['gap_final'])}" in output
    printed = set()
    for before, after in re.findall(rf"\bgap:? (?:plain )?({NUMBER})(?: -> (?:final )?({NUMBER}))?", output):
        printed |= {before} | ({after} if after else set())
    assert printed and printed <= written, (sorted(printed - written), output)
    # The Markdown report uses the same numbers.
    markdown = (tmp_path / "out" / "diagnosis.md").read_text()
    step = result["steps"][0]
    assert f"| {gap_text(step['gap_before'])} | {gap_text(step['gap_after'])} |" in markdown


def test_candidates_without_loo_say_skipped_not_nan(rendered, tmp_path):
    fit_dir = truth_fit_folder(rendered("interreflection"), tmp_path / "fit")
    outcome = _diagnose(fit_dir, tmp_path / "out", "--max-steps", "1")
    assert outcome.exit_code == 0, outcome.output
    assert "nan" not in outcome.output.lower(), outcome.output
    result = json.loads((tmp_path / "out" / "diagnosis.json").read_text())
    untested = [row for row in result["candidates"] if "delta_elpd_loo" not in row and "error" not in row]
    assert untested, "the test needs a candidate whose log BF is below ln 100"
    for row in untested:
        assert row["loo_skipped"] == "log BF <= ln 100, cannot be decisive"
        assert re.search(rf"step 1 {row['effect']}\s+log BF .* dLOO skipped: log BF <= ln 100", outcome.output), \
            outcome.output
    # Only one step allowed and an effect named: the summary says the search was cut short.
    assert "stopped after 1 step (max_steps)" in outcome.output
    markdown = (tmp_path / "out" / "diagnosis.md").read_text()
    assert "nan" not in markdown.lower() and "skipped (log BF <= ln 100, cannot be decisive)" in markdown


def test_max_steps_zero_says_the_search_was_skipped(rendered, tmp_path):
    fit_dir = truth_fit_folder(rendered("interreflection"), tmp_path / "fit")
    outcome = _diagnose(fit_dir, tmp_path / "out", "--max-steps", "0")
    assert outcome.exit_code == 0, outcome.output
    assert "no missing effect" not in outcome.output, outcome.output
    assert "named effects: none (search skipped: max_steps is 0" in outcome.output, outcome.output
    result = json.loads((tmp_path / "out" / "diagnosis.json").read_text())
    assert result["candidates"] == [] and result["steps"] == []
    assert result["search"] == {"max_steps": 0, "stopped": result["search"]["stopped"], "base_refits": []}
    assert result["search"]["stopped"].startswith("search skipped: max_steps is 0")
    markdown = (tmp_path / "out" / "diagnosis.md").read_text()
    assert "no missing effect" not in markdown and "search skipped: max_steps is 0" in markdown
    # A negative count is refused before any work, by the command line and by the function.
    refused = _diagnose(fit_dir, tmp_path / "out2", "--max-steps", "-1")
    assert refused.exit_code == 2 and "--max-steps" in refused.output
    from rjfit.diagnose.workflow import diagnose

    dataset = load_dataset(rendered("interreflection"))
    with pytest.raises(ValueError, match="max_steps must be an integer >= 0"):
        diagnose(dataset, dataset.truth_labels, tmp_path / "out3", max_steps=-1)


@pytest.mark.skipif(not (BALL / "filenames.txt").is_file(), reason=f"measured data set not present at {BALL.resolve()}")
def test_measured_data_prints_skipped_candidates_with_the_reason(tmp_path, capsys):
    """The DiLiGenT ball has no mesh: interreflection and cast shadows cannot be tried. They
    are printed as skipped with the reason (they used to appear only in diagnosis.json). A
    12 x 12 patch of the ball keeps the run short."""
    from rjfit.data.diligent import crop_to_mask
    from rjfit.diagnose.workflow import diagnose

    ball = crop_to_mask(load_dataset(BALL))
    height, width = ball.image_shape
    labels = np.full(ball.image_shape, -1)
    patch = np.zeros(ball.image_shape, dtype=bool)
    patch[height // 2 - 6:height // 2 + 6, width // 2 - 6:width // 2 + 6] = True
    labels[patch & ball.object_mask] = 0
    result = diagnose(ball, labels, tmp_path / "out", max_steps=1, make_figures=False, progress=True)
    output = capsys.readouterr().out
    assert set(result["skipped"]) == {"interreflection", "cast_shadows"}
    for name, why in result["skipped"].items():
        assert re.search(rf"{name}\s+skipped: {re.escape(why)}", output), output
        assert "mesh" in why
    assert "nan" not in output.lower()
