"""The folder ``rjfit fit`` writes: its files, the ``summary.json`` schema, and their reading, checked.

:data:`SUMMARY_FIELDS` is the one statement of what ``summary.json`` holds: every entry with
its JSON type and meaning. :func:`write_summary` refuses to write an entry that is not in it
or has another type (so the schema cannot drift from the writer), and :func:`read_summary`
checks a folder's summary against it. Its readers (``rjfit report``, ``rjfit diagnose``,
``rjfit compare --fit``) get the contents, or one :class:`~rjfit.errors.DatasetError` that
names the file, says what is wrong with it and what to do: a damaged or hand-edited file
never reaches them as a traceback. (``chains.nc`` is read by ArviZ itself:
``arviz.from_netcdf``; :func:`rjfit.pipeline.load.load_fit` reads the whole folder.)

Every file a fit writes records rjfit's version, :data:`SCHEMA_VERSION` and the fit's
options (:func:`file_attributes`): summary.json as entries, chains.nc in every group's
attributes, the EXR files in their headers, the ``.npz`` files as arrays. Paths in
summary.json (``dataset``, ``validation.path``) are relative to the fit folder
(:func:`relative_paths`); :func:`read_summary` gives them back resolved, and reads the
absolute paths of folders written before schema 2 as they are.
"""
from __future__ import annotations

import hashlib
import json
import os
from contextlib import contextmanager, suppress
from importlib.metadata import version as installed_version
from pathlib import Path

import numpy as np

from rjfit.data.exr import read_exr
from rjfit.data.formats import CHANNELS, COLOUR
from rjfit.data.noise import NOISE_MODELS
from rjfit.errors import DatasetError, DatasetFileNotFoundError, OutputError
from rjfit.io import os_error_text, publish, read_json, write_json_atomic

__all__ = ["SUMMARY_FIELDS", "write_summary", "read_summary", "read_map_labels", "results_digest", "publish_results",
           "MAP_LABEL_FILES", "RESULT_FILES", "DERIVED_RESULTS", "PARAMETERS_ATTR", "save_chain_arrays",
           "kept_chains", "remove_checkpoints",
           "SCHEMA_VERSION", "file_attributes", "stamp", "relative_paths", "resolved_paths", "PATH_ENTRIES"]

#: the fit folder's schema: 1 before 2026-11-28 (absolute paths, chains.nc with NaN-padded regions and the log
#: posterior in posterior); 2: paths relative to the folder, chains.nc in ArviZ's groups
#: (rjfit.posterior.inference_data), version, schema and options in every file
SCHEMA_VERSION = 2
#: the summary's paths, as (entry, key within it or None): stored relative to the fit folder
PATH_ENTRIES = (("dataset", None), ("validation", "path"))

#: what chains.nc says its parameter dimension holds (either region model)
PARAMETERS_ATTR = ("I0 (intensity), kd (diffuse fraction), gamma (Blinn-Phong exponent), sigma2 (noise variance), "
                   "in the units of the observations")


def save_chain_arrays(path, records, keys, attributes=None) -> None:
    """Each chain's record fields ``keys`` into one compressed ``.npz`` (``chain{c}_{key}``), with
    ``attributes`` (:func:`file_attributes`) as 0-d string arrays of their names."""
    payload = {f"chain{c}_{k}": getattr(r, k) for c, r in enumerate(records) for k in keys}
    payload.update({name: np.array(value) for name, value in (attributes or {}).items()})
    with open(path, "wb") as handle:
        np.savez_compressed(handle, **payload)


def file_attributes(options_json: dict, fit_id: str | None = None) -> dict:
    """What every file of a fit records of it, as strings: ``rjfit_version``, ``rjfit_schema_version``,
    ``rjfit_fit_options`` (JSON of :meth:`FitOptions.to_json <rjfit.pipeline.options.FitOptions.to_json>`)
    and, when given, ``rjfit_fit_id``."""
    out = {"rjfit_version": installed_version("rjfit"), "rjfit_schema_version": str(SCHEMA_VERSION),
           "rjfit_fit_options": json.dumps(options_json, sort_keys=True)}
    if fit_id is not None:
        out["rjfit_fit_id"] = fit_id
    return out


