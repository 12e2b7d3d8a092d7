"""``rjfit diagnose FIT``: the criticism workflow on a fit folder, with the data set and MAP
segmentation the fit recorded."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from rjfit.data.calibrate import replay_calibration
from rjfit.data.exr import read_exr
from rjfit.data.fingerprint import dataset_fingerprint
from rjfit.data.formats import COLOUR
from rjfit.data.lights import turned_normals
from rjfit.data.noise import DEFAULT_FLOOR
from rjfit.diagnose.workflow import diagnose
from rjfit.errors import DatasetError
from rjfit.pipeline.fit_folder import read_map_labels, read_summary
from rjfit.progress import phase
from rjfit.render.datasets import load_dataset

__all__ = ["diagnose_fit", "fit_mean_normals"]


def diagnose_fit(fit_dir, out_dir, *, dataset=None, **options):
    """The criticism workflow (:func:`rjfit.diagnose.workflow.diagnose`) on a fit folder: its ``summary.json`` names the data set (or ``dataset``
    gives it, when the folder has moved) and the channel fitted, ``map_labels.exr`` (or
    ``labels.exr``, as ``rjfit.pipeline.fit`` writes it; channel ``labels``) holds the MAP segmentation.
    A joint colour fit (``--channel rgb``) is diagnosed on its channel mean, on its MAP materials; a fit
    under ``--preset measured`` on the data it saw (:func:`rjfit.data.calibrate.replay_calibration`); a fit that
    sampled its normals (``--normals sample``) at their posterior mean (its ``maps.exr``), as its prediction is.

    Parameters
    ----------
    fit_dir : path
        The folder ``rjfit fit`` wrote (``summary.json`` and the MAP labels).
    out_dir : path
        Where the diagnosis goes (see :func:`rjfit.diagnose.workflow.diagnose`).
    dataset : path or Dataset, optional
        The fitted data set, when the one ``summary.json`` names has moved.
    **options
        Keyword arguments of :func:`rjfit.diagnose.workflow.diagnose`; ``channel``, ``likelihood_power``, ``noise``,
        ``noise_floor``, ``base_effects`` (the effects it sampled) and ``normals`` (its posterior mean normals, where
        it sampled them) default to the fit's, and ``provenance`` is always set to the fit's folder and ``fit_id``.

    Returns
    -------
    dict
        The contents of ``diagnosis.json``.

    Raises
    ------
    FileNotFoundError
        If ``fit_dir`` is not a fit folder, has no MAP labels, or the data set it names is not there.
    ValueError
        If ``summary.json`` names no data set and ``dataset`` is not given, or the data set's files differ from
        those the fit recorded (``dataset_sha256``), or its recorded calibration does not fit the data set; and as
        :func:`rjfit.diagnose.workflow.diagnose`.
    DatasetError
        If ``summary.json`` or the MAP labels are damaged (:func:`rjfit.pipeline.fit_folder.read_summary`,
        :func:`~rjfit.pipeline.fit_folder.read_map_labels`), or a fit's maps lack its sampled normals
        (:func:`fit_mean_normals`); and as :func:`rjfit.diagnose.workflow.diagnose`.
    """
    fit_dir = Path(fit_dir)
    summary = read_summary(fit_dir)
    if dataset is None:
        named = summary.get("dataset")
        if not named:
            raise ValueError(f"{fit_dir / 'summary.json'}: no 'dataset' entry; pass the data set (--dataset DIR)")
        dataset = Path(named)
        if not dataset.is_absolute() and not dataset.exists():
            dataset = fit_dir / dataset
        if not dataset.exists():
            raise FileNotFoundError(f"{fit_dir}: the data set this fit names, {named}, is not there (moved?); "
                                    f"pass its new place with --dataset DIR")
    recorded = summary.get("dataset_sha256")
    if recorded:
        if dataset_fingerprint(dataset) != recorded:
            raise ValueError(f"{dataset}: not the data this fit was made from (its files differ from those "
                             f"{fit_dir / 'summary.json'} records); give the fitted data set, or fit this one again")
    fitted_channel = summary.get("channel") or "mean"
    power = summary.get("likelihood_power", 1.0)
    if fitted_channel == COLOUR:
        # a joint colour fit is criticised on its channel mean (the refits and effects see one
        # channel), on the colour fit's segmentation, at its power without the channels' part
        # (channels that repeat each other are one channel's information)
        design_effect = (summary.get("likelihood_power_suggestion") or {}).get("channel_design_effect") or 1.0
        fitted_channel, power = "mean", min(1.0, float(power) * float(design_effect))
    options.setdefault("channel", fitted_channel)     # the channel the fit used
    # the power of a coarsened fit: its Bayes factors weigh the data as the fit did
    options.setdefault("likelihood_power", power)
    # and its noise model: the refits weigh the observations as its sampler did
    noise_record = summary.get("noise") or {}
    options.setdefault("noise", noise_record.get("model") or "constant")
    options.setdefault("noise_floor", noise_record.get("floor") or DEFAULT_FLOOR)
    # the effects the fit sampled: the search starts from them and names only further ones
    options.setdefault("base_effects", [entry["name"] for entry in summary.get("effects") or []])
    options["provenance"] = {"fit_dir": str(fit_dir.resolve()), "fit_id": summary.get("fit_id")}
    with phase("diagnosis: loading the data set (and replaying the fit's calibration)", options.get("progress", False)):
        dataset = _data_the_fit_saw(dataset if hasattr(dataset, "images") else load_dataset(dataset), summary,
                                    fit_dir / "summary.json")
    labels = read_map_labels(fit_dir, dataset.object_mask)
    options.setdefault("normals", fit_mean_normals(fit_dir, summary, dataset.normals))
    return diagnose(dataset, labels, out_dir, **options)


def fit_mean_normals(fit_dir, summary: dict, given):
    """The posterior mean normals (H, W, 3) of a fit that sampled them (``summary`` "normals"), else None: the
    ``given`` normals turned by its maps' ``normal_dx``, ``normal_dy`` (:func:`rjfit.data.lights.turned_normals`);
    the given ones where it has none.

    Raises
    ------
    DatasetError
        If its maps file cannot be read or lacks those channels, or they are not of the normals' shape.
    """
    if (summary.get("normals") or {}).get("mode") != "sample":
        return None
    path = Path(fit_dir) / (summary.get("maps") or "maps.exr")
    try:
        maps = read_exr(path)
    except (OSError, ValueError) as error:
        raise DatasetError(f"{path}: cannot read the fit's maps ({error}); the diagnosis of a fit that sampled its "
                           f"normals needs their posterior mean (normal_dx, normal_dy)") from None
    if not {"normal_dx", "normal_dy"} <= set(maps):
        raise DatasetError(f"{path}: no normal_dx / normal_dy channels, yet {Path(fit_dir) / 'summary.json'} says "
                           f"the fit sampled its normals; fit the data set again")
    d = np.stack([maps["normal_dx"], maps["normal_dy"]], axis=-1).astype(float)
    if d.shape[:2] != given.shape[:2]:
        raise DatasetError(f"{path}: its maps are {d.shape[:2]}, the data set's images {given.shape[:2]}")
    return np.where(np.isfinite(d).all(axis=-1, keepdims=True), turned_normals(given, np.nan_to_num(d)), given)


def _data_the_fit_saw(dataset, summary: dict, source):
    """The data set as the fit recorded in ``summary`` transformed and limited it (``--preset measured``)."""
    if summary.get("calibration"):
        # a fit under --preset measured saw transformed data (pixels left out, the response
        # linearised, the lights' gains divided out): criticise the data it saw
        dataset = replay_calibration(dataset, summary["calibration"], source=str(source))
    if summary.get("max_view_angle") is not None:   # the rim the fit left out (--max-view-angle)
        dataset = dataclasses.replace(dataset, max_view_angle=float(summary["max_view_angle"]))
    return dataset
