"""Moves of the RJMCMC kernel, one small unit each.

Within-model moves act on one region of a mutable working copy (:class:`Work`) that the
kernel turns into a new immutable state at the end of a step. Each returns whether it
accepted. Change-point sweeps move one element of every row (column) at once: given the
parameters and the other axis, the target factorises over rows (a u element only changes
pixels of its row), so the rows' independent MH decisions together form a valid move.
Birth/death proposals (:func:`propose_birth`, :func:`propose_death`) return
``(proposal, log acceptance ratio)`` with the split map's Jacobian computed by the map's
own unit (:func:`split_phi` / :func:`merge_phi`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.special import log_ndtr

from rjfit.sampler import jit
from rjfit.sampler.changepoints import log_prior_cp_state, n_regions, obs_region_labels
from rjfit.sampler.likelihood import (LOG_2PI, STAT_AA, STAT_AB, STAT_BB, STAT_N, STAT_YA, STAT_YB, STAT_YY, RegionData,
                                      ab_from_theta, b_terms, log_likelihood_from_stats, region_stats)
from rjfit.sampler.priors import from_phi, to_phi

__all__ = ["Work", "update_region_adaptive", "update_region_paper", "sweep_changepoints", "propose_vector_redraw",
           "accept_vector_redraw",
           "propose_birth_free", "propose_death_free",
           "split_phi", "merge_phi", "propose_birth", "propose_death", "log_posterior"]


@dataclass
class Work:
    """Mutable working copy of a state during one step (never shared across steps)."""

    u: np.ndarray
    v: np.ndarray
    theta: np.ndarray
    stats: np.ndarray
    log_lik: np.ndarray
    labels: np.ndarray
    labels_owned: bool = False
    region_index: dict | None = None  # region -> RegionData, valid for ``labels``

    def region_data(self, r: int, problem):
        """:class:`RegionData` of region r; every region's runs come from one read of the labels, once per labelling."""
        if self.region_index is None:
            self.region_index = {}
        if not self.region_index:     # filled in place: the kernel memoises this dict per labelling
            self.region_index.update(enumerate(RegionData.split(problem, self.labels, self.theta.shape[0])))
        return self.region_index[r]


# ----------------------------------------------------------------------------- within model

def _b_sums_region(work, problem, r, gamma):
    """(SyB, SAB, SBB) of region r at exponent gamma: the only O(n_r) work of a gamma move."""
    # np.dot on 1-D arrays; the runner limits BLAS to one thread (threads only add overhead here).
    return work.region_data(r, problem).b_sums(gamma)


def _norm(g: float) -> float:
    """Scalar Giesen normalisation (as :func:`rjfit.model.blinn.blinn_normalisation`)."""
    return (g + 2.0) * (g + 4.0) / (8.0 * math.pi * (2.0 ** (-g / 2.0) + g))


def _ll(stats_r, I0, kd, g, s2) -> float:
    """Scalar log-likelihood of one region from its statistics (fast path of log_likelihood_from_stats)."""
    n, syy, sya, saa, syb, sab, sbb = stats_r
    a = I0 * kd
    b = I0 * (1.0 - kd) * _norm(g)
    ssr = syy - 2.0 * a * sya - 2.0 * b * syb + a * a * saa + 2.0 * a * b * sab + b * b * sbb
    return -0.5 * n * (LOG_2PI + math.log(s2)) - 0.5 * ssr / s2


