"""Within-material moves of a joint colour fit: C parameter rows per material sharing gamma (:mod:`rjfit.sampler.colour`).

Given gamma the rows are independent single-channel regions, so each row's (a, b) redraw
(:func:`~rjfit.sampler.moves.ab_conditional.move_ab`) and sigma^2 move
(:func:`~rjfit.sampler.moves.sigma2.move_sigma2`) run on it unchanged: their ratios hold
gamma fixed, so its prior cancels. Gamma moves once per material (:func:`move_gamma_colour`):
log gamma proposed (a random walk, or a Newton step on the profile log-likelihood summed
over the rows), every row's (a, b) redrawn from its conditional given it, accepted by the
sum of the rows' targets in (a_c, b_c, sigma2_c, log gamma) coordinates with gamma's prior
and log-Jacobian counted once. Materials too small for the conditionals
(:func:`move_phi_rw_colour`) take a phi-space random walk: (I0, kd, sigma^2) per row, then
log gamma for all rows at once.
"""
from __future__ import annotations

import math

import numpy as np

from rjfit.sampler.likelihood import STAT_AA, STAT_N, STAT_YA
from rjfit.sampler.moves.ab_conditional import ab_conditional, draw_ab, log_q_ab, log_target_ab
from rjfit.sampler.moves.accept import accept
from rjfit.sampler.moves.base import decide_row
from rjfit.sampler.moves.gamma import log_q_log_gamma, ls_profile_nonnegative
from rjfit.sampler.moves.proposal import RowProposal
from rjfit.sampler.moves.region_terms import (
    edge_delta,
    edge_rows_delta,
    giesen_norm,
    region_log_lik,
    set_region,
    stats_at_gamma,
)
from rjfit.sampler.moves.sigma2 import move_amplitudes_and_variance

__all__ = ["update_materials_colour", "move_gamma_colour", "newton_log_gamma_colour", "move_phi_rw_colour"]


