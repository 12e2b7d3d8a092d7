"""Scalar terms of one region shared by the within-region moves: Giesen's normalisation, the log-likelihood.

Python floats, not NumPy: these run millions of times per chain, where a NumPy call on a
scalar costs ten times the arithmetic.
"""
from __future__ import annotations

import math

from rjfit.sampler.likelihood import AB_PLAIN_MAX, LOG_2PI, STAT_AB, STAT_BB, STAT_YB, log_lik_large_ab

__all__ = ["giesen_norm", "region_log_lik", "stats_at_gamma", "set_region", "edge_delta", "edge_rows_delta"]


def giesen_norm(g: float) -> float:
    """Giesen's normalisation of a scalar exponent.

    The formula of :func:`rjfit.model.blinn.blinn_normalisation` (the definition) with
    ``2.0 ** x`` for ``np.exp2(x)``; ``tests/sampler/test_normalisation.py`` checks the two
    agree within rounding (5 ulp-sized units, the bound derived there: NumPy's ``exp2`` kernel
    depends on the CPU).
    """
    return (g + 2.0) * (g + 4.0) / (8.0 * math.pi * (2.0 ** (-g / 2.0) + g))


def region_log_lik(stats_r, I0, kd, g, s2) -> float:
    """Log-likelihood of one region from its statistics (the scalar case of ``log_likelihood_from_stats``)."""
    n, syy, sya, saa, syb, sab, sbb = stats_r
    a = I0 * kd
    b = I0 * (1.0 - kd) * giesen_norm(g)
    if abs(a) > AB_PLAIN_MAX or abs(b) > AB_PLAIN_MAX:      # the plain sum would overflow
        return log_lik_large_ab(stats_r, a, b, s2)
    ssr = syy - 2.0 * a * sya - 2.0 * b * syb + a * a * saa + 2.0 * a * b * sab + b * b * sbb
    if ssr < 0.0:       # floored as in likelihood.log_likelihood_from_stats
        ssr = 0.0
    return -0.5 * n * (LOG_2PI + math.log(s2)) - 0.5 * ssr / s2


def stats_at_gamma(work, r, problem, g):
    """Region r's statistics with (SyB, SAB, SBB) at exponent ``g``: a copy, one compiled pass over the region."""
    stats_new = work.stats[r].copy()
    stats_new[[STAT_YB, STAT_AB, STAT_BB]] = work.region_data(r, problem).b_sums(g)
    return stats_new


def edge_delta(work, r, theta_r) -> float:
    """The change of the target's edge term (:mod:`rjfit.sampler.regions.materials.edges`) when region ``r``'s parameters become
    ``theta_r``; 0 without an edge term. A parameter move adds it to its log ratio."""
    if work.edges is None:
        return 0.0
    return work.edges.region_delta(work.layout.pixels, work.theta, r, theta_r, work.edge_memo)


def edge_rows_delta(work, rows, theta_rows) -> float:
    """:func:`edge_delta` of several rows at once (a colour material's rows at a new gamma)."""
    if work.edges is None:
        return 0.0
    return work.edges.rows_delta(work.layout.pixels, work.theta, rows, theta_rows, work.edge_memo)


def set_region(work, r, theta_r, stats_r=None, log_lik_r=None):
    """Make ``theta_r`` (and new statistics, if given) region r's in ``work``, with its log-likelihood."""
    work.theta[r] = theta_r
    if stats_r is not None:
        work.stats[r] = stats_r
    work.log_lik[r] = region_log_lik(work.stats[r], *theta_r) if log_lik_r is None else log_lik_r