def stamp(summary: dict) -> dict:
    """Add ``fit_id`` (:func:`results_digest`), ``rjfit_version`` and ``schema_version`` to a finished fit's
    ``summary`` (with its ``fit_options``), and return its files' :func:`file_attributes`."""
    summary["fit_id"] = results_digest(summary)
    attributes = file_attributes(summary["fit_options"], summary["fit_id"])
    summary.update(rjfit_version=attributes["rjfit_version"], schema_version=SCHEMA_VERSION)
    return attributes


def _path_entries(summary: dict):
    """``(holder, key)`` of every path of :data:`PATH_ENTRIES` that ``summary`` holds as a string."""
    for entry, key in PATH_ENTRIES:
        holder, name = (summary, entry) if key is None else (summary.get(entry), key)
        if isinstance(holder, dict) and isinstance(holder.get(name), str):
            yield holder, name


def relative_paths(summary: dict, fit_dir) -> dict:
    """The summary with its paths (:data:`PATH_ENTRIES`) relative to ``fit_dir``, what summary.json stores (a
    path on another drive stays absolute)."""
    out = _copied(summary)
    base = Path(fit_dir).resolve()
    for holder, name in _path_entries(out):
        try:
            holder[name] = os.path.relpath(Path(holder[name]).resolve(), base)
        except ValueError:          # another drive (Windows): no relative path
            pass
    return out


def _copied(summary: dict) -> dict:
    """A copy of ``summary`` whose path entries (:data:`PATH_ENTRIES`) can be changed without changing it."""
    return {key: dict(value) if isinstance(value, dict) and key in dict(PATH_ENTRIES) else value
            for key, value in summary.items()}


def resolved_paths(summary: dict, fit_dir) -> dict:
    """The summary with its relative paths (:data:`PATH_ENTRIES`) made absolute against ``fit_dir``; an absolute
    path (a fit folder of schema 1) is kept."""
    out = _copied(summary)
    base = Path(fit_dir).resolve()
    for holder, name in _path_entries(out):
        path = Path(holder[name])
        holder[name] = str(path if path.is_absolute() else os.path.normpath(base / path))
    return out

#: file names of the MAP labels in a fit folder, tried in this order (the fit writes labels.exr)
MAP_LABEL_FILES = ("map_labels.exr", "labels.exr")
#: the results a fit writes beside summary.json (published together with it)
RESULT_FILES = ("labels.exr", "chains.nc", "changepoints.npz", "materials.npz", "maps.exr", "figures")
#: results derived from a fit by later commands; those of a replaced fit no longer describe it
DERIVED_RESULTS = ("report.html",)