class ABConditional(NamedTuple):
    """Gaussian of (a, b) given gamma and sigma^2 under a flat prior (see :func:`_ab_conditional`).

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


def _ab_conditional(stats_r, s2):
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


def _draw_ab(cond: ABConditional, rng):
    z1, z2 = rng.normal(size=2)
    return cond.ma + cond.la * z1, cond.mb + cond.lc * z1 + cond.lb * z2


def _log_q_ab(a, b, cond: ABConditional):
    saa, sab, sbb, det, s2 = cond.saa, cond.sab, cond.sbb, cond.det, cond.s2
    da, db = a - cond.ma, b - cond.mb
    # log N((a,b); m, s2 P^-1) with |cov| = s2^2 / det(P)
    return -LOG_2PI - math.log(s2) + 0.5 * math.log(det) - 0.5 * (saa * da * da + 2 * sab * da * db + sbb * db * db) / s2


def _log_target_ab(prior, I0, kd, g, s2, log_lik_r):
    """Log target in coordinates (a, b, log gamma, sigma^2): p(theta) / (I0 N(g)) * g * L."""
    return log_lik_r + prior.logpdf_scalar(I0, kd, g, s2) - math.log(I0) - math.log(_norm(g)) + math.log(g)


def _set_region(work, r, theta_r, stats_r=None, log_lik_r=None):
    work.theta[r] = theta_r
    if stats_r is not None:
        work.stats[r] = stats_r
    work.log_lik[r] = _ll(work.stats[r], *theta_r) if log_lik_r is None else log_lik_r


def _move_ab(work, r, rng, prior):
    I0, kd, g, s2 = work.theta[r]
    cond = _ab_conditional(work.stats[r], s2)
    if cond is None:
        return None
    a, b = _draw_ab(cond, rng)
    log_u = math.log(rng.random())
    if a <= 0 or b <= 0:
        return False
    I0_new = a + b / _norm(g)
    kd_new = a / I0_new
    log_alpha = (prior.logpdf_scalar(I0_new, kd_new, g, s2) - math.log(I0_new)
                 - prior.logpdf_scalar(I0, kd, g, s2) + math.log(I0))
    if log_u < log_alpha:
        _set_region(work, r, (I0_new, kd_new, g, s2))
        return True
    return False


def _move_sigma2(work, r, rng, prior):
    I0, kd, g, s2 = work.theta[r]
    stats_r = work.stats[r]
    n = stats_r[STAT_N]
    if n < 3:
        return None
    ssr = -2.0 * s2 * (_ll(stats_r, I0, kd, g, s2) + 0.5 * n * (LOG_2PI + math.log(s2)))
    if not ssr > 0:
        return None
    # Independence proposal proportional to the likelihood in sigma^2: InvGamma(n/2 - 1, ssr/2).
    s2_new = 0.5 * ssr / rng.gamma(0.5 * n - 1.0)
    log_alpha = prior.params[3].logpdf_scalar(s2_new) - prior.params[3].logpdf_scalar(s2)
    if math.log(rng.random()) < log_alpha:
        _set_region(work, r, (I0, kd, g, s2_new))
        return True
    return False


def _accept_gamma_ab(work, r, rng, prior, cond_old, g_new, stats_new, log_q_ratio_gamma):
    """What every gamma move shares: (a, b) redrawn from their conditional given the proposed gamma, then MH.

    ``log_q_ratio_gamma`` is the log gamma proposal's ``log q(old | new) - log q(new | old)``
    (0 for a random walk). Returns whether the move was accepted.
    """
    I0, kd, g, s2 = work.theta[r]
    cond_new = _ab_conditional(stats_new, s2)
    if cond_new is None:
        return False
    a_new, b_new = _draw_ab(cond_new, rng)
    log_u = math.log(rng.random())
    if a_new <= 0 or b_new <= 0:
        return False
    I0_new = a_new + b_new / _norm(g_new)
    kd_new = a_new / I0_new
    ll_new = _ll(stats_new, I0_new, kd_new, g_new, s2)
    a_old, b_old = I0 * kd, I0 * (1.0 - kd) * _norm(g)
    log_alpha = (_log_target_ab(prior, I0_new, kd_new, g_new, s2, ll_new)
                 - _log_target_ab(prior, I0, kd, g, s2, work.log_lik[r])
                 + _log_q_ab(a_old, b_old, cond_old) - _log_q_ab(a_new, b_new, cond_new) + log_q_ratio_gamma)
    if log_u < log_alpha:
        _set_region(work, r, (I0_new, kd_new, g_new, s2), stats_new, ll_new)
        return True
    return False


def _move_gamma_ab(work, r, rng, prior, problem, step):
    """Random walk on log gamma with (a, b) redrawn from their conditional given the new gamma."""
    g, s2 = work.theta[r, 2], work.theta[r, 3]
    stats_r = work.stats[r]
    cond_old = _ab_conditional(stats_r, s2)
    if cond_old is None:
        return None
    g_new = g * math.exp(step * rng.normal())
    stats_new = stats_r.copy()
    stats_new[[STAT_YB, STAT_AB, STAT_BB]] = _b_sums_region(work, problem, r, g_new)
    return _accept_gamma_ab(work, r, rng, prior, cond_old, g_new, stats_new, 0.0)


def _ls_profile(sya, saa, sums, g):
    """``f = s.S^-1 s`` (so ``SSR_min = Syy - f`` without the a, b > 0 bound), ``det S``, and their l-derivatives.

    ``l = log gamma``; ``S = [[SAA, SAB], [SAB, SBB]]``, ``s = (SyA, SyB)``; ``sums`` are
    :meth:`RegionData.b_sums_newton` at ``g``. Since ``dB/dl = g log<h.n> B``, the
    l-derivatives of SyB, SAB and SBB are g- and g^2-weighted sums of them. With
    ``c = S^-1 s`` (the least-squares a, b) and primes for d/dl: ``f' = 2 c.s' - c.S'c`` and
    ``f'' = 2 d.S^-1 d + 2 c.s'' - c.S''c`` with ``d = s' - S'c``.
    Returns ``(f, f', f'', det, det', det'', a, b)`` or None for a singular S.
    """
    syb, sab, sbb, yb1, ab1, bb1, yb2, ab2, bb2 = sums
    det = saa * sbb - sab * sab
    if not (saa > 0 and sbb > 0 and det > 1e-10 * saa * sbb):
        return None
    ca = (sbb * sya - sab * syb) / det
    cb = (saa * syb - sab * sya) / det
    s1b, S1ab, S1bb = g * yb1, g * ab1, 2.0 * g * bb1               # s'_a = S'_aa = 0
    s2b, S2ab, S2bb = g * yb1 + g * g * yb2, g * ab1 + g * g * ab2, 2.0 * g * bb1 + 4.0 * g * g * bb2
    f = ca * sya + cb * syb
    f1 = 2.0 * cb * s1b - (2.0 * ca * cb * S1ab + cb * cb * S1bb)
    da = -S1ab * cb
    db = s1b - S1ab * ca - S1bb * cb
    f2 = (2.0 * (sbb * da * da - 2.0 * sab * da * db + saa * db * db) / det
          + 2.0 * cb * s2b - (2.0 * ca * cb * S2ab + cb * cb * S2bb))
    det1 = saa * S1bb - 2.0 * sab * S1ab
    det2 = saa * S2bb - 2.0 * S1ab * S1ab - 2.0 * sab * S2ab
    return f, f1, f2, det, det1, det2, ca, cb


def _newton_log_gamma(stats_r, sums, g, s2, scale):
    """Newton proposal of log gamma at ``g``: (mean, sd), or None where the profile is not concave.

    ``h(l) = -SSR_min(e^l) / (2 sigma^2) = (f - Syy) / (2 sigma^2)`` (:func:`_ls_profile`):
    the log-likelihood with (a, b) at their least-squares values, the O(n) part of log
    gamma's conditional; the prior and the (a, b) volume term are O(1) and left to the
    acceptance ratio.
    """
    profile = _ls_profile(stats_r[STAT_YA], stats_r[STAT_AA], sums, g)
    if profile is None:
        return None
    h1, h2 = 0.5 * profile[1] / s2, 0.5 * profile[2] / s2
    if not (math.isfinite(h1) and math.isfinite(h2) and h2 < 0):
        return None
    step, sd = -h1 / h2, scale / math.sqrt(-h2)
    # far from a quadratic (small or flat regions): the random walk is the safer rule there
    return (math.log(g) + step, sd) if abs(step) <= 5.0 and sd <= 2.0 else None


def _log_q_log_gamma(ell_to, ell_from, newton, rw_sd):
    mean, sd = newton if newton is not None else (ell_from, rw_sd)
    return -0.5 * ((ell_to - mean) / sd) ** 2 - math.log(sd) - 0.5 * LOG_2PI


def _move_gamma_newton(work, r, rng, prior, problem, scale, rw_sd):
    """Gamma move with a Newton proposal of log gamma, (a, b) redrawn from their conditional given it.

    The proposal's mean and sd come from the curvature of the profile log-likelihood at the
    current gamma (:func:`_newton_log_gamma`), so one move crosses the posterior's width
    and follows the kd-gamma ridge; the reverse density is the same rule at the proposed
    gamma, so the ratio is exact. Where the profile is not concave the rule is a random
    walk of sd ``rw_sd`` (a deterministic choice per point: still a valid proposal).
    """
    g, s2 = work.theta[r, 2], work.theta[r, 3]
    stats_r = work.stats[r]
    cond_old = _ab_conditional(stats_r, s2)
    if cond_old is None:
        return None
    data = work.region_data(r, problem)
    ell = math.log(g)
    forward = _newton_log_gamma(stats_r, data.b_sums_newton(g), g, s2, scale)
    ell_new = (forward[0] + forward[1] * rng.normal()) if forward is not None else ell + rw_sd * rng.normal()
    if ell_new > 700.0:         # gamma beyond e^700: the lobe (and the target) vanish numerically
        return False
    g_new = math.exp(ell_new)
    sums_new = data.b_sums_newton(g_new)
    stats_new = stats_r.copy()
    stats_new[[STAT_YB, STAT_AB, STAT_BB]] = sums_new[:3]
    backward = _newton_log_gamma(stats_new, sums_new, g_new, s2, scale)
    log_q_ratio = _log_q_log_gamma(ell, ell_new, backward, rw_sd) - _log_q_log_gamma(ell_new, ell, forward, rw_sd)
    return _accept_gamma_ab(work, r, rng, prior, cond_old, g_new, stats_new, log_q_ratio)


def _move_phi_rw(work, r, rng, prior, problem, step):
    """Component-wise random walk in phi space (small or degenerate regions)."""
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
        stats_new = work.stats[r]
        if k == 2:
            stats_new = stats_new.copy()
            stats_new[[STAT_YB, STAT_AB, STAT_BB]] = _b_sums_region(work, problem, r, new[2])
        ll_new = _ll(stats_new, *new)
        log_prior_new = prior.logpdf_phi_scalar(phi_new)
        if log_u < ll_new + log_prior_new - work.log_lik[r] - log_prior:
            _set_region(work, r, new, stats_new if k == 2 else None, ll_new)
            phi, log_prior = phi_new, log_prior_new
            accepted += 1
    return accepted


def update_region_adaptive(work, r, rng, prior, problem, config, g_step, info):
    """The default within-model update of region ``r``; returns the gamma moves' acceptances."""
    n = work.stats[r, STAT_N]
    g_acc = []
    if n < config.min_obs_conditional:
        info.count("phi_rw", _move_phi_rw(work, r, rng, prior, problem, config.fallback_step), 4)
        return g_acc
    for k in range(config.g_moves):
        # 'newton' alternates a random walk and a Newton move: the Newton proposal crosses
        # the posterior in one step near the mode, but from far away (a start, a tail) its
        # reverse density is negligible and it is rarely accepted; the random walk gets there.
        newton = config.gamma_move == "newton" and k % 2 == 1
        if newton:
            result = _move_gamma_newton(work, r, rng, prior, problem, config.newton_scale, g_step / np.sqrt(n))
        else:
            result = _move_gamma_ab(work, r, rng, prior, problem, g_step / np.sqrt(n))
        if result is None:
            info.count("phi_rw", _move_phi_rw(work, r, rng, prior, problem, config.fallback_step), 4)
            return g_acc
        if not newton:       # the adapted step is the random walk's
            g_acc.append(result)
        info.count("gamma_newton" if newton else "gamma_ab", result)
    result = _move_ab(work, r, rng, prior)
    if result is not None:
        info.count("ab", result)
    result = _move_sigma2(work, r, rng, prior)
    if result is not None:
        info.count("sigma2", result)
    if n < config.small_region_obs:
        # Small regions: the conditional proposals ignore the prior, which then matters;
        # a cheap phi-space random walk on top keeps them mixing (chosen by n only: valid).
        info.count("phi_rw", _move_phi_rw(work, r, rng, prior, problem, config.fallback_step), 4)
    return g_acc


def _full_pass_log_lik(work, problem, theta):
    """Total log-likelihood by one pass over every observation (the paper's way)."""
    t = theta[work.labels]
    a, b = ab_from_theta(t)
    mu = a * problem.A + b * b_terms(problem.C, problem.log_cos_hn, t[:, 2])
    resid = problem.y - mu
    return problem.likelihood_power * float(np.sum(-0.5 * (LOG_2PI + np.log(t[:, 3])) - 0.5 * resid * resid / t[:, 3]))


