"""The effects a fit samples with the regions (``rjfit fit --effects``, ``--effects-from``; issue 26).

:func:`fit_effects` turns the names a user gives (and those a diagnosis named) into the
sampler's effects (:mod:`rjfit.sampler.effects`) for one data set's observations: each
library effect (:mod:`rjfit.diagnose.effects`) builds its sampler effect from a criticism
context of the data set (:func:`rjfit.diagnose.context.build_context`), whose observations
are the fit's, so the features (view angles, Mitsuba's visibility and indirect light) are
computed once, by the code the criticism uses, and put in the order of the fit's
observations.

Interreflection's feature is the indirect light of a fitted model: with ``--effects-from``
it is rendered at the region parameters (posterior means) and on the MAP segmentation of
the fit the diagnosis was made from. It is a fixed feature of the fit, not resampled with
the regions (the summary says so).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from rjfit.diagnose.context import build_context
from rjfit.diagnose.effects import get_effect
from rjfit.errors import DatasetError
from rjfit.pipeline.fit_folder import read_map_labels, read_summary

__all__ = ["effect_names", "fit_effects", "INTERREFLECTION_NOTE"]

INTERREFLECTION_NOTE = ("the indirect light F is rendered by Mitsuba once, at the region parameters and MAP segmentation "
                        "of the fit the diagnosis was made from: a fixed feature of this fit, not resampled with its "
                        "regions")


def _diagnosis(folder: Path) -> dict:
    path = Path(folder) / "diagnosis.json"
    if not path.is_file():
        raise DatasetError(f"{folder}: no diagnosis.json (--effects-from takes the folder `rjfit diagnose` wrote)")
    try:
        diagnosis = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise DatasetError(f"{path}: not a diagnosis ({error}); run `rjfit diagnose` again") from None
    if not isinstance(diagnosis, dict) or not isinstance(diagnosis.get("named_effects"), list):
        raise DatasetError(f"{path}: has no list 'named_effects'; it was not written by `rjfit diagnose`")
    return diagnosis


def effect_names(options) -> tuple[list, dict | None]:
    """The effects to sample (the options' then the diagnosis', each once) and the diagnosis (None without one).

    Raises
    ------
    DatasetError
        If ``options.effects_from`` holds no readable ``diagnosis.json``.
    """
    names = list(options.effects)
    diagnosis = None
    if options.effects_from is not None:
        diagnosis = _diagnosis(options.effects_from)
        names += [n for n in diagnosis["named_effects"] if n not in names]
    return names, diagnosis


def _previous_fit(diagnosis, dataset):
    """The MAP labels and per-label region parameters (I0, kd, gamma, sigma2 posterior means) of the diagnosed fit."""
    fit_dir = (diagnosis or {}).get("fit_dir")
    if not fit_dir:
        raise ValueError("interreflection's feature is the indirect light of a fitted model: give --effects-from "
                         "DIAGNOSIS_DIR (a diagnosis of a fit of this data set, which names that fit)")
    summary = read_summary(fit_dir)
    labels = read_map_labels(fit_dir, dataset.object_mask)
    table = np.full((max(int(labels.max()) + 1, len(summary.get("regions") or [])), 4), np.nan)
    for index, region in enumerate(summary.get("regions") or []):
        table[int(region.get("region", index))] = [region[name]["mean"] for name in ("I0", "kd", "gamma", "sigma2")]
    return Path(fit_dir), labels, table


def _order_in(ctx, observations) -> np.ndarray:
    """Position in ``ctx``'s observations of each of ``observations`` (the same set, matched by pixel and light).

    Raises
    ------
    ValueError
        If an observation of the fit is not one of the context's.
    """
    n_lights = ctx.n_lights
    ctx_key = ctx.pixel.astype(np.int64) * n_lights + ctx.light
    key = np.asarray(observations.pixel, np.int64) * n_lights + np.asarray(observations.light, np.int64)
    order = np.argsort(ctx_key, kind="stable")
    at = np.minimum(np.searchsorted(ctx_key[order], key), order.size - 1)
    found = ctx_key[order][at] == key
    if not np.all(found):
        raise ValueError(f"{int(np.count_nonzero(~found))} of the fit's observations are not in the effects' context "
                         "(its valid mask differs from the fit's)")
    return order[at]


def fit_effects(dataset, observations, options) -> tuple[list, dict]:
    """The sampler's effects for ``observations`` of ``dataset`` (in their order), and what the summary records.

    Returns ``([], {})`` when no effect is asked for. The record maps each effect to where its
    features came from (``{"from": ...}``, and the diagnosis).

    Raises
    ------
    ValueError
        If an effect cannot be used on this data set (a Mitsuba effect without the scene's
        mesh; interreflection without a diagnosed fit).
    DatasetError
        If the diagnosis, or the fit it names, cannot be read.
    """
    names, diagnosis = effect_names(options)
    if not names:
        return [], {}
    library = [get_effect(name) for name in names]
    labels = np.where(dataset.object_mask, 0, -1)
    source = {}
    if "interreflection" in names:
        fit_dir, labels, table = _previous_fit(diagnosis, dataset)
        source["interreflection"] = {"fit": str(fit_dir), "note": INTERREFLECTION_NOTE}
    ctx = build_context(dataset, labels, channel=options.channel, seed=options.seed)
    if "interreflection" in names:
        # the context numbers the regions 0..R-1 in the order of their labels
        first_pixel = [int(np.flatnonzero(ctx.labels.ravel() == r)[0]) for r in range(ctx.n_regions)]
        ctx.features["fit_region_params"] = table[labels.ravel()[first_pixel]]
    for effect in library:
        ok, why = effect.available(ctx)
        if not ok:
            raise ValueError(f"effect {effect.name} cannot be fitted on {dataset.path}: {why}")
    order = _order_in(ctx, observations)
    effects = [effect.sampler_effect(ctx).in_order(order) for effect in library]
    for effect in library:
        entry = source.setdefault(effect.name, {})
        entry["requested_by"] = "--effects" if effect.name in options.effects else "--effects-from"
        if effect.name not in options.effects and diagnosis is not None:
            entry["diagnosis"] = str(Path(options.effects_from).resolve())
    return effects, source
