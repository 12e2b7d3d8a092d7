"""A trial of effects with the regions in ``rjfit refine`` (issue 45).

A diagnosis judges each candidate effect on the segmentation of the fit it criticises. Where that
fit split materials to absorb the misfit, a candidate that explains the misfit leaves the split-off
regions misfitting, and it closes less of the gap on that segmentation than it would on its own
(:mod:`rjfit.diagnose.pairs`). The diagnosis then names nothing and offers a ``trial``: a single
effect or a pair that is decisive and physical and falls short of the naming rule's gap share only.

The loop fits again with the trial's effects sampled with the regions, diagnoses that fit, and
KEEPS the trial only when all three hold:

1. the gap of the trial fit on its own segmentation is at most :data:`TRIAL_GAP_SHARE` of the
   fit before it (the naming rule's rule 2, measured after the regions have followed the effect;
   as there, a gap that falls into :data:`rjfit.diagnose.misfit.UNEXPLAINED_GAP` without halving
   is not enough: on the GGX roughplastic stack coating + light_calibration took 0.105 to 0.069
   with 3 regions for 4, docs/results/2026-11-29-trials.md);
2. the trial fit has at most as many regions as the fit before it: an effect that explains what
   the split-off regions absorbed lets them merge, and a fit that needs more regions may owe its
   smaller gap to them (Mitsuba's Beckmann roughplastic under change points: fresnel took the gap
   from 1.51 to 0.012 with 9 regions where the fit before had 6, for 4 true ones);
3. its diagnosis keeps every effect of the trial (the revisit drops an effect that the new
   segmentation no longer needs decisively, :mod:`rjfit.diagnose.revisit`).

A trial offered where the fit before it had a gap within :data:`rjfit.diagnose.misfit.UNEXPLAINED_GAP`
(its regions absorbed the misfit, so no effect could close a share of it: the naming rule's rule 5) is judged
by what it can show there. Rule 1 is then a ratio of two numbers within the gap's own error, so it becomes:

1'. the trial fit's gap stays within :data:`rjfit.diagnose.misfit.UNEXPLAINED_GAP`, and
2'. the trial fit has FEWER regions than the fit before it: the effect let regions that absorbed the misfit
    merge. A model the data already fit at its true regions cannot gain here, which keeps out the flexible
    effects that are decisive on a tiny gap (light_calibration on a gap of 0.001,
    :mod:`rjfit.diagnose.naming`);

and rule 3 as above.

A pair kept by a trial can carry a passenger: on the GGX lobe under a smooth coating (the plugin, the material
model, seed 1), coating + light_calibration was kept on a fit of 8 regions for 4, the coating alone being in
prior-data conflict there; with both the fit stayed at 8 regions, and without light_calibration it has 4 at
accuracy 1.000 (docs/results/2026-12-01-floor-trials.md). So where a round's fit has a gap within the floor and
its diagnosis offers no trial, the final model less one effect that came in with a kept pair is a trial too
(:func:`drop_trial`, the effect of most parameters first), judged by rules 1', 2' and 3 (every effect it keeps
kept by its diagnosis).

Otherwise the fit before the trial stays the loop's result, and ``refine.json`` says what was
tried and why it was not kept. Each effect set is tried once.

A trial not kept whose diagnosis SWAPPED an effect the trial fit sampled for another of the same kind (the
smooth coating for the rough one, :mod:`rjfit.diagnose.revisit`) says that fit held the wrong member of that
kind: the diagnosis' final model (its swaps and drops made) is then a trial of its own (:func:`revised_trial`),
fitted once more and judged against the same fit before the first, while rounds are left. The swapped effect
may be the trial's or one the fit before it had already kept: on the GGX lobe under a smooth coating (the
plugin, change points, seed 1) the trial of ggx + light_calibration on the kept fresnel made 12 regions, and its
diagnosis swapped fresnel for the coating and dropped light_calibration, which is the stack's own model
(``docs/results/2026-12-01-revised-trials.md``).

A trial not kept and not revised leaves the loop where it was, with rounds it may still use: the next
trial that the same diagnosis offered (its ``trials``, by log BF, :func:`rjfit.diagnose.pairs.trial_candidates`)
is fitted and judged against the same fit (:func:`next_trial`). On Mitsuba's Beckmann roughplastic under the
material model the rough coating had the larger log BF but its trial fit did not halve the gap; fresnel,
offered second, did (``docs/results/2026-11-30-split-normal-draws.md``).

A trial need not be decisive: a supported candidate (its log BF decisive, its LOO gain over the observations where
PSIS is reliable positive: :mod:`rjfit.diagnose.candidates`) is offered after every decisive one, by log BF, and
judged by the same rules, which ask the regions, not the LOO's SE, whether the effect explains what they absorbed
(``docs/results/2026-12-01-supported-trials.md``).
"""
from __future__ import annotations

