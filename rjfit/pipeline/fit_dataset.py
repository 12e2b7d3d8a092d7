"""Fit data sets from disk: the cross-check gate, observations, the RJMCMC fit, batches.

``rjfit fit DATASET [DATASET ...]`` calls :func:`fit_datasets`. One data set runs its
chains in parallel (worker processes, or Dask workers with ``scheduler``); several data
sets are independent fits, run one per Dask task when a scheduler is given.
"""
from __future__ import annotations

import dataclasses
import functools
import math
from pathlib import Path


from rjfit.data.calibrate import calibrate_measured, calibration_warnings
from rjfit.data.dataset import read_validation_result
from rjfit.data.fingerprint import dataset_fingerprint
from rjfit.data.loading import dataset_kind
from rjfit.data.formats import COLOUR
from rjfit.pipeline.fit import FitSource, fit
from rjfit.pipeline.fit_effects import fit_effects
from rjfit.pipeline.options import EACH_CHANNEL, FitOptions
from rjfit.pipeline.resolve import (GHOST_ODDS, GHOST_PIXELS, DataFacts, default_lines, ghost_material_prior,
                                    refuse_early, resolve_options)
from rjfit.progress import phase
from rjfit.render.datasets import load_dataset
from rjfit.render.gate import require_validated
from rjfit.sampler.runner import run_chain

__all__ = ["fit_dataset", "fit_datasets", "check_validation_file", "validation_record", "ghost_material_prior",
           "GHOST_PIXELS", "GHOST_ODDS"]

def fit_dataset(dataset_dir, out_dir, options: FitOptions | None = None, *, validation_path=None,
                allow_unvalidated=False, scheduler=None, n_workers=2, client=None, **option_keywords) -> dict:
    """Fit one data set after checking that its forward model passed the gate.

    Besides :func:`rjfit.pipeline.fit.fit`'s results it records the data set (its folder,
    digest, channel, crop and the validation it was fitted under) and, with figures, draws
    ``figures/valid_images.png`` (the valid-images map beside a map per rule that left
    observations out).

    Parameters
    ----------
    dataset_dir, out_dir : path
    options : FitOptions, optional
        The options given (``option_keywords`` build or change them), resolved for this data set
        (:func:`rjfit.pipeline.resolve.resolve_options`: a measured stack's default is the
        material model under ``--preset measured``). ``options.channel`` is the colour channel
        fitted (see :meth:`rjfit.data.dataset.Dataset.channel_values`).
    validation_path : path, optional
        The gate's ``validation.json`` (default ``dataset_dir/validation/validation.json``).
    allow_unvalidated : bool
        Fit even without a passing validation; the summary records it.
    scheduler, n_workers, client
        Run the chains as Dask tasks (``scheduler='local'`` starts a local cluster).

    Returns
    -------
    dict
        The summary, also written to ``out_dir/summary.json``.

    Raises
    ------
    rjfit.render.gate.ValidationRequiredError
        If the data set has not passed the gate and ``allow_unvalidated`` is False.
    DatasetError
        If the validation file is not a validation result (e.g. a fit's ``summary.json``), or
        the data set cannot be loaded (see :func:`rjfit.render.datasets.load_dataset`).
    ValueError
        For an option out of range (:class:`FitOptions`), or one the fit's models do not read
        (:func:`rjfit.pipeline.resolve.resolve_options`).
    """
    options = FitOptions.build(options, **option_keywords)
    dataset_dir = Path(dataset_dir)
    check_validation_file(dataset_dir, validation_path)
    validation = require_validated(dataset_dir, validation_path, allow_unvalidated=allow_unvalidated)
    refuse_early(options, dataset_kind(dataset_dir))     # the one line before any work
    # before resolve_options (it needs the data set): a progress not given is the default's
    progress = FitOptions.default("progress") if options.progress is None else options.progress
    with phase(f"loading the data set {dataset_dir}", progress):
        dataset = load_dataset(dataset_dir)
    facts = DataFacts.of(dataset)
    options = resolve_options(options, facts)
    dataset, calibration = _prepared(dataset, options)
    chain_runner = None
    if scheduler is not None or client is not None:
        from rjfit.pipeline.distributed import dask_map  # Dask: only when asked for

        address = None if scheduler in (None, "local") else scheduler
        # a Dask worker runs one chain on one core unless told otherwise (--threads)
        chain = functools.partial(run_chain, threads=options.threads or 1)
        chain_runner = functools.partial(dask_map, chain, scheduler=address, n_workers=n_workers, client=client,
                                         key_prefix="rjfit-chain")
    validation_file = Path(validation_path) if validation_path else dataset_dir / "validation" / "validation.json"
    record = validation_record(validation, validation_file)
    entries = {"dataset": str(dataset_dir.resolve()),
               "dataset_sha256": dataset_fingerprint(dataset_dir),     # what later commands check it against
               "channel": options.channel, "validation": record}
    entries.update(_data_entries(dataset, calibration, default_lines(options, facts)))
    warnings = () if record.get("passed") else (
        f"the forward model {record['note']}: the fit was forced (--allow-unvalidated), so its regions and parameters "
        f"are not trustworthy",)
    warnings += calibration_warnings(calibration)
    source = FitSource(entries=entries, warnings=warnings, exclusion_counts=dataset.exclusion_counts(
                            "mean" if options.channel == COLOUR else options.channel),
                       object_mask=dataset.object_mask, n_lights=dataset.n_lights, view_angle=dataset.view_angles())
    observations = dataset.observations(options.channel, tangents=options.normals == "sample")
    effects, effect_source = fit_effects(dataset, observations, options)
    return fit(observations, out_dir, options, truth_labels=dataset.truth_labels,
               truth_params=dataset.truth_params, chain_runner=chain_runner, source=source, sampler_effects=effects,
               effect_source=effect_source)


