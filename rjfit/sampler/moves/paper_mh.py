"""The paper's within-region sampler: component-wise normal random-walk MH in natural space.

Each of ``(I0, kd, gamma, sigma^2)`` in turn gets a normal step of the prior preset's width
(``Prior.proposal_sd``). With ``full_recompute`` every proposal is evaluated by a pass over
all observations, as the paper's implementation did (the same value as the statistics give;
the benchmark's like-for-like baseline).
"""
from __future__ import annotations

import math

import numpy as np

from rjfit.sampler.likelihood import LOG_2PI, ab_from_theta, lobe_column
from rjfit.sampler.moves.base import decide_row
from rjfit.sampler.moves.proposal import RowProposal
from rjfit.sampler.moves.region_terms import region_log_lik, stats_at_gamma

__all__ = ["update_region_paper", "full_pass_log_lik"]


def full_pass_log_lik(work, problem, theta):
    """Total log-likelihood by one pass over every observation (the paper's way)."""
    t = theta[work.labels]
    a, b = ab_from_theta(t)
    mu = a * problem.A + b * lobe_column(problem, slice(None), t[:, 2])
    resid = problem.y - mu
    return problem.likelihood_power * float(np.sum(-0.5 * (LOG_2PI + np.log(t[:, 3])) - 0.5 * resid * resid / t[:, 3]))


def update_region_paper(work, r, rng, prior, problem, info, full_recompute=False):
    """The paper's component-wise normal random-walk MH of region r (kinds 'rw_0' .. 'rw_3').

    A proposal outside the support (or of zero prior density) is rejected with its uniform
    drawn, as every proposal's is.
    """
    for k in range(4):
        theta = work.theta[r]
        new = theta.copy()
        new[k] += prior.proposal_sd[k] * rng.normal()
        log_u = math.log(rng.random())
        lp_new = prior.logpdf_scalar(*new)
        if not math.isfinite(lp_new) or new[k] <= 0 or (k == 1 and new[k] >= 1):
            info.count(f"rw_{k}", False)
            continue
        stats_new = stats_at_gamma(work, r, problem, new[2]) if k == 2 else work.stats[r]
        ll_new = region_log_lik(stats_new, *new)
        if full_recompute:
            # the paper's cost model: one full likelihood pass per proposal (same value)
            all_theta = work.theta.copy()
            all_theta[r] = new
            ll_new = full_pass_log_lik(work, problem, all_theta) - (float(np.sum(work.log_lik)) - work.log_lik[r])
        log_alpha = ll_new + lp_new - work.log_lik[r] - prior.logpdf_scalar(*theta)
        accepted = decide_row(work, RowProposal(r, new, stats_new if k == 2 else None, ll_new, log_alpha, log_u,
                                                f"rw_{k}"), info)
        info.count(f"rw_{k}", accepted)
