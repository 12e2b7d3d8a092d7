"""Finding a refit's MAP: Levenberg-Marquardt on the normal equations for the mean parameters,
alternated with the closed-form sigma^2 update, then Newton corrections with the Hessian.
"""
from __future__ import annotations

import math

import numpy as np

from rjfit.diagnose.hessian import objective_hessian

__all__ = ["levenberg_marquardt", "find_map", "newton_corrections"]


def levenberg_marquardt(fun, normal_equations, x0, args=(), *, tol=1e-10, max_iterations=200):
    """Minimise ``|fun(x)|^2 / 2`` by Levenberg-Marquardt on the normal equations.

    MINPACK's ``lm`` (scipy's ``least_squares(method="lm")``) factorises the whole N x M
    Jacobian by QR at every step, which costs most of a refit on a million observations;
    here each step solves the M x M system ``(J'J + mu D) step = -J'r`` (``D``: the largest
    diagonal of J'J seen so far, as MINPACK scales) with the damping ``mu`` updated by
    Nielsen's rule (Madsen, Nielsen and Tingleff, "Methods for non-linear least squares
    problems", 2004, eq. 2.21). The residuals here are standardised and the parameters
    unconstrained and of order 1, so forming J'J loses little in double precision, and what
    a step gets wrong the next one corrects (only the minimum found matters).

    Stops when the step is below ``tol`` relative to x, the relative decrease of the cost
    and its prediction are below ``tol``, the gradient is orthogonal to the residuals to
    ``tol``, or after ``max_iterations`` steps. ``normal_equations(x, residuals, *args)``
    returns ``(J'J, J'r)`` at x (so a structured Jacobian need not be formed). Returns ``(x,
    J'J at x)``.
    """
    x = np.array(x0, dtype=float)
    residuals = fun(x, *args)
    cost = 0.5 * float(residuals @ residuals)
    normal, gradient = normal_equations(x, residuals, *args)
    scale = np.diag(normal).copy()
    mu, nu = 1e-3, 2.0
    for _ in range(max_iterations):
        scale = np.maximum(scale, np.diag(normal))
        weights = np.maximum(scale, 1e-12 * max(float(scale.max()), 1e-300))
        if np.max(np.abs(gradient) / np.sqrt(weights)) <= tol * math.sqrt(2.0 * cost):
            break
        try:
            step = np.linalg.solve(normal + mu * np.diag(weights), -gradient)
        except np.linalg.LinAlgError:
            mu, nu = mu * nu, nu * 2.0
            continue
        if np.linalg.norm(np.sqrt(weights) * step) <= tol * (np.linalg.norm(np.sqrt(weights) * x) + tol):
            break
        candidate = fun(x + step, *args)
        cost_new = 0.5 * float(candidate @ candidate)
        predicted = -float(step @ gradient) - 0.5 * float(step @ normal @ step)
        rho = (cost - cost_new) / predicted if predicted > 0 else -1.0
        if rho > 0:
            decrease = (cost - cost_new) / max(cost, 1e-300)
            x, residuals, cost = x + step, candidate, cost_new
            normal, gradient = normal_equations(x, residuals, *args)
            mu, nu = mu * max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3), 2.0
            if decrease <= tol and predicted / max(cost, 1e-300) <= tol:
                break
        else:
            mu, nu = mu * nu, nu * 2.0
    return x, normal


def find_map(objective, z, *, max_outer=6, tol=1e-3):
    """Minimise ``objective.f`` from ``z`` (modified in place): alternate a Levenberg-Marquardt
    solve of the mean parameters at fixed sigma^2 (:meth:`RefitObjective.mean_residuals`: f
    itself up to a constant) with the closed-form update of each region's log sigma^2
    (:meth:`RefitObjective.update_sigma`), until f changes by less than ``tol`` or after
    ``max_outer`` rounds (>= 1). Returns ``(z, J'J of the last least-squares solve)``.
    """
    z = objective.update_sigma(z)
    f_old = objective.f(z)
    for _ in range(max_outer):
        z[objective.mean_index], gauss_newton = levenberg_marquardt(
            objective.mean_residuals, objective.mean_normal_equations, z[objective.mean_index], args=(z,))
        z = objective.update_sigma(z)
        f_new = objective.f(z)
        if abs(f_old - f_new) < tol:
            break
        f_old = f_new
    return z, gauss_newton


def newton_corrections(objective, z, steps, *, max_corrections=2):
    """Up to ``max_corrections`` Newton steps from ``z`` with the finite-difference Hessian
    (:func:`rjfit.diagnose.hessian.objective_hessian`, ``steps``), each kept only while it
    lowers f (a least-squares solve stops a little short of the optimum). Returns ``(z, H)``:
    the point reached and the Hessian there (not symmetrised)."""
    hessian, gradient, f0 = objective_hessian(objective, z, steps)
    for _ in range(max_corrections):
        try:
            step = np.linalg.solve(hessian, gradient)
        except np.linalg.LinAlgError:
            break
        if not np.all(np.isfinite(step)) or float(gradient @ step) < 1e-6:
            break
        candidate = z - step
        if objective.f(candidate) < f0:
            z = candidate
            hessian, gradient, f0 = objective_hessian(objective, z, steps)
        else:
            break
    return z, hessian
