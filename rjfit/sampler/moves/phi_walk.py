"""Component-wise random walk in phi space, for small or degenerate regions.

``phi = (log I0, logit kd, log gamma, log sigma^2)`` (:mod:`rjfit.sampler.priors`): a
region whose (a, b) conditional does not exist, or whose posterior the prior shapes
(few observations), still mixes under this plain move.
"""
from __future__ import annotations

import math

from rjfit.sampler.moves.base import decide_row
from rjfit.sampler.moves.proposal import RowProposal
from rjfit.sampler.moves.region_terms import edge_delta, region_log_lik, stats_at_gamma

__all__ = ["move_phi_rw"]


def move_phi_rw(work, r, rng, prior, problem, step, info):
    """Four Metropolis steps, one per phi component, each N(0, step^2) (kind 'phi_rw'); returns how many accepted.

    A proposal with kd outside (0, 1) after rounding is rejected (its uniform still drawn).
    """
    accepted = 0
    I0, kd, g, s2 = work.theta[r]
    phi = [math.log(I0), math.log(kd) - math.log1p(-kd), math.log(g), math.log(s2)]
    log_prior = prior.logpdf_phi_scalar(phi)
    for k in range(4):
        phi_new = list(phi)
        phi_new[k] += step * rng.normal()
        log_u = math.log(rng.random())
        kd_new = 1.0 / (1.0 + math.exp(-phi_new[1]))
        new = (math.exp(phi_new[0]), kd_new, math.exp(phi_new[2]), math.exp(phi_new[3]))
        if not 0.0 < kd_new < 1.0:
            continue
        stats_new = stats_at_gamma(work, r, problem, new[2]) if k == 2 else work.stats[r]
        ll_new = region_log_lik(stats_new, *new)
        log_prior_new = prior.logpdf_phi_scalar(phi_new)
        log_alpha = ll_new + log_prior_new - work.log_lik[r] - log_prior
        if k < 3 and log_alpha > -math.inf:     # sigma^2 (k = 3) does not enter the edge term
            log_alpha += edge_delta(work, r, new)
        if decide_row(work, RowProposal(r, new, stats_new if k == 2 else None, ll_new, log_alpha, log_u, "phi_rw"), info):
            phi, log_prior = phi_new, log_prior_new
            accepted += 1
    return accepted