_NUMBER = (int, float)
#: every entry of summary.json: (JSON type(s), meaning). null is allowed for every entry (a
#: value that could not be computed, such as an R-hat of one chain) and reads as absent.
SUMMARY_FIELDS = {
    # the posterior
    "model_posterior": (dict, "posterior probability of each model 'n_u,n_v' (pooled over chains, kept draws)"),
    "map_model": (dict, "the most probable model: n_u, n_v and its number m"),
    "model_number_convention": (str, "how m is computed from (n_u, n_v)"),
    "regions": (list, "per region of the MAP model: posterior mean, sd, 95 % interval of I0, kd, gamma, sigma2, "
                      "with its pixel count (materials: label_agreement, the mean over its pixels of the share of "
                      "the draws at its K giving them its label, its parameters' draws; parameters_from, where that "
                      "is under one half: its parameters summarised instead over the draws of any K that hold its "
                      "pixels, with their number, chains and R-hat; contrast_to_surroundings, with two or more "
                      "materials, the Lambertian albedo (observations over their shading E <l.n>) of its pixels "
                      "up to 3 px inside its outline over that of the pixels 2 to 4 px outside it, per light: lights, "
                      "min, lower_quartile, median, upper_quartile, max, spread (max over min), middle_spread "
                      "(upper over lower quartile), pixels, border_pixels, ring_pixels, ring; a colour fit's also per "
                      "channel, channels: R, G, B "
                      "(rjfit.posterior.contrast); fitted from a data set: "
                      "steep_view_share, the share of its pixels seen beyond steep_view_angle)"),
    "chain_regions": (list, "the same per chain, each with its own MAP labels' pixel counts"),
    "chain_model_posterior": (list, "model posterior of each chain"),
    "region_model": (str, "what partitions the pixels: a --regions name (rjfit.pipeline.regions.REGION_FITS: "
                          "'changepoints', the paper's; 'materials', free-form materials under a Potts prior; ...); "
                          "the model-specific entries below are that model's"),
    "materials_posterior": (dict, "materials: posterior probability of each number of materials K (pooled over "
                                  "chains, kept draws)"),
    "map_materials": (int, "materials: the most probable K"),
    "segmentation_materials": (int, "materials: the K of the segmentation (labels.exr; the 'regions' entries are its "
                                    "materials)"),
    "segmentation": (str, "materials: how the segmentation is chosen among the kept label snapshots"),
    "segmentation_snapshot": (dict, "materials: the chain and iteration of the snapshot the segmentation starts from, "
                                    "and the changes made to it (materials joined or set apart)"),
    "chain_materials_posterior": (list, "materials: the posterior over K of each chain"),
    "material_relabelling": (str, "materials: how draws are relabelled to the segmentation before summaries"),
    "empty_materials": (str, "materials: why no material is ever empty"),
    "map_probability_mean": (_NUMBER, "materials: mean over labelled pixels of the share of the kept snapshots with "
                                      "the segmentation's K that give the pixel its material there (per pixel: "
                                      "maps.exr channel map_probability)"),
    "max_materials": (int, "materials: the most materials a state may have (a cap; warned about when it binds)"),
    "potts_beta": (_NUMBER, "materials: Potts prior strength per neighbour pair of different materials"),
    "potts_rho": (_NUMBER, "materials: prior factor per material (rho^K)"),
    "edge_power": (_NUMBER, "materials: power of the edge term in the target (0: none; docs/materials.md)"),
    "edge_gain_sd": (_NUMBER, "materials: sd of the local gain the edge term integrates out of each pair (0: none)"),
    "edge_noise": ((dict, type(None)), "materials: the edge term's measured noise, each match's variance white + "
                                       "shading g^2 + turn t^2 of the differences' spread squared, and whether white "
                                       "sits at its floor (floored); null: one scale"),
    "boundaries": (list, "materials: per pair of adjacent MAP materials, whether the data step where they meet "
                         "(log_likelihood_ratio above log 100: an edge; below -log 100: none; "
                         "rjfit.posterior.boundaries)"),
    "edge_supported_materials": (int, "materials: the number of groups left when MAP materials that meet where the "
                                      "data show no edge are joined (per pixel: maps.exr channel edge_group)"),
    "material_groups": (list, "materials: the MAP materials of each such group"),
    "edge_groups_posterior": (dict, "materials: share of kept label snapshots (edge_groups_snapshots of them) whose "
                                    "materials form each number of groups once those that meet where the data show no "
                                    "edge are joined (rjfit.posterior.boundaries.edge_group_count)"),
    "chain_edge_groups_posterior": (list, "materials: edge_groups_posterior of each chain"),
    "edge_groups_snapshots": (int, "materials: the label snapshots edge_groups_posterior counts"),
    "material_resolution": (dict, "materials: the smallest disc of half the albedo of the largest material that the "
                                  "fit would give a material of its own (radius_px, pixels; "
                                  "rjfit.posterior.resolution)"),
    "materials_right_probability": (_NUMBER, "materials: posterior probability of the true number of materials"),
    "rhat_max": (_NUMBER, "largest R-hat over the MAP model's parameters (null: not computable)"),
    "rhat_reason": (str, "why rhat_max is null (null when it is a number)"),
    "ess_min": (_NUMBER, "smallest of the bulk and tail ESS"),
    "ess_bulk_min": (_NUMBER, "smallest bulk ESS"),
    "ess_tail_min": (_NUMBER, "smallest tail ESS"),
    "diagnostics": (dict, "R-hat and ESS per parameter, and their extremes"),
    "acceptance": (dict, "acceptance rate of each move kind (effect_NAME: each effect's move)"),
    "acceptance_counts": (dict, "per move kind: proposed, accepted and nan_rejected (rejected because the acceptance "
                                "ratio was NaN) over all chains"),
    "data_defaults": (list, "what the data chose of the options not given, one line each: the measured default "
                            "and how to opt out, a declared calibration applied (rjfit.pipeline.resolve)"),
    "rjfit_version": (str, "the rjfit version that wrote the fit"),
    "schema_version": (int, "the fit folder's schema (rjfit.pipeline.fit_folder.SCHEMA_VERSION; absent: 1)"),
    "log_likelihood": (dict, "the size of chains.nc's log_likelihood group (points, block_pixels, chains, "
                             "draws_per_chain, values, likelihood_power), or why it is absent (note)"),
    "fit_options": (dict, "every option of the fit (rjfit.pipeline.options.FitOptions.to_json) and, under sources, "
                          "where each value came from (given, data, preset, default): `rjfit refine` fits again with "
                          "the given ones, plus the effects named"),
    "effects": (list, "per effect sampled with the regions (--effects): name, stage, and per parameter its prior and "
                      "posterior mean, sd, 95 % interval (constrained), R-hat and bulk ESS; per-light gains per light; "
                      "where its features came from"),
    "warnings": (list, "what a reader must know before trusting the numbers, one sentence each"),
    # against the truth (synthetic data only)
    "label_accuracy": (_NUMBER, "share of object pixels whose MAP label matches the truth after matching"),
    "label_matching": (dict, "region -> true label of that matching"),
    "exact_truth_probability": (_NUMBER, "posterior probability that the partition equals the true one exactly"),
    "true_region_count": (int, "number of true regions"),
    "four_region_probability": (_NUMBER, "posterior probability of as many regions holding object pixels as the truth"),
    "true_regions_probability": (_NUMBER, "posterior probability that the object's pixels fall into exactly the true "
                                          "regions (99 % agreement)"),
    "chain_true_regions_probability": (list, "the same per chain"),
    "truth_params": (list, "true parameters per true label"),
    # the settings it ran with
    "iterations": (int, "iterations per chain"),
    "burn_in": (int, "burn-in iterations per chain"),
    "anneal_iterations": (int, "tempered warm-up iterations (within the burn-in)"),
    "n_chains": (int, "chains"),
    "seed": (int, "the user's seed"),
    "n_observations": (int, "observations fitted"),
    "sampler": (str, "within-model moves"),
    "prior": (dict, "the prior (preset name, parameters, caveat)"),
    "max_u": (int, "most u change-point vectors"),
    "max_v": (int, "most v change-point vectors"),
    "split_map": (str, "parameters of born regions"),
    "cp_prior": (str, "change-point prior"),
    "drop_jacobian": (bool, "the paper's acceptance ratio without its Jacobian (wrong; for study)"),
    "likelihood_power": (_NUMBER, "zeta of the coarsened posterior"),
    "likelihood_power_suggestion": (dict, "the measured spatial correlation of per-pixel-fit residuals and the zeta it "
                                          "suggests"),
    "noise": (dict, "the noise model, its floor and scale range"),
    "normals": (dict, "sampled normals (--normals sample): the prior's sd, the posterior mean normal's shift from the "
                      "given one (median, 95th percentile) and its sd (median), degrees; the maps in maps.exr"),
    "model_misfit": (dict, "the lag-1 spatial correlation of the fitted model's own standardised residuals (its "
                           "posterior mean prediction) and the likelihood power it would imply"),
    "chain_seconds": (list, "seconds each chain sampled"),
    "chain_threads": (list, "threads each chain ran on"),
    "chain_resumed_from": (list, "iterations of the checkpoints each chain resumed from"),
    "seconds": (_NUMBER, "seconds of the whole fit"),
    "fit_id": (str, "digest identifying these results (later commands check it)"),
    "figures": (dict, "figure name -> file in the fit folder"),
    "maps": (str, "the per-pixel maps file"),
    # the data set it was made from
    "dataset": (str, "the data set folder, relative to the fit folder (schema 1: absolute)"),
    "dataset_sha256": (str, "digest of the data set's files"),
    "channel": (str, "the colour channel fitted"),
    "crop": (dict, "where the maps sit in the original frame (row0, col0)"),
    "calibration": (dict, "the data transforms applied before the fit (--preset measured): isolated pixels left "
                          "out, the estimated camera response and light gains with their uncertainty"),
    "max_view_angle": (_NUMBER, "degrees: pixels seen further than this from their normal (the rim) gave no "
                                "observation (--max-view-angle; --preset measured)"),
    "rim_pixels": (int, "object pixels beyond max_view_angle: no observation, their labels follow their "
                        "neighbours'"),
    "steep_view_angle": (_NUMBER, "materials: degrees from the normal beyond which the object's most steeply seen "
                                  "tenth of labelled pixels lies (null: no view angle known); a material with more "
                                  "than half its pixels there is warned of (rjfit.posterior.caveats)"),
    "chain_steep_materials": (list, "materials: per chain, the materials of its last label snapshot but its largest, "
                                    "each with its pixels and steep_view_share"),
    "extra_materials": ((dict, type(None)), "materials: the kept label snapshots with more materials than the "
                                            "segmentation: their share (all chains and per chain), their extra "
                                            "materials' pixels in all, min, median and max, and the pixel most often "
                                            "in one (most_often: row, column of the maps, share; per pixel: maps.exr "
                                            "channel extra_material_share; its contrast: the same entry as a "
                                            "region's contrast_to_surroundings, of the connected pixels there in at "
                                            "least half as many snapshots) (rjfit.posterior.caveats.extra_materials)"),
    "validation": (dict, "the cross-check the fit was made under: passed, errors, path (relative to the fit folder; "
                         "schema 1: absolute), note"),
}
_TYPE_NAMES = {str: "a string", dict: "an object", list: "a list", float: "a number", int: "an integer",
               bool: "true or false", _NUMBER: "a number"}


