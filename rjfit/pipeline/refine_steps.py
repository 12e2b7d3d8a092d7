"""The refine loop's steps around a trial (:mod:`rjfit.pipeline.refine`): choose it after a round, judge it,
follow a trial not kept with the next, and say where the cap of rounds leaves one unfitted.

Each step reads and updates the loop's record (``refine.json``: its ``rounds``, ``trials``, ``named_effects``,
``stopped`` and ``warnings``); which trial comes next is decided by the rules of
:mod:`rjfit.pipeline.refine_trial`, and whether a round is left to fit it here: a trial chosen after the last
round (``max_rounds``) stays in that round's record as ``trial_not_fitted``, the loop stops with the fit it had,
and a warning says so and how to go on (a run into the same folder with a larger cap keeps the finished rounds).
"""
from __future__ import annotations

from pathlib import Path

from rjfit.data.formats import COLOUR
from rjfit.io import read_json
from rjfit.pipeline.refine_trial import judge_trial, next_trial, revised_trial, trial_after

__all__ = ["warn", "named_after", "trial_instead", "trial_kept", "another_trial", "cap_on_trial"]


def warn(result: dict, warning: str | None, say) -> None:
    """Record and say the loop's ``warning`` (none: nothing)."""
    if warning:
        result["warnings"].append(warning)
        say(f"warning: {warning}")


def named_after(named: list, dropped: list, new: list) -> list:
    """The effects named so far after a round that dropped or swapped out ``dropped`` and named
    ``new``: a revised effect leaves the list (the round's ``revisions`` keep it)."""
    kept = [name for name in named if name not in dropped]
    return kept + [name for name in new if name not in kept]


def trial_instead(result: dict, round_: tuple, tried: list, options, last: bool) -> tuple:
    """``(the trial to fit or None, the effects kept beside it, the cap's warning or None)`` after a round
    (``round_``: its diagnosis, record and the diagnosis' final model) where the loop would stop
    (``result["stopped"]``): :func:`rjfit.pipeline.refine_trial.trial_after`'s, the stop undone and the trial
    recorded in the round's ``record`` (``trial``; a drop's ``trial_drops`` too); else ``(None, the final model,
    None)``. Where the round was the ``last``, the trial is not fitted (:func:`cap_on_trial`)."""
    diagnosis, record, final = round_
    chosen = (trial_after(diagnosis, record, final, (result["trials"], tried), options.channel != COLOUR)
              if result["stopped"] else None)
    if chosen is None:
        return None, list(final), None
    result["stopped"], record["trial"] = "", chosen[0]
    if chosen[2]:
        record["trial_drops"] = chosen[2]
    record["trial_offer"] = None if chosen[2] else diagnosis["trial"]     # as the diagnosis offered it
    if last:
        index = len(result["rounds"]) - 1
        return None, list(final), cap_on_trial(result, (index, index), chosen[1], chosen[0])
    return chosen[0], chosen[1], None


def trial_kept(result: dict, effects: list, before: int, index: int, final: list, say) -> bool:
    """Judge the trial of ``effects`` that round ``index + 1``'s fit sampled against round ``before + 1``'s fit
    (:func:`rjfit.pipeline.refine_trial.judge_trial`), record it in ``result["trials"]``; where it is not kept, the
    loop stops with round ``before + 1``'s fit as its result."""
    rounds = result["rounds"]
    verdict = judge_trial(effects, rounds[before], rounds[index], final)
    verdict["round"] = index + 1
    if rounds[before].get("trial_drops"):
        verdict["drops"] = rounds[before]["trial_drops"]
    result["trials"].append(verdict)
    say(f"round {index + 1}: the trial of {' + '.join(effects)} with the regions is "
        f"{'kept' if verdict['kept'] else 'not kept'}: {verdict['why']}")
    if verdict["kept"]:
        # a revised trial may have swapped out an effect the loop named before (not sampled by this fit)
        gone = [name for name in result["named_effects"] if name not in final]
        result["named_effects"] = named_after(result["named_effects"], gone, effects)
        return True
    result["stopped"] = (f"round {index + 1}'s trial of {' + '.join(effects)} was not kept ({verdict['why']}): "
                         f"round {before + 1}'s fit is the result")
    return False


