"""One step of the criticism's search: refit the current model plus each candidate effect, on
threads, and score each candidate (its evidence, LOO, signature and prior-data conflicts).

Decision rule (stated once, used everywhere): a candidate is DECISIVE when

    log BF = log Z(model + effect) - log Z(model) > ln 100 ~ 4.6      (Jeffreys: "decisive")
    and  delta ELPD_LOO > 4 SE(delta)                                  (PSIS-LOO agrees)

with Z the Laplace marginal likelihood (:func:`rjfit.diagnose.refit.refit`), which penalises
extra parameters through their Occam factor, and ELPD_LOO from PSIS-LOO on the Laplace draws
(ArviZ's estimator, vectorised in :mod:`rjfit.diagnose.psis`; a second opinion that does not
rest on the Laplace evidence; 4 SE because the pointwise differences of nested models are
skewed and a 2-SE rule names too eagerly). Among decisive candidates the largest log BF is
named (:mod:`rjfit.diagnose.workflow`).

A candidate is SUPPORTED when it is decisive, or its log BF passes the same bar and its delta ELPD_LOO over the
observations where PSIS is reliable (both models' k-hat at most the threshold for the draws) is positive: the
second opinion does not contradict the evidence. A supported candidate that is not decisive is never named, but
``rjfit refine`` may try it with the regions (:mod:`rjfit.diagnose.pairs`), where the regions judge it.
"""
from __future__ import annotations

import math
import os
from contextlib import contextmanager

import numpy as np

from rjfit.diagnose.loo import draws_pareto_k, loo_difference
from rjfit.diagnose.refit import refit, standardised_residuals, template_columns

__all__ = ["LOG_BF_THRESHOLD", "LOO_SE_FACTOR", "PRIOR_CONFLICT_SD", "DECISION_RULE", "BASE_TOLERANCE",
           "try_candidates", "refit_threads", "converge_base", "candidate_row", "judged_fields", "loo_support_text",
           "prior_conflicts", "fit_prior_conflicts"]

LOG_BF_THRESHOLD = math.log(100.0)
LOO_SE_FACTOR = 4.0
# An effect parameter whose MAP lies more than this many prior sd from its prior's centre (in
# the unconstrained coordinate: prior probability 0.27 % of being as far) is reported as a
# prior-data conflict: the data pull it where its physics is implausible, so the effect may
# be standing in for another with a similar signature.
PRIOR_CONFLICT_SD = 3.0
# The current model counts as at its optimum when a refit of it from a candidate's point (its
# region and shared parameters) lowers its negative log posterior by no more than this (nats):
# more, and every candidate's log BF carries that common gain (a step of the measured issue
# had fresnel, masking, ambient and camera_gamma all at 8,729 to 8,733).
BASE_TOLERANCE = 0.5
DECISION_RULE = (f"decisive when log Bayes factor (Laplace evidence) > ln 100 = {LOG_BF_THRESHOLD:.2f} and "
                 f"delta ELPD (PSIS-LOO) > {LOO_SE_FACTOR:g} SE; the decisive candidate with the largest log BF is named")


@contextmanager
def refit_threads(jobs, n_tasks):
    """A pool of ``min(jobs, n_tasks)`` threads (at least one) for refits, with BLAS on one thread meanwhile, so
    that the refits do not depend on ``jobs`` (:func:`try_candidates` says why threads)."""
    from concurrent.futures import ThreadPoolExecutor

    from threadpoolctl import threadpool_limits

    with threadpool_limits(1), ThreadPoolExecutor(max_workers=max(1, min(jobs, n_tasks))) as pool:
        yield pool


def _try_candidate(ctx, current, effect, residuals, sigma2_hat, seed, threshold):
    """Refit ``current`` plus ``effect`` and score it: ``(candidate, its residuals, (signature score,
    signature map), (delta ELPD, SE, max k-hat, unreliable fraction) or None)``; LOO only where the
    log Bayes factor exceeds ``threshold`` (below it the candidate cannot be decisive). Runs on a
    worker thread: it reads ``ctx`` and ``current`` and writes nothing they share (its features
    are cached before, see :func:`try_candidates`)."""
    candidate = refit(ctx, tuple(current.effects) + (effect,), start=current, seed=seed)
    columns = template_columns(current, ctx, effect)
    signature = effect.signature(ctx, residuals, sigma2_hat, columns)
    loo = loo_difference(candidate, current) if candidate.log_evidence - current.log_evidence > threshold else None
    return candidate, standardised_residuals(ctx, candidate), signature, loo