def _data_entries(dataset, calibration, data_defaults) -> dict:
    """The summary's entries of what the fit did to the data set and what the data chose."""
    entries = {}
    if dataset.meta.get("crop"):
        entries["crop"] = dataset.meta["crop"]      # where the maps sit in the original frame
    if calibration is not None:
        entries["calibration"] = calibration
    if data_defaults:
        entries["data_defaults"] = data_defaults
    if dataset.max_view_angle is not None:     # what `rjfit diagnose` leaves out again
        entries.update(max_view_angle=dataset.max_view_angle, rim_pixels=int(dataset.rim_pixels().sum()))
    return entries


def _prepared(dataset, options: FitOptions):
    """The data set a fit runs on under its resolved options, and the calibration record (None without one):
    under ``options.calibrate`` the calibrated images; the rim limit (``--max-view-angle``)."""
    calibration = None
    if options.calibrate:
        dataset, calibration = calibrate_measured(dataset, options.channel, options.seed, progress=options.progress,
                                                   field_degree=options.light_field)
    if options.max_view_angle is not None and options.max_view_angle < 90.0:
        dataset = dataclasses.replace(dataset, max_view_angle=options.max_view_angle)
    return dataset, calibration


def check_validation_file(dataset_dir, validation_path=None) -> None:
    """Check the validation file a fit will read, before the gate reads it: ``validation_path``
    (``--validation FILE``), else ``dataset_dir/validation/validation.json`` where it exists.

    A file that is not a validation result (a fit's ``summary.json``, ``{"passed": false}``)
    must be refused with a message naming it, not fail while the gate formats its numbers.
    A missing file is left to :func:`rjfit.render.gate.require_validated`, which says what to run.

    Raises
    ------
    DatasetError
        If the file is not JSON or not a validation result written by ``rjfit validate``.
    """
    path = Path(dataset_dir) / "validation" / "validation.json" if validation_path is None else Path(validation_path)
    if path.is_file():
        read_validation_result(path)


def _measure(value) -> str:
    """A validation measure for a message: ``n/a`` where the result has none (null, missing, NaN)."""
    if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value):
        return f"{value:.3g}"
    return "n/a"


