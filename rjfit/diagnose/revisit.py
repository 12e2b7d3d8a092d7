"""Revisiting earlier choices (issue 26, item 3): the search names one effect at a time, so an
effect named early can stand in for one that is named later, or for a relative of its own
kind that was never tried beside the later one (a power-law camera curve named before ambient
light, where the truth is sRGB plus ambient).

After each step that leaves two or more effects in the model, every effect in it other than
the one just named is revisited, in the model's order:

1. **Swap**: each usable candidate of the same kind (the two camera curves) replaces it, and the
   model is refitted. The best replacement is taken when its log Bayes factor over the current
   model exceeds the decision rule's threshold (ln 100): decisively better with the others present.
2. **Drop**: otherwise the model is refitted without it. It is dropped when the model with it
   is no longer decisively better (log BF <= the threshold): the later effects explain its part.

Revisions use the Laplace evidence only (no LOO): a swap or drop changes an effect the search
already found decisive on its own, and the evidence compares the two models directly. An effect
kept is not revisited again until the next step. A swap or drop is recorded in
``diagnosis.json`` ``revisions`` and said on the progress lines.
"""
from __future__ import annotations

from rjfit.diagnose.document import revision_text
from rjfit.diagnose.refit import refit

__all__ = ["REVISION_RULE", "revisit"]

REVISION_RULE = ("after each step, every earlier effect is revisited: swapped for one of its kind when that is "
                 "decisively better (log BF > ln 100) with the others present, else dropped when the model with it "
                 "is no longer decisively better than without it")


def _swap(ctx, current, effect, alternatives, *, seed, threshold):
    """The best refit of ``current`` with ``effect`` replaced by one of ``alternatives`` whose log
    Bayes factor over ``current`` exceeds ``threshold``: ``(refit, replacement, log BF)``, or None."""
    best = None
    for alternative in alternatives:
        effects = tuple(alternative if e is effect else e for e in current.effects)
        swapped = refit(ctx, effects, start=current, seed=seed)
        log_bf = swapped.log_evidence - current.log_evidence
        if log_bf > threshold and (best is None or log_bf > best[2]):
            best = (swapped, alternative, log_bf)
    return best


def revisit(ctx, current, newest, usable, *, step, seed, threshold, say=print):
    """Revisit every effect of ``current`` (a :class:`~rjfit.diagnose.refit.FitResult`) but
    ``newest`` (the one just named): swap it for a decisively better one of its kind among
    ``usable``, else drop it when it is no longer decisive (see the module docstring).

    Returns
    -------
    (FitResult, list of dict)
        The model after the revisions (``current`` itself when none) and one record per
        revision: ``{"after_step", "action": "swapped" | "dropped", "effect", "replacement"
        (swaps), "log_bayes_factor"}`` (a swap's: replacement over the effect; a drop's: the
        model with the effect over the model without it).
    """
    revisions = []
    for effect in [e for e in current.effects if e is not newest]:
        if effect not in current.effects:
            continue
        alternatives = [a for a in usable if a.kind == effect.kind and a is not effect and a not in current.effects]
        swapped = _swap(ctx, current, effect, alternatives, seed=seed, threshold=threshold)
        if swapped is not None:
            current, replacement, log_bf = swapped
            revisions.append({"after_step": step, "action": "swapped", "effect": effect.name,
                              "replacement": replacement.name, "log_bayes_factor": log_bf})
            say(f"  revisited: {revision_text(revisions[-1])}")
            continue
        reduced = refit(ctx, tuple(e for e in current.effects if e is not effect), start=current, seed=seed)
        log_bf = current.log_evidence - reduced.log_evidence
        if log_bf <= threshold:
            revisions.append({"after_step": step, "action": "dropped", "effect": effect.name,
                              "log_bayes_factor": log_bf})
            say(f"  revisited: {revision_text(revisions[-1])}")
            current = reduced
    return current, revisions