def try_candidates(ctx, current, effects, residuals, sigma2_hat, *, seed, threshold, jobs, report):
    """Refit ``current`` plus each of ``effects`` and score it, ``jobs`` at a time on threads:
    effect name -> its outcome ``(candidate refit, its standardised residuals, (signature score,
    signature map), (delta ELPD, SE, max k-hat, unreliable fraction) or None)``, or the exception
    it raised (raised instead with ``RJFIT_DEBUG`` set). LOO only where the log Bayes factor
    exceeds ``threshold``; ``residuals`` and ``sigma2_hat`` are the current model's, which the
    signatures are fitted to.

    Threads, not processes: a refit's time goes to NumPy passes over every observation, which
    release the GIL (two threads refit the ball's candidates 1.5 to 1.8 times faster on 2
    cores, measured), and a thread shares the context's arrays and cached features instead of
    copying them. BLAS runs on one thread meanwhile, for every ``jobs``, so the outcomes do not
    depend on it (BLAS's own threads gave these small products nothing, measured). Mitsuba
    features (interreflection, cast shadows) are rendered first, here, one effect at a time:
    a render uses every core itself and drjit's state is per thread. ``report(effect, outcome)``
    is called on this thread as each candidate finishes.
    """
    from concurrent.futures import as_completed

    debug = bool(os.environ.get("RJFIT_DEBUG"))     # a programming error then shows its traceback
    outcomes = {}
    ready = []
    for effect in current.effects:
        # every candidate's refit prepares the current model's effects too: where one of them is
        # a Mitsuba feature not yet in ctx's cache (interreflection's, after the search changed the
        # materials it is rendered at), the workers would each render it at once, on their threads
        # (measured: a segfault in rjfit refine's second round, or with RJFIT_DEBUG "jit_var_gather():
        # attempted to gather from an empty array"). Rendered here instead, once.
        if effect.needs_mitsuba:
            effect.prepare(ctx)
    for effect in effects:
        try:
            if effect.needs_mitsuba:
                effect.prepare(ctx)        # caches its rendered feature in ctx (ctx.feature)
            ready.append(effect)
        except Exception as error:
            if debug:
                raise
            outcomes[effect.name] = error
            report(effect, error)
    if not ready:
        return outcomes
    with refit_threads(jobs, len(ready)) as pool:
        futures = {pool.submit(_try_candidate, ctx, current, effect, residuals, sigma2_hat, seed, threshold): effect
                   for effect in ready}
        for future in as_completed(futures):
            effect = futures[future]
            try:
                outcomes[effect.name] = future.result()
            except Exception as error:
                if debug:
                    raise
                outcomes[effect.name] = error
            report(effect, outcomes[effect.name])
    return outcomes


def converge_base(ctx, current, candidates, *, seed, tol=BASE_TOLERANCE):
    """The current model refitted from the point of the best candidate (by evidence) among
    ``candidates`` (refits of ``current`` plus one effect each), where that lowers its objective
    (negative log posterior) by more than ``tol``; else None.

    A candidate's refit re-optimises the current model's parameters too: when the current
    refit stopped short of its optimum (or in a poorer local one), every candidate gains the
    same part, and the log Bayes factors measure the refit, not the effect. Refitting the
    current model from where a candidate went takes that common part into the base.
    """
    if not candidates:
        return None
    best = max(candidates, key=lambda fit: fit.log_evidence)
    base = refit(ctx, current.effects, start=best, seed=seed)
    gain = current.objective.f(current.z) - base.objective.f(base.z)
    return base if gain > tol else None


def _towards_null(param, z) -> bool:
    """Whether ``z`` lies between the prior's centre and the parameter's null (where the effect
    vanishes): a parameter pulled there says the effect is absent, not that it stands in for another."""
    if param.null is None:          # no value of it alone removes the effect: no side to tell
        return False
    with np.errstate(divide="ignore"):
        z_null = float(param.prior.to_unconstrained(param.null))      # +-inf at a bound
    return (z - param.prior.loc) * (z_null - param.prior.loc) > 0 and abs(z - param.prior.loc) <= abs(z_null - param.prior.loc)


def _towards_physical_end(param, z) -> bool:
    """Whether ``z`` lies on the side of the prior's centre where one of the parameter's
    ``physical_ends`` is (a weight near 1 is full occlusion: physical, however far on the logit scale)."""
    with np.errstate(divide="ignore"):
        ends = [float(param.prior.to_unconstrained(end)) for end in param.physical_ends]       # +-inf
    return any((z - param.prior.loc) * (z_end - param.prior.loc) > 0 for z_end in ends)


def prior_conflicts(z, n_regions, effects, effect_params, effect_name):
    """The parameters of the effect ``effect_name`` whose MAP lies beyond :data:`PRIOR_CONFLICT_SD`
    prior sd of the prior's centre, away from the effect's null and from its physical ends
    (:class:`rjfit.effects.Param`): ``[{"param", "map",
    "prior_sd_from_centre"}]``.

    ``z`` is a refit's unconstrained MAP, with ``n_regions`` regions' 4 parameters first, then
    each of ``effects``' parameters (``effect_params``: its :class:`rjfit.effects.Param`
    list) in order; a :class:`rjfit.diagnose.refit.FitResult` gives them as ``fit.z``,
    ``fit.n_regions``, ``fit.objective.effects`` and ``fit.objective.effect_params``.
    """
    conflicts, offset = [], 4 * n_regions
    for effect, params in zip(effects, effect_params):
        for k, param in enumerate(params if effect.name == effect_name else ()):
            value = float(z[offset + k])
            distance = abs(value - param.prior.loc) / param.prior.scale
            if distance > PRIOR_CONFLICT_SD and not (_towards_null(param, value) or _towards_physical_end(param, value)):
                conflicts.append({"param": f"{effect.name}.{param.name}",
                                  "map": float(param.prior.to_constrained(value)), "prior_sd_from_centre": distance})
        offset += len(params)
    return conflicts


