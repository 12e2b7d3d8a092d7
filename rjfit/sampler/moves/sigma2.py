"""The sigma^2 move: an independence proposal from the likelihood's inverse gamma, corrected by the prior."""
from __future__ import annotations

import math

from rjfit.sampler.likelihood import LOG_2PI, STAT_N
from rjfit.sampler.moves.ab_conditional import move_ab
from rjfit.sampler.moves.base import decide_row
from rjfit.sampler.moves.proposal import RowProposal
from rjfit.sampler.moves.region_terms import region_log_lik

__all__ = ["move_sigma2", "move_amplitudes_and_variance"]


def move_sigma2(work, r, rng, prior, info):
    """Redraw region r's sigma^2 from ``InvGamma(n/2 - 1, SSR/2)`` (kind 'sigma2').

    That proposal is proportional to the likelihood in sigma^2, so the acceptance ratio is
    the prior's ratio alone. Returns whether it accepted, or None for a region with fewer
    than 3 observations or no positive residual (the proposal does not exist).
    """
    I0, kd, g, s2 = work.theta[r]
    stats_r = work.stats[r]
    n = stats_r[STAT_N]
    if n < 3:
        return None
    ssr = -2.0 * s2 * (region_log_lik(stats_r, I0, kd, g, s2) + 0.5 * n * (LOG_2PI + math.log(s2)))
    if not ssr > 0:
        return None
    # Independence proposal proportional to the likelihood in sigma^2: InvGamma(n/2 - 1, ssr/2).
    s2_new = 0.5 * ssr / rng.gamma(0.5 * n - 1.0)
    log_alpha = prior.params[3].logpdf_scalar(s2_new) - prior.params[3].logpdf_scalar(s2)
    return decide_row(work, RowProposal(r, (I0, kd, g, s2_new), None, None, log_alpha, math.log(rng.random()), "sigma2"),
                      info)


def move_amplitudes_and_variance(work, r, rng, prior, info) -> None:
    """Row ``r``'s (a, b) move, then its sigma^2 move, each counted in ``info`` (given gamma):
    the part of a region's update that a colour material runs once per channel row."""
    result = move_ab(work, r, rng, prior, info)
    if result is not None:
        info.count("ab", result)
    result = move_sigma2(work, r, rng, prior, info)
    if result is not None:
        info.count("sigma2", result)