def validation_record(validation, validation_file) -> dict:
    """What a summary records of the cross-check it was fitted under (``note`` says why it did not pass)."""
    if validation is None:
        return {"passed": None, "note": "was not cross-checked (no validation.json)"}
    record = {**{key: validation.get(key) for key in ("passed", "median_rel_err", "p99_rel_err", "unexplained_fraction")},
              "path": str(Path(validation_file).resolve())}
    if not validation.get("passed"):
        record["note"] = (f"FAILED the cross-check (median rel. err. {_measure(validation.get('median_rel_err'))}, "
                          f"p99 {_measure(validation.get('p99_rel_err'))})")
    elif validation.get("stale"):
        record["passed"] = None
        record["note"] = "was cross-checked on other files (the data set changed since)"
    return record


def _fit_one(arguments):
    dataset_dir, out_dir, options, gate = arguments
    return fit_dataset(dataset_dir, out_dir, options, **gate)


def fit_datasets(dataset_dirs, out_dir, options: FitOptions | None = None, *, validation_path=None,
                 allow_unvalidated=False, scheduler=None, n_workers=2, **option_keywords):
    """Fit several data sets: ``out_dir`` itself for one, ``out_dir/<name>`` for each of several.

    With ``channel="each"`` every data set is fitted once per colour channel
    (:data:`rjfit.pipeline.options.EACH_CHANNEL`), into a sub-folder named after the channel
    (``out_dir/R``, or ``out_dir/<name>/R`` for several data sets). With a scheduler and
    several fits, each fit is one Dask task (its chains run in that worker, one after
    another); results equal the serial ones for the same seed. Parameters as
    :func:`fit_dataset`.

    Returns
    -------
    list of (Path, dict)
        Each fit folder with its summary.

    Raises
    ------
    rjfit.render.gate.ValidationRequiredError
        If a data set has not passed the gate and ``allow_unvalidated`` is not set.
    DatasetError
        If a validation file is not a validation result, or a data set cannot be loaded.
    ValueError
        If several data sets share a folder name, or an option is out of range.
    """
    options = FitOptions.build(options, **option_keywords)
    dataset_dirs = [Path(d) for d in dataset_dirs]
    out_dir = Path(out_dir)
    for dataset_dir in dataset_dirs:     # every gate first: a batch must not stop at its third data set
        check_validation_file(dataset_dir, validation_path)
        require_validated(dataset_dir, validation_path, allow_unvalidated=allow_unvalidated)
    if len(dataset_dirs) == 1:
        folders = [out_dir]
    else:
        names = [d.resolve().name for d in dataset_dirs]
        if len(set(names)) != len(names):
            raise ValueError(f"data sets share folder names {names}; fit them into separate --out folders")
        folders = [out_dir / name for name in names]
    if options.channel == "each":
        jobs = [(d, folder / channel, options.replace(channel=channel))
                for d, folder in zip(dataset_dirs, folders) for channel in EACH_CHANNEL]
    else:
        jobs = [(d, folder, options) for d, folder in zip(dataset_dirs, folders)]
    gate = {"validation_path": validation_path, "allow_unvalidated": allow_unvalidated}
    if len(jobs) == 1:
        dataset_dir, folder, job_options = jobs[0]
        return [(folder, fit_dataset(dataset_dir, folder, job_options, scheduler=scheduler, n_workers=n_workers,
                                     **gate))]
    if scheduler is None:
        return [(folder, fit_dataset(d, folder, job_options, **gate)) for d, folder, job_options in jobs]
    from rjfit.pipeline.distributed import dask_map  # Dask: only when asked for

    address = None if scheduler == "local" else scheduler
    tasks = [(d, folder, job_options.replace(processes=1, threads=1, progress=False), gate)
             for d, folder, job_options in jobs]
    summaries = dask_map(_fit_one, tasks, scheduler=address, n_workers=n_workers, key_prefix="rjfit-fit")
    return list(zip([folder for _, folder, _ in jobs], summaries))
