"""Loading a data set of any layout, mesh stacks included (their geometry is traced with Mitsuba)."""
from __future__ import annotations

from pathlib import Path

from rjfit.data.dataset import Dataset
from rjfit.data.formats import is_mesh_stack_folder
from rjfit.data.loading import read_dataset
from rjfit.render.mesh_stack import load_mesh_stack

__all__ = ["load_dataset"]


def load_dataset(path, **options) -> Dataset:
    """Load a data set: the rjfit layout, a photometric-stereo folder or a mesh stack.

    Parameters
    ----------
    path : path-like
        The data set folder.
    **options
        Loader options of photometric-stereo folders (see :func:`rjfit.data.diligent.load_diligent`)
        or mesh stacks (``variant``, the Mitsuba variant that traces the mesh); none apply to the
        rjfit layout.

    Returns
    -------
    Dataset

    Raises
    ------
    FileNotFoundError
        If the folder is not a data set of any layout.
    DatasetFileNotFoundError
        (a ``DatasetError`` and a ``FileNotFoundError``) if a file the description names is missing.
    DatasetError
        (a ``ValueError``) as :func:`rjfit.data.loading.read_dataset` and
        :func:`rjfit.render.mesh_stack.load_mesh_stack` raise: a description that is not valid
        JSON or misses an entry, NaN/Inf pixels, missing channels, sizes that disagree,
        unusable geometry.
    """
    if is_mesh_stack_folder(Path(path)):
        return load_mesh_stack(path, **options)
    return read_dataset(path, **options)
