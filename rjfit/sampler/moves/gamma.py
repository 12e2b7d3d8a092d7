"""Gamma moves: a random walk or a Newton proposal on log gamma, with (a, b) redrawn from their conditional.

Gamma and kd are strongly correlated (a wider lobe with a larger diffuse share fits much
the same), so a move of gamma alone barely moves. Each gamma move here proposes log gamma
and then redraws (a, b) from their conditional given the proposed gamma
(:mod:`rjfit.sampler.moves.ab_conditional`), which follows that ridge; the acceptance
ratio holds the target in (a, b, log gamma, sigma^2) coordinates and both proposal
densities. :func:`move_gamma_rw` is a random walk whose width the kernel adapts during
burn-in; :func:`move_gamma_newton` centres its proposal by a Newton step on the profile
log-likelihood, with closed-form derivatives (:func:`ls_profile`) from the same pass over
the region.
"""
from __future__ import annotations

import math
import sys

from rjfit.sampler.likelihood import LOG_2PI, STAT_AA, STAT_AB, STAT_BB, STAT_YA, STAT_YB
from rjfit.sampler.moves.ab_conditional import ab_conditional, decide_amplitudes, draw_ab, log_q_ab
from rjfit.sampler.moves.region_terms import giesen_norm, stats_at_gamma

__all__ = ["move_gamma_rw", "move_gamma_newton", "ls_profile", "ls_profile_nonnegative", "ls_point_slopes",
           "newton_log_gamma", "log_q_log_gamma"]


def _accept_gamma_ab(work, r, rng, prior, cond_old, g_new, stats_new, log_q_ratio_gamma, info, kind):
    """What every gamma move shares: (a, b) redrawn from their conditional given the proposed gamma, then MH.

    ``log_q_ratio_gamma`` is the log gamma proposal's ``log q(old | new) - log q(new | old)``
    (0 for a random walk). Returns whether the move was accepted.
    """
    I0, kd, g, s2 = work.theta[r]
    cond_new = ab_conditional(stats_new, s2)
    if cond_new is None:
        return False
    a_new, b_new = draw_ab(cond_new, rng)
    log_u = math.log(rng.random())
    log_q_ratio = log_q_ab(I0 * kd, I0 * (1.0 - kd) * giesen_norm(g), cond_old) - log_q_ab(a_new, b_new, cond_new)
    return decide_amplitudes(work, r, prior, a_new, b_new, g_new, stats_new, log_q_ratio + log_q_ratio_gamma,
                             log_u, kind, info)


def move_gamma_rw(work, r, rng, prior, problem, step, info):
    """Random walk on log gamma (sd ``step``) with (a, b) redrawn from their conditional given the new gamma.

    Kind 'gamma_ab'. Returns whether it accepted, or None where (a, b) have no conditional.
    """
    g, s2 = work.theta[r, 2], work.theta[r, 3]
    stats_r = work.stats[r]
    cond_old = ab_conditional(stats_r, s2)
    if cond_old is None:
        return None
    g_new = g * math.exp(step * rng.normal())
    stats_new = stats_at_gamma(work, r, problem, g_new)      # the only O(n_r) work of the move
    return _accept_gamma_ab(work, r, rng, prior, cond_old, g_new, stats_new, 0.0, info, "gamma_ab")


def _l_derivatives(sums, g):
    """First and second l-derivatives ``(SyB', SAB', SBB', SyB'', SAB'', SBB'')`` from :meth:`RegionData.b_sums_newton`.

    ``dB/dl = g log<h.n> B``; the a-column does not depend on gamma (``s'_a = S'_aa = 0``).
    """
    yb1, ab1, bb1, yb2, ab2, bb2 = (float(x) for x in sums[3:])
    g = float(g)
    return (g * yb1, g * ab1, 2.0 * g * bb1,
            g * yb1 + g * g * yb2, g * ab1 + g * g * ab2, 2.0 * g * bb1 + 4.0 * g * g * bb2)


