"""Resuming ``rjfit refine``: a round's diagnosis or fit that an earlier run finished for the same request is kept.

A refinement of a measured stack runs for an hour or more (each diagnosis refits every candidate on every
observation; each round fits the stack again). Run again into the same folder after an interruption, it keeps
what the earlier run finished instead of redoing it; an interrupted fit already resumes from its checkpoints
(:func:`rjfit.pipeline.fit_dataset.fit_dataset`).

A finished step is kept only when its folder holds its result and ``request.json`` equals the request of this run:
for a diagnosis, the fit it diagnosed (its ``fit_id``, a digest of its results) and every option that changes the
diagnosis; for a fit, the data set, the fit's options (effects included) and a digest of the diagnosis whose
effects it starts from; for both, rjfit's version (another version may decide otherwise). ``request.json`` is
written after the result and removed before a step is redone, so an interruption between the two leaves no
request to match and the step is redone.
"""
from __future__ import annotations

import hashlib
import json
from importlib.metadata import version as installed_version
from pathlib import Path

from rjfit.io import read_json, write_json_atomic

__all__ = ["REQUEST_FILE", "diagnosis_request", "fit_request", "is_kept", "forget", "remember"]

REQUEST_FILE = "request.json"
#: diagnosis options that do not change its results (the refits do not depend on the number of threads)
_NOT_IN_REQUEST = ("progress", "jobs")


def _as_json(value):
    """``value`` as JSON reads it back (tuples as lists; what JSON cannot hold by its text), so that requests
    compare as written."""
    return json.loads(json.dumps(value, sort_keys=True, default=str))


def diagnosis_request(fit_summary: dict, seed: int, max_steps: int, diagnose_options: dict) -> dict:
    """What a diagnosis of the fit whose ``summary.json`` is ``fit_summary`` depends on."""
    options = {key: value for key, value in diagnose_options.items() if key not in _NOT_IN_REQUEST}
    return _as_json({"step": "diagnosis", "rjfit_version": installed_version("rjfit"),
                     "fit_id": fit_summary.get("fit_id"), "seed": seed, "max_steps": max_steps, "options": options})


def fit_request(dataset_dir: Path, options_json: dict, diagnosis_file: Path, gate: dict) -> dict:
    """What a round's fit depends on: the data set, its options (``FitOptions.to_json``), the diagnosis it starts
    its effects from (a digest of ``diagnosis.json``) and the gate's options."""
    digest = hashlib.sha256(Path(diagnosis_file).read_bytes()).hexdigest()
    return _as_json({"step": "fit", "rjfit_version": installed_version("rjfit"),
                     "dataset": str(Path(dataset_dir).resolve()), "options": options_json, "diagnosis_sha256": digest,
                     "gate": gate})


def is_kept(folder: Path, result_file: str, request: dict) -> bool:
    """Whether ``folder`` holds ``result_file`` finished for ``request`` (an unreadable request: not kept)."""
    folder = Path(folder)
    if not (folder / result_file).is_file() or not (folder / REQUEST_FILE).is_file():
        return False
    try:
        return read_json(folder / REQUEST_FILE) == request
    except (OSError, ValueError):
        return False


def forget(folder: Path) -> None:
    """Remove ``folder``'s request before its step is redone."""
    (Path(folder) / REQUEST_FILE).unlink(missing_ok=True)


def remember(folder: Path, request: dict) -> None:
    """Record ``request`` as the one ``folder``'s finished result was made for."""
    write_json_atomic(Path(folder) / REQUEST_FILE, request)
