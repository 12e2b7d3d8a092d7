"""Pareto-smoothed importance-sampling leave-one-out cross-validation (PSIS-LOO), vectorised.

The same estimator as ArviZ's ``az.loo`` (Vehtari, Gelman and Gabry 2017, "Practical Bayesian
model evaluation using leave-one-out cross-validation and WAIC", Statistics and Computing 27;
Vehtari et al. 2024, "Pareto smoothed importance sampling", JMLR 25): per observation i the
importance ratios of leaving it out, ``r_s = 1 / p(y_i | z_s)``, have their largest
``M = ceil(min(S / 5, 3 sqrt(S)))`` values replaced by the expected order statistics of a
generalized Pareto distribution fitted to them (Zhang and Stephens 2009, with the weakly
informative prior on its shape k), truncated at the largest raw ratio; the fitted k is the
diagnostic k-hat. Then ``elpd_i = log sum_s w_s p(y_i | z_s) / sum_s w_s``.

Why not ``az.loo``: it smooths one observation at a time in Python, about 2.4 s per 20,000
observations, so minutes per model on a measured stack of a million observations. Here
the sort, the Pareto fit and the smoothing run on blocks of observations as array
operations. ``tests/diagnose/test_psis.py`` checks the result against ``az.loo`` and ``az.psislw``.

Two differences, both deliberate:

- ``likelihood_power`` zeta: draws from a coarsened posterior (likelihood to the power
  zeta) leave observation i out with the ratios ``p(y_i | z_s)^-zeta``; the predictive
  density they weigh stays ``p(y_i | z_s)``. At zeta = 1 this is the usual estimator.
- Where the Pareto fit is degenerate (a non-positive scale, a non-finite shape), the tail
  is left unsmoothed and k-hat is reported as infinite (ArviZ would return NaN weights).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

__all__ = ["LooResult", "good_k_threshold", "psis_loo", "psis_smooth"]

_TINY_LOG = math.log(np.finfo(float).tiny)
_EPS = np.finfo(float).eps
_PRIOR_K_WEIGHT = 10       # the shape's weakly informative prior: 10 pseudo-observations at k = 0.5
_PRIOR_BS = 3


class LooResult(NamedTuple):
    """PSIS-LOO estimate: total ``elpd``, its standard error, per-observation terms and k-hats."""

    elpd: float
    se: float
    pointwise: np.ndarray
    pareto_k: np.ndarray


def good_k_threshold(n_draws: int) -> float:
    """The k-hat above which an observation's PSIS estimate is unreliable with ``n_draws`` draws:
    ``min(1 - 1 / log10(S), 0.7)`` (Vehtari et al. 2024, section 3.2.4; ArviZ's ``good_k``);
    0.5 for 100 draws."""
    return min(1.0 - 1.0 / math.log10(n_draws), 0.7)


def _log_sum_exp(values):
    """log sum exp of each row of a finite (n, S) array. Not scipy's ``logsumexp``: its checks
    for infinities and signs made the whole estimator 1.5 times slower (measured with
    ``validation/bench_psis.py``), and these rows are finite by construction."""
    top = values.max(axis=1)
    return top + np.log(np.exp(values - top[:, None]).sum(axis=1))


def _tail_length(n_draws: int) -> int:
    return int(math.ceil(min(n_draws / 5.0, 3.0 * math.sqrt(n_draws))))


def _gpd_fit(exceedances):
    """Zhang-Stephens fit of a generalized Pareto to each row of ascending ``exceedances`` (n, M).

    Returns (k, sigma), each (n,); k includes the prior's pull towards 0.5.
    """
    m = exceedances.shape[1]
    m_grid = 30 + int(math.sqrt(m))
    quartile = exceedances[:, int(m / 4.0 + 0.5) - 1]
    base = 1.0 - np.sqrt(m_grid / (np.arange(1, m_grid + 1, dtype=float) - 0.5))
    b = base[None, :] / (_PRIOR_BS * quartile[:, None]) + 1.0 / exceedances[:, -1:]          # (n, m_grid)
    k_grid = np.log1p(-b[:, :, None] * exceedances[:, None, :]).mean(axis=2)
    profile = m * (np.log(-(b / k_grid)) - k_grid - 1.0)
    weights = np.exp(profile - profile.max(axis=1, keepdims=True))
    weights /= weights.sum(axis=1, keepdims=True)
    weights[weights < 10.0 * _EPS] = 0.0           # negligible grid points dropped, as ArviZ does
    weights /= weights.sum(axis=1, keepdims=True)
    b_post = np.sum(b * weights, axis=1)
    k_post = np.log1p(-b_post[:, None] * exceedances).mean(axis=1)
    sigma = -k_post / b_post
    k_post = (m * k_post + _PRIOR_K_WEIGHT * 0.5) / (m + _PRIOR_K_WEIGHT)
    return k_post, sigma


def _gpd_quantiles(probs, k, sigma):
    """Quantiles (n, M) of generalized Paretos with shapes ``k`` and scales ``sigma`` (n,) at ``probs`` (M,)."""
    k = k[:, None]
    log_survival = np.log1p(-probs)[None, :]
    small = np.abs(k) < _EPS
    safe_k = np.where(small, 1.0, k)
    return sigma[:, None] * np.where(small, -log_survival, np.expm1(-safe_k * log_survival) / safe_k)


def _smooth_sorted(sorted_x, tail_len):
    """Smooth the ``tail_len`` largest entries of each row of ``sorted_x`` (ascending, max 0), in place; k-hats."""
    n_rows = sorted_x.shape[0]
    if tail_len <= 4:          # too few tail draws for a Pareto fit: unsmoothed, k-hat infinite
        return np.full(n_rows, np.inf)
    cutoff = sorted_x[:, -tail_len - 1]
    cutoff = np.maximum(cutoff, _TINY_LOG)
    exp_cutoff = np.exp(cutoff)
    exceedances = np.exp(sorted_x[:, -tail_len:]) - exp_cutoff[:, None]
    k, sigma = _gpd_fit(exceedances)
    ok = np.isfinite(k) & (sigma > 0)
    probs = np.arange(0.5, tail_len) / tail_len
    smoothed = np.log(_gpd_quantiles(probs, np.where(ok, k, 0.0), np.where(ok, sigma, 1.0)) + exp_cutoff[:, None])
    tail = sorted_x[:, -tail_len:]
    tail[ok] = np.minimum(smoothed[ok], 0.0)       # truncated at the largest raw ratio (0 after the shift)
    return np.where(ok, k, np.inf)


def psis_smooth(log_ratios):
    """Pareto-smoothed, normalised log importance weights of each row of ``log_ratios`` (n, S).

    Returns ``(log_weights, pareto_k, order)``: the weights (n, S) in ascending order of the
    raw ratios, ``order`` the permutation of each row that sorts them (``np.argsort``), and
    the Pareto shape k-hat (n,) of each row.
    """
    log_ratios = np.asarray(log_ratios, dtype=float)
    n_rows, n_draws = log_ratios.shape
    order = np.argsort(log_ratios, axis=1, kind="stable")
    x = np.take_along_axis(log_ratios, order, axis=1)
    x -= x[:, -1:]
    khat = np.empty(n_rows)
    tail_len = _tail_length(n_draws)
    cutoff = np.maximum(x[:, -tail_len - 1], _TINY_LOG)
    # ties at the cutoff (or a cutoff clamped at the smallest float) shorten a row's tail:
    # the tail is the draws strictly above the cutoff, as in ArviZ
    lengths = np.sum(x > cutoff[:, None], axis=1)
    for length in np.unique(lengths):
        rows = np.flatnonzero(lengths == length)
        block = x[rows]
        khat[rows] = _smooth_sorted(block, int(length))
        x[rows] = block
    x -= _log_sum_exp(x)[:, None]
    return x, khat, order


def psis_loo(log_lik, *, likelihood_power: float = 1.0, block_size: int = 8192) -> LooResult:
    """PSIS-LOO from the pointwise log-likelihood of posterior draws.

    Parameters
    ----------
    log_lik : ndarray (S, N)
        ``log p(y_i | z_s)`` of N observations under S independent posterior draws (one
        chain, so the relative efficiency is 1).
    likelihood_power : float
        The power zeta in (0, 1] on the likelihood of the posterior the draws come from
        (coarsened fits): leaving observation i out divides by ``p(y_i | z)^zeta``.
    block_size : int
        Observations smoothed at a time (memory: about 300 ``block_size`` floats per draw).

    Returns
    -------
    LooResult
        ``elpd`` = sum of the pointwise terms, ``se`` = sqrt(N var(pointwise)), and k-hat per
        observation (above 0.7 the importance sampling of that observation is unreliable).

    Raises
    ------
    ValueError
        If ``log_lik`` is not a finite 2-D array with at least 5 draws (the smallest tail
        that a Pareto fit needs), or the power is outside (0, 1].
    """
    log_lik = np.asarray(log_lik, dtype=float)
    if log_lik.ndim != 2 or log_lik.shape[0] < 5 or log_lik.shape[1] < 1:
        raise ValueError(f"log_lik must be (draws, observations) with at least 5 draws, got shape {log_lik.shape}")
    if not np.all(np.isfinite(log_lik)):
        raise ValueError("log_lik has non-finite entries: PSIS-LOO needs a finite log-likelihood for every draw")
    if not 0.0 < likelihood_power <= 1.0:
        raise ValueError(f"likelihood_power must be in (0, 1], got {likelihood_power}")
    n_obs = log_lik.shape[1]
    pointwise = np.empty(n_obs)
    pareto_k = np.empty(n_obs)
    for lo in range(0, n_obs, block_size):
        block = log_lik[:, lo:lo + block_size].T
        log_weights, pareto_k[lo:lo + block_size], order = psis_smooth(-likelihood_power * block)
        sorted_ll = np.take_along_axis(block, order, axis=1)
        pointwise[lo:lo + block_size] = _log_sum_exp(log_weights + sorted_ll)
    return LooResult(elpd=float(pointwise.sum()), se=float(math.sqrt(n_obs * np.var(pointwise))),
                     pointwise=pointwise, pareto_k=pareto_k)