def another_trial(result: dict, fitted: tuple, record: dict, tried: list, where: tuple, say) -> tuple:
    """After a trial was not kept: ``(the trial to fit next or None, the effects kept beside it, the diagnosis
    folder its fit starts from)``, the stop undone and the trial recorded in the round's ``record``.

    ``fitted`` is (the trial fit's base, the trial's effects, its diagnosis' final model, the final model of the fit
    it was judged against); ``where`` is (the round of that fit, this round, this round's diagnosis folder, whether
    this round was the last). The trial fit's diagnosis' final model where that diagnosis swapped an effect the fit
    sampled (:func:`rjfit.pipeline.refine_trial.revised_trial`, from this round's diagnosis), else the next trial
    that the diagnosis of the fit it was judged against offered (:func:`rjfit.pipeline.refine_trial.next_trial`,
    from that diagnosis). Either is judged against that fit. After the last round, none is fitted: the cap's
    warning is recorded and said (:func:`cap_on_trial`).
    """
    before, index, diagnosis_dir, last = where
    base, trying, final, kept_final = fitted
    revised = revised_trial(base, trying, final, record.get("revisions") or [], tried)
    source = None if revised else Path(result["rounds"][before]["diagnosis"])
    following = None if revised else next_trial(read_json(source / "diagnosis.json"), result["rounds"][before], tried)
    if revised is None and following is None:
        return None, kept_final, None
    chosen = revised or (kept_final, following)
    result["stopped"], record["trial"] = "", chosen[1]
    if last:
        warn(result, cap_on_trial(result, (index, before), chosen[0], chosen[1]), say)
        return None, kept_final, None
    if revised:
        say(f"round {index + 2}: round {index + 1}'s diagnosis swapped an effect the trial fit sampled for one of "
            f"its kind; fitting its final model, {' + '.join(revised[0] + revised[1])}, with the regions, judged "
            f"against round {before + 1}'s fit")
        return revised[1], revised[0], diagnosis_dir
    say(f"round {index + 2}: fitting again with {' + '.join(following)} sampled with the regions, the next trial "
        f"round {before + 1}'s diagnosis offered, judged against round {before + 1}'s fit")
    return following, kept_final, source


def cap_on_trial(result: dict, rounds: tuple, base: list, trying: list) -> str:
    """Where round ``rounds[0] + 1`` was the last (``max_rounds``) and the loop chose a trial to fit next (``trying``
    beside ``base``): the stop (``result["stopped"]``: round ``rounds[1] + 1``'s fit is the result), the trial left
    in the round's record as ``trial_not_fitted`` (``trial`` says what a next fit tried), and the cap's warning."""
    index, result_round = rounds
    record = result["rounds"][index]
    record["trial_not_fitted"] = record.pop("trial")
    effects = " + ".join(list(base) + [name for name in trying if name not in base]) or "no effect"
    result["stopped"] = (f"stopped after {index + 1} rounds (max_rounds) with a trial left unfitted: round "
                         f"{result_round + 1}'s fit is the result")
    return (f"the cap of {index + 1} rounds bound: after round {index + 1} the loop would fit {effects} with the "
            f"regions (a trial), which no round was left to fit and judge{_trials_since(result, result_round)}; run "
            f"refine again into the same --out with a larger --max-rounds (it keeps the rounds finished here)")


def _trials_since(result: dict, result_round: int) -> str:
    """What the trials not kept since round ``result_round + 1`` (each judged against its fit) did to its gap, as a
    clause of the cap's warning ("" where there were none): where none moved it, more rounds are unlikely to pay,
    the misfit being outside what the trials carry, and the user reading the warning should see that."""
    gaps = [verdict["gap_after"] for verdict in result["trials"]
            if not verdict["kept"] and verdict["round"] > result_round + 1]
    if not gaps:
        return ""
    return (f"; the {len(gaps)} trial{'s' if len(gaps) > 1 else ''} not kept since round {result_round + 1} left its "
            f"gap of {float(result['rounds'][result_round]['gap']):.3g} at {min(gaps):.3g}"
            + (f" to {max(gaps):.3g}" if len(gaps) > 1 else ""))