def ls_profile(sya, saa, sums, g):
    """``f = s.S^-1 s`` (so ``SSR_min = Syy - f`` without the a, b > 0 bound), ``det S``, and their l-derivatives.

    ``l = log gamma``; ``S = [[SAA, SAB], [SAB, SBB]]``, ``s = (SyA, SyB)``; ``sums`` are
    :meth:`RegionData.b_sums_newton` at ``g``. Since ``dB/dl = g log<h.n> B``, the
    l-derivatives of SyB, SAB and SBB are g- and g^2-weighted sums of them. With
    ``c = S^-1 s`` (the least-squares a, b) and primes for d/dl: ``f' = 2 c.s' - c.S'c`` and
    ``f'' = 2 d.S^-1 d + 2 c.s'' - c.S''c`` with ``d = s' - S'c``.
    Returns ``(f, f', f'', det, det', det'', a, b)``, or None for a singular S and where the
    lobe has vanished from the region at this gamma: ``<h.n>^gamma`` underflows, SBB falls
    below the smallest normal float (its sums keep a few bits; measured on psm-rock: SBB
    8.8e-322 at gamma 838, least-squares b -4e160, f' overflowing) and the profile, flat
    to double precision, has no curvature to use. A result that is still not finite (gamma
    near e^700, whose square overflows) is None too. The arithmetic runs on Python floats
    (the same IEEE operations as NumPy's scalars, so the same bits) and is checked on its
    results.
    """
    syb, sab, sbb = (float(x) for x in sums[:3])
    sya, saa, g = float(sya), float(saa), float(g)
    det = saa * sbb - sab * sab
    if not (saa > 0 and sbb >= sys.float_info.min and det > 1e-10 * saa * sbb):
        return None
    ca = (sbb * sya - sab * syb) / det
    cb = (saa * syb - sab * sya) / det
    s1b, S1ab, S1bb, s2b, S2ab, S2bb = _l_derivatives(sums, g)
    f = ca * sya + cb * syb
    f1 = 2.0 * cb * s1b - (2.0 * ca * cb * S1ab + cb * cb * S1bb)
    da = -S1ab * cb
    db = s1b - S1ab * ca - S1bb * cb
    f2 = (2.0 * (sbb * da * da - 2.0 * sab * da * db + saa * db * db) / det
          + 2.0 * cb * s2b - (2.0 * ca * cb * S2ab + cb * cb * S2bb))
    det1 = saa * S1bb - 2.0 * sab * S1ab
    det2 = saa * S2bb - 2.0 * S1ab * S1ab - 2.0 * sab * S2ab
    profile = (f, f1, f2, det, det1, det2, ca, cb)
    return profile if all(math.isfinite(x) for x in profile) else None


def ls_profile_nonnegative(sya, saa, sums, g, piece=None):
    """:func:`ls_profile` of the least squares over ``a, b >= 0``: ``(f, f', f'', det, det', det'', piece)``, or None.

    This is the profile the region proposals' Laplace fit uses (``SSR = Syy - f`` as
    :func:`~rjfit.sampler.moves.region_proposals.ssr_min` gives it). Where the unconstrained
    least-squares point lies in ``a, b >= 0`` it is :func:`ls_profile`'s, bit for bit.
    Elsewhere the constrained optimum lies on a face, chosen as ``ssr_min`` chooses it (the
    larger of ``max(SyA, 0)^2 / SAA`` and ``max(SyB, 0)^2 / SBB``): on ``b = 0``,
    ``f = SyA^2 / SAA`` does not depend on gamma (f' = f'' = 0); on ``a = 0``, with
    ``c = SyB / SBB`` and ``d = SyB' - SBB' c``: ``f = c SyB``, ``f' = 2 c SyB' - c^2 SBB'``,
    ``f'' = 2 d^2 / SBB + 2 c SyB'' - c^2 SBB''``. ``det`` and its derivatives are the full
    matrix's on every face, as in the Laplace objective. The constrained minimum of a convex
    quadratic is continuously differentiable in l; its f'' jumps where the face changes.
    ``piece`` says which: 0 inside, 1 on ``a = 0``, 2 on ``b = 0``; given, that piece's
    formula is evaluated wherever the point lies (both sides' curvatures at a kink).
    """
    profile = ls_profile(sya, saa, sums, g)
    if profile is None:
        return None
    ca, cb = profile[6], profile[7]
    if piece is None:
        # as ab_conditional chooses the centre of ssr_min
        piece = (0 if ca >= 0 and cb >= 0
                 else 2 if max(float(sya), 0.0) ** 2 / float(saa) >= max(float(sums[0]), 0.0) ** 2 / float(sums[2])
                 else 1)
    if piece == 0:
        return profile[:6] + (0,)
    det, det1, det2 = profile[3:6]
    sya, saa, syb, sbb = float(sya), float(saa), float(sums[0]), float(sums[2])
    if piece == 2:
        return max(sya, 0.0) ** 2 / saa, 0.0, 0.0, det, det1, det2, 2
    s1b, _, S1bb, s2b, _, S2bb = _l_derivatives(sums, g)
    c = max(syb, 0.0) / sbb
    d = s1b - S1bb * c
    face = (c * syb, 2.0 * c * s1b - c * c * S1bb, 2.0 * d * d / sbb + 2.0 * c * s2b - c * c * S2bb, det, det1, det2)
    return face + (1,) if all(math.isfinite(x) for x in face) else None


