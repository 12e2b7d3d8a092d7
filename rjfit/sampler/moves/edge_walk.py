"""Random walks of a material's parameters for a target with an edge term.

The conditional moves (:mod:`~rjfit.sampler.moves.ab_conditional`, :mod:`~rjfit.sampler.moves.gamma`)
propose (a, b) from the pixel likelihood's conditional. An edge term
(:mod:`rjfit.sampler.regions.materials.edges`) adds a second dependence on a material's
parameters, at a power often ten times the pixel term's, which those proposals do not see: under
it nearly every proposal was rejected and the parameters of every material that has a boundary
froze (psm-cat under the measured default, 4 x 300: 'ab' 2.6 % and the gamma moves 2 % accepted,
against 70 % and 60 % without the term; docs/results/2026-11-28-gamma-moves.md). These two moves
propose small symmetric steps instead, so their ratio is the target's, edge term included:

- :func:`move_ab_walk`: ``(a, b) + scale L z``, ``L`` the Cholesky factor of the conditional's
  covariance at the current gamma and sigma^2, which the move does not change (so the step's law
  is the same both ways).
- :func:`move_ridge_walk`: ``log gamma + step z``, and (a, b) shifted by the change of the
  conditional's centre between the two gammas. For a given pair of gammas the map of (a, b) is a
  translation, and the reverse step (``-z``) undoes it, so the proposal is symmetric with unit
  Jacobian; it follows the kd-gamma ridge as the conditional moves do.

A proposal outside ``a, b > 0`` has target 0 and is rejected.
"""
from __future__ import annotations

import math

from rjfit.sampler.moves.ab_conditional import ab_conditional, decide_amplitudes
from rjfit.sampler.moves.region_terms import giesen_norm, stats_at_gamma

__all__ = ["move_ab_walk", "move_ridge_walk"]


def move_ab_walk(work, r, rng, prior, scale, info):
    """A random walk of row ``r``'s (a, b) shaped by their conditional's covariance, times ``scale`` (kind 'ab_walk').

    Returns whether it accepted, or None where the conditional does not exist (nothing drawn).
    """
    I0, kd, g, s2 = work.theta[r]
    cond = ab_conditional(work.stats[r], s2)
    if cond is None:
        return None
    z1, z2 = rng.normal(size=2)
    log_u = math.log(rng.random())
    a = I0 * kd + scale * cond.la * z1
    b = I0 * (1.0 - kd) * giesen_norm(g) + scale * (cond.lc * z1 + cond.lb * z2)
    return decide_amplitudes(work, r, prior, a, b, g, work.stats[r], 0.0, log_u, "ab_walk", info)


def move_ridge_walk(work, r, rng, prior, problem, step, info):
    """A random walk of row ``r``'s log gamma (sd ``step``) with (a, b) carried along the conditional's centre
    (kind 'ridge_walk').

    Returns whether it accepted, or None where the conditional does not exist at the current gamma (nothing
    drawn); a proposed gamma where it does not exist is rejected.
    """
    I0, kd, g, s2 = work.theta[r]
    cond = ab_conditional(work.stats[r], s2)
    if cond is None:
        return None
    z = rng.normal()
    log_u = math.log(rng.random())
    ell_new = math.log(g) + step * z
    if ell_new > 700.0:       # gamma beyond e^700: the lobe (and the target) vanish numerically
        return False
    g_new = math.exp(ell_new)
    stats_new = stats_at_gamma(work, r, problem, g_new)
    cond_new = ab_conditional(stats_new, s2)
    if cond_new is None:
        return False
    a = I0 * kd + (cond_new.ma - cond.ma)
    b = I0 * (1.0 - kd) * giesen_norm(g) + (cond_new.mb - cond.mb)
    return decide_amplitudes(work, r, prior, a, b, g_new, stats_new, 0.0, log_u, "ridge_walk", info)
