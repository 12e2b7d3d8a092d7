"""Which layout a folder holds, and reading the layouts whose geometry is on disk.

Three layouts hold a data set: the rjfit layout (``dataset.json``, :mod:`rjfit.data.dataset`),
photometric-stereo folders (:mod:`rjfit.data.diligent`) and mesh stacks (``stack.json``). A
mesh stack's per-pixel geometry comes from tracing its mesh with Mitsuba, so it is read one
layer up, by :func:`rjfit.render.datasets.load_dataset`, which reads every layout.
"""
from __future__ import annotations

import json
from pathlib import Path

from rjfit.data.dataset import Dataset, load_rjfit_layout
from rjfit.data.diligent import is_diligent_folder, load_diligent
from rjfit.data.formats import is_mesh_stack_folder
from rjfit.errors import DatasetError

__all__ = ["dataset_kind", "is_dataset", "read_dataset"]


def is_dataset(path) -> bool:
    """Whether ``path`` is a data set folder of any layout (rjfit layout, mesh stack or DiLiGenT)."""
    path = Path(path)
    return (path / "dataset.json").is_file() or is_mesh_stack_folder(path) or is_diligent_folder(path)


def read_dataset(path, **options) -> Dataset:
    """Read a data set in the rjfit layout or a photometric-stereo folder.

    Parameters
    ----------
    path : path-like
        The data set folder.
    **options
        Loader options of photometric-stereo folders (see :func:`rjfit.data.diligent.load_diligent`);
        none apply to the rjfit layout.

    Returns
    -------
    Dataset

    Raises
    ------
    FileNotFoundError
        If the folder is not a data set of any layout.
    DatasetError
        If it is a mesh stack (read those with :func:`rjfit.render.datasets.load_dataset`), if
        options are given for the rjfit layout, or as :func:`rjfit.data.dataset.load_rjfit_layout`
        and :func:`rjfit.data.diligent.load_diligent` raise.
    """
    path = Path(path)
    if (path / "dataset.json").is_file():
        if options:
            raise DatasetError(f"{path}: options {sorted(options)} apply to photometric-stereo folders only")
        return load_rjfit_layout(path)
    if is_mesh_stack_folder(path):
        raise DatasetError(f"{path}: a mesh stack; its geometry comes from tracing the mesh with Mitsuba, so read it "
                           f"with rjfit.render.datasets.load_dataset")
    if is_diligent_folder(path):
        return load_diligent(path, **options)
    raise FileNotFoundError(f"{path}: not a data set (no dataset.json, and not a DiLiGenT-style folder)")


def dataset_kind(path) -> str:
    """'measured' or 'rendered', read without loading the images: a mesh stack or a photometric-stereo
    folder is measured; the rjfit layout says in its ``dataset.json`` ("kind"; `rjfit render` writes
    'synthetic'). A file that cannot be read is left to the loader, which names the problem."""
    path = Path(path)
    description = path / "dataset.json"
    if not description.is_file():
        return "measured"
    try:
        kind = json.loads(description.read_text()).get("kind")
    except (OSError, ValueError, AttributeError):
        return "rendered"
    return "measured" if kind == "measured" else "rendered"

