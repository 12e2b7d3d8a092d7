"""Builders shared by several test files (``from builders import ...``: pytest puts tests/ on the
path, ``pythonpath = ["tests"]`` in pyproject.toml). One section per package; each builder
makes real data (Mitsuba renders, EXR files), nothing mocked."""
from __future__ import annotations

import json
from pathlib import Path


# ---------------------------------------------------------------------------------------------
# criticism (rjfit.diagnose): hidden-effect data sets and fit folders for `rjfit diagnose`
# ---------------------------------------------------------------------------------------------

def hidden_data_sets(tmp_path_factory, resolution=32):
    """A function ``get(kind)`` that renders the hidden-effect data set ``kind``
    (:func:`rjfit.render.hidden.render_hidden`, e.g. "ambient", "ambient+light_calibration") at
    ``resolution`` once, into a folder of ``tmp_path_factory``, and returns its path: a
    module-scoped fixture returns it so that each kind is rendered once per test file."""
    from rjfit.render.hidden import render_hidden

    cache = {}

    def get(kind):
        if kind not in cache:
            folder = tmp_path_factory.mktemp(kind.replace("+", "_")) / "dataset"
            cache[kind] = render_hidden(kind, folder, resolution=resolution)
        return cache[kind]
    return get


def truth_fit_folder(dataset_path, folder: Path) -> Path:
    """A fit folder as ``rjfit fit`` leaves it for ``rjfit diagnose``: ``summary.json`` naming the
    data set and ``map_labels.exr`` holding its TRUTH labels as the MAP segmentation (created)."""
    from rjfit.data.exr import write_exr
    from rjfit.render.datasets import load_dataset

    folder.mkdir()
    (folder / "summary.json").write_text(json.dumps({"dataset": str(dataset_path)}))
    write_exr(folder / "map_labels.exr", {"labels": load_dataset(dataset_path).truth_labels.astype(float)})
    return folder