def update_region_paper(work, r, rng, prior, problem, info, full_recompute=False):
    """The paper's component-wise normal random-walk MH in natural space."""
    for k in range(4):
        theta = work.theta[r]
        new = theta.copy()
        new[k] += prior.proposal_sd[k] * rng.normal()
        log_u = math.log(rng.random())
        lp_new = prior.logpdf_scalar(*new)
        if not math.isfinite(lp_new) or new[k] <= 0 or (k == 1 and new[k] >= 1):
            info.count(f"rw_{k}", False)
            continue
        stats_new = work.stats[r]
        if k == 2:
            stats_new = stats_new.copy()
            stats_new[[STAT_YB, STAT_AB, STAT_BB]] = _b_sums_region(work, problem, r, new[2])
        ll_new = _ll(stats_new, *new)
        if full_recompute:
            # the paper's cost model: one full likelihood pass per proposal (same value)
            all_theta = work.theta.copy()
            all_theta[r] = new
            ll_new = _full_pass_log_lik(work, problem, all_theta) - (float(np.sum(work.log_lik)) - work.log_lik[r])
        log_alpha = ll_new + lp_new - work.log_lik[r] - prior.logpdf_scalar(*theta)
        accept = log_u < log_alpha
        if accept:
            _set_region(work, r, new, stats_new if k == 2 else None, ll_new)
        info.count(f"rw_{k}", accept)


# ----------------------------------------------------------------------------- change points

def sweep_changepoints(work, rng, problem, config, axis: str, info, parity: int = 0):
    """Move one element of every other row (axis 'u') or column (axis 'v') at once.

    Rows of one ``parity`` move together while the other rows stay fixed, so the
    neighbour-guided proposal (around the same-rank element of row r - 1 or r + 1) has a
    well-defined reverse density. A proposal outside [-1, size + 1] has zero prior density
    and is rejected.
    """
    height, width = problem.image_shape
    cps = work.u if axis == "u" else work.v
    n_all, n_cp = cps.shape
    if n_cp == 0:
        return
    size = width if axis == "u" else height       # positions run along this size
    lines = np.arange(parity, n_all, 2)
    n_lines = len(lines)
    if n_lines == 0:
        return
    k = rng.integers(n_cp, size=n_lines)
    kind = rng.random(n_lines)
    z = rng.normal(size=n_lines)
    pick_up = rng.random(n_lines) < 0.5
    unif = rng.uniform(-1.0, size + 1.0, n_lines)
    # proposal and its log ratio (reverse / forward density, smooth prior's terms): compiled
    x_old = cps[lines, k]
    x_new, inside, log_q_ratio = jit.sweep_proposal(
        np.ascontiguousarray(cps), lines, k, kind, z, pick_up, unif, float(size), config.cp_uniform_prob,
        config.cp_neighbour_prob, config.cp_step, config.cp_neighbour_sd,
        config.cp_smooth_sd if config.cp_prior == "smooth" else 0.0)
    starts, ends, delta = _element_shift(problem, work, axis, lines, x_old, x_new)
    log_u = np.log(rng.random(n_lines))
    d_ll = problem.likelihood_power * jit.obs_log_density_delta(
        problem.y, problem.C, problem.log_cos_hn, problem.colmajor_order, axis == "v", starts, ends, work.labels,
        delta, work.theta)
    accept = inside & (log_u < d_ll + log_q_ratio)
    info.count(f"cp_{axis}", accept, n_lines)
    if not np.any(accept):
        return
    new_cps = cps.copy()
    new_cps[lines[accept], k[accept]] = x_new[accept]
    new_cps.sort(axis=1)
    if axis == "u":
        work.u = new_cps
    else:
        work.v = new_cps
    _apply_shift(work, problem, axis, starts[accept], ends[accept], delta[accept])


def _element_shift(problem, work, axis, lines, x_old, x_new):
    """The observations that change region when element positions move from ``x_old`` to ``x_new``.

    Each of ``lines`` has one element moving within its rank: the pixels t with
    ``min < t + 0.5 <= max`` of the two positions change side, so their label moves by the
    vector's label step, down when the element moves right. Returns ``(starts, ends, delta)``:
    per line the slice of its observations (row-major for 'u', ``colmajor_order`` for 'v')
    and the label change.
    """
    size = problem.width if axis == "u" else problem.height
    step_label = (work.v.shape[1] + 1) if axis == "u" else 1
    offsets = problem.pixel_start if axis == "u" else problem.colmajor_start
    return jit.element_shift(np.ascontiguousarray(x_old, dtype=float), np.ascontiguousarray(x_new, dtype=float),
                             np.ascontiguousarray(lines, dtype=np.int64), size, offsets, step_label)


def _apply_shift(work, problem, axis, starts, ends, delta):
    """Relabel the observations of an :func:`_element_shift` and move their terms between regions (in place)."""
    moved = ends > starts
    if not np.any(moved):
        return
    if not work.labels_owned:
        work.labels = work.labels.copy()
        work.labels_owned = True
    jit.shift_stats(problem.y, problem.C, problem.log_cos_hn, problem.colmajor_order, axis == "v", starts[moved],
                    ends[moved], work.labels, delta[moved], np.ascontiguousarray(work.theta[:, 2]), work.stats,
                    problem.likelihood_power)
    work.region_index = None
    work.log_lik = log_likelihood_from_stats(work.stats, work.theta)


# ----------------------------------------------------------------------------- birth / death

def split_phi(phi, w, split_map: str):
    """Split a region's phi (.., 4) with auxiliary w into (phi_a, phi_b); returns also log|det J|.

    'mean': phi_a = phi - w, phi_b = phi + w, |det| = 2 per component.
    'paper': phi_a = phi - w, phi_b = phi + 2 w, |det| = 3 per component (the size of the
    determinant the design notes give for the paper's eq. 10).
    """
    n_components = np.size(phi)
    if split_map == "mean":
        return phi - w, phi + w, n_components * np.log(2.0)
    return phi - w, phi + 2.0 * w, n_components * np.log(3.0)


def merge_phi(phi_a, phi_b, split_map: str):
    """Inverse of :func:`split_phi`: (phi, w, log|det J| of the split)."""
    n_components = np.size(phi_a)
    if split_map == "mean":
        return 0.5 * (phi_a + phi_b), 0.5 * (phi_b - phi_a), n_components * np.log(2.0)
    w = (phi_b - phi_a) / 3.0
    return phi_a + w, w, n_components * np.log(3.0)


def birth_probability(n: int, n_max: int) -> float:
    if n_max == 0:
        return 0.0
    return 1.0 if n == 0 else (0.0 if n >= n_max else 0.5)


def log_posterior(problem, prior, u, v, theta, log_lik, config=None) -> float:
    """Log joint density (up to the constant model prior): likelihood, phi-space prior, change points."""
    cp_prior, sd = ("paper", 1.0) if config is None else (config.cp_prior, config.cp_smooth_sd)
    return float(np.sum(log_lik) + np.sum(prior.logpdf_phi(to_phi(theta)))
                 + log_prior_cp_state(u, v, problem.image_shape, cp_prior, sd))


def _build(problem, u, v, theta):
    labels = obs_region_labels(u, v, problem.row, problem.col, pixel_start=problem.pixel_start)
    stats = region_stats(problem, labels, theta[:, 2], theta.shape[0])
    return labels, stats, log_likelihood_from_stats(stats, theta)


def _gaps(cps, j, size):
    lower = cps[:, j - 1] if j > 0 else np.full(cps.shape[0], -1.0)
    upper = cps[:, j] if j < cps.shape[1] else np.full(cps.shape[0], size + 1.0)
    return lower, upper


def _log_normal(w, scale):
    return float(np.sum(-0.5 * (w / scale) ** 2 - np.log(scale) - 0.5 * LOG_2PI))


# --- the new vector's elements ------------------------------------------------------------

def _vector_log_q(x, lower, upper, size, config) -> float:
    """Log density of proposing the elements ``x`` of a new vector inside the gaps (lower, upper).

    Mixture: with probability ``birth_straight_prob`` a near-straight vector
    (``x0 ~ U(-1, size+1)``, ``x_r = x0 + tau z_r``; the density integrates x0 out in closed
    form), otherwise a draw from the change-point prior's own shape: for the 'smooth' prior
    its random walk, for the 'paper' prior each element uniform in its gap. Elements outside
    their gap: -inf (the proposal is rejected).
    """
    if not np.all((x > lower) & (x < upper)):
        return -np.inf
    if config.cp_prior == "smooth":
        # the prior's own random walk (x0 uniform, steps N(0, s^2)) replaces the uniform component
        sd = config.cp_smooth_sd
        log_unif = float(-math.log(size + 2.0) + np.sum(-0.5 * (np.diff(x) / sd) ** 2 - math.log(sd) - 0.5 * LOG_2PI))
    else:
        log_unif = -float(np.sum(np.log(upper - lower)))
    p_s = config.birth_straight_prob
    if p_s <= 0:
        return log_unif
    tau, H = config.birth_straight_sd, x.size
    xbar = float(np.mean(x))
    hi, lo = (size + 1.0 - xbar) * math.sqrt(H) / tau, (-1.0 - xbar) * math.sqrt(H) / tau
    log_mass = log_ndtr(hi) + math.log1p(-math.exp(min(0.0, log_ndtr(lo) - log_ndtr(hi))))
    log_s = (-0.5 * (H - 1) * math.log(2 * math.pi * tau * tau) - 0.5 * math.log(H)
             - float(np.sum((x - xbar) ** 2)) / (2 * tau * tau) + log_mass - math.log(size + 2.0))
    if p_s >= 1:
        return log_s
    return float(np.logaddexp(math.log(p_s) + log_s, math.log1p(-p_s) + log_unif))