def _type_name(kind) -> str:
    return _TYPE_NAMES.get(kind, str(kind))


def _has_type(value, kind) -> bool:
    if isinstance(value, bool):         # JSON true/false is not a number
        return kind is bool
    if kind is int:
        return isinstance(value, (int, np.integer))
    return isinstance(value, kind if kind is not _NUMBER else (int, float, np.integer, np.floating))


def results_digest(summary: dict) -> str:
    """A short digest of a fit's results (models, regions, seed, settings): it identifies the
    fit that a diagnosis or comparison was made from, so a report can tell a stale one."""
    keys = ("model_posterior", "map_model", "materials_posterior", "map_materials", "regions", "iterations", "burn_in", "n_chains", "seed", "n_observations",
            "likelihood_power", "prior")
    digested = {key: summary.get(key) for key in keys}
    if "effects" in summary:        # a fit with effects (a plain fit's digest is what it always was)
        digested["effects"] = summary["effects"]
    text = json.dumps(digested, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def write_summary(path, summary: dict) -> None:
    """Write ``summary`` as ``summary.json`` (strict JSON, atomically), after checking it against the schema.

    Raises
    ------
    TypeError
        If an entry is not in :data:`SUMMARY_FIELDS` or has another type: a programming error
        (the writer and the schema disagree), never the user's.
    """
    for key, value in summary.items():
        if key not in SUMMARY_FIELDS:
            raise TypeError(f"summary entry {key!r} is not in rjfit.pipeline.fit_folder.SUMMARY_FIELDS; add it there")
        kind = SUMMARY_FIELDS[key][0]
        if value is not None and not _has_type(value, kind):
            raise TypeError(f"summary entry {key!r} is {type(value).__name__}, the schema says {_type_name(kind)}")
    write_json_atomic(path, summary)


def publish_results(staging: Path, out_dir: Path) -> None:
    """Move a finished fit's files from ``staging`` into ``out_dir``, replacing the previous fit's.

    The previous ``summary.json`` goes first and the new one comes last: a folder without
    ``summary.json`` is an incomplete fit, never a mixture of two. Previous result files
    the new fit does not write are removed too. Every file is on disk (fsync) before the
    new ``summary.json`` appears (see :func:`rjfit.io.publish`).
    """
    publish(staging, out_dir, manifest="summary.json", names=RESULT_FILES, remove=RESULT_FILES + DERIVED_RESULTS)


@contextmanager
def kept_chains(checkpoint_paths, out_dir):
    """Turn an ``OSError`` raised while a fit's results are written, after its chains ran, into
    one line (:class:`~rjfit.errors.OutputError`): the path and why, that the folder keeps its
    previous results, and where the sampled chains are kept (each chain's final checkpoint,
    ``checkpoint_paths``) with how to publish them."""
    try:
        yield
    except OSError as error:
        out_dir = Path(out_dir)
        if all(path and Path(path).is_file() for path in checkpoint_paths):
            advice = (f"the sampled chains are kept in {out_dir / 'checkpoints'}: once that is fixed, run the same "
                      f"command again to publish them without sampling again")
        else:
            advice = "the chains have no checkpoint to resume from, so running it again samples anew"
        raise OutputError(f"{os_error_text(error)}; the fit's results were not written ({out_dir} keeps its previous "
                          f"ones, if any); {advice}") from error


def remove_checkpoints(checkpoint_paths, out_dir) -> None:
    """The results are written: the checkpoints (for resuming an interrupted run) have served,
    and a later run into ``out_dir`` must start afresh, not resume them."""
    for path in checkpoint_paths:
        if path and os.path.exists(path):
            os.remove(path)
    with suppress(OSError):      # only when empty: a folder the user keeps files in stays
        (Path(out_dir) / "checkpoints").rmdir()


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
            return [f"'{key}' entry {name!r} is {_short(value)}, not {_type_name(kind)}"]
    return []


def read_summary(fit_dir) -> dict:
    """The contents of ``fit_dir/summary.json``, checked.

    Parameters
    ----------
    fit_dir : path
        A folder ``rjfit fit`` wrote. No entry is required (a reader checks those it cannot
        do without); each entry of :data:`SUMMARY_FIELDS` that is there must have its type.

    Returns
    -------
    dict
        The summary, its paths (:data:`PATH_ENTRIES`) absolute (:func:`resolved_paths`).

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
    for key, (kind, _) in SUMMARY_FIELDS.items():
        value = summary.get(key)
        if value is not None and not _has_type(value, kind):
            problems.append(f"'{key}' is {_short(value)}, not {_type_name(kind)}")
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
    if isinstance(summary.get("channel"), str) and summary["channel"] not in CHANNELS + (COLOUR,):
        problems.append(f"'channel' is {summary['channel']!r}, not one of {', '.join(CHANNELS + (COLOUR,))}")
    if problems:
        raise DatasetError(f"{path}: not a summary `rjfit fit` wrote ({'; '.join(problems)}); {_again(fit_dir)}")
    return resolved_paths(summary, fit_dir)


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