from rjfit.diagnose.candidates import loo_support_text
from rjfit.diagnose.misfit import UNEXPLAINED_GAP
from rjfit.diagnose.naming import GAP_SHARE

__all__ = ["TRIAL_GAP_SHARE", "trial_to_fit", "drop_trial", "trial_after", "trial_line", "judge_trial",
           "revised_trial", "next_trial"]

#: the share of the gap before it that a trial fit's gap may keep: the naming rule's, 1 - GAP_SHARE
TRIAL_GAP_SHARE = 1.0 - GAP_SHARE


def trial_to_fit(diagnosis: dict, record: dict, tried: list, can_sample: bool) -> list | None:
    """The effects the next fit should try with the regions, or None.

    ``diagnosis`` is the round's (its ``trial``), ``record`` its round record (``named``, ``dropped``,
    ``feature_change``), ``tried`` the effect sets tried so far (each a sorted list), ``can_sample`` whether the fit
    can sample effects (not a joint colour fit). A trial is fitted only where the round changed nothing (nothing
    named or dropped, every rendered feature follows the fit); whether a round is left to fit it is the loop's
    to say (:func:`rjfit.pipeline.refine.refine`).
    """
    trial = diagnosis.get("trial")
    if trial is None or not can_sample or record["named"] or record["dropped"]:
        return None
    if not all(entry["follows"] for entry in record["feature_change"]):
        return None
    effects = [name for name in trial["effects"] if name not in record["effects"]]
    if not effects or sorted(effects) in tried:
        return None
    return effects


def drop_trial(diagnosis: dict, record: dict, trials: list, tried: list) -> tuple | None:
    """The diagnosis' final model less one effect that a kept pair brought in, as a trial, or None.

    ``diagnosis`` and ``record`` are the round's (its fit's ``gap``, ``named``, ``dropped``, ``feature_change``),
    ``trials`` the loop's verdicts so far (``refine.json``'s ``trials``), ``tried`` the sets tried (sorted; the
    trial's is added). Only where the round changed nothing and its gap is within
    :data:`rjfit.diagnose.misfit.UNEXPLAINED_GAP`.
    Of the effects of the kept trials of two or more effects that the final model holds, the one with the most
    parameters goes first (a flexible passenger absorbs most); a set tried before is skipped. Returns ``(the
    effects kept, the effect dropped)``.
    """
    if record["named"] or record["dropped"] or record["gap"] is None:
        return None
    if record["gap"] > UNEXPLAINED_GAP or not all(entry["follows"] for entry in record["feature_change"]):
        return None
    model = diagnosis.get("final_model") or {}
    final = list(model.get("effects") or [])
    passengers = {name for verdict in trials if verdict["kept"] and len(verdict["effects"]) > 1
                  and not verdict.get("drops") for name in verdict["effects"] if name in final}
    n_params = {name: sum(key.startswith(f"{name}.") for key in model.get("parameters") or {}) for name in passengers}
    for name in sorted(passengers, key=lambda effect: (-n_params[effect], effect)):
        kept = [effect for effect in final if effect != name]
        if kept and sorted(kept) not in tried:
            tried.append(sorted(kept))
            return kept, name
    return None


def trial_after(diagnosis: dict, record: dict, final: list, done: tuple, can_sample: bool) -> tuple | None:
    """The trial after a round that would end the loop: ``(its effects, the effects kept beside them, the effects
    it drops)``, or None. The diagnosis' trial (:func:`trial_to_fit`) beside the final model ``final``, else the
    final model less an effect a kept pair brought in (:func:`drop_trial`). ``done``: the loop's verdicts and the
    sets tried (the chosen set is added)."""
    verdicts, tried = done
    trying = trial_to_fit(diagnosis, record, tried, can_sample)
    if trying is not None:
        tried.append(sorted(trying))
        return trying, list(final), []
    dropping = drop_trial(diagnosis, record, verdicts, tried) if can_sample else None
    return None if dropping is None else (dropping[0], [], [dropping[1]])