def _draw_vector(rng, lower, upper, size, config):
    if rng.random() < config.birth_straight_prob:
        x0 = rng.uniform(-1.0, size + 1.0)
        return x0 + config.birth_straight_sd * rng.normal(size=lower.size)
    if config.cp_prior == "smooth":
        x0 = rng.uniform(-1.0, size + 1.0)
        steps = config.cp_smooth_sd * rng.normal(size=lower.size - 1)
        return x0 + np.concatenate([[0.0], np.cumsum(steps)])
    return lower + (upper - lower) * rng.random(lower.size)


# --- region parameters: independent conditional proposals ------------------------------

def _stats_at(data, g):
    return data.stats_at(g)


def _ssr_min(stats_r):
    """Least-squares residual of (a, b) at fixed gamma, and the Gaussian pieces, or None."""
    cond = _ab_conditional(stats_r, 1.0)
    if cond is None:
        return None
    ma, mb, saa, sab, sbb = cond.ma, cond.mb, cond.saa, cond.sab, cond.sbb
    # at the unconstrained least-squares point this is Syy - ma SyA - mb SyB; written out
    # in full because the centre may be the non-negative one
    ssr = (stats_r[STAT_YY] - 2.0 * (ma * stats_r[STAT_YA] + mb * stats_r[STAT_YB])
           + ma * ma * saa + 2.0 * ma * mb * sab + mb * mb * sbb)
    return (ssr, cond.det) if ssr > 0 else None


def _sigma2_prior_as_invgamma(prior):
    """(shape, scale) of an inverse gamma standing in for sigma^2's prior in proposals."""
    p = prior.params[3]
    if p.kind == "invgamma":
        return p.a, p.b
    if p.kind == "lognormal":       # match mean and variance of 1 / sigma^2 (lognormal(-a, b))
        mean = math.exp(-p.a + 0.5 * p.b ** 2)
        shape = 1.0 / math.expm1(p.b ** 2)
        return shape, shape / mean
    return 0.0, 0.0


LAPLACE_COARSE_OBS = 4096
LAPLACE_GRID = np.linspace(math.log(0.2), math.log(500.0), 9)    # log gamma: the coarse search's points


def _thinned(data, max_obs):
    """Every m-th observation of a region (sums scaled by m), or the region itself if it is small."""
    m = data.n // max_obs
    if m < 2:
        return data
    return data.thinned(m)


def _laplace_log_gamma(data, prior):
    """Deterministic Laplace fit (mean, sd) of log gamma's approximate marginal.

    ``h(l) = -(n/2 - 1 + a0) log(SSR_min(l)/2 + b0) - log det P(l) / 2 + log p_gamma(e^l) + l``
    with (a0, b0) the inverse gamma standing in for sigma^2's prior: (a, b) and sigma^2
    integrated out under flat priors for (a, b). The mode is located on a coarse grid
    evaluated on a thinning of the region (at most :data:`LAPLACE_COARSE_OBS`
    observations), then refined by Newton steps on the whole region with the closed-form
    derivatives of :func:`_ls_profile`, first on the thinning, then on the whole region from
    the thinning's mode: about 2 passes over the region instead of 18.
    Where that fails (a non-concave or bounded profile) it falls back to finite
    differences on the whole region. A function of the region's data only, as a
    proposal's parameters must be.
    """
    n = data.n * data.weight       # observations count zeta each under a coarsened likelihood
    a0, b0 = _sigma2_prior_as_invgamma(prior)
    g_prior = prior.params[2]
    k = 0.5 * n - 1.0 + a0

    def h_of_stats(stats_r, ell):
        res = _ssr_min(stats_r)
        if res is None:
            return -np.inf
        return -k * math.log(0.5 * res[0] + b0) - 0.5 * math.log(res[1]) + g_prior.logpdf_scalar(math.exp(ell)) + ell

    def prior_part(ell):
        return g_prior.logpdf_scalar(math.exp(ell)) + ell

    grid = LAPLACE_GRID
    coarse = _thinned(data, LAPLACE_COARSE_OBS)
    # the grid's sums in one compiled call (nine calls from Python cost more than the sums)
    values = [h_of_stats(stats_r, e) for stats_r, e in zip(coarse.stats_at_many(np.exp(grid)), grid)]
    best = int(np.argmax(values))
    if not np.isfinite(values[best]):
        return None
    # Newton on the thinning first (cheap), so the passes over the whole region start within
    # a few posterior sds of its mode: about 2 of them instead of 4 to 5 from a grid point.
    start = grid[best]
    if coarse is not data:
        coarse_mode = _laplace_newton(coarse, start, k, b0, prior_part)
        if coarse_mode is not None:
            start = coarse_mode[0]
    newton = _laplace_newton(data, start, k, b0, prior_part)
    if newton is not None:
        return newton
    return _laplace_finite_differences(lambda ell: h_of_stats(data.stats_at(math.exp(ell)), ell), grid)


def _laplace_newton(data, ell, k, b0, prior_part, max_steps=8, eps=1e-3):
    syy, sya, saa = data.fixed[1], data.fixed[2], data.fixed[3]
    for _ in range(max_steps):
        g = math.exp(ell)
        profile = _ls_profile(sya, saa, data.b_sums_newton(g), g)
        if profile is None:
            return None
        f, f1, f2, det, det1, det2, ca, cb = profile
        q = 0.5 * (syy - f) + b0
        p0, pp, pm = prior_part(ell), prior_part(ell + eps), prior_part(ell - eps)
        h1 = k * f1 / (2.0 * q) - 0.5 * det1 / det + (pp - pm) / (2.0 * eps)
        h2 = (k * f2 / (2.0 * q) + k * f1 * f1 / (4.0 * q * q) - 0.5 * (det2 / det - (det1 / det) ** 2)
              + (pp - 2.0 * p0 + pm) / eps ** 2)
        if not (math.isfinite(h1) and math.isfinite(h2) and h2 < 0 and q > 0):
            return None
        sd = 1.0 / math.sqrt(-h2)
        step = min(max(-h1 / h2, -0.5), 0.5)
        ell += step
        if abs(step) < 0.2 * sd:        # what is left after this step is O(step^2): negligible
            # only inside a, b > 0 is this unbounded profile the one h uses
            return (ell, min(max(sd, 1e-4), 2.0)) if ca > 0 and cb > 0 else None
    return None


def _laplace_finite_differences(h, grid):
    values = [h(e) for e in grid]
    best = int(np.argmax(values))
    centre, delta, h0 = grid[best], grid[1] - grid[0], values[best]
    if not np.isfinite(h0):
        return None
    curvature = -1.0
    for _ in range(3):
        hm, hp = h(centre - delta), h(centre + delta)
        curvature = (hp - 2 * h0 + hm) / (delta * delta)
        if not (np.isfinite(hm) and np.isfinite(hp)) or curvature >= 0:
            break
        shift = min(max(-0.5 * (hp - hm) / delta / curvature, -delta), delta)
        centre += shift
        h0 = h(centre)
        delta /= 3.0
    sd = 1.0 / math.sqrt(-curvature) if np.isfinite(curvature) and curvature < 0 else 2.0
    return centre, min(max(sd, 1e-4), 2.0)


def _prior_in_q_coords(prior, theta, conditional):
    """Log prior density of a region's parameters in the coordinates its proposal uses.

    The likelihood is not included: the jump ratio takes it from the full recompute.
    """
    I0, kd, g, s2 = theta
    if conditional:      # coordinates (a, b, log gamma, sigma^2)
        return prior.logpdf_scalar(I0, kd, g, s2) - math.log(I0) - math.log(_norm(g)) + math.log(g)
    return prior.logpdf_scalar(I0, kd, g, s2)   # natural coordinates


def _region_proposal(data, config, prior):
    """What proposes a region's parameters: ('conditional', laplace) or ('prior', None).

    The count is the effective one (observations times the likelihood power), as in the
    within-model moves: the conditional proposals need a well-posed sigma^2 shape.
    """
    if data.n * data.weight < config.min_obs_conditional:
        return ("prior", None)
    lap = _laplace_log_gamma(data, prior)
    return ("prior", None) if lap is None else ("conditional", lap)


