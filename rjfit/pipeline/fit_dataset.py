"""Fit data sets from disk: the cross-check gate, observations, the RJMCMC fit, batches.

``rjfit fit DATASET [DATASET ...]`` calls :func:`fit_datasets`. One data set runs its
chains in parallel (worker processes, or Dask workers with ``scheduler``); several data
sets are independent fits, run one per Dask task when a scheduler is given.
"""
from __future__ import annotations

import functools
from pathlib import Path

from rjfit.render.datasets import load_dataset

__all__ = ["fit_dataset", "fit_datasets", "check_validation_file"]


def fit_dataset(dataset_dir, out_dir, *, channel="mean", burn_in=None, validation_path=None,
                allow_unvalidated=False, scheduler=None, n_workers=2, client=None, **fit_options) -> dict:
    """Fit one data set after checking that its forward model passed the gate.

    Besides :func:`rjfit.pipeline.fit.fit`'s results it writes ``maps.exr`` (per-pixel parameters,
    labels, valid-images count and residual RMS) and, with figures, ``figures/valid_images.png``
    (the valid-images map beside a map per rule that left observations out).

    Parameters
    ----------
    dataset_dir, out_dir : path
    channel : str
        Colour channel fitted (see :meth:`rjfit.data.dataset.Dataset.channel_values`).
    burn_in : float, optional
        Default 0.5 for synthetic data and 0.2 for measured data (the paper's choices).
    validation_path : path, optional
        The gate's ``validation.json`` (default ``dataset_dir/validation/validation.json``).
    allow_unvalidated : bool
        Fit even without a passing validation; the summary records it.
    scheduler, n_workers, client
        Run the chains as Dask tasks (``scheduler='local'`` starts a local cluster).
    **fit_options
        Passed to :func:`rjfit.pipeline.fit.fit` (n_chains, iterations, seed, max_u, max_v, ...).

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
    """
    from rjfit.data.fingerprint import dataset_fingerprint
    from rjfit.pipeline.fit import fit
    from rjfit.render.gate import require_validated

    dataset_dir = Path(dataset_dir)
    check_validation_file(dataset_dir, validation_path)
    validation = require_validated(dataset_dir, validation_path, allow_unvalidated=allow_unvalidated)
    dataset = load_dataset(dataset_dir)
    if burn_in is None:
        burn_in = 0.2 if dataset.meta.get("kind") == "measured" else 0.5
    chain_runner = None
    if scheduler is not None or client is not None:
        from rjfit.pipeline.distributed import dask_map
        from rjfit.sampler.runner import run_chain

        address = None if scheduler in (None, "local") else scheduler
        # a Dask worker runs one chain on one core unless told otherwise (--threads)
        chain = functools.partial(run_chain, threads=fit_options.get("threads") or 1)
        chain_runner = functools.partial(dask_map, chain, scheduler=address, n_workers=n_workers, client=client,
                                         key_prefix="rjfit-chain")
    observations = dataset.observations(channel)
    validation_file = Path(validation_path) if validation_path else dataset_dir / "validation" / "validation.json"

    def describe_data_set(summary, staging, prediction):
        summary["maps"] = write_parameter_maps(observations, summary, staging, prediction)
        if fit_options.get("figures", True):
            from rjfit.plotting import exclusion_figure

            # which observations the stated rules left out, and why (the valid-images map)
            exclusion_figure(staging / "figures" / "valid_images.png", dataset.exclusion_counts(channel),
                             dataset.object_mask, dataset.n_lights)
            summary.setdefault("figures", {})["valid_images"] = "figures/valid_images.png"
        summary["dataset"] = str(dataset_dir.resolve())
        summary["dataset_sha256"] = dataset_fingerprint(dataset_dir)    # what later commands check it against
        if dataset.meta.get("crop"):
            summary["crop"] = dataset.meta["crop"]      # where the maps sit in the original frame
        summary["channel"] = channel
        summary["validation"] = validation_record(validation, validation_file)
        if not summary["validation"].get("passed"):
            summary["warnings"].insert(0, f"the forward model {summary['validation']['note']}: the fit was forced "
                                          f"(--allow-unvalidated), so its regions and parameters are not trustworthy")

    return fit(observations, out_dir, truth_labels=dataset.truth_labels, truth_params=dataset.truth_params,
               burn_in=burn_in, chain_runner=chain_runner, before_publish=describe_data_set, **fit_options)


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
    from rjfit.data.dataset import read_validation_result

    path = Path(dataset_dir) / "validation" / "validation.json" if validation_path is None else Path(validation_path)
    if path.is_file():
        read_validation_result(path)


def _measure(value) -> str:
    """A validation measure for a message: ``n/a`` where the result has none (null, missing, NaN)."""
    import math

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


