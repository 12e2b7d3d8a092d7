"""``rjfit refine FIT --out DIR``: close the loop of model criticism (issue 26).

Diagnose the fit (:func:`rjfit.pipeline.diagnose.diagnose_fit`), fit the data set again with
the effects the diagnosis named sampled jointly with the segmentation (``rjfit fit
--effects-from``), diagnose that fit (its search starts from the effects it sampled, after revisiting them on
its segmentation: :mod:`rjfit.diagnose.revisit`), and repeat until a diagnosis names, swaps
and drops nothing and every feature rendered from the fitted regions (interreflection's
indirect light) follows the fit's segmentation, at most ``max_rounds`` diagnoses.

A refit renders such a feature once, on the MAP labels of the fit its diagnosis was made of, at that diagnosis'
final model. When the refit moves the labels (an over-segmented plain fit's 8 regions become 2) or the materials, it
was sampled with a feature of a model it no longer is. So after a diagnosis that names nothing, the loop renders the
feature the next refit would sample (this fit's labels, this diagnosis' final model, the fit's seed and samples: the
same Monte Carlo streams as the fit's own feature) and compares the two in predicted values. The stopping rule
(:data:`FEATURE_CHANGE`): the root mean square of ``beta (F_next - F_fit)`` over the fit's observations, beta the
fit's posterior mean, is below 0.1 of the noise sd (the diagnosis' estimate), so the gap the old feature can leave
is below 0.01. Otherwise the loop fits again with the new feature. ``refine.json`` records the change per round
(``feature_change``).
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from rjfit.data.formats import COLOUR
from rjfit.diagnose.document import revision_text
from rjfit.effects import get_effect
from rjfit.errors import DatasetError
from rjfit.io import read_json, write_json_atomic
from rjfit.pipeline.diagnose import diagnose_fit
from rjfit.pipeline.fit_effects import fit_effects
from rjfit.pipeline.fit_dataset import fit_dataset
from rjfit.pipeline.fit_folder import read_map_labels, read_summary
from rjfit.pipeline.options import FitOptions
from rjfit.pipeline.refine_resume import diagnosis_request, fit_request, forget, is_kept, remember
from rjfit.pipeline.refine_steps import another_trial, named_after, trial_instead, trial_kept, warn
from rjfit.pipeline.refine_trial import trial_line
from rjfit.pipeline.regions import REGION_FITS
from rjfit.pipeline.report import build_report
from rjfit.render.datasets import load_dataset

__all__ = ["refine", "MAX_ROUNDS", "FEATURE_CHANGE", "fit_options_of"]

#: most diagnoses of one refinement (the first fit's and those of up to MAX_ROUNDS - 1 refits). Each trial takes
#: a round and a revised trial another: 4 left no round for the revision after two trials not kept on the GGX
#: dielectric (docs/results/2026-12-02-trial-rounds.md); the cap is a budget, and a warning says when it binds
MAX_ROUNDS = 6
#: a feature rendered from the fitted regions no longer changes the fit when rendering it again
#: (this fit's labels and final model) moves the predicted values by less than this share of the
#: noise sd in root mean square: a change c raises the gap by at most c^2, here 0.01, a tenth of
#: what counts as a missing effect (0.1)
FEATURE_CHANGE = 0.1


def fit_options_of(summary: dict, fit_dir) -> FitOptions:
    """The options a fit ran with (``summary.json`` "fit_options").

    Raises
    ------
    DatasetError
        If the summary does not record them (a fit made before rjfit recorded its options) or
        records options out of range.
    """
    record = summary.get("fit_options")
    if not isinstance(record, dict):
        raise DatasetError(f"{Path(fit_dir) / 'summary.json'}: records no 'fit_options' (a fit made by an older "
                           f"rjfit); fit the data set again to refine it")
    try:
        return FitOptions.from_json(record, {name: fit.reads for name, fit in REGION_FITS.items()})
    except (TypeError, ValueError) as error:
        raise DatasetError(f"{Path(fit_dir) / 'summary.json'}: its 'fit_options' cannot be used ({error}); fit the "
                           f"data set again") from None


def _round_record(fit_dir: Path, summary: dict, diagnosis: dict, diagnosis_dir: Path, fit_seconds) -> dict:
    """One round of ``refine.json``: the fit (its effects, MAP model, regions, label accuracy)
    and its diagnosis (gap of the fitted model on its MAP segmentation, Mitsuba's simulated gap,
    the effects it named)."""
    simulated = (diagnosis.get("simulation") or {}).get("plain", {}).get("gap")
    seconds = None if fit_seconds is None else float(fit_seconds) + float(diagnosis.get("seconds") or 0.0)
    return {"fit": str(fit_dir), "diagnosis": str(diagnosis_dir),
            "effects": [entry["name"] for entry in summary.get("effects") or []],
            "map_model": summary.get("map_model"), "n_regions": len(summary.get("regions") or []),
            "label_accuracy": summary.get("label_accuracy"),
            "gap": diagnosis.get("gap_plain"), "gap_simulated": simulated,
            "named": list(diagnosis.get("named_effects") or []),
            "revisions": list(diagnosis.get("revisions") or []),
            "fit_seconds": fit_seconds, "diagnosis_seconds": diagnosis.get("seconds"), "seconds": seconds}


def _refuse_sampled_normals(options: FitOptions, fit_dir: Path) -> None:
    """Refuse a fit that sampled its normals: every refit samples the effects a diagnosis named (the first fit has
    none), and a fit refuses effects with sampled normals (:func:`rjfit.pipeline.resolve.resolve_options`), so the
    loop could only fail after its first diagnosis.

    Raises
    ------
    ValueError
        If ``options.normals`` is 'sample'.
    """
    if options.normals == "sample":
        raise ValueError(f"{fit_dir}: a fit that sampled its normals (--normals sample) cannot be refined: refine fits "
                         f"again with the effects a diagnosis names, and a fit with effects takes the given normals; "
                         f"fit the data set with --normals fixed to refine it, or criticise this fit with rjfit "
                         f"diagnose")


def _validation_options(summary: dict) -> dict:
    """How the refits pass the gate: the validation file the first fit was given, and
    ``allow_unvalidated`` where that fit was made without a passing one."""
    validation = summary.get("validation") or {}
    options = {"allow_unvalidated": validation.get("passed") is not True}
    if validation.get("path") and Path(validation["path"]).is_file():
        options["validation_path"] = Path(validation["path"])
    return options


def _dataset_of(summary: dict, fit_dir: Path) -> Path:
    """The data set a fit names, as diagnose reads it (a relative name may be relative to the fit folder)."""
    dataset_dir = Path(summary["dataset"]) if summary.get("dataset") else None
    if dataset_dir is not None and not dataset_dir.is_absolute() and not dataset_dir.exists():
        dataset_dir = fit_dir / dataset_dir
    if dataset_dir is None or not dataset_dir.exists():
        raise DatasetError(f"{fit_dir / 'summary.json'}: the data set it names ({summary.get('dataset')}) is not "
                           f"there; refine needs it to fit again")
    return dataset_dir


def refine(fit_dir, out_dir, *, max_rounds=MAX_ROUNDS, seed=0, max_steps=3, progress=False, say=print,
           first_diagnosis_dir=None, **diagnose_options) -> dict:
    """Diagnose, refit with what was named (or revised), diagnose again, until nothing changes.

    A diagnosis that names nothing but offers a trial is fitted once more with it; a trial not kept, with its
    diagnosis' final model where that swapped an effect, else the next trial (:mod:`rjfit.pipeline.refine_trial`).

    Parameters
    ----------
    fit_dir : path
        A folder ``rjfit fit`` wrote (its ``summary.json`` records the options it ran with).
    out_dir : path
        ``round{k}/diagnosis`` and ``round{k}/fit`` (k >= 2), ``refine.json`` and ``segmentations.png`` go there.
    max_rounds : int >= 1
        Most diagnoses; the record says when the last one still named an effect (the cap bound).
    seed, max_steps, progress, **diagnose_options
        Of each diagnosis (:func:`rjfit.diagnose.workflow.diagnose`).
    say : callable
        Receives a line per round and the cap's warning.
    first_diagnosis_dir : path, optional
        The first diagnosis' folder (default ``out_dir/round1/diagnosis``; `rjfit run`: ``FIT/diagnosis``).

    Returns
    -------
    dict
        ``refine.json``: ``rounds`` (per round: ``fit``, ``diagnosis``, ``effects`` sampled, ``map_model``,
        ``n_regions``, ``label_accuracy``, ``gap``, ``gap_simulated`` (null without truth, a mesh), ``named``,
        ``revisions`` (swaps, drops), ``feature_change`` (per feature rendered from the fitted regions:
        :func:`feature_change`), ``trial`` (what the next fit tried), ``seconds``), ``named_effects`` (the last final
        model's, in the order named), ``trials`` (verdicts, :mod:`rjfit.pipeline.refine_trial`), ``final_fit``,
        ``stopped`` and ``warnings``.

    Raises
    ------
    ValueError
        If ``max_rounds`` is not an integer >= 1; before any work, if the fit sampled its normals (``--normals
        sample``: :func:`_refuse_sampled_normals`); as the diagnosis and the fit.
    DatasetError
        If the fit's summary does not record its options (see :func:`fit_options_of`).
    """
    if isinstance(max_rounds, bool) or not isinstance(max_rounds, (int, np.integer)) or max_rounds < 1:
        raise ValueError(f"max_rounds must be an integer >= 1, got {max_rounds!r}")
    started, fit_dir, out_dir = time.perf_counter(), Path(fit_dir), Path(out_dir)
    summary = read_summary(fit_dir)
    options = fit_options_of(summary, fit_dir)
    _refuse_sampled_normals(options, fit_dir)
    dataset_dir = _dataset_of(summary, fit_dir)
    gate = _validation_options(summary)
    result = {"source_fit": str(fit_dir.resolve()), "fit_options": options.to_json(), "rounds": [],
              "named_effects": [], "final_fit": str(fit_dir), "stopped": "", "warnings": [], "trials": []}
    current, fit_seconds = fit_dir, summary.get("seconds")
    # the trial's effects and those kept beside them; the result's round and its final model; the sets tried
    trying, base, final_round, kept_final, tried = None, [], 0, [], []
    for index in range(max_rounds):
        diagnosis_dir, last = _diagnosis_dir(out_dir, index, first_diagnosis_dir), index + 1 == max_rounds
        diagnosis, record, final, new = _round(current, diagnosis_dir, index, fit_seconds, result, say, seed=seed,
                                               max_steps=max_steps, progress=progress, **diagnose_options)
        if trying is not None and not trial_kept(result, trying, final_round, index, final, say):
            trying, base, source = another_trial(result, (base, trying, final, kept_final), record, tried,
                                                 (final_round, index, diagnosis_dir, last), say)
            if trying is None:
                break
            effects = _sampled(base, trying)
            current, fit_seconds = _fit_next(dataset_dir, out_dir, index, effects, source, options, gate, say)
            continue
        trying, final_round, kept_final, result["final_fit"] = None, index, list(final), str(current)
        result["named_effects"] = named_after(result["named_effects"], record["dropped"], new)
        record["feature_change"] = ([] if new or record["dropped"] else
                                    feature_change(dataset_dir, current, diagnosis_dir))
        result["stopped"], warning = _why_stop(index, max_rounds, options, record, new, current)
        trying, base, capped = trial_instead(result, (diagnosis, record, final), tried, options, last)
        if result["stopped"]:
            warn(result, warning or capped, say)
            break
        write_json_atomic(out_dir / "refine.json", result)       # the rounds so far, should the next fit stop
        effects = _sampled(base, trying)
        for line in _next_round_lines(index, record, effects):
            say(line)
        current, fit_seconds = _fit_next(dataset_dir, out_dir, index, effects, diagnosis_dir, options, gate, say)
    return _finish(result, out_dir, dataset_dir, final_round, started)


def _diagnosis_dir(out_dir: Path, index: int, first_diagnosis_dir) -> Path:
    """Round ``index + 1``'s diagnosis folder: ``out_dir/round<k>/diagnosis``, the first one given (`rjfit run`'s)."""
    if index == 0 and first_diagnosis_dir is not None:
        return Path(first_diagnosis_dir)
    return out_dir / f"round{index + 1}" / "diagnosis"


def _round(current: Path, diagnosis_dir: Path, index: int, fit_seconds, result: dict, say, **options) -> tuple:
    """Round ``index + 1``'s diagnosis of ``current`` and its record (appended to ``result["rounds"]`` and said):
    ``(diagnosis, record, the final model's effects, those the fit did not sample)``."""
    diagnosis = _diagnosis(current, diagnosis_dir, index, say, **options)
    record = _round_record(current, read_summary(current), diagnosis, diagnosis_dir, fit_seconds)
    result["rounds"].append(record)
    say(_round_line(index, record))
    return (diagnosis, record) + _final_model(diagnosis, record)


def _diagnosis(fit_dir: Path, diagnosis_dir: Path, index: int, say, *, seed, max_steps, **options) -> dict:
    """Round ``index + 1``'s diagnosis of ``fit_dir`` into ``diagnosis_dir``; kept, not redone, where an earlier
    run finished it for the same fit and options (:mod:`rjfit.pipeline.refine_resume`)."""
    request = diagnosis_request(read_summary(fit_dir), seed, max_steps, options)
    if is_kept(diagnosis_dir, "diagnosis.json", request):
        say(f"round {index + 1}: the diagnosis an earlier run finished for this fit and these options is kept "
            f"({diagnosis_dir})")
        return read_json(diagnosis_dir / "diagnosis.json")
    forget(diagnosis_dir)
    diagnosis = diagnose_fit(fit_dir, diagnosis_dir, seed=seed, max_steps=max_steps, **options)
    remember(diagnosis_dir, request)
    return diagnosis


def _fit_round(dataset_dir: Path, fit_dir: Path, options: FitOptions, gate: dict, index: int, say) -> float:
    """Round ``index + 2``'s fit with ``options`` into ``fit_dir`` (kept where an earlier run finished it for the
    same request, :mod:`rjfit.pipeline.refine_resume`); its seconds."""
    request = fit_request(dataset_dir, options.to_json(), Path(options.effects_from) / "diagnosis.json", gate)
    if is_kept(fit_dir, "summary.json", request):
        say(f"round {index + 2}: the fit an earlier run finished for these options is kept ({fit_dir})")
        return read_summary(fit_dir).get("seconds")
    forget(fit_dir)
    started = time.perf_counter()
    fit_dataset(dataset_dir, fit_dir, options, **gate)
    remember(fit_dir, request)
    return time.perf_counter() - started


def _finish(result: dict, out_dir: Path, dataset_dir: Path, final_round: int, started: float) -> dict:
    """``refine.json`` with the segmentations' figure and the seconds, and the report of the result's fit (round
    ``final_round + 1``'s, with its diagnosis)."""
    result["segmentations"] = _segmentation_figure(out_dir, result["rounds"], dataset_dir)
    result["seconds"] = time.perf_counter() - started
    write_json_atomic(out_dir / "refine.json", result)
    build_report(Path(result["final_fit"]), out_dir / "report.html",
                 diagnosis_dir=result["rounds"][final_round]["diagnosis"], refine_dir=out_dir)
    return result


def _sampled(base: list, trying: list | None) -> tuple:
    """The effects the next fit samples: those kept beside the trial, then the trial's own not among them."""
    return tuple(base) + tuple(name for name in trying or () if name not in base)


def _fit_next(dataset_dir: Path, out_dir: Path, index: int, effects: tuple, diagnosis_dir: Path, options, gate: dict,
              say) -> tuple:
    """Round ``index + 2``'s fit, sampling ``effects`` with the regions from ``diagnosis_dir``'s estimates: its folder
    and seconds."""
    next_fit = out_dir / f"round{index + 2}" / "fit"
    return next_fit, _fit_round(dataset_dir, next_fit, options.replace(effects=effects, effects_from=diagnosis_dir),
                                gate, index, say)


def _final_model(diagnosis: dict, record: dict) -> tuple:
    """``(the diagnosis' final model's effects, those the fit did not sample)``: the fit's effects
    less any the diagnosis dropped or swapped (recorded in ``record["dropped"]``), and what it named."""
    final = list((diagnosis.get("final_model") or {}).get("effects") or record["effects"] + record["named"])
    record["dropped"] = [name for name in record["effects"] if name not in final]
    return final, [name for name in final if name not in record["effects"]]


def _cannot_sample(index: int, diagnosis_dir: Path) -> tuple:
    """Why the loop stops when its diagnosis named effects that a joint colour fit cannot sample
    (the effects are of one channel): ``(reason, warning)``."""
    return (f"round {index + 1}'s diagnosis named effects, which a joint colour fit cannot sample",
            f"the fit is of --channel rgb, which cannot sample effects yet: refine stopped after round "
            f"{index + 1}'s diagnosis ({diagnosis_dir}); fit one channel (--channel mean) with --effects-from "
            f"{diagnosis_dir} to sample what it named with the regions")


def feature_change(dataset_dir: Path, fit_dir: Path, diagnosis_dir: Path) -> list:
    """How much rendering the fit's rendered features again would change its predicted values.

    Per effect of the fit whose feature Mitsuba renders from the fitted regions
    (``renders_fitted_model``): the feature the fit sampled (its options: rendered on the labels
    of the fit its ``--effects-from`` diagnosis was made of) and the one a refit with
    ``--effects-from diagnosis_dir`` (a diagnosis of the fit ``fit_dir``) would sample (this
    fit's labels, that diagnosis' final model), rendered with the fit's seed and samples, so
    with the same Monte Carlo streams.

    Returns
    -------
    list of dict
        ``{"effect", "rendered_on", "beta", "rms_change", "noise_sd", "change", "follows"}``:
        ``rms_change`` the root mean square of ``beta (F_next - F_fit)`` over the observations,
        ``change`` that over the noise sd of the diagnosis, ``follows`` whether it is below
        :data:`FEATURE_CHANGE`. Empty when the fit samples no such effect.
    """
    summary = read_summary(fit_dir)
    entries = {entry["name"]: entry for entry in summary.get("effects") or []
               if get_effect(entry["name"]).renders_fitted_model}
    if not entries:
        return []
    resolved = summary["fit_options"]         # the channel and seed the fit ran with (given or resolved)
    options = fit_options_of(summary, fit_dir).replace(
        effects=tuple(entries), channel=resolved["channel"], seed=resolved["seed"])
    dataset = load_dataset(dataset_dir)
    observations = dataset.observations(options.channel)
    fitted, _ = fit_effects(dataset, observations, options)
    following, _ = fit_effects(dataset, observations, options.replace(effects_from=Path(diagnosis_dir)))
    following = {form.name: form for form in following}
    diagnosis = json.loads((Path(diagnosis_dir) / "diagnosis.json").read_text(encoding="utf-8"))
    noise_sd = float(np.sqrt(diagnosis["noise_variance_estimate"]))
    records = []
    for before in (form for form in fitted if form.name in entries):
        beta = float(entries[before.name]["parameters"][0]["mean"])
        rms = float(np.sqrt(np.mean((beta * (following[before.name].feature - before.feature)) ** 2)))
        records.append({"effect": before.name, "rendered_on": entries[before.name]["source"]["fit"], "beta": beta,
                        "rms_change": rms, "noise_sd": noise_sd, "change": rms / noise_sd,
                        "follows": rms / noise_sd < FEATURE_CHANGE})
    return records


def _moved_text(record: dict) -> str:
    """What a round's fit says of its rendered features that would change it (``record["feature_change"]``)."""
    return "; ".join(f"its {entry['effect']} feature, rendered again on its labels, changes the predicted values by "
                     f"{entry['change']:.3g} noise sd (>= {FEATURE_CHANGE})"
                     for entry in record["feature_change"] if not entry["follows"])


def _next_round_lines(index: int, record: dict, effects: tuple) -> list:
    """The lines that announce round ``index + 2``'s fit (and why, where nothing was named)."""
    if record.get("trial"):
        return [trial_line(index, record, effects)]
    why = [] if record["named"] or record["dropped"] else [
        f"round {index + 2}: round {index + 1}'s fit: {_moved_text(record)}; fitting again with it rendered on "
        f"round {index + 1}'s labels"]
    return why + [f"round {index + 2}: fitting again with {', '.join(effects)} sampled with the regions"]


def _why_stop(index: int, max_rounds: int, options, record: dict, new: list, current: Path) -> tuple:
    """``(reason, warning or None)`` where the loop stops after round ``index + 1``, else ``("", None)``:
    it goes on while a diagnosis names, drops or swaps an effect or a rendered feature would change the fit."""
    changed = bool(new or record["dropped"])
    if changed and options.channel == COLOUR:
        return _cannot_sample(index, Path(record["diagnosis"]))
    if not changed and all(entry["follows"] for entry in record["feature_change"]) or index + 1 == max_rounds:
        return _stop(index, max_rounds, new, record["dropped"], current, record)
    return "", None


def _stop(index: int, max_rounds: int, new: list, dropped: list, current: Path, record: dict) -> tuple:
    """Why the loop stops after round ``index + 1`` (its diagnosis names ``new`` effects and drops
    or swaps out ``dropped`` ones of the fit; ``record["feature_change"]``: whether its rendered
    features would change it): ``(reason, warning or None)``."""
    moved = [entry for entry in record["feature_change"] if not entry["follows"]]
    if not (new or dropped or moved):
        return f"round {index + 1}'s diagnosis named nothing more (and no rendered feature moved)", None
    if not (new or dropped):
        return (f"stopped after {max_rounds} rounds (max_rounds)",
                f"the cap of {max_rounds} rounds bound: round {index + 1}'s fit: {_moved_text(record)}; refine "
                f"{current} again or raise --max-rounds")
    changes = ([f"named {', '.join(new)}"] if new else []) + ([f"dropped {', '.join(dropped)}"] if dropped else [])
    return (f"stopped after {max_rounds} rounds (max_rounds)",
            f"the cap of {max_rounds} rounds bound: round {index + 1}'s diagnosis still {' and '.join(changes)}, "
            f"which no fit has done; refine {current} again or raise --max-rounds")


def _round_line(index: int, record: dict) -> str:
    accuracy = "" if record["label_accuracy"] is None else f", label accuracy {record['label_accuracy']:.3f}"
    simulated = "" if record["gap_simulated"] is None else f", simulated gap {record['gap_simulated']:.3g}"
    effects = ", ".join(record["effects"]) or "none"
    named = ", ".join(record["named"]) or "nothing"
    revised = "".join(f"; {revision_text(r, brief=True)}" for r in record.get("revisions") or [])
    return (f"round {index + 1}: effects sampled {effects}; {record['n_regions']} regions{accuracy}; gap "
            f"{record['gap']:.3g}{simulated}; diagnosis named {named}{revised}")


def _segmentation_figure(out_dir: Path, rounds: list, dataset_dir: Path) -> str:
    """Each round's MAP segmentation beside the last (``segmentations.png``); its file name."""
    from rjfit.plotting import label_image, pyplot, save_figure, zoom_to_object

    mask = load_dataset(dataset_dir).object_mask
    labels = [read_map_labels(Path(r["fit"]), mask) for r in rounds]
    count = max(int(lab.max()) + 1 for lab in labels)
    plt = pyplot()
    figure, axes = plt.subplots(1, len(labels), figsize=(3.2 * len(labels), 3.4), squeeze=False)
    for index, (axis, lab, record) in enumerate(zip(axes[0], labels, rounds)):
        axis.imshow(label_image(lab, count), interpolation="nearest")
        zoom_to_object(axis, mask)
        effects = ", ".join(record["effects"]) or "plain"
        accuracy = "" if record["label_accuracy"] is None else f", acc. {record['label_accuracy']:.3f}"
        axis.set_title(f"round {index + 1}: {effects}\n{record['n_regions']} regions{accuracy}", fontsize=8)
        axis.set_axis_off()
    save_figure(figure, out_dir / "segmentations.png", tight=True)
    return "segmentations.png"