def update_materials_colour(work, rng, prior, problem, settings, g_step, info) -> list:
    """The 'adaptive' within-material moves of every material of a colour fit; returns the gamma random walks'
    acceptances (as :class:`rjfit.sampler.moves.within.AdaptiveWithin` per region)."""
    n_ch = problem.n_channels
    g_acc = []
    for m in range(work.theta.shape[0] // n_ch):
        rows = range(m * n_ch, (m + 1) * n_ch)
        n_min = min(float(work.stats[r, STAT_N]) for r in rows)
        n_all = sum(float(work.stats[r, STAT_N]) for r in rows)
        if n_min < settings.min_obs_conditional:
            info.count("phi_rw", move_phi_rw_colour(work, rows, rng, prior, problem, settings.fallback_step, info),
                       3 * n_ch + 1)
            continue
        fallback = False
        for k in range(settings.g_moves):
            newton = settings.gamma_move == "newton" and k % 2 == 1
            result = move_gamma_colour(work, rows, rng, prior, problem, newton, settings.newton_scale,
                                       g_step / np.sqrt(n_all), info)
            if result is None:
                fallback = True
                break
            if not newton:
                g_acc.append(result)
            info.count("gamma_newton" if newton else "gamma_ab", result)
        if fallback:
            info.count("phi_rw", move_phi_rw_colour(work, rows, rng, prior, problem, settings.fallback_step, info),
                       3 * n_ch + 1)
            continue
        for r in rows:
            move_amplitudes_and_variance(work, r, rng, prior, info)
        if n_all < settings.small_region_obs * n_ch:
            info.count("phi_rw", move_phi_rw_colour(work, rows, rng, prior, problem, settings.fallback_step, info),
                       3 * n_ch + 1)
    return g_acc


def newton_log_gamma_colour(stats_rows, sums_rows, g, s2_rows, scale):
    """Newton proposal (mean, sd) of log gamma from the profile log-likelihood summed over rows, or None.

    ``h(l) = sum_c (f_c - Syy_c) / (2 sigma2_c)``, each ``f_c`` the least squares over ``a, b >= 0``
    (:func:`~rjfit.sampler.moves.gamma.ls_profile_nonnegative`); the same rule as the single channel's
    :func:`~rjfit.sampler.moves.gamma.newton_log_gamma` (concave, step within 5, sd within 2). The bounded
    profile matters where a channel's unbounded least-squares point has ``a < 0`` (kd near 0, as the DiLiGenT
    ball's red channel): the unbounded profile's mode lies off the posterior's there, and its proposals were
    accepted 0.1 % of the time on the ball (docs/results/2026-11-30-colour-noise.md).
    """
    h1 = h2 = 0.0
    for stats_r, sums, s2 in zip(stats_rows, sums_rows, s2_rows):
        profile = ls_profile_nonnegative(stats_r[STAT_YA], stats_r[STAT_AA], sums, g)
        if profile is None:
            return None
        h1 += 0.5 * profile[1] / s2
        h2 += 0.5 * profile[2] / s2
    if not (math.isfinite(h1) and math.isfinite(h2) and h2 < 0):
        return None
    step, sd = -h1 / h2, scale / math.sqrt(-h2)
    return (math.log(g) + step, sd) if abs(step) <= 5.0 and sd <= 2.0 else None


def move_gamma_colour(work, rows, rng, prior, problem, newton, scale, rw_sd, info):
    """One gamma move of a material's rows (kind 'gamma_newton' or 'gamma_ab'): True/False, None without conditionals.

    Draws: the log gamma proposal's normal, then per row two normals for (a, b), then the
    uniform.
    """
    rows = list(rows)
    g = float(work.theta[rows[0], 2])
    s2s = [float(work.theta[r, 3]) for r in rows]
    conds_old = [ab_conditional(work.stats[r], s2) for r, s2 in zip(rows, s2s)]
    if any(cond is None for cond in conds_old):
        return None
    ell = math.log(g)
    datas = [work.region_data(r, problem) for r in rows] if newton else None
    forward = (newton_log_gamma_colour([work.stats[r] for r in rows], [d.b_sums_newton(g) for d in datas], g, s2s,
                                       scale) if newton else None)
    ell_new = (forward[0] + forward[1] * rng.normal()) if forward is not None else ell + rw_sd * rng.normal()
    if ell_new > 700.0:
        return False
    g_new = math.exp(ell_new)
    if newton:
        stats_new = []
        for r, data in zip(rows, datas):
            stats_r = work.stats[r].copy()
            stats_r[4:7] = data.b_sums_newton(g_new)[:3]
            stats_new.append(stats_r)
        backward = newton_log_gamma_colour(stats_new, [d.b_sums_newton(g_new) for d in datas], g_new, s2s, scale)
        log_q_ratio = log_q_log_gamma(ell, ell_new, backward, rw_sd) - log_q_log_gamma(ell_new, ell, forward, rw_sd)
    else:
        stats_new = [stats_at_gamma(work, r, problem, g_new) for r in rows]
        log_q_ratio = 0.0
    kind = "gamma_newton" if newton else "gamma_ab"
    conds_new = [ab_conditional(stats_r, s2) for stats_r, s2 in zip(stats_new, s2s)]
    if any(cond is None for cond in conds_new):
        return False
    draws = [draw_ab(cond, rng) for cond in conds_new]
    log_u = math.log(rng.random())
    if any(a <= 0 or b <= 0 for a, b in draws):
        return False
    log_alpha = log_q_ratio
    new_rows = []
    for r, s2, (a, b), cond_old, cond_new, stats_r in zip(rows, s2s, draws, conds_old, conds_new, stats_new):
        I0, kd = float(work.theta[r, 0]), float(work.theta[r, 1])
        I0_new = a + b / giesen_norm(g_new)
        kd_new = a / I0_new
        ll_new = region_log_lik(stats_r, I0_new, kd_new, g_new, s2)
        a_old, b_old = I0 * kd, I0 * (1.0 - kd) * giesen_norm(g)
        log_alpha += (log_target_ab(prior, I0_new, kd_new, g_new, s2, ll_new)
                      - log_target_ab(prior, I0, kd, g, s2, work.log_lik[r])
                      + log_q_ab(a_old, b_old, cond_old) - log_q_ab(a, b, cond_new))
        new_rows.append((I0_new, kd_new, g_new, s2, ll_new))
    # log_target_ab holds gamma's prior and log-Jacobian once per row: the material has them once
    g_prior = prior.params[2]
    log_alpha -= (len(rows) - 1) * (g_prior.logpdf_scalar(g_new) + ell_new - g_prior.logpdf_scalar(g) - ell)
    if log_alpha > -math.inf:       # the target's edge term (materials), sigma^2 not in it
        log_alpha += edge_rows_delta(work, rows, [row[:4] for row in new_rows])
    if accept(log_u, log_alpha, info, kind):
        for r, stats_r, (I0_new, kd_new, g_new, s2, ll_new) in zip(rows, stats_new, new_rows):
            set_region(work, r, (I0_new, kd_new, g_new, s2), stats_r, ll_new)
        return True
    return False


def _phi(theta_r):
    I0, kd, g, s2 = (float(t) for t in theta_r)
    return [math.log(I0), math.log(kd) - math.log1p(-kd), math.log(g), math.log(s2)]


def move_phi_rw_colour(work, rows, rng, prior, problem, step, info) -> int:
    """Phi-space random walk of a material's rows (kind 'phi_rw'): per row log I0, logit kd and log sigma^2 (gamma
    held), then log gamma for every row at once; returns how many of the 3 C + 1 steps accepted."""
    accepted = 0
    rows = list(rows)
    for r in rows:
        phi = _phi(work.theta[r])
        log_prior = prior.logpdf_phi_scalar(phi)
        for k in (0, 1, 3):
            phi_new = list(phi)
            phi_new[k] += step * rng.normal()
            log_u = math.log(rng.random())
            kd_new = 1.0 / (1.0 + math.exp(-phi_new[1]))
            if not 0.0 < kd_new < 1.0:
                continue
            new = (math.exp(phi_new[0]), kd_new, math.exp(phi_new[2]), math.exp(phi_new[3]))
            ll_new = region_log_lik(work.stats[r], *new)
            log_prior_new = prior.logpdf_phi_scalar(phi_new)
            log_ratio = ll_new + log_prior_new - work.log_lik[r] - log_prior
            if k < 3 and log_ratio > -math.inf:     # sigma^2 (k = 3) does not enter the edge term
                log_ratio += edge_delta(work, r, new)
            if decide_row(work, RowProposal(r, new, None, ll_new, log_ratio, log_u, "phi_rw"), info):
                phi, log_prior = phi_new, log_prior_new
                accepted += 1
    g = float(work.theta[rows[0], 2])
    ell_new = math.log(g) + step * rng.normal()
    log_u = math.log(rng.random())
    g_new = math.exp(ell_new)
    stats_new = [stats_at_gamma(work, r, problem, g_new) for r in rows]
    lls = [region_log_lik(s, float(work.theta[r, 0]), float(work.theta[r, 1]), g_new, float(work.theta[r, 3]))
           for r, s in zip(rows, stats_new)]
    g_prior = prior.params[2]
    log_alpha = (sum(lls) - sum(float(work.log_lik[r]) for r in rows)
                 + g_prior.logpdf_scalar(g_new) + ell_new - g_prior.logpdf_scalar(g) - math.log(g))
    if log_alpha > -math.inf:
        log_alpha += edge_rows_delta(work, rows, [(float(work.theta[r, 0]), float(work.theta[r, 1]), g_new,
                                                   float(work.theta[r, 3])) for r in rows])
    if accept(log_u, log_alpha, info, "phi_rw"):
        for r, s, ll in zip(rows, stats_new, lls):
            set_region(work, r, (float(work.theta[r, 0]), float(work.theta[r, 1]), g_new, float(work.theta[r, 3])),
                       s, ll)
        accepted += 1
    return accepted