def _draw_region(rng, data, proposal, prior, config):
    """Draw a region's parameters; returns (theta, log q) or None if invalid."""
    kind, lap = proposal
    if kind == "prior":
        theta = prior.sample(rng)
        I0, kd, g, s2 = (float(t) for t in theta)
        return (I0, kd, g, s2), prior.logpdf_scalar(I0, kd, g, s2)
    mean, sd = lap
    sd *= config.birth_gamma_inflation
    ell = mean + sd * rng.normal()
    g = math.exp(ell)
    stats_r = _stats_at(data, g)
    res = _ssr_min(stats_r)
    if res is None:
        return None
    shape, scale = _sigma2_proposal(stats_r, res, prior)
    s2 = scale / rng.gamma(shape)
    cond = _ab_conditional(stats_r, s2)
    if cond is None:
        return None
    a, b = _draw_ab(cond, rng)
    if a <= 0 or b <= 0:
        return None
    I0 = a + b / _norm(g)
    theta = (I0, a / I0, g, s2)
    return theta, _log_q_region(theta, stats_r, proposal, prior, config)


def _sigma2_proposal(stats_r, res, prior):
    """Inverse gamma of sigma^2 given gamma ((a, b) integrated out), prior folded in approximately."""
    a0, b0 = _sigma2_prior_as_invgamma(prior)
    return 0.5 * stats_r[STAT_N] - 1.0 + a0, 0.5 * res[0] + b0


def _log_q_region(theta, stats_r, proposal, prior, config):
    kind, lap = proposal
    I0, kd, g, s2 = theta
    if kind == "prior":
        return prior.logpdf_scalar(I0, kd, g, s2)
    mean, sd = lap
    sd *= config.birth_gamma_inflation
    res = _ssr_min(stats_r)
    cond = _ab_conditional(stats_r, s2)
    if res is None or cond is None:
        return -np.inf
    shape, scale = _sigma2_proposal(stats_r, res, prior)
    log_ig = shape * math.log(scale) - math.lgamma(shape) - (shape + 1.0) * math.log(s2) - scale / s2
    a, b = I0 * kd, I0 * (1.0 - kd) * _norm(g)
    return (-0.5 * ((math.log(g) - mean) / sd) ** 2 - math.log(sd) - 0.5 * LOG_2PI + log_ig + _log_q_ab(a, b, cond))


def _regions_term(problem, prior, config, labels, theta, regions, draw_rng=None):
    """Sum over ``regions`` of (log prior in q-coordinates - log q); draws new parameters if ``draw_rng``.

    Returns (theta, total) where theta has the drawn parameters filled in (or None if a draw
    was invalid).
    """
    total = 0.0
    theta = theta.copy()
    split = RegionData.split(problem, labels, theta.shape[0])
    for r in regions:
        data = split[r]
        proposal = _region_proposal(data, config, prior)
        if draw_rng is not None:
            drawn = _draw_region(draw_rng, data, proposal, prior, config)
            if drawn is None:
                return None, -np.inf
            theta[r], log_q = drawn
        else:
            log_q = _log_q_region(tuple(theta[r]), _stats_at(data, theta[r, 2]), proposal, prior, config)
        total += _prior_in_q_coords(prior, tuple(theta[r]), proposal[0] == "conditional") - log_q
    return theta, total


# --- birth and death ----------------------------------------------------------------------

def _axis_info(work, problem, config, axis):
    height, width = problem.image_shape
    if axis == "u":
        return work.u, width, work.u.shape[1], config.max_u
    return work.v, height, work.v.shape[1], config.max_v


def _grid(theta, n_u, n_v, axis):
    grid = theta.reshape(n_u + 1, n_v + 1, -1)
    return grid.transpose(1, 0, 2) if axis == "v" else grid


def _ungrid(grid, axis):
    grid = grid.transpose(1, 0, 2) if axis == "v" else grid
    return grid.reshape(-1, grid.shape[-1])


def _region_ids(n_u, n_v, axis, columns):
    """Region indices of grid columns ``columns`` (along ``axis``) in model (n_u, n_v)."""
    ids = np.arange((n_u + 1) * (n_v + 1)).reshape(n_u + 1, n_v + 1)
    ids = ids.T if axis == "v" else ids
    return np.concatenate([ids[c] for c in columns])


def _jump_ratio(problem, prior, config, small, big, axis, j, x, gaps_bounds, size, n, n_max, theta_term):
    """Log acceptance ratio of the birth small -> big (vector x inserted at rank j)."""
    lower, upper = gaps_bounds
    log_q_vec = _vector_log_q(x, lower, upper, size, config)
    (u_s, v_s, ll_s), (u_b, v_b, ll_b) = small, big
    return (ll_b - ll_s
            + log_prior_cp_state(u_b, v_b, problem.image_shape, config.cp_prior, config.cp_smooth_sd)
            - log_prior_cp_state(u_s, v_s, problem.image_shape, config.cp_prior, config.cp_smooth_sd)
            + math.log(1.0 - birth_probability(n + 1, n_max)) - math.log(birth_probability(n, n_max))
            - log_q_vec + theta_term)


def propose_birth(work, rng, problem, prior, config, axis: str):
    """Birth of a u (v) vector, splitting every region it cuts.

    Returns ``(u, v, theta, labels, stats, log_lik, log_ratio)`` of the proposal
    (``log_ratio`` = -inf for an invalid proposal). The rank ``j`` of the new vector is
    uniform over the n + 1 gaps and the death picks one of the n + 1 vectors, so these
    choices cancel.
    """
    cps, size, n, n_max = _axis_info(work, problem, config, axis)
    n_u, n_v = work.u.shape[1], work.v.shape[1]
    j = int(rng.integers(n + 1))
    lower, upper = _gaps(cps, j, size)
    x = _draw_vector(rng, lower, upper, size, config)
    new_cps = np.insert(cps, j, x, axis=1)
    u_new, v_new = (new_cps, work.v) if axis == "u" else (work.u, new_cps)
    nb_u, nb_v = u_new.shape[1], v_new.shape[1]
    grid = _grid(work.theta, n_u, n_v, axis)
    if config.split_map == "conditional":
        theta_new = _ungrid(np.concatenate([grid[:j], grid[j:j + 1], grid[j:]], axis=0), axis)
    else:
        w = rng.normal(0.0, config.split_scale, grid[j].shape)
        phi_a, phi_b, log_jac = split_phi(to_phi(grid[j]), w, config.split_map)
        theta_new = _ungrid(np.concatenate([grid[:j], from_phi(phi_a)[None], from_phi(phi_b)[None], grid[j + 1:]],
                                           axis=0), axis)
    labels = obs_region_labels(u_new, v_new, problem.row, problem.col, pixel_start=problem.pixel_start)
    if not np.isfinite(_vector_log_q(x, lower, upper, size, config)):
        return u_new, v_new, theta_new, labels, None, None, -np.inf
    if config.split_map == "conditional":
        old_ids = _region_ids(n_u, n_v, axis, [j])
        new_ids = _region_ids(nb_u, nb_v, axis, [j, j + 1])
        theta_new, term_new = _regions_term(problem, prior, config, labels, theta_new, new_ids, draw_rng=rng)
        if theta_new is None:
            return u_new, v_new, None, labels, None, None, -np.inf
        _, term_old = _regions_term(problem, prior, config, work.labels, work.theta, old_ids)
        theta_term = term_new - term_old
    else:
        theta_term = (float(np.sum(prior.logpdf_phi(to_phi(theta_new))) - np.sum(prior.logpdf_phi(to_phi(work.theta))))
                      - _log_normal(w, config.split_scale) + (0.0 if config.drop_jacobian else log_jac))
    stats = region_stats(problem, labels, theta_new[:, 2], theta_new.shape[0])
    log_lik = log_likelihood_from_stats(stats, theta_new)
    log_ratio = _jump_ratio(problem, prior, config, (work.u, work.v, float(np.sum(work.log_lik))),
                            (u_new, v_new, float(np.sum(log_lik))), axis, j, x, (lower, upper), size, n, n_max,
                            theta_term)
    return u_new, v_new, theta_new, labels, stats, log_lik, float(log_ratio)


