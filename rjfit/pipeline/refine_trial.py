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

Otherwise the fit before the trial stays the loop's result, and ``refine.json`` says what was
tried and why it was not kept. Each effect set is tried once.

A trial not kept whose diagnosis SWAPPED one of its effects for another of the same kind (the smooth
coating for the rough one, :mod:`rjfit.diagnose.revisit`) says the trial fitted the wrong member of that
kind: the set with the swap made is then a trial of its own (:func:`revised_trial`), fitted once more
and judged against the same fit before the first, while rounds are left.

A trial not kept and not revised leaves the loop where it was, with rounds it may still use: the next
trial that the same diagnosis offered (its ``trials``, by log BF, :func:`rjfit.diagnose.pairs.trial_candidates`)
is fitted and judged against the same fit (:func:`next_trial`). On Mitsuba's Beckmann roughplastic under the
material model the rough coating had the larger log BF but its trial fit did not halve the gap; fresnel,
offered second, did (``docs/results/2026-11-30-split-normal-draws.md``).
"""
from __future__ import annotations

from rjfit.diagnose.naming import GAP_SHARE

__all__ = ["TRIAL_GAP_SHARE", "trial_to_fit", "judge_trial", "revised_trial", "next_trial"]

#: the share of the gap before it that a trial fit's gap may keep: the naming rule's, 1 - GAP_SHARE
TRIAL_GAP_SHARE = 1.0 - GAP_SHARE


def trial_to_fit(diagnosis: dict, record: dict, tried: list, rounds_left: int, can_sample: bool) -> list | None:
    """The effects the next fit should try with the regions, or None.

    ``diagnosis`` is the round's (its ``trial``), ``record`` its round record (``named``, ``dropped``,
    ``feature_change``), ``tried`` the effect sets tried so far (each a sorted list), ``rounds_left`` the
    diagnoses the loop may still make, ``can_sample`` whether the fit can sample effects (not a joint colour fit).
    A trial is fitted only where the round changed nothing (nothing named or dropped, every rendered feature
    follows the fit) and one round is left to judge it.
    """
    trial = diagnosis.get("trial")
    if trial is None or not can_sample or rounds_left < 1 or record["named"] or record["dropped"]:
        return None
    if not all(entry["follows"] for entry in record["feature_change"]):
        return None
    effects = [name for name in trial["effects"] if name not in record["effects"]]
    if not effects or sorted(effects) in tried:
        return None
    return effects


def judge_trial(effects: list, before: dict, after: dict, final_effects: list) -> dict:
    """Whether the trial of ``effects`` is kept: ``{"effects", "gap_before", "gap_after", "kept", "why"}``.

    ``before`` and ``after`` are the round records of the fit before the trial and of the trial fit (their
    ``gap``: each fitted model on its own MAP segmentation; ``n_regions``); ``final_effects`` the trial
    diagnosis' final model.
    """
    gap_before, gap_after = float(before["gap"]), float(after["gap"])
    dropped = [name for name in effects if name not in final_effects]
    why = []
    if not gap_after <= TRIAL_GAP_SHARE * gap_before:
        why.append(f"the gap on the new segmentation, {gap_after:.3g}, is above {TRIAL_GAP_SHARE:.0%} of the "
                   f"gap before it ({gap_before:.3g})")
    if after["n_regions"] > before["n_regions"]:
        why.append(f"the new segmentation has more regions ({after['n_regions']} against {before['n_regions']})")
    if dropped:
        why.append(f"its diagnosis dropped {', '.join(dropped)} on the new segmentation")
    return {"effects": list(effects), "gap_before": gap_before, "gap_after": gap_after, "kept": not why,
            "why": "; ".join(why) if why else (f"the gap fell from {gap_before:.3g} to {gap_after:.3g} on the new "
                                               f"segmentation")}


def revised_trial(effects: list, revisions: list, tried: list, rounds_left: int) -> list | None:
    """The trial of ``effects`` with the swaps of the trial fit's diagnosis made (``revisions``: its round record's,
    each ``{"action", "effect", "replacement"}``), where one of them swapped an effect of the trial, the revised set
    was not tried (``tried``: sorted sets, to which it is added) and a round is left to judge it; else None."""
    swaps = {entry["effect"]: entry["replacement"] for entry in revisions if entry.get("action") == "swapped"}
    if rounds_left < 1 or not any(name in swaps for name in effects):
        return None
    revised = [swaps.get(name, name) for name in effects]
    if sorted(revised) in tried:
        return None
    tried.append(sorted(revised))
    return revised


def next_trial(diagnosis: dict, record: dict, tried: list, rounds_left: int) -> list | None:
    """The next trial of ``diagnosis`` (the round whose fit a trial was judged against; its ``trials``, best first)
    after one was not kept: the first whose effects not in that round's fit (``record["effects"]``) form a set not
    tried (``tried``: sorted sets, to which it is added), where a round is left to judge it; else None."""
    if rounds_left < 1:
        return None
    for trial in diagnosis.get("trials") or []:
        effects = [name for name in trial["effects"] if name not in record["effects"]]
        if effects and sorted(effects) not in tried:
            tried.append(sorted(effects))
            return effects
    return None
