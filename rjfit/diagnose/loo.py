"""PSIS-LOO of a refit's Laplace draws, and the difference between two refits' LOO: the
second opinion beside the Laplace evidence (:mod:`rjfit.diagnose.psis` is the estimator)."""
from __future__ import annotations

import math

import numpy as np

from rjfit.diagnose.proposal import importance_log_weights, weight_pareto_k
from rjfit.diagnose.psis import good_k_threshold, psis_loo

__all__ = ["pointwise_log_lik", "refit_loo", "draws_pareto_k", "loo_difference"]


def pointwise_log_lik(fit):
    """(S, N) log-likelihood of every observation under every draw of ``fit`` (a
    :class:`rjfit.diagnose.refit.FitResult`; not cached: S N floats)."""
    objective = fit.objective
    return np.stack([objective.log_lik_pointwise(d) for d in fit.draws])


def refit_loo(fit):
    """PSIS-LOO on ``fit``'s Laplace draws: a :class:`rjfit.diagnose.psis.LooResult` (elpd, se,
    pointwise elpd, pointwise k-hat), computed once per fit.

    :func:`rjfit.diagnose.psis.psis_loo` (ArviZ's estimator, vectorised); a coarsened refit's
    draws leave an observation out with its likelihood to the refit's power. Only the result
    is kept: the (S, N) pointwise log-likelihood it is computed from is dropped at once, so a
    diagnosis holds one such array per candidate refitting at that moment, not one per fit.
    """
    return fit.cached("loo", _loo_and_draws_check)[0]


def draws_pareto_k(fit) -> float:
    """The Pareto k-hat of ``fit``'s draws' importance weights (above
    :data:`rjfit.diagnose.proposal.POOR_DRAWS_KHAT` they cover the posterior too poorly for the
    LOO taken from them), from the same pointwise log-likelihood as its LOO."""
    return fit.cached("loo", _loo_and_draws_check)[1]


def _loo_and_draws_check(fit):
    log_lik = pointwise_log_lik(fit)
    objective = fit.objective
    log_joint = objective.zeta * log_lik.sum(axis=1) + np.array([objective.log_prior(d) for d in fit.draws])
    khat = weight_pareto_k(importance_log_weights(log_joint, fit.draws_log_proposal))
    return psis_loo(log_lik, likelihood_power=objective.zeta), khat


def loo_difference(candidate, current):
    """``(delta ELPD, its SE, max k-hat, fraction of observations with an unreliable k-hat, delta ELPD and its SE
    over the reliable observations only)`` of the refit ``candidate`` over the refit ``current`` (same
    observations).

    An observation is unreliable where either model's k-hat exceeds the threshold for the
    number of draws (:func:`rjfit.diagnose.psis.good_k_threshold`, 0.5 for 100 draws): there its
    importance weights have too heavy a tail for the estimate to converge. Such observations can carry the SE:
    on an over-segmented fit, those of a region of a few pixels, whose leave-one-out posterior is far from the
    full one (the GGX dielectric under change points: SE 15.9 over all, 7.7 over the reliable, and 25.9 and 39.4
    over all with 400 and 1,600 draws; docs/results/2026-12-01-supported-trials.md)."""
    loo_c, loo_0 = refit_loo(candidate), refit_loo(current)
    diff = loo_c.pointwise - loo_0.pointwise
    khat = np.maximum(loo_c.pareto_k, loo_0.pareto_k)
    reliable = khat <= good_k_threshold(min(len(candidate.draws), len(current.draws)))
    return (float(diff.sum()), _sum_se(diff), float(khat.max()), float(np.mean(~reliable)),
            float(diff[reliable].sum()), _sum_se(diff[reliable]))


def _sum_se(diff) -> float:
    """The SE of the sum of the pointwise differences ``diff`` (0 for none)."""
    return float(math.sqrt(diff.size * np.var(diff))) if diff.size else 0.0