def propose_death(work, rng, problem, prior, config, axis: str):
    """Death of a u (v) vector, merging the regions on its two sides (reverse of the birth)."""
    cps, size, n, n_max = _axis_info(work, problem, config, axis)
    n_u, n_v = work.u.shape[1], work.v.shape[1]
    k = int(rng.integers(n))
    x = cps[:, k]
    new_cps = np.delete(cps, k, axis=1)
    lower, upper = _gaps(new_cps, k, size)     # the gap the reverse birth draws in
    u_new, v_new = (new_cps, work.v) if axis == "u" else (work.u, new_cps)
    ns_u, ns_v = u_new.shape[1], v_new.shape[1]
    grid = _grid(work.theta, n_u, n_v, axis)
    labels = obs_region_labels(u_new, v_new, problem.row, problem.col, pixel_start=problem.pixel_start)
    if config.split_map == "conditional":
        theta_new = _ungrid(np.concatenate([grid[:k + 1], grid[k + 2:]], axis=0), axis)
        new_ids = _region_ids(ns_u, ns_v, axis, [k])
        old_ids = _region_ids(n_u, n_v, axis, [k, k + 1])
        theta_new, term_new = _regions_term(problem, prior, config, labels, theta_new, new_ids, draw_rng=rng)
        if theta_new is None:
            return u_new, v_new, None, labels, None, None, -np.inf
        _, term_old = _regions_term(problem, prior, config, work.labels, work.theta, old_ids)
        theta_term = term_old - term_new          # as seen by the reverse birth
    else:
        phi, w, log_jac = merge_phi(to_phi(grid[k]), to_phi(grid[k + 1]), config.split_map)
        theta_new = _ungrid(np.concatenate([grid[:k], from_phi(phi)[None], grid[k + 2:]], axis=0), axis)
        theta_term = (float(np.sum(prior.logpdf_phi(to_phi(work.theta))) - np.sum(prior.logpdf_phi(to_phi(theta_new))))
                      - _log_normal(w, config.split_scale) + (0.0 if config.drop_jacobian else log_jac))
    stats = region_stats(problem, labels, theta_new[:, 2], theta_new.shape[0])
    log_lik = log_likelihood_from_stats(stats, theta_new)
    birth_ratio = _jump_ratio(problem, prior, config, (u_new, v_new, float(np.sum(log_lik))),
                              (work.u, work.v, float(np.sum(work.log_lik))), axis, k, x, (lower, upper), size,
                              n - 1, n_max, theta_term)
    return u_new, v_new, theta_new, labels, stats, log_lik, float(-birth_ratio)


def propose_block_shift(work, rng, problem, prior, config, axis: str):
    """Shift a contiguous block of one vector's elements by a common delta, redrawing the regions it changes.

    The block (first line uniform, length uniform in 1..``block_max``) and the shift
    ``delta ~ N(0, block_shift_sd^2)`` are chosen independently of the state, and a shift
    that would reorder a row's elements or leave [-1, size + 1] is rejected, so the reverse
    move (same block, -delta) has the same density. The parameters of every region whose
    pixel set changes are redrawn from the conditional proposals used by birth/death, and
    the reverse move's density of the current parameters enters the ratio. This lets a
    stretch of a boundary that settled on the wrong side of an object move back together
    with the parameters that had adapted to it (a trap for element-by-element moves).

    Returns ``(u, v, theta, labels, stats, log_lik, log_ratio)``.
    """
    cps, size, n, _ = _axis_info(work, problem, config, axis)
    n_lines = cps.shape[0]
    k = int(rng.integers(n))
    start = int(rng.integers(n_lines))
    length = int(rng.integers(1, config.block_max + 1))
    stop = min(n_lines, start + length)
    delta = config.block_shift_sd * rng.normal()
    new_cps = cps.copy()
    new_cps[start:stop, k] += delta
    block = new_cps[start:stop]
    u_new, v_new = (new_cps, work.v) if axis == "u" else (work.u, new_cps)
    invalid = (np.any(block[:, k] < -1.0) or np.any(block[:, k] > size + 1.0)
               or np.any(np.diff(block, axis=1) <= 0))
    if invalid:
        return u_new, v_new, None, None, None, None, -np.inf
    labels = obs_region_labels(u_new, v_new, problem.row, problem.col, pixel_start=problem.pixel_start)
    changed = labels != work.labels
    if not np.any(changed):
        log_lik = work.log_lik
        theta_new, theta_term = work.theta, 0.0
        stats = work.stats
    else:
        affected = np.union1d(np.unique(labels[changed]), np.unique(work.labels[changed]))
        theta_new, term_new = _regions_term(problem, prior, config, labels, work.theta, affected, draw_rng=rng)
        if theta_new is None:
            return u_new, v_new, None, labels, None, None, -np.inf
        _, term_old = _regions_term(problem, prior, config, work.labels, work.theta, affected)
        theta_term = term_new - term_old
        stats = region_stats(problem, labels, theta_new[:, 2], theta_new.shape[0])
        log_lik = log_likelihood_from_stats(stats, theta_new)
    log_ratio = (float(np.sum(log_lik)) - float(np.sum(work.log_lik))
                 + log_prior_cp_state(u_new, v_new, problem.image_shape, config.cp_prior, config.cp_smooth_sd)
                 - log_prior_cp_state(work.u, work.v, problem.image_shape, config.cp_prior, config.cp_smooth_sd)
                 + theta_term)
    return u_new, v_new, theta_new, labels, stats, log_lik, float(log_ratio)


# ----------------------------------------------------------------------------- whole-vector redraw

def _vector_cells(lower, upper, size):
    """Width (L, size + 1) of each likelihood cell of an element inside its gap (lower, upper).

    An element ``x`` is left of the pixel with along-line index ``t`` when ``x < t + 0.5``, so
    the likelihood depends on x only through its cell ``j``: [j - 0.5, j + 0.5), widened to
    [-1, 0.5) for j = 0 and [size - 0.5, size + 1] for j = size.
    """
    j = np.arange(size + 1, dtype=float)
    cell_lo = np.maximum(j - 0.5, -1.0)
    cell_lo[0] = -1.0
    cell_hi = j + 0.5
    cell_hi[-1] = size + 1.0
    lo = np.maximum(cell_lo[None, :], lower[:, None])
    hi = np.minimum(cell_hi[None, :], upper[:, None])
    return np.maximum(hi - lo, 0.0), lo


def _cell_of(x, size):
    return np.clip(np.floor(np.asarray(x) + 0.5).astype(np.int64), 0, size)


def _forward_filter(log_emit, log_kernel):
    """Forward pass of the chain of cells along the lines: normalised log alphas (L, S + 1), or None.

    ``log_kernel`` (2 K + 1,) holds the log weights of cell steps -K..K between neighbouring
    lines (:func:`_truncated_log_kernel`: the steps whose weight is at least 1e-30 of the
    largest), or is None for independent lines. The sums run in linear space (compiled:
    :func:`rjfit.sampler.jit.forward_filter`); round-off and the cut only perturb the
    proposal, whose density the move computes from the same alphas and steps both ways, so
    it stays exact.
    """
    if log_kernel is None:
        kernel, reach = np.zeros(0), 0
    else:
        reach = (log_kernel.size - 1) // 2
        kernel = np.exp(log_kernel - log_kernel.max())
    alpha, ok = jit.forward_filter(np.ascontiguousarray(log_emit, dtype=float), kernel, reach)
    return alpha if ok else None


def _truncated_log_kernel(log_kernel):
    """The log step weights -K..K whose weight is at least 1e-30 of the largest (the chain's steps)."""
    centre = log_kernel.size // 2
    keep = np.flatnonzero(log_kernel - log_kernel.max() >= math.log(1e-30))
    reach = int(max(abs(keep[0] - centre), abs(keep[-1] - centre)))
    return log_kernel[centre - reach: centre + reach + 1]


def _cell_step_logits(log_kernel):
    """Backward logits of the cell chain: line r's cells given line r + 1's cell.

    ``log_kernel`` (2 K + 1,) holds the log weights of steps -K..K; cells further than K
    from line r + 1's cell get -inf (None: independent lines).
    """
    def logits(alpha, r, cell_next):
        if log_kernel is None:
            return alpha[r]
        reach = (log_kernel.size - 1) // 2
        steps = np.arange(alpha.shape[1]) - cell_next
        inside = np.abs(steps) <= reach
        out = np.full(alpha.shape[1], -np.inf)
        out[inside] = alpha[r, inside] + log_kernel[reach + steps[inside]]
        return out
    return logits


def _path_log_prob(alpha, path, logits_given_next):
    """Log probability that backward sampling from ``alpha`` draws ``path``."""
    total = float(alpha[-1, path[-1]])            # alpha rows are normalised
    for r in range(alpha.shape[0] - 2, -1, -1):
        logits = logits_given_next(alpha, r, path[r + 1])
        if not np.isfinite(logits[path[r]]):
            return -np.inf
        top = np.max(logits)
        total += float(logits[path[r]] - top - np.log(np.sum(np.exp(logits - top))))
    return total