def ls_point_slopes(sya, saa, sums, g):
    """The unconstrained least-squares ``(a, b)`` at ``g`` and their l-derivatives ``(a, b, a', b')``, or None.

    Where ``a`` (``b``) crosses 0 the constrained profile of :func:`ls_profile_nonnegative`
    changes piece; both are smooth in l, so Newton steps on them find that kink.
    """
    syb, sab, sbb = (float(x) for x in sums[:3])
    sya, saa = float(sya), float(saa)
    det = saa * sbb - sab * sab
    if not (saa > 0 and sbb >= sys.float_info.min and det > 1e-10 * saa * sbb):
        return None
    s1b, S1ab, S1bb, _, _, _ = _l_derivatives(sums, g)
    ca, cb = (sbb * sya - sab * syb) / det, (saa * syb - sab * sya) / det
    det1 = saa * S1bb - 2.0 * sab * S1ab
    ca1 = (S1bb * sya - S1ab * syb - sab * s1b - ca * det1) / det
    cb1 = (saa * s1b - S1ab * sya - cb * det1) / det
    out = (ca, cb, ca1, cb1)
    return out if all(math.isfinite(x) for x in out) else None


def newton_log_gamma(stats_r, sums, g, s2, scale):
    """Newton proposal of log gamma at ``g``: (mean, sd), or None where the profile is not concave.

    ``h(l) = -SSR_min(e^l) / (2 sigma^2) = (f - Syy) / (2 sigma^2)`` (:func:`ls_profile_nonnegative`):
    the log-likelihood with (a, b) at their least-squares values over ``a, b >= 0``, the O(n)
    part of log gamma's conditional; the prior and the (a, b) volume term are O(1) and left to
    the acceptance ratio. ``scale`` multiplies the sd.

    Why the bounded profile: where the unbounded least-squares point has ``a < 0`` (a material
    whose lobe takes up the diffuse light, kd near 0: the DiLiGenT ball), the unbounded profile's
    mode lies off the posterior's, and Newton proposals aimed there were accepted 1 % of the
    time; inside ``a, b >= 0`` both profiles are the same, bit for bit.
    """
    profile = ls_profile_nonnegative(stats_r[STAT_YA], stats_r[STAT_AA], sums, g)
    if profile is None:
        return None
    h1, h2 = 0.5 * profile[1] / s2, 0.5 * profile[2] / s2
    if not (math.isfinite(h1) and math.isfinite(h2) and h2 < 0):
        return None
    step, sd = -h1 / h2, scale / math.sqrt(-h2)
    # far from a quadratic (small or flat regions): the random walk is the safer rule there
    return (math.log(g) + step, sd) if abs(step) <= 5.0 and sd <= 2.0 else None


def log_q_log_gamma(ell_to, ell_from, newton, rw_sd):
    """Log density of proposing ``log gamma = ell_to`` from ``ell_from``: Newton's normal, or the random walk's."""
    mean, sd = newton if newton is not None else (ell_from, rw_sd)
    return -0.5 * ((ell_to - mean) / sd) ** 2 - math.log(sd) - 0.5 * LOG_2PI


def move_gamma_newton(work, r, rng, prior, problem, scale, rw_sd, info):
    """Gamma move with a Newton proposal of log gamma, (a, b) redrawn from their conditional given it.

    Kind 'gamma_newton'. The proposal's mean and sd come from the curvature of the profile log-likelihood at the
    current gamma (:func:`newton_log_gamma`), so one move crosses the posterior's width
    and follows the kd-gamma ridge; the reverse density is the same rule at the proposed
    gamma, so the ratio is exact. Where the profile is not concave the rule is a random
    walk of sd ``rw_sd`` (a deterministic choice per point: still a valid proposal).
    Returns whether it accepted, or None where (a, b) have no conditional.
    """
    g, s2 = work.theta[r, 2], work.theta[r, 3]
    stats_r = work.stats[r]
    cond_old = ab_conditional(stats_r, s2)
    if cond_old is None:
        return None
    data = work.region_data(r, problem)
    ell = math.log(g)
    forward = newton_log_gamma(stats_r, data.b_sums_newton(g), g, s2, scale)
    ell_new = (forward[0] + forward[1] * rng.normal()) if forward is not None else ell + rw_sd * rng.normal()
    if ell_new > 700.0:         # gamma beyond e^700: the lobe (and the target) vanish numerically
        return False
    g_new = math.exp(ell_new)
    sums_new = data.b_sums_newton(g_new)
    stats_new = stats_r.copy()
    stats_new[[STAT_YB, STAT_AB, STAT_BB]] = sums_new[:3]
    backward = newton_log_gamma(stats_new, sums_new, g_new, s2, scale)
    log_q_ratio = log_q_log_gamma(ell, ell_new, backward, rw_sd) - log_q_log_gamma(ell_new, ell, forward, rw_sd)
    return _accept_gamma_ab(work, r, rng, prior, cond_old, g_new, stats_new, log_q_ratio, info, "gamma_newton")
