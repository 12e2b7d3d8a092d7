"""Reading the folder ``rjfit fit`` wrote: ``summary.json`` and the MAP labels, checked.

Its readers (``rjfit report``, ``rjfit diagnose``, ``rjfit compare --fit``) get the contents,
or one :class:`~rjfit.errors.DatasetError` that names the file, says what is wrong with it
and what to do: a damaged or hand-edited file never reaches them as a traceback.
(``chains.nc`` is read by ArviZ itself: ``arviz.from_netcdf``.)
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from rjfit.data.formats import CHANNELS
from rjfit.data.noise import NOISE_MODELS
from rjfit.errors import DatasetError, DatasetFileNotFoundError
from rjfit.io import read_json

__all__ = ["read_summary", "read_map_labels", "MAP_LABEL_FILES", "SUMMARY_TYPES"]

#: file names of the MAP labels in a fit folder, tried in this order (rjfit/fit.py writes labels.exr)
MAP_LABEL_FILES = ("map_labels.exr", "labels.exr")

#: the entries of summary.json that a reader uses and the JSON type each must have (null reads as absent)
SUMMARY_TYPES = {"dataset": str, "dataset_sha256": str, "fit_id": str, "channel": str, "map_model": dict,
                 "regions": list, "model_posterior": dict, "warnings": list, "noise": dict, "validation": dict,
                 "crop": dict, "truth_params": list, "label_matching": dict, "chain_regions": list}
_TYPE_NAMES = {str: "a string", dict: "an object", list: "a list", float: "a number"}


def _again(fit_dir) -> str:
    return f"run `rjfit fit DATASET --out {fit_dir}` again"


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _first_bad(key, items, good, kind) -> list:
    """A problem naming the first of ``items`` (name, value) that is not ``good``; [] if none."""
    for name, value in items:
        if not good(value):
            return [f"'{key}' entry {name!r} is {_short(value)}, not {_TYPE_NAMES[kind]}"]
    return []


def read_summary(fit_dir) -> dict:
    """The contents of ``fit_dir/summary.json``, checked.

    Parameters
    ----------
    fit_dir : path
        A folder ``rjfit fit`` wrote. No entry is required (a reader checks those it cannot
        do without); each of :data:`SUMMARY_TYPES` that is there must have its type.

    Raises
    ------
    DatasetFileNotFoundError
        If there is no ``summary.json`` (not a fit folder, or an interrupted fit).
    DatasetError
        If it is not valid JSON, not a JSON object, or an entry has the wrong type (``regions``
        must hold objects, ``warnings`` strings, ``model_posterior`` numbers, ``channel`` one of
        :data:`rjfit.data.formats.CHANNELS`, ``likelihood_power`` a number in (0, 1], ``noise`` a
        model of :data:`rjfit.data.noise.NOISE_MODELS` with a positive floor or none).
    """
    fit_dir = Path(fit_dir)
    path = fit_dir / "summary.json"
    if not path.is_file():
        raise DatasetFileNotFoundError(f"{fit_dir}: not a fit folder (no summary.json); give the folder that "
                                       f"`rjfit fit DATASET --out FOLDER` wrote, or run it again if it was interrupted")
    try:
        summary = read_json(path)
    except DatasetError as error:
        text = str(error) if str(error).endswith("?") else f"{error}."
        raise DatasetError(f"{text} Run `rjfit fit DATASET --out {fit_dir}` again to rewrite it.") from None
    if not isinstance(summary, dict):
        raise DatasetError(f"{path}: not a summary `rjfit fit` wrote (a JSON {type(summary).__name__}, not an "
                           f"object); {_again(fit_dir)}")
    problems = []
    for key, kind in SUMMARY_TYPES.items():
        value = summary.get(key)
        if value is not None and not isinstance(value, kind):
            problems.append(f"'{key}' is {_short(value)}, not {_TYPE_NAMES[kind]}")
    if isinstance(summary.get("regions"), list):
        problems += _first_bad("regions", enumerate(summary["regions"]), lambda v: isinstance(v, dict), dict)
    if isinstance(summary.get("warnings"), list):
        problems += _first_bad("warnings", enumerate(summary["warnings"]), lambda v: isinstance(v, str), str)
    if isinstance(summary.get("model_posterior"), dict):
        problems += _first_bad("model_posterior", summary["model_posterior"].items(), _is_number, float)
    power = summary.get("likelihood_power")
    if power is not None and not (_is_number(power) and 0.0 < power <= 1.0):
        problems.append(f"'likelihood_power' is {_short(power)}, not a number in (0, 1]")
    noise = summary.get("noise")
    if isinstance(noise, dict):
        if noise.get("model") is not None and noise["model"] not in NOISE_MODELS:
            problems.append(f"'noise' entry 'model' is {_short(noise['model'])}, not one of {', '.join(NOISE_MODELS)}")
        floor = noise.get("floor")
        if floor is not None and not (_is_number(floor) and 0.0 < floor < float("inf")):
            problems.append(f"'noise' entry 'floor' is {_short(floor)}, not a positive number")
    if isinstance(summary.get("channel"), str) and summary["channel"] not in CHANNELS:
        problems.append(f"'channel' is {summary['channel']!r}, not one of {', '.join(CHANNELS)}")
    if problems:
        raise DatasetError(f"{path}: not a summary `rjfit fit` wrote ({'; '.join(problems)}); {_again(fit_dir)}")
    return summary


def read_map_labels(fit_dir, mask) -> np.ndarray:
    """The fit's MAP segmentation: ``map_labels.exr`` (or, failing that, ``labels.exr``), channel
    ``labels``, checked against the data set's object mask.

    Parameters
    ----------
    fit_dir : path
        A folder ``rjfit fit`` wrote.
    mask : ndarray of bool, shape (H, W)
        The data set's object mask: its pixels must hold a whole number from -1 (no region) to
        H W - 1; outside it any value (-1, NaN) means "off the object".

    Returns
    -------
    ndarray of int64, shape (H, W)
        The region index per pixel; -1 outside ``mask`` and wherever the file has -1.

    Raises
    ------
    DatasetFileNotFoundError
        If the folder holds neither file.
    DatasetError
        If the file is not EXR, has no ``labels`` channel, another size than ``mask`` or, on
        the mask, a value that is not finite, not a whole number or out of range.
    """
    from rjfit.data.exr import read_exr

    fit_dir, mask = Path(fit_dir), np.asarray(mask, dtype=bool)
    path = next((fit_dir / name for name in MAP_LABEL_FILES if (fit_dir / name).is_file()), None)
    if path is None:
        raise DatasetFileNotFoundError(f"{fit_dir}: no MAP segmentation (looked for {', '.join(MAP_LABEL_FILES)}); "
                                       f"give the folder that `rjfit fit` wrote, or {_again(fit_dir)}")
    try:
        channels = read_exr(path)
    except ValueError as error:
        raise DatasetError(f"{error}; {_again(fit_dir)}") from None
    if "labels" not in channels:
        raise DatasetError(f"{path}: needs a channel 'labels' (the MAP labels), has "
                           f"{' '.join(sorted(channels)) or 'none'}; {_again(fit_dir)}")
    raw = np.asarray(channels["labels"], dtype=np.float64)
    if raw.shape != mask.shape:
        raise DatasetError(f"{path}: labels are {raw.shape[1]} x {raw.shape[0]} (width x height) but the data set's "
                           f"images are {mask.shape[1]} x {mask.shape[0]}; give the fit of this data set (the data "
                           f"set it was run on), or {_again(fit_dir)}")
    with np.errstate(invalid="ignore"):
        bad = mask & ~(np.isfinite(raw) & (raw == np.round(raw)) & (raw >= -1) & (raw < raw.size))
    if bad.any():
        row, col = (int(i[0]) for i in np.nonzero(bad))
        count = "1 pixel is" if bad.sum() == 1 else f"{int(bad.sum())} pixels are"
        raise DatasetError(f"{path}: the labels on the object must be region indices (whole numbers from -1 to "
                           f"{raw.size - 1}); {count} not (the first at row {row}, column {col}: {raw[row, col]:g}); "
                           f"{_again(fit_dir)}")
    labels = np.full(raw.shape, -1, dtype=np.int64)
    labels[mask] = raw[mask].astype(np.int64)
    return labels
