"""The (a, b) conditional: the Gaussian of a region's two linear amplitudes given gamma and sigma^2.

With ``a = I0 kd`` and ``b = I0 (1 - kd) N(gamma)`` the mean of every observation is linear
in (a, b) (:mod:`rjfit.sampler.forward`), so given gamma and sigma^2 their conditional under
a flat prior is a bivariate normal computed from the region's statistics alone
(:func:`ab_conditional`). :func:`move_ab` redraws (a, b) from it; the gamma moves and the
region proposals of births and deaths draw from it too.
"""
from __future__ import annotations

import math
from typing import NamedTuple

from rjfit.sampler.likelihood import LOG_2PI
from rjfit.sampler.moves.base import decide_row
from rjfit.sampler.moves.proposal import RowProposal
from rjfit.sampler.moves.region_terms import edge_delta, giesen_norm, region_log_lik

__all__ = ["ABConditional", "ab_conditional", "draw_ab", "log_q_ab", "log_target_ab", "decide_amplitudes", "move_ab"]


class ABConditional(NamedTuple):
    """Gaussian of (a, b) given gamma and sigma^2 under a flat prior (see :func:`ab_conditional`).

    The covariance is ``s2 * P^-1`` with the precision-like matrix ``P = [[saa, sab], [sab, sbb]]``.
    """

    ma: float    # mean of a (the least-squares point, or the non-negative one)
    mb: float    # mean of b
    la: float    # lower Cholesky factor [[la, 0], [lc, lb]] of the covariance
    lc: float
    lb: float
    saa: float   # entries of P (the region's SAA, SAB, SBB statistics)
    sab: float
    sbb: float
    det: float   # det(P)
    s2: float    # sigma^2 the covariance is scaled by


def ab_conditional(stats_r, s2):
    """Gaussian of (a, b) given gamma and sigma^2 under a flat prior: an :class:`ABConditional`, or None.

    None when the system is singular or not finite.
    """
    _, _, sya, saa, syb, sab, sbb = stats_r.tolist() if hasattr(stats_r, "tolist") else stats_r
    s2 = float(s2)
    det = saa * sbb - sab * sab
    # Python floats: a near-singular system overflows to inf quietly and is caught below
    if not (saa > 0 and sbb > 0 and det > 1e-10 * saa * sbb):
        return None
    ma = (sbb * sya - sab * syb) / det
    mb = (saa * syb - sab * sya) / det
    if ma < 0 or mb < 0:
        # The least-squares point lies outside a, b > 0 (say, a start far from the data, or
        # a region without a lobe): centred there, nearly every draw would be rejected and
        # the chain could stick. Centre on the non-negative least-squares point instead
        # (a proposal may be any function of gamma, sigma^2 and the data).
        ma, mb = ((max(sya, 0.0) / saa, 0.0) if max(sya, 0.0) ** 2 / saa >= max(syb, 0.0) ** 2 / sbb
                  else (0.0, max(syb, 0.0) / sbb))
    caa, cab, cbb = s2 * sbb / det, -s2 * sab / det, s2 * saa / det
    if not (math.isfinite(caa) and math.isfinite(cbb) and math.isfinite(ma) and math.isfinite(mb)) or caa <= 0:
        return None
    la = math.sqrt(caa)
    lc = cab / la
    lb2 = cbb - lc * lc
    if not (math.isfinite(lb2) and lb2 > 0):
        return None
    lb = math.sqrt(lb2)
    return ABConditional(ma=ma, mb=mb, la=la, lc=lc, lb=lb, saa=saa, sab=sab, sbb=sbb, det=det, s2=s2)


def draw_ab(cond: ABConditional, rng):
    """One draw of (a, b) from the conditional (two standard normals)."""
    z1, z2 = rng.normal(size=2)
    return cond.ma + cond.la * z1, cond.mb + cond.lc * z1 + cond.lb * z2


def log_q_ab(a, b, cond: ABConditional):
    """Log density of (a, b) under the conditional."""
    saa, sab, sbb, det, s2 = cond.saa, cond.sab, cond.sbb, cond.det, cond.s2
    da, db = a - cond.ma, b - cond.mb
    # log N((a,b); m, s2 P^-1) with |cov| = s2^2 / det(P)
    return -LOG_2PI - math.log(s2) + 0.5 * math.log(det) - 0.5 * (saa * da * da + 2 * sab * da * db + sbb * db * db) / s2


def log_target_ab(prior, I0, kd, g, s2, log_lik_r):
    """Log target in coordinates (a, b, log gamma, sigma^2): p(theta) / (I0 N(g)) * g * L."""
    return log_lik_r + prior.logpdf_scalar(I0, kd, g, s2) - math.log(I0) - math.log(giesen_norm(g)) + math.log(g)


def decide_amplitudes(work, r, prior, a, b, g, stats_new, log_q_ratio, log_u, kind, info) -> bool:
    """The MH test of row ``r`` at amplitudes ``(a, b)`` and gamma ``g`` (``stats_new``: its statistics at ``g``),
    sigma^2 kept: the target in (a, b, log gamma, sigma^2) coordinates (:func:`log_target_ab`), the proposal's
    ``log_q_ratio`` (``log q(old | new) - log q(new | old)``) and the edge term's change. Outside ``a, b > 0``
    the target is 0: rejected. Returns whether it accepted (not counted: the move counts)."""
    if a <= 0 or b <= 0:
        return False
    I0, kd, g_old, s2 = work.theta[r]
    I0_new = a + b / giesen_norm(g)
    kd_new = a / I0_new
    ll_new = region_log_lik(stats_new, I0_new, kd_new, g, s2)
    log_alpha = (log_target_ab(prior, I0_new, kd_new, g, s2, ll_new)
                 - log_target_ab(prior, I0, kd, g_old, s2, work.log_lik[r]) + log_q_ratio)
    if log_alpha > -math.inf:
        log_alpha += edge_delta(work, r, (I0_new, kd_new, g, s2))
    return decide_row(work, RowProposal(r, (I0_new, kd_new, g, s2), stats_new, ll_new, log_alpha, log_u, kind), info)


def move_ab(work, r, rng, prior, info):
    """Redraw region r's (a, b) from their conditional (an independence MH move; kind 'ab').

    The proposal is the likelihood's conditional, so the ratio is the prior's in (a, b)
    coordinates (``p(theta) / I0``; the Jacobian of (I0, kd) -> (a, b) is ``I0 N(g)``).
    Returns whether it accepted, or None when the conditional does not exist (singular).
    """
    I0, kd, g, s2 = work.theta[r]
    cond = ab_conditional(work.stats[r], s2)
    if cond is None:
        return None
    a, b = draw_ab(cond, rng)
    log_u = math.log(rng.random())
    if a <= 0 or b <= 0:
        return False
    I0_new = a + b / giesen_norm(g)
    kd_new = a / I0_new
    log_alpha = (prior.logpdf_scalar(I0_new, kd_new, g, s2) - math.log(I0_new)
                 - prior.logpdf_scalar(I0, kd, g, s2) + math.log(I0))
    if log_alpha > -math.inf:
        log_alpha += edge_delta(work, r, (I0_new, kd_new, g, s2))
    return decide_row(work, RowProposal(r, (I0_new, kd_new, g, s2), None, None, log_alpha, log_u, "ab"), info)
