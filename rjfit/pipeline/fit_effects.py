"""The effects a fit samples with the regions (``rjfit fit --effects``, ``--effects-from``; issue 26).

:func:`fit_effects` turns the names a user gives (and those a diagnosis named) into the
effects' fit forms (:class:`rjfit.effects.base.FitForm`) for one data set's observations: each
library effect (:mod:`rjfit.effects`) builds its fit form from a criticism
context of the data set (:func:`rjfit.diagnose.context.build_context`), whose observations
are the fit's, so the features (view angles, Mitsuba's visibility and indirect light) are
computed once, by the code the criticism uses, and put in the order of the fit's
observations.

Interreflection's feature is the indirect light of a fitted model: with ``--effects-from``
it is rendered on the MAP segmentation of the fit the diagnosis was made from, at the region
parameters of the diagnosis' final model (MAP, fitted WITH the effects it named: its
materials no longer absorb the indirect light, as the plain fit's do, whose over-segmented
regions come out brighter where light bounces); a diagnosis that records no such parameters
(an older one) falls back to the fit's posterior means. It is a fixed feature of the fit,
not resampled with the regions; the summary records the fit whose labels it was rendered on
(``source.fit``, which ``rjfit refine`` compares with this fit's labels), which parameters it
was rendered at, with how many samples, and the share by which its Monte Carlo noise
attenuates beta.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from rjfit.diagnose.context import build_context
from rjfit.effects import get_effect
from rjfit.effects.interreflection import FEATURE_SPP, feature_record
from rjfit.errors import DatasetError
from rjfit.pipeline.fit_folder import read_map_labels, read_summary

__all__ = ["effect_names", "fit_effects", "INTERREFLECTION_NOTE"]

INTERREFLECTION_NOTE = ("the indirect light F is rendered by Mitsuba once, on the MAP segmentation of the fit the "
                        "diagnosis was made from, at the region parameters named in 'feature_model': a fixed feature "
                        "of this fit, not resampled with its regions (rjfit refine renders it again on this fit's "
                        "labels while they differ from that fit's)")
#: ``feature_model`` values: where the region parameters the feature was rendered at came from
FINAL_MODEL = "the diagnosis' final model (MAP, with the effects it named)"
FIT_MEANS = "the diagnosed fit's posterior means (the diagnosis records no final-model region parameters)"


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


def _final_model_params(diagnosis, n_regions: int):
    """(R, 4) I0, kd, gamma, sigma2 (MAP) of the diagnosis' final model, in the order of its
    context's regions; None where it records none for ``n_regions`` regions (an older diagnosis)."""
    parameters = ((diagnosis or {}).get("final_model") or {}).get("parameters") or {}
    names = [f"{name}[{r}]" for r in range(n_regions) for name in ("I0", "kd", "gamma", "sigma2")]
    if (diagnosis or {}).get("n_regions") != n_regions or not all(isinstance(parameters.get(n), dict) for n in names):
        return None
    return np.array([parameters[n]["map"] for n in names], dtype=float).reshape(n_regions, 4)


def _feature_params(ctx, diagnosis, labels, table) -> tuple[np.ndarray, str]:
    """The region parameters (in ``ctx``'s region order) interreflection's feature is rendered
    at, and where they came from (``FINAL_MODEL`` or ``FIT_MEANS``)."""
    final = _final_model_params(diagnosis, ctx.n_regions)
    if final is not None:
        # the diagnosis numbered the regions as ctx does: the same fit's MAP labels, in label order
        return final, FINAL_MODEL
    first_pixel = [int(np.flatnonzero(ctx.labels.ravel() == r)[0]) for r in range(ctx.n_regions)]
    return table[labels.ravel()[first_pixel]], FIT_MEANS


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
    """The effects' fit forms for ``observations`` of ``dataset`` (in their order), and what the summary records.

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
    # a feature rendered from the fitted regions' BRDFs: on the diagnosed fit's MAP labels, whose
    # folder source[name]["fit"] records (rjfit refine renders it again while the labels move)
    rendered = [effect.name for effect in library if effect.renders_fitted_model]
    if rendered:
        fit_dir, labels, table = _previous_fit(diagnosis, dataset)
        source.update({name: {"fit": str(fit_dir), "note": INTERREFLECTION_NOTE} for name in rendered})
    ctx = build_context(dataset, labels, channel=options.channel, seed=options.seed)
    if rendered:
        params, feature_model = _feature_params(ctx, diagnosis, labels, table)
        ctx.features["fit_region_params"] = params
        ctx.features["indirect_spp"] = FEATURE_SPP
        for name in rendered:
            source[name].update(feature_model=feature_model, feature_region_params=np.round(params[:, :3], 6).tolist())
    for effect in library:
        ok, why = effect.available(ctx)
        if not ok:
            raise ValueError(f"effect {effect.name} cannot be fitted on {dataset.path}: {why}")
    order = _order_in(ctx, observations)
    effects = [effect.fit_form(ctx).in_order(order) for effect in library]
    if "interreflection" in names:
        source["interreflection"].update(feature_record(ctx))
    for effect in library:
        entry = source.setdefault(effect.name, {})
        entry["requested_by"] = "--effects" if effect.name in options.effects else "--effects-from"
        if effect.name not in options.effects and diagnosis is not None:
            entry["diagnosis"] = str(Path(options.effects_from).resolve())
    return effects, source
