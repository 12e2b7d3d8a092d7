"""A refit's posterior draws and their importance weights: the Laplace Gaussian, or a split
normal along its axes where the log posterior does not fall as the Gaussian says.

The Laplace draws ``N(z*, H^-1)`` represent the posterior only where it is close to Gaussian. A
rough interface's roughness, traded against the lobes' weights, is not: along one axis of ``H``
the log posterior falls as the fourth power (0.011 / 5.6 / 104 at steps of 0.1 / 0.5 / 1
against the quadratic's 0.003 / 0.08 / 0.32, ``docs/results/2026-11-30-rough-coating.md``), and
the Gaussian's draws land where the posterior is negligible. The LOO of such draws said a model
that predicts better by 840 nats predicts worse by 2,600.

So the draws here come from the split normal of Geweke (1989, "Bayesian inference in
econometric models using Monte Carlo integration", Econometrica 57): along each eigenvector
``v_j`` of ``H``, on each side, the scale is the distance ``t`` at which ``f = -log p(y, z)``
has risen by 1/2 over its minimum, the Gaussian's one-sd rise (Geweke takes the widest of
several secants, for heavy tails; here the tails are light, and the widest is the Gaussian's).
Where the Gaussian's own scale ``lambda_j^-1/2`` gives a rise within a factor of 2 of that on
both sides of every axis, the draws are the Laplace draws, unchanged.

PSIS-LOO (:mod:`rjfit.diagnose.loo`) takes the draws as the posterior's, as it took the
Laplace draws. Each draw's importance log weight ``log p(y, z_s) - log q(z_s)`` is the check: the
Pareto k-hat of the weights says how well the proposal covers the posterior. Folding the weights
into every observation's ratios (Magnusson, Andersen, Jonasson and Vehtari 2019, "Bayesian
leave-one-out cross-validation for large data", ICML) was tried: with 100 draws the weights' own
tail enters every observation's: on the clean stack the share of observations whose LOO is
unreliable went from 1 to 4 % to 4, 59 and 97 % for three candidates
(``docs/results/2026-11-30-split-normal-draws.md``).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from rjfit.diagnose.evidence import laplace_draws
from rjfit.diagnose.objective import LOG_2PI
from rjfit.diagnose.psis import psis_smooth

__all__ = ["PosteriorDraws", "posterior_draws", "axis_scales", "importance_log_weights", "weight_pareto_k",
           "POOR_DRAWS_KHAT"]

#: above this Pareto k-hat of its importance weights a proposal covers the posterior too poorly for
#: estimates from its draws, whatever their number (Vehtari et al. 2024, "Pareto smoothed
#: importance sampling", JMLR 25, section 3)
POOR_DRAWS_KHAT = 0.7

#: the rise of f at one sd of a normal
ONE_SD_RISE = 0.5
#: the Gaussian's scale is kept on a side of an axis where its rise is within this factor of
#: ONE_SD_RISE (the scale then within a factor sqrt(2) of the secant's, where an importance
#: sampler from a wider normal keeps 87 % of its draws' worth in one dimension)
RISE_FACTOR = 2.0
#: bisection steps for a secant scale (2^-12 of the bracket)
BISECTION_STEPS = 12
#: a secant is looked for up to this many of the Gaussian's scales out
MAX_SCALE_RATIO = 8.0


class PosteriorDraws(NamedTuple):
    """A refit's draws ``(S, P)`` (unconstrained), the log density ``(S,)`` of the proposal they
    come from, and a note of the proposal (None for the Laplace)."""

    draws: np.ndarray
    log_proposal: np.ndarray
    note: str | None


def _rise(f, z, f0, direction, t):
    return f(z + t * direction) - f0


def _secant(f, z, f0, direction, scale):
    """The distance t along ``direction`` at which f has risen by ONE_SD_RISE, the Gaussian's
    ``scale`` where its rise there is within RISE_FACTOR of it. Returns ``(t, kept)``."""
    rise = _rise(f, z, f0, direction, scale)
    if ONE_SD_RISE / RISE_FACTOR <= rise <= ONE_SD_RISE * RISE_FACTOR:
        return scale, True
    if rise > ONE_SD_RISE:
        low, high = 0.0, scale
    else:
        low, high = scale, MAX_SCALE_RATIO * scale
        if _rise(f, z, f0, direction, high) < ONE_SD_RISE:
            return high, False
    for _ in range(BISECTION_STEPS):
        middle = 0.5 * (low + high)
        if _rise(f, z, f0, direction, middle) < ONE_SD_RISE:
            low = middle
        else:
            high = middle
    return 0.5 * (low + high), False


def axis_scales(f, z, hessian):
    """``(eigenvectors (P, P), the Gaussian's scales (P,), the scales on the + side (P,), on the
    - side (P,), whether each axis kept the Gaussian's on both sides (P,))`` of the split normal
    at the minimum ``z`` of ``f`` with ``hessian`` (module docstring)."""
    eigenvalues, vectors = np.linalg.eigh(0.5 * (hessian + hessian.T))
    gaussian = 1.0 / np.sqrt(eigenvalues)
    f0 = f(z)
    plus, minus, kept = np.empty(z.size), np.empty(z.size), np.empty(z.size, dtype=bool)
    for j in range(z.size):
        plus[j], kept_plus = _secant(f, z, f0, vectors[:, j], gaussian[j])
        minus[j], kept_minus = _secant(f, z, f0, -vectors[:, j], gaussian[j])
        kept[j] = kept_plus and kept_minus
    return vectors, gaussian, plus, minus, kept


def importance_log_weights(log_joint, log_proposal):
    """The draws' importance log weights ``log p(y, z_s) - log q(z_s)``, their largest 0 (-inf
    where the joint density is 0 or not finite).

    Raises
    ------
    ValueError
        If every draw has a zero or non-finite joint density.
    """
    log_weights = np.asarray(log_joint, dtype=float) - log_proposal
    finite = np.isfinite(log_weights)
    if not finite.any():
        raise ValueError("every posterior draw of the refit has a zero or non-finite density")
    return np.where(finite, log_weights - log_weights[finite].max(), -np.inf)


def posterior_draws(objective, z, hessian, n_draws, seed) -> PosteriorDraws:
    """``n_draws`` draws of the refit's posterior, seeded, with their proposal's log density (the
    importance weights need the joint density at each draw: :func:`importance_log_weights`).

    Parameters
    ----------
    objective
        The refit's objective (:class:`rjfit.diagnose.objective.RefitObjective`): ``f(z)`` is
        ``-log p(y, z)``.
    z, hessian : ndarray
        Its minimum and the (positive definite) Hessian of ``f`` there.
    n_draws, seed : int

    Returns
    -------
    PosteriorDraws
        The Laplace draws of :func:`rjfit.diagnose.evidence.laplace_draws` (the same numbers)
        where the Gaussian's scales hold on every axis, else the split normal's; the note says
        how many axes were rescaled and by how much.
    """
    f = objective.f
    vectors, gaussian, plus, minus, kept = axis_scales(f, z, hessian)
    if kept.all():
        draws = laplace_draws(z, hessian, n_draws, seed)
        offset = draws - z
        log_q = -0.5 * np.einsum("sp,pq,sq->s", offset, hessian, offset) + 0.5 * np.linalg.slogdet(hessian)[1]
        note = None
    else:
        normal = np.random.default_rng(seed).standard_normal((n_draws, z.size))
        draws = z + (normal * np.where(normal > 0, plus, minus)) @ vectors.T
        log_q = -0.5 * np.sum(normal ** 2, axis=1) - np.sum(np.log(0.5 * (plus + minus)))
        ratios = np.concatenate([plus, minus]) / np.concatenate([gaussian, gaussian])
        note = (f"the log posterior is not Gaussian along {int(np.sum(~kept))} of the Laplace approximation's "
                f"{z.size} axes: draws from a split normal (scales {ratios.min():.2g} to {ratios.max():.2g} of the Gaussian's)")
    return PosteriorDraws(draws=draws, log_proposal=log_q - 0.5 * z.size * LOG_2PI, note=note)


def weight_pareto_k(log_weights) -> float:
    """The Pareto k-hat of the draws' importance weights alone (POOR_DRAWS_KHAT says what is too high);
    infinite with fewer than 5 draws of positive density."""
    finite = np.isfinite(log_weights)
    return float(psis_smooth(log_weights[finite][None, :])[1][0]) if finite.sum() >= 5 else math.inf