def trial_line(index: int, record: dict, effects: tuple) -> str:
    """The line that announces round ``index + 2``'s fit of the trial round ``index + 1`` chose (``record``'s
    ``trial``, and ``trial_drops`` for a drop), which samples ``effects``, and the rule it will be judged by."""
    floor = (f"kept if the new segmentation has fewer than {record['n_regions']} regions and a gap within "
             f"{UNEXPLAINED_GAP:g}")
    head = f"round {index + 2}: round {index + 1}'s diagnosis named nothing"
    if record.get("trial_drops"):
        return (f"{head}, its gap within {UNEXPLAINED_GAP:g}; fitting again without "
                f"{', '.join(record['trial_drops'])} (brought in by a kept trial of two or more effects), with "
                f"{', '.join(effects)} sampled with the regions ({floor})")
    offer = record.get("trial_offer") or {}
    support = ("decisive" if offer.get("decisive", True) else
               f"supported (its LOO gain {loo_support_text(offer)}, short of the decision rule's)")
    if record["gap"] <= UNEXPLAINED_GAP:
        return (f"{head} but offers {' + '.join(record['trial'])}, {support} where round {index + 1}'s regions left a "
                f"gap within {UNEXPLAINED_GAP:g}; fitting again with {', '.join(effects)} sampled with the regions "
                f"({floor})")
    return (f"{head} but offers {' + '.join(record['trial'])}, {support}, short of the naming rule's gap share "
            f"on round {index + 1}'s segmentation; fitting again with {', '.join(effects)} sampled with the regions (kept "
            f"if the gap on the new segmentation is at most {TRIAL_GAP_SHARE:.0%} of {record['gap']:.3g})")


def judge_trial(effects: list, before: dict, after: dict, final_effects: list) -> dict:
    """Whether the trial of ``effects`` is kept: ``{"effects", "gap_before", "gap_after", "kept", "why"}``.

    ``before`` and ``after`` are the round records of the fit before the trial and of the trial fit (their
    ``gap``: each fitted model on its own MAP segmentation; ``n_regions``); ``final_effects`` the trial
    diagnosis' final model.
    """
    gap_before, gap_after = float(before["gap"]), float(after["gap"])
    dropped = [name for name in effects if name not in final_effects]
    why = []
    if gap_before <= UNEXPLAINED_GAP:       # rules 1' and 2' (module docstring)
        if not gap_after <= UNEXPLAINED_GAP:
            why.append(f"the gap on the new segmentation, {gap_after:.3g}, is above {UNEXPLAINED_GAP:g}")
        if not after["n_regions"] < before["n_regions"]:
            why.append(f"the new segmentation has no fewer regions ({after['n_regions']} against "
                       f"{before['n_regions']}) and the gap before it was within {UNEXPLAINED_GAP:g}")
    else:
        if not gap_after <= TRIAL_GAP_SHARE * gap_before:
            why.append(f"the gap on the new segmentation, {gap_after:.3g}, is above {TRIAL_GAP_SHARE:.0%} of the "
                       f"gap before it ({gap_before:.3g})")
        if after["n_regions"] > before["n_regions"]:
            why.append(f"the new segmentation has more regions ({after['n_regions']} against "
                       f"{before['n_regions']})")
    if dropped:
        why.append(f"its diagnosis dropped {', '.join(dropped)} on the new segmentation")
    if why:
        reason = "; ".join(why)
    elif gap_before <= UNEXPLAINED_GAP:
        reason = (f"the new segmentation has {after['n_regions']} regions for {before['n_regions']}, its gap "
                  f"{gap_after:.3g} (before {gap_before:.3g})")
    else:
        reason = f"the gap fell from {gap_before:.3g} to {gap_after:.3g} on the new segmentation"
    return {"effects": list(effects), "gap_before": gap_before, "gap_after": gap_after, "kept": not why,
            "why": reason}


def revised_trial(base: list, effects: list, final: list, revisions: list, tried: list) -> tuple | None:
    """The trial fit's diagnosis' final model as a trial, where that diagnosis swapped an effect the fit sampled.

    The trial fit sampled ``base`` (what the fit before it kept) and the trial's ``effects``; ``final`` is its
    diagnosis' final model, ``revisions`` its round record's (each ``{"action", "effect", "replacement"}``),
    ``tried`` the trials' sorted sets (the revised trial's is added). Returns ``(the base it keeps, the trial's
    effects)``: ``base`` less what the diagnosis swapped or dropped, and the rest of ``final``; None where no swap
    touched the fit's effects or the revised trial is empty or was tried.
    """
    fitted = set(base) | set(effects)
    swapped = {entry["effect"] for entry in revisions if entry.get("action") == "swapped"}
    if not swapped & fitted:
        return None
    kept = [name for name in base if name in final]
    trial = [name for name in final if name not in kept]
    if not trial or sorted(trial) in tried:
        return None
    tried.append(sorted(trial))
    return kept, trial


def next_trial(diagnosis: dict, record: dict, tried: list) -> list | None:
    """The next trial of ``diagnosis`` (the round whose fit a trial was judged against; its ``trials``, best first)
    after one was not kept: the first whose effects not in that round's fit (``record["effects"]``) form a set not
    tried (``tried``: sorted sets, to which it is added); else None."""
    for trial in diagnosis.get("trials") or []:
        effects = [name for name in trial["effects"] if name not in record["effects"]]
        if effects and sorted(effects) not in tried:
            tried.append(sorted(effects))
            return effects
    return None
