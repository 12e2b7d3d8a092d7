"""Revisiting earlier choices (issue 26, item 3): the search names one effect at a time, so an
effect named early can stand in for one that is named later, or for a relative of its own
kind that was never tried beside the later one (a power-law camera curve named before ambient
light, where the truth is sRGB plus ambient). And an effect chosen on one segmentation is in
question again on another: ``rjfit refine`` fits again with the named effects, and that fit's
regions can differ from those the effects were chosen on.

Effects are revisited at two points of a diagnosis:

- **after each step** that leaves two or more effects in the model: every effect in it other
  than the one just named, in the model's order;
- **before the first step**, when the diagnosed fit sampled effects (``base_effects``: a round
  of ``rjfit refine`` after the first): each of them, on the new fit's segmentation. A
  diagnosis of such a fit thus does not take its effects as given; a swap or drop changes the
  diagnosis' final model, and ``rjfit refine`` fits again with the revised set.

Each revisited effect is, in order:

1. **Swapped** for the best same-kind alternative among the usable candidates (the two camera
   curves), refitted in its place with the others present, when that alternative's Laplace
   evidence is HIGHER than the current model's and its parameters are physical (no prior-data
   conflict, :func:`rjfit.diagnose.candidates.fit_prior_conflicts`). Same-kind alternatives are
   mutually exclusive explanations of one part of the data, so the incumbent has no claim to
   priority (it may have been chosen on another segmentation or before a later effect was
   present): the higher evidence wins, without a decisive margin. The Laplace evidence
   already carries each curve's Occam factor (camera_gamma's free exponent against sRGB's
   fixed curve). Where the two are within ln 100 of each other, the record says so
   (``not_told_apart``).
2. **Dropped** otherwise, when the model with it is no longer decisively better than the model
   without it (log BF <= the decision rule's threshold, ln 100): the other effects, or the
   regions of the new segmentation, explain its part.

Revisions use the Laplace evidence only (no LOO): a swap or drop changes an effect the search
already found decisive on its own, and the evidence compares the two models directly. An effect
kept is not revisited again until the next step. A swap or drop is recorded in
``diagnosis.json`` ``revisions`` and said on the progress lines.
"""
from __future__ import annotations

from rjfit.diagnose.candidates import fit_prior_conflicts
from rjfit.diagnose.document import revision_text
from rjfit.diagnose.refit import refit

__all__ = ["REVISION_RULE", "revisit"]

REVISION_RULE = ("every earlier effect is revisited after each step, and the effects the diagnosed fit sampled "
                 "before the first step (on its segmentation): swapped for the same-kind alternative with the "
                 "higher Laplace evidence (the incumbent has no priority; its parameters physical), else dropped "
                 "when the model with it is no longer decisively better (log BF <= ln 100) than without it")


def _swap(ctx, current, effect, alternatives, *, seed):
    """The best refit of ``current`` with ``effect`` replaced by one of ``alternatives`` whose
    evidence is higher than ``current``'s and whose parameters are physical:
    ``(refit, replacement, log BF)``, or None."""
    best = None
    for alternative in alternatives:
        effects = tuple(alternative if e is effect else e for e in current.effects)
        swapped = refit(ctx, effects, start=current, seed=seed)
        log_bf = swapped.log_evidence - current.log_evidence
        if log_bf > 0 and not fit_prior_conflicts(swapped, alternative.name) and (best is None or log_bf > best[2]):
            best = (swapped, alternative, log_bf)
    return best


def revisit(ctx, current, newest, usable, *, step, seed, threshold, say=print):
    """Revisit every effect of ``current`` (a :class:`~rjfit.diagnose.refit.FitResult`) but
    ``newest`` (the one just named; None: revisit them all): swap it for the same-kind
    alternative among ``usable`` with the higher evidence, else drop it when it is no longer
    decisive (see the module docstring).

    Parameters
    ----------
    step : int or None
        The step just taken (0-based), or None for the revisit of the diagnosed fit's own
        effects before the first step.
    threshold : float
        The decision rule's log Bayes factor (a drop's bound).

    Returns
    -------
    (FitResult, list of dict)
        The model after the revisions (``current`` itself when none) and one record per
        revision: ``{"after_step" (None: before the first step), "action": "swapped" |
        "dropped", "effect", "replacement" (swaps), "log_bayes_factor", "not_told_apart"
        (swaps: whether within the threshold)}`` (a swap's log BF: replacement over the
        effect; a drop's: the model with the effect over the model without it).
    """
    revisions = []
    for effect in [e for e in current.effects if e is not newest]:
        if effect not in current.effects:
            continue
        alternatives = [a for a in usable if a.kind == effect.kind and a is not effect and a not in current.effects]
        swapped = _swap(ctx, current, effect, alternatives, seed=seed)
        if swapped is not None:
            current, replacement, log_bf = swapped
            revisions.append({"after_step": step, "action": "swapped", "effect": effect.name,
                              "replacement": replacement.name, "log_bayes_factor": log_bf,
                              "not_told_apart": bool(log_bf <= threshold)})
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