def _draw_index(logits, rng):
    weights = np.cumsum(np.exp(logits - np.max(logits)))
    return min(int(np.searchsorted(weights, rng.random() * weights[-1], side="right")), logits.size - 1)


def _backward_sample(alpha, logits_given_next, rng):
    """A path drawn from the chain whose normalised forward log alphas are ``alpha``, last line first."""
    path = np.empty(alpha.shape[0], np.int64)
    path[-1] = _draw_index(alpha[-1], rng)
    for r in range(alpha.shape[0] - 2, -1, -1):
        path[r] = _draw_index(logits_given_next(alpha, r, path[r + 1]), rng)
    return path


def _within_cell_log_density(x, x_next, lo, hi, sd):
    """Log density of positions x (L,) inside their cells [lo, hi) of the backward draw.

    The reference of :func:`rjfit.sampler.jit.within_cells_log_density`, which the move uses.

    Line L - 1 is uniform in its cell; line r < L - 1 follows the prior's step, a normal
    around the next line's position x_next truncated to the cell (uniform where the cell
    holds less than 1e-12 of that normal's mass, or without a step model, ``sd`` None).
    """
    out = -np.log(hi - lo)
    if sd is None:
        return out
    a, b = (lo[:-1] - x_next) / sd, (hi[:-1] - x_next) / sd
    mass = _normal_mass(a, b)
    normal = mass > 1e-12
    with np.errstate(divide="ignore"):
        log_trunc = -0.5 * ((x[:-1] - x_next) / sd) ** 2 - math.log(sd) - 0.5 * LOG_2PI - np.log(mass)
    out[:-1] = np.where(normal, log_trunc, out[:-1])
    return out


def _normal_mass(a, b):
    """P(a < Z < b) for a standard normal, accurate in both tails."""
    from scipy.special import ndtr

    upper = a > 0                       # both in the upper tail: use the mirrored lower tail
    return np.where(upper, ndtr(-a) - ndtr(-b), ndtr(b) - ndtr(a))


def _draw_within_cells(lo, hi, sd, rng):
    """Positions inside the cells [lo, hi), drawn from line L - 1 backwards (see :func:`_within_cell_log_density`).

    The reference of :func:`rjfit.sampler.jit.within_cells_draw`, which the move uses.
    """
    from scipy.special import ndtr, ndtri

    n_lines = lo.size
    x = np.empty(n_lines)
    x[-1] = lo[-1] + (hi[-1] - lo[-1]) * rng.random()
    for r in range(n_lines - 2, -1, -1):
        u = rng.random()
        if sd is not None:
            a, b = (lo[r] - x[r + 1]) / sd, (hi[r] - x[r + 1]) / sd
            if float(_normal_mass(np.array(a), np.array(b))) > 1e-12:
                if a > 0:        # mirrored, so the inverse CDF works away from 1
                    z = -ndtri(ndtr(-a) - u * (ndtr(-a) - ndtr(-b)))
                else:
                    z = ndtri(ndtr(a) + u * (ndtr(b) - ndtr(a)))
                x[r] = min(max(x[r + 1] + sd * z, lo[r]), np.nextafter(hi[r], lo[r]))
                continue
        x[r] = lo[r] + (hi[r] - lo[r]) * u
    return x


def propose_vector_redraw(work, rng, problem, prior, config, axis: str):
    """Redraw every element of one change-point vector at once (forward filtering, backward sampling).

    Given the parameters and the other vectors, the likelihood of vector k depends on each
    element only through its cell (see :func:`_vector_cells`), and the 'smooth' prior
    couples neighbouring lines by a Gaussian step, so the conditional of the cell path is
    close to a hidden Markov chain along the lines. The proposal draws the path from that
    chain (steps between cells weighted by N(0, s^2 + 1/12)), then the positions inside
    the cells and gaps, each line's from the prior's step around the next line's position
    (:func:`_draw_within_cells`), so every element keeps its rank. It is an independence
    proposal from an approximation of the exact conditional; the acceptance ratio uses the
    exact continuous prior and the proposal's density of both the new and the current
    vector, so the move is exact (for the 'paper' prior the chain is exact and every
    proposal is accepted). One move can carry a whole vector across the image: what
    element-wise steps and block shifts cannot do when two vectors compensate each other's
    errors.

    Returns ``(cps, shift, log_ratio)``; ``shift`` (the observations that change region,
    for :func:`accept_vector_redraw`) is None for an invalid proposal.
    """
    height, width = problem.image_shape
    cps = work.u if axis == "u" else work.v
    n_lines, n = cps.shape
    size = width if axis == "u" else height
    k = int(rng.integers(n))
    lower, upper = _gaps(np.delete(cps, k, axis=1), k, size)
    step_label = (work.v.shape[1] + 1) if axis == "u" else 1
    x_old = cps[:, k]
    # per-pixel log-likelihood with the element right of the pixel (base) or left of it (base + step)
    per_pixel = [np.zeros(n_lines * size), np.zeros(n_lines * size)]
    line_of, along_of = (problem.row, problem.col) if axis == "u" else (problem.col, problem.row)
    jit.per_pixel_two_cases(problem.y, problem.C, problem.log_cos_hn, line_of, along_of, work.labels,
                            np.ascontiguousarray(x_old), step_label, work.theta, size, per_pixel[0], per_pixel[1])
    log_lik_cell = jit.cell_log_lik(per_pixel[0], per_pixel[1], n_lines, size, problem.likelihood_power)  # (L, S + 1)
    widths, cell_lo = _vector_cells(lower, upper, size)
    with np.errstate(divide="ignore"):
        log_emit = log_lik_cell + np.log(widths)
    log_kernel, sd = None, None
    if config.cp_prior == "smooth":
        sd = config.cp_smooth_sd
        offsets = np.arange(-size, size + 1)
        log_kernel = _truncated_log_kernel(-0.5 * offsets ** 2 / (sd ** 2 + 1.0 / 12.0))
    alpha = _forward_filter(log_emit, log_kernel)
    if alpha is None:
        return cps, None, -np.inf
    rows = np.arange(n_lines)
    # compiled twins of _backward_sample / _path_log_prob with _cell_step_logits' steps
    log_steps = np.zeros(0) if log_kernel is None else log_kernel
    cells_new = jit.cell_backward_sample(alpha, log_steps, rng.random(n_lines))
    lo_new, hi_new = cell_lo[rows, cells_new], cell_lo[rows, cells_new] + widths[rows, cells_new]
    # compiled twins of _draw_within_cells / _within_cell_log_density (sd <= 0: no step
    # model); the reference draws one uniform per line, last line first
    step_sd = -1.0 if sd is None else float(sd)
    x_new = jit.within_cells_draw(lo_new, hi_new, step_sd, rng.random(n_lines)[::-1].copy())
    cells_old = _cell_of(x_old, size)
    lo_old, hi_old = cell_lo[rows, cells_old], cell_lo[rows, cells_old] + widths[rows, cells_old]
    log_q_new = (jit.cell_path_log_prob(alpha, cells_new, log_steps)
                 + jit.within_cells_log_density(x_new, lo_new, hi_new, step_sd))
    log_q_old = (jit.cell_path_log_prob(alpha, cells_old, log_steps)
                 + jit.within_cells_log_density(np.ascontiguousarray(x_old), lo_old, hi_old, step_sd))
    new_cps = cps.copy()
    new_cps[:, k] = x_new
    u_new, v_new = (new_cps, work.v) if axis == "u" else (work.u, new_cps)
    log_ratio = (float(np.sum(log_lik_cell[rows, cells_new]) - np.sum(log_lik_cell[rows, cells_old]))
                 + log_prior_cp_state(u_new, v_new, problem.image_shape, config.cp_prior, config.cp_smooth_sd)
                 - log_prior_cp_state(work.u, work.v, problem.image_shape, config.cp_prior, config.cp_smooth_sd)
                 + log_q_old - log_q_new)
    return new_cps, _element_shift(problem, work, axis, rows, x_old, x_new), float(log_ratio)


def accept_vector_redraw(work, problem, axis: str, cps, shift) -> None:
    """Make an accepted :func:`propose_vector_redraw` the current state of ``work`` (in place).

    Only the observations between each line's old and new element change region: their
    terms move between the statistics as in an element move, O(changed) instead of a pass
    over every observation.
    """
    if axis == "u":
        work.u = cps
    else:
        work.v = cps
    _apply_shift(work, problem, axis, *shift)


# ----------------------------------------------------------------------------- birth / death at any rank

