"""The Laplace approximation of a refit's posterior: its log evidence, its draws, and the
importance-sampling check of that evidence.

At the MAP z* with the Hessian H of f = -log p(y, z) (:mod:`rjfit.diagnose.hessian`),

    log Z = -f(z*) + d/2 log 2 pi - 1/2 log det H,

the marginal likelihood whose differences are log Bayes factors (they penalise extra
parameters through the Occam factor of their prior and posterior widths), and the posterior
draws are z ~ N(z*, H^-1) (seeded).
"""
from __future__ import annotations

import math

import numpy as np

from rjfit.diagnose.objective import LOG_2PI

__all__ = ["laplace_log_evidence", "laplace_draws", "evidence_by_importance_sampling"]


def laplace_log_evidence(objective, z, hessian):
    """``(log Z, log-likelihood, log prior)`` at the MAP ``z`` with the symmetric ``hessian``
    (module docstring; the log-likelihood is the one the objective weighs, zeta times the sum)."""
    sign, logdet = np.linalg.slogdet(hessian)
    log_lik = objective.log_lik(z)
    log_prior = objective.log_prior(z)
    log_evidence = log_lik + log_prior + 0.5 * objective.P * LOG_2PI - 0.5 * logdet
    return float(log_evidence), log_lik, log_prior


def laplace_draws(z, hessian, n_draws, seed):
    """(n_draws, P) draws from N(z, hessian^-1), from ``numpy.random.default_rng(seed)``."""
    rng = np.random.default_rng(seed)
    cov = np.linalg.inv(hessian)
    chol = np.linalg.cholesky(0.5 * (cov + cov.T))
    return z + rng.standard_normal((n_draws, z.size)) @ chol.T


def evidence_by_importance_sampling(fit, n_draws=2000, seed=0, inflate=1.2):
    """Check of a refit's Laplace evidence (``fit``: a :class:`rjfit.diagnose.refit.FitResult`):
    importance sampling from the Laplace Gaussian (covariance inflated by ``inflate^2`` for
    heavier coverage), log Z = log mean p(y, z) / q(z).

    Returns ``(log_Z_is, its Monte Carlo standard error in log units, effective sample size)``.
    Agreement with ``fit.log_evidence`` to a fraction of a nat says the Laplace approximation
    is adequate for Bayes factors of this model.
    """
    objective = fit.objective
    rng = np.random.default_rng(seed)
    cov = np.linalg.inv(fit.hessian) * inflate ** 2
    chol = np.linalg.cholesky(0.5 * (cov + cov.T))
    eps = rng.standard_normal((n_draws, fit.z.size))
    z = fit.z + eps @ chol.T
    log_q = (-0.5 * np.sum(eps ** 2, axis=1) - np.sum(np.log(np.diag(chol))) - 0.5 * fit.z.size * LOG_2PI)
    log_joint = np.array([-objective.f(zz) for zz in z])
    log_w = log_joint - log_q
    top = log_w.max()
    w = np.exp(log_w - top)
    log_z = float(top + np.log(w.mean()))
    ess = float(w.sum() ** 2 / np.sum(w ** 2))
    se = float(w.std() / (w.mean() * math.sqrt(n_draws)))
    return log_z, se, ess