def write_parameter_maps(observations, summary, out_dir: Path, prediction=None) -> str:
    """Per-pixel maps of the MAP segmentation as one EXR: each region's posterior mean and sd
    of I0, kd, gamma, sigma^2, the label, the valid-images count (paper, Fig. 8) and the RMS
    over lights of the standardised residual ``(y - mu) / (sigma s)`` (``s`` the known noise
    scales of the summary's noise model, 1 for 'constant').

    The residual is ``prediction["residual_rms"]`` when given (the posterior mean prediction,
    averaged draw by draw: :func:`rjfit.posterior.summary.posterior_mean_prediction`, what a
    fit passes), else computed at the summary's region means on these labels (a plug-in that
    mixes modes when chains disagree)."""
    import numpy as np

    from rjfit.data.exr import read_exr, write_exr
    from rjfit.data.noise import noise_scale
    from rjfit.model.blinn import radiance

    labels = np.rint(np.nan_to_num(read_exr(out_dir / "labels.exr")["labels"], nan=-1)).astype(int)
    names = ("I0", "kd", "gamma", "sigma2")
    table = np.full((max(len(summary["regions"]), int(labels.max()) + 1) + 1, 8), np.nan)
    for index, region in enumerate(summary["regions"]):
        row = int(region.get("region", index))
        table[row] = [region[name][stat] for name in names for stat in ("mean", "sd")]
    region_of_pixel = np.where(labels >= 0, labels, table.shape[0] - 1)      # last row stays NaN
    channels = {f"{name}{suffix}": table[region_of_pixel, 2 * k + j]
                for k, name in enumerate(names) for j, suffix in enumerate(("", "_sd"))}
    size = labels.size
    count = np.bincount(observations.pixel, minlength=size)
    if prediction is not None:
        rms = prediction["residual_rms"]
    else:
        obs_params = table[region_of_pixel.ravel()[observations.pixel]]
        mu = radiance(obs_params[:, 0], obs_params[:, 2], obs_params[:, 4], observations.cos_ln, observations.cos_hn,
                      observations.irradiance)
        standardised = (observations.y - mu) / np.sqrt(obs_params[:, 6])
        noise = summary.get("noise") or {"model": "constant"}
        if noise["model"] != "constant":
            standardised /= noise_scale(observations, noise["model"], noise["floor"])
        sum_squares = np.bincount(observations.pixel, weights=np.nan_to_num(standardised) ** 2, minlength=size)
        rms = np.where(count > 0, np.sqrt(sum_squares / np.maximum(count, 1)), np.nan).reshape(labels.shape)
    channels.update(label=labels, valid_images=count.reshape(labels.shape), residual_rms=rms)
    write_exr(out_dir / "maps.exr", channels)
    return "maps.exr"


def _fit_one(arguments):
    dataset_dir, out_dir, options = arguments
    return fit_dataset(dataset_dir, out_dir, **options)


EACH_CHANNEL = ("R", "G", "B")     # what ``channel="each"`` fits, one fit per channel


def fit_datasets(dataset_dirs, out_dir, *, scheduler=None, n_workers=2, **options):
    """Fit several data sets: ``out_dir`` itself for one, ``out_dir/<name>`` for each of several.

    With ``channel="each"`` every data set is fitted once per colour channel
    (:data:`EACH_CHANNEL`), into a sub-folder named after the channel (``out_dir/R``, or
    ``out_dir/<name>/R`` for several data sets). With a scheduler and several fits, each fit
    is one Dask task (its chains run in that worker, one after another); results equal the
    serial ones for the same seed.

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
        If several data sets share a folder name.
    """
    from rjfit.render.gate import require_validated

    dataset_dirs = [Path(d) for d in dataset_dirs]
    out_dir = Path(out_dir)
    for dataset_dir in dataset_dirs:     # every gate first: a batch must not stop at its third data set
        check_validation_file(dataset_dir, options.get("validation_path"))
        require_validated(dataset_dir, options.get("validation_path"),
                          allow_unvalidated=options.get("allow_unvalidated", False))
    if len(dataset_dirs) == 1:
        folders = [out_dir]
    else:
        names = [d.resolve().name for d in dataset_dirs]
        if len(set(names)) != len(names):
            raise ValueError(f"data sets share folder names {names}; fit them into separate --out folders")
        folders = [out_dir / name for name in names]
    if options.get("channel") == "each":
        jobs = [(d, folder / channel, dict(options, channel=channel))
                for d, folder in zip(dataset_dirs, folders) for channel in EACH_CHANNEL]
    else:
        jobs = [(d, folder, options) for d, folder in zip(dataset_dirs, folders)]
    if len(jobs) == 1:
        dataset_dir, folder, job_options = jobs[0]
        return [(folder, fit_dataset(dataset_dir, folder, scheduler=scheduler, n_workers=n_workers, **job_options))]
    if scheduler is None:
        return [(folder, fit_dataset(d, folder, **job_options)) for d, folder, job_options in jobs]
    from rjfit.pipeline.distributed import dask_map

    address = None if scheduler == "local" else scheduler
    tasks = [(d, folder, dict(job_options, processes=1, threads=1, progress=False)) for d, folder, job_options in jobs]
    summaries = dask_map(_fit_one, tasks, scheduler=address, n_workers=n_workers, key_prefix="rjfit-fit")
    return list(zip([folder for _, folder, _ in jobs], summaries))