def _removal_log_emit(problem, labels, theta, n, n_v, axis):
    """(L, n): how well each line's observations fit when its element of rank k is removed.

    Removing element k of a line merges the line's columns k and k + 1 (regions along the
    axis). The score is the log-likelihood change of the better of the two ways to merge
    with the current parameters: column k + 1's pixels given column k's parameters, or
    column k's given column k + 1's. Only a proposal ingredient: any function of the state
    keeps the move exact.
    """
    n_lines = problem.height if axis == "u" else problem.width
    step = (n_v + 1) if axis == "u" else 1
    sums = np.zeros((3, n_lines * (n + 1)))   # current labels, column's pixels moved down, moved up
    jit.removal_sums(problem.y, problem.C, problem.log_cos_hn, problem.row if axis == "u" else problem.col, labels,
                     np.ascontiguousarray(theta, dtype=float), n, n_v, step, axis == "u", sums)
    sums *= problem.likelihood_power
    current, down, up = (x.reshape(n_lines, n + 1) for x in sums)
    return np.maximum(down[:, 1:] - current[:, 1:], up[:, :-1] - current[:, :-1])


def _rank_transitions(n_lines, n):
    """Log transitions (n, n) of the rank chain: keep the rank with probability 1 - 1/L, else any other."""
    eps = 1.0 / n_lines if n > 1 else 0.0
    with np.errstate(divide="ignore"):
        log_t = np.full((n, n), np.log(eps / max(n - 1, 1)))
        np.fill_diagonal(log_t, np.log1p(-eps))
    return log_t


def _rank_chain(log_emit):
    """Forward alphas and backward logits of the chain of removed ranks along the lines.

    A line keeps the previous line's rank with probability 1 - 1/L and switches to one of
    the other ranks otherwise, so a removed vector may change rank where vectors meet. The
    reference of the compiled :func:`rjfit.sampler.jit.rank_forward`,
    :func:`~rjfit.sampler.jit.rank_backward_sample` and
    :func:`~rjfit.sampler.jit.rank_path_log_prob`, which the moves use.
    """
    n_lines, n = log_emit.shape
    log_t = _rank_transitions(n_lines, n)
    alpha = np.empty_like(log_emit)
    previous = None
    for r in range(n_lines):
        a = log_emit[r].copy()
        if previous is not None:
            a += np.logaddexp.reduce(previous[:, None] + log_t, axis=0)
        a -= np.logaddexp.reduce(a)
        alpha[r] = previous = a

    def logits(alpha, r, rank_next):
        return alpha[r] + log_t[:, rank_next]
    return alpha, logits


def _rank_path_log_prob(problem, u, v, theta, labels, axis, ranks):
    cps = u if axis == "u" else v
    log_emit = _removal_log_emit(problem, labels, theta, cps.shape[1], v.shape[1], axis)
    log_t = _rank_transitions(*log_emit.shape)
    return jit.rank_path_log_prob(jit.rank_forward(log_emit, log_t), np.asarray(ranks, np.int64), log_t)


def _free_birth_ratio(problem, prior, config, small, big, axis, x, log_q_ranks, n, n_max, theta_term):
    """Log acceptance ratio of the free birth small -> big (the element x_r inserted in line r).

    ``log_q_ranks``: log probability that the reverse death draws the inserted elements' ranks.
    """
    (u_s, v_s, ll_s), (u_b, v_b, ll_b) = small, big
    size = problem.width if axis == "u" else problem.height
    bounds = np.full(x.size, -1.0), np.full(x.size, size + 1.0)
    return (ll_b - ll_s
            + log_prior_cp_state(u_b, v_b, problem.image_shape, config.cp_prior, config.cp_smooth_sd)
            - log_prior_cp_state(u_s, v_s, problem.image_shape, config.cp_prior, config.cp_smooth_sd)
            + math.log(1.0 - birth_probability(n + 1, n_max)) - math.log(birth_probability(n, n_max))
            + log_q_ranks - _vector_log_q(x, *bounds, size, config) + theta_term)


def _redraw_all(problem, prior, config, u_new, v_new, work, rng):
    """The new change points' labels, fresh conditional parameters for every region, and their statistics.

    Returns ``(labels, theta, log term new - old, stats, log_lik)``; theta is None when a
    draw was invalid.
    """
    labels = obs_region_labels(u_new, v_new, problem.row, problem.col, pixel_start=problem.pixel_start)
    n_new = n_regions(u_new.shape[1], v_new.shape[1])
    theta_new, term_new = _regions_term(problem, prior, config, labels, np.ones((n_new, 4)), range(n_new),
                                        draw_rng=rng)
    if theta_new is None:
        return labels, None, -np.inf, None, None
    _, term_old = _regions_term(problem, prior, config, work.labels, work.theta, range(work.theta.shape[0]))
    stats = region_stats(problem, labels, theta_new[:, 2], n_new)
    return labels, theta_new, term_new - term_old, stats, log_likelihood_from_stats(stats, theta_new)


def propose_birth_free(work, rng, problem, prior, config, axis: str):
    """Birth of a vector whose elements may fall at any rank of their lines; every region redrawn.

    The new vector is drawn over the whole [-1, size + 1] of each line (the birth
    proposal's straight or prior-shaped vectors, unconstrained by gaps) and inserted into
    each line's sorted elements, so it may cross existing vectors. All region parameters
    of the new model are drawn from their conditional proposals (:func:`_draw_region`)
    and the reverse death's density of the current parameters enters the ratio (Jacobian
    1). The reverse move is :func:`propose_death_free`, which removes from each line the
    element of a rank drawn by a chain along the lines; the probability that it draws
    the inserted elements' ranks enters the ratio.

    Returns ``(u, v, theta, labels, stats, log_lik, log_ratio)``.
    """
    cps, size, n, n_max = _axis_info(work, problem, config, axis)
    n_lines = cps.shape[0]
    x = _draw_vector(rng, np.full(n_lines, -1.0), np.full(n_lines, size + 1.0), size, config)
    ranks = np.sum(cps < x[:, None], axis=1)
    new_cps = np.sort(np.concatenate([cps, x[:, None]], axis=1), axis=1)
    u_new, v_new = (new_cps, work.v) if axis == "u" else (work.u, new_cps)
    if np.any(x < -1.0) or np.any(x > size + 1.0):
        return u_new, v_new, None, None, None, None, -np.inf
    labels, theta_new, theta_term, stats, log_lik = _redraw_all(problem, prior, config, u_new, v_new, work, rng)
    if theta_new is None:
        return u_new, v_new, None, labels, None, None, -np.inf
    log_q_ranks = _rank_path_log_prob(problem, u_new, v_new, theta_new, labels, axis, ranks)
    log_ratio = _free_birth_ratio(problem, prior, config, (work.u, work.v, float(np.sum(work.log_lik))),
                                  (u_new, v_new, float(np.sum(log_lik))), axis, x, log_q_ranks, n, n_max, theta_term)
    return u_new, v_new, theta_new, labels, stats, log_lik, float(log_ratio)


def propose_death_free(work, rng, problem, prior, config, axis: str):
    """Death that removes from each line the element of a rank drawn along the lines (reverse of the free birth).

    The removed ranks follow a chain along the lines (:func:`_rank_chain`) that favours
    removing, in each line, the element whose removal costs the least likelihood, and
    switches rank rarely. This is what undoes two vectors that each hold half of one true
    boundary and an unneeded half elsewhere: no single vector's death can remove both
    unneeded halves, this move can.
    """
    cps, size, n, n_max = _axis_info(work, problem, config, axis)
    n_lines = cps.shape[0]
    log_emit = _removal_log_emit(problem, work.labels, work.theta, n, work.v.shape[1], axis)
    log_t = _rank_transitions(*log_emit.shape)
    alpha = jit.rank_forward(log_emit, log_t)
    ranks = jit.rank_backward_sample(alpha, log_t, rng.random(n_lines))   # compiled twins of _rank_chain, _backward_sample
    rows = np.arange(n_lines)
    x = cps[rows, ranks]
    keep = np.ones(cps.shape, bool)
    keep[rows, ranks] = False
    new_cps = cps[keep].reshape(n_lines, n - 1)
    u_new, v_new = (new_cps, work.v) if axis == "u" else (work.u, new_cps)
    labels, theta_new, term, stats, log_lik = _redraw_all(problem, prior, config, u_new, v_new, work, rng)
    if theta_new is None:
        return u_new, v_new, None, labels, None, None, -np.inf
    birth_ratio = _free_birth_ratio(problem, prior, config, (u_new, v_new, float(np.sum(log_lik))),
                                    (work.u, work.v, float(np.sum(work.log_lik))), axis, x,
                                    jit.rank_path_log_prob(alpha, ranks, log_t), n - 1, n_max, -term)
    return u_new, v_new, theta_new, labels, stats, log_lik, float(-birth_ratio)
