"""A diagnosis's files are published together (diagnosis.json last) and replace the previous
diagnosis's: no figure of an earlier run stays in the folder or reaches the report, and an
interrupted diagnosis leaves the previous one whole. Ambient light hidden in a 16 x 16 render
keeps each run to a few seconds."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from rjfit.diagnose import document, figures
from rjfit.diagnose.workflow import diagnose
from rjfit.pipeline.report import build_report
from rjfit.render.datasets import load_dataset
from rjfit.render.hidden import render_hidden

QUICK = dict(candidates=["ambient", "fresnel"], max_steps=1, simulate=False)


@pytest.fixture(scope="module")
def ambient(tmp_path_factory):
    return load_dataset(render_hidden("ambient", tmp_path_factory.mktemp("ambient") / "dataset", resolution=16))


def _snapshot(folder: Path) -> dict:
    return {path.relative_to(folder): path.read_bytes() for path in folder.rglob("*") if path.is_file()}


def _report(tmp_path, diagnosis_dir) -> str:
    fit_dir = tmp_path / "fit"
    fit_dir.mkdir(exist_ok=True)
    (fit_dir / "summary.json").write_text("{}")
    return build_report(fit_dir, diagnosis_dir=diagnosis_dir).read_text()


def test_a_new_diagnosis_leaves_no_figure_of_the_previous_one(ambient, tmp_path):
    out = tmp_path / "diagnosis"
    first = diagnose(ambient, ambient.truth_labels, out, **QUICK)
    first_figures = figures.listed_figures(first)
    assert first["named_effects"] == ["ambient"] and "signatures_step1.png" in first_figures
    assert {path.name for path in out.glob("*.png")} == set(first_figures)
    (out / "my_notes.png").write_bytes((out / first_figures[0]).read_bytes())      # not diagnose's
    html = _report(tmp_path, out)
    assert all(f"diagnosis: {Path(name).stem.replace('_', ' ')}" in html for name in first_figures)
    assert "my notes" not in html, "the report embeds a PNG the diagnosis does not name"

    # the same folder, another search: the plain model's gap only, no figure at all
    second = diagnose(ambient, ambient.truth_labels, out, max_steps=0, simulate=False)
    assert figures.listed_figures(second) == []
    assert sorted(path.name for path in out.iterdir()) == ["diagnosis.json", "diagnosis.md", "my_notes.png"]
    html = _report(tmp_path, out)
    assert "data:image/png" not in html and "search skipped: max_steps is 0" in html


@pytest.mark.parametrize("interrupted", ["signature_figure", "markdown"])
def test_an_interrupted_diagnosis_leaves_the_previous_one_whole(ambient, tmp_path, monkeypatch, interrupted):
    """Ctrl-C while the figures are written, or between diagnosis.json and diagnosis.md (which
    used to pair a new json with the old Markdown): the folder is as the previous run left it."""
    out = tmp_path / "diagnosis"
    diagnose(ambient, ambient.truth_labels, out, **QUICK)
    before = _snapshot(out)

    def interrupt(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(figures if interrupted == "signature_figure" else document, interrupted, interrupt)
    with pytest.raises(KeyboardInterrupt):
        diagnose(ambient, ambient.truth_labels, out, seed=1, candidates=["ambient"], max_steps=1, simulate=False)
    assert _snapshot(out) == before
    assert not list(out.glob(".*")), "a staging folder or temporary file stayed behind"
    monkeypatch.undo()
    result = json.loads((out / "diagnosis.json").read_text())
    assert result["seed"] == 0 and (out / "diagnosis.md").read_text() == document.markdown(result)
