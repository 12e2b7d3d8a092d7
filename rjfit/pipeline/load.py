"""Load a fit folder into Python: ``rjfit.load_fit(DIR)`` (the summary, the chains and the maps).

What each file holds is :mod:`rjfit.pipeline.fit_folder`'s (the summary's schema) and
:mod:`rjfit.posterior.inference_data`'s (chains.nc's groups); this module only reads them.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rjfit.data.exr import read_exr
from rjfit.errors import DatasetError, DatasetFileNotFoundError
from rjfit.pipeline.fit_folder import read_summary

__all__ = ["LoadedFit", "load_fit"]


@dataclass(frozen=True)
class LoadedFit:
    """A fit folder's results in memory.

    Attributes
    ----------
    folder : Path
        The fit folder.
    summary : dict
        ``summary.json`` (:data:`rjfit.pipeline.fit_folder.SUMMARY_FIELDS`), its paths absolute.
    inference_data : arviz.InferenceData
        ``chains.nc``: ``posterior`` (the MAP model's region parameters), ``sample_stats``
        (``lp``, the model per kept iteration), ``log_likelihood`` (per pixel block) and
        ``constant_data`` (:mod:`rjfit.posterior.inference_data`); ready for ``az.summary``,
        ``az.loo``, ``az.plot_trace`` and ``az.plot_rank``.
    maps : dict of str to ndarray (H, W)
        ``maps.exr``'s channels: per-pixel posterior means and sd of the parameters, the MAP
        ``label``, ``valid_images``, ``residual_rms`` (and ``map_probability`` for materials).
    """

    folder: Path
    summary: dict
    inference_data: object
    maps: dict

    @property
    def labels(self) -> np.ndarray:
        """The MAP labels (H, W), int64, -1 off the object."""
        return np.rint(np.nan_to_num(self.maps["label"], nan=-1.0)).astype(np.int64)


def load_fit(fit_dir) -> LoadedFit:
    """The results of the fit in folder ``fit_dir``: its summary, its chains as ArviZ InferenceData and its maps.

    Parameters
    ----------
    fit_dir : path
        A folder that ``rjfit fit DATASET --out FOLDER`` (or :func:`rjfit.pipeline.fit.fit`) wrote.

    Returns
    -------
    LoadedFit

    Raises
    ------
    DatasetFileNotFoundError
        If the folder has no ``summary.json`` (not a fit folder, or an interrupted fit), no
        ``chains.nc`` or no ``maps.exr``.
    DatasetError
        If ``summary.json`` is damaged (:func:`rjfit.pipeline.fit_folder.read_summary`), or
        ``chains.nc`` or ``maps.exr`` cannot be read.
    """
    from rjfit.posterior.summary import _arviz  # ArviZ (xarray, netCDF): only when a fit is loaded

    folder = Path(fit_dir)
    summary = read_summary(folder)
    again = f"run `rjfit fit DATASET --out {folder}` again"
    chains, maps = folder / "chains.nc", folder / summary.get("maps", "maps.exr")
    for path in (chains, maps):
        if not path.is_file():
            raise DatasetFileNotFoundError(f"{path}: missing from the fit folder (an incomplete copy?); {again}")
    try:
        inference_data = _arviz().from_netcdf(str(chains))
    except (OSError, ValueError) as error:
        raise DatasetError(f"{chains}: not a readable netCDF file of chains ({error}); {again}") from None
    try:
        channels = read_exr(maps)
    except ValueError as error:
        raise DatasetError(f"{error}; {again}") from None
    return LoadedFit(folder=folder, summary=summary, inference_data=inference_data, maps=channels)