def fit_prior_conflicts(fit, effect_name):
    """:func:`prior_conflicts` of the effect ``effect_name`` in the refit ``fit``."""
    objective = fit.objective
    return prior_conflicts(fit.z, objective.ctx.n_regions, objective.effects, objective.effect_params, effect_name)


def candidate_row(step, effect, outcome, current, threshold, loo_se_factor):
    """A candidate's row of ``diagnosis.json``: its error, or its evidence, signature score,
    parameters and whether it is decisive (``outcome`` as :func:`try_candidates` gives it)."""
    row = {"step": step, "effect": effect.name, "kind": effect.kind}
    if isinstance(outcome, Exception):
        # A failing candidate (a refit that does not converge, a Mitsuba feature that cannot
        # be rendered) is reported in its row and the search goes on
        row["error"] = f"{type(outcome).__name__}: {outcome}"
        return row
    candidate, _, (score, _), loo = outcome
    row["signature_score"] = score
    row.update(judged_fields(candidate, current, (effect.name,), loo, threshold, loo_se_factor))
    return row


def judged_fields(candidate, current, names, loo, threshold, loo_se_factor) -> dict:
    """The fields of a row of ``diagnosis.json`` that the decision rule (module docstring) judges, for the refit
    ``candidate`` of ``current`` plus the effects ``names`` (one, or a pair's two): evidence, the added effects'
    parameters and prior-data conflicts, LOO (``loo`` as :func:`loo_difference` gives it, None where the log BF
    is at most ``threshold``), ``decisive`` and ``supported`` (decisive, or its log BF above ``threshold`` and a
    positive delta ELPD over the observations where PSIS is reliable)."""
    fields = {"log_evidence": candidate.log_evidence, "log_bayes_factor": candidate.log_evidence - current.log_evidence,
              "n_params_added": candidate.n_params - current.n_params,
              "effect_params": {k: v for k, v in candidate.summary().items() if k.split(".")[0] in names},
              "hessian": candidate.hessian_kind, "seconds": candidate.seconds,
              "posterior_draws": {"proposal": candidate.draws_proposal}}
    conflicts = [conflict for name in names for conflict in fit_prior_conflicts(candidate, name)]
    if conflicts:
        fields["prior_conflict"] = conflicts
    if loo is not None:
        fields.update(delta_elpd_loo=loo[0], delta_elpd_loo_se=loo[1], max_khat=loo[2], khat_unreliable_fraction=loo[3],
                      delta_elpd_loo_reliable=loo[4], delta_elpd_loo_reliable_se=loo[5])
        fields["posterior_draws"]["weights_khat"] = draws_pareto_k(candidate)
    else:
        bound = "ln 100" if math.isclose(threshold, LOG_BF_THRESHOLD) else f"{threshold:.4g}"
        fields["loo_skipped"] = f"log BF <= {bound}, cannot be decisive"
    def clear_by(factor, which=""):
        return bool(fields["log_bayes_factor"] > threshold and fields.get(f"delta_elpd_loo{which}", -np.inf)
                    > factor * fields.get(f"delta_elpd_loo{which}_se", np.inf))

    fields["decisive"] = clear_by(loo_se_factor)
    # A trial (a refit of the regions with the effect, kept only where it needs fewer regions or
    # halves the gap: rjfit.pipeline.refine_trial) asks of LOO only its sign. Where the fit split
    # off regions of a few pixels to absorb a misfit, the effect that explains it gains little on
    # that segmentation, and those regions' observations, whose PSIS estimates do not converge,
    # carry the SE: Mitsuba's GGX dielectric under change points, 6 regions for 4, the lobe's SE
    # 15.9, 25.9 and 39.4 with 100, 400 and 1,600 draws, and its gain over the reliable observations
    # 1.6 to 2.8 SE between two diagnoses of one fit, where light_calibration (log BF 6.9 against
    # the lobe's 31.8) had 2.4 (docs/results/2026-12-01-supported-trials.md).
    fields["supported"] = fields["decisive"] or clear_by(0.0, "_reliable")
    return fields


def loo_support_text(row) -> str:
    """A judged row's (or a trial's) LOO gain in SE over all observations and over those where PSIS is reliable,
    e.g. "26.3 = 1.7 SE; 21.6 = 2.8 SE where PSIS is reliable"."""
    def ratio(which):
        se = row.get(f"delta_elpd_loo{which}_se")
        return row[f"delta_elpd_loo{which}"] / se if se else float("nan")

    return (f"{row['delta_elpd_loo']:.1f} = {ratio(''):.1f} SE; {row['delta_elpd_loo_reliable']:.1f} = "
            f"{ratio('_reliable'):.1f} SE where PSIS is reliable")
