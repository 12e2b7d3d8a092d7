"""Refit on a fixed segmentation: MAP, Laplace approximation, evidence and draws of one model
(a set of effects) on one context.

:func:`refit` minimises the objective (:class:`rjfit.diagnose.objective.RefitObjective`) by
alternating a Levenberg-Marquardt least-squares solve for the mean parameters with the
closed-form update of each region's log sigma^2, then up to two Newton corrections with a
finite-difference Hessian (:mod:`rjfit.diagnose.optimise`, :mod:`rjfit.diagnose.hessian`);
the Laplace approximation at that MAP gives the log evidence, whose differences are the log
Bayes factors (:mod:`rjfit.diagnose.evidence`), and seeded posterior draws: the Laplace
Gaussian's, or a split normal's where the posterior is not Gaussian along its axes
(:mod:`rjfit.diagnose.proposal`), with the density of the proposal they came from. PSIS-LOO on
those draws (:mod:`rjfit.diagnose.loo`) is the second opinion; its Pareto k-hat, and that of the
draws' importance weights, say where the draws are a poor proposal. The region priors are
data-centred and shared by every model of a context, so they cancel in Bayes factors
(:mod:`rjfit.diagnose.region_priors`).
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

import numpy as np

from rjfit.diagnose.evidence import laplace_log_evidence
from rjfit.diagnose.hessian import gauss_newton_hessian, hessian_steps
from rjfit.diagnose.objective import RefitObjective
from rjfit.diagnose.optimise import find_map, newton_corrections
from rjfit.diagnose.proposal import posterior_draws
from rjfit.diagnose.region_priors import initial_region_params, region_priors

__all__ = ["FitResult", "refit", "predictions", "posterior_mean_prediction", "standardised_residuals",
           "template_columns", "objective_with", "moved_parameters"]


@dataclass
class FitResult:
    """One refit: the model (``effects``), its parameters' names and priors, the MAP ``z`` and
    Laplace ``hessian`` (unconstrained), the evidence and its parts, and the posterior draws."""

    effects: tuple
    names: list
    priors: list
    z: np.ndarray
    hessian: np.ndarray
    log_evidence: float
    log_lik: float
    log_prior: float
    draws: np.ndarray                # (S, P) unconstrained
    draws_log_proposal: np.ndarray   # (S,) log density of the proposal of the draws (rjfit.diagnose.proposal)
    draws_proposal: str              # "Laplace", or why and how a split normal replaced it
    n_regions: int
    seconds: float
    hessian_kind: str = "finite differences"
    notes: list = field(default_factory=list)
    _cache: dict = field(default_factory=dict, repr=False)

    @property
    def effect_names(self):
        return [e.name for e in self.effects]

    @property
    def n_params(self):
        return int(self.z.size)

    @property
    def objective(self) -> RefitObjective:
        """The objective this refit minimised (its context, effects, priors and f)."""
        return self._cache["objective"]

    def cached(self, key, compute):
        """``compute(self)``, computed once per fit and key even when several threads ask at once
        (the diagnosis' candidate refits all ask for the current model's LOO)."""
        lock = self._cache.setdefault("lock", threading.Lock())        # setdefault is atomic
        with lock:
            if key not in self._cache:
                self._cache[key] = compute(self)
        return self._cache[key]

    def constrained(self, z=None):
        z = self.z if z is None else z
        return np.array([p.to_constrained(v) for p, v in zip(self.priors, z)], dtype=float)

    def region_params(self, z=None):
        """(R, 4) constrained I0, kd, gamma, sigma2."""
        return self.constrained(z)[: 4 * self.n_regions].reshape(self.n_regions, 4)

    def effect_thetas(self, z=None):
        """The constrained parameters of each effect, in the order of ``effects``."""
        values = self.constrained(z)[4 * self.n_regions:]
        out, start = [], 0
        for size in self.objective.sizes:
            out.append(values[start:start + size])
            start += size
        return out

    def posterior_sd(self):
        """Posterior standard deviation of each constrained parameter (from the draws)."""
        return np.array([self.constrained(d) for d in self.draws]).std(axis=0)

    def summary(self):
        values = self.constrained()
        sd = self.posterior_sd()
        return {name: {"map": float(v), "sd": float(s)} for name, v, s in zip(self.names, values, sd)}


def _place_effect_starts(objective, z, previous):
    """Each effect's start in ``z`` (in place): its values in ``previous`` {effect name:
    constrained values} where it has some, else its parameters' ``init``."""
    offset = 4 * objective.ctx.n_regions
    for effect, plist in zip(objective.effects, objective.effect_params):
        for j, p in enumerate(plist):
            value = previous[effect.name][j] if effect.name in previous else p.init
            z[offset + j] = p.prior.to_unconstrained(value)
        offset += len(plist)
    return z


def _start_point(objective, start):
    """Where a refit starts: the context's initial region fit, or ``start``'s region and shared
    effects' parameters (a previous refit), new effects at their ``init``."""
    ctx = objective.ctx
    z = np.zeros(objective.P)
    region0 = ctx.features["region_init"] if start is None else start.region_params()
    for r in range(ctx.n_regions):
        for k in range(4):
            z[4 * r + k] = objective.priors[4 * r + k].to_unconstrained(region0[r, k])
    previous = {} if start is None else dict(zip(start.effect_names, start.effect_thetas()))
    return _place_effect_starts(objective, z, previous)


def _positive_definite(objective, hessian, gauss_newton):
    """``(symmetric Hessian, its kind, notes)``: the finite-difference ``hessian``, or the
    Gauss-Newton curvature where that is not positive definite."""
    eigenvalues = np.linalg.eigvalsh(0.5 * (hessian + hessian.T))
    if eigenvalues.min() > 0:
        return 0.5 * (hessian + hessian.T), "finite differences", []
    hessian = gauss_newton_hessian(objective, gauss_newton)
    return (0.5 * (hessian + hessian.T), "Gauss-Newton",
            ["finite-difference Hessian not positive definite; Gauss-Newton curvature used"])


#: Newton corrections of a refit's MAP where the data set declares a dark threshold: the least
#: squares stop short of the truncated likelihood's optimum (ambient + camera_gamma on the
#: power-law stack, 64 x 64: 8 steps from the least squares' f to within 0.02 of L-BFGS-B's;
#: 2 left the log evidence 6.6 low)
TRUNCATED_CORRECTIONS = 12


def refit(ctx, effects=(), *, start=None, seed=0, n_draws=100, max_outer=6, tol=1e-3) -> FitResult:
    """Fit region parameters and effect parameters on ``ctx``'s fixed segmentation.

    Parameters
    ----------
    effects : sequence of Effect
    start : FitResult, optional
        Warm start: region parameters and shared effects' parameters from a previous fit;
        new effects start at their ``init`` values.
    n_draws : int
        Posterior draws (seeded by ``seed``): the Laplace approximation's, or a split normal's
        (:func:`rjfit.diagnose.proposal.posterior_draws`).
    max_outer, tol
        At most ``max_outer`` rounds of least squares and sigma^2 updates, stopped when f
        changes by less than ``tol`` (:func:`rjfit.diagnose.optimise.find_map`).
    """
    started = time.perf_counter()
    if "region_priors" not in ctx.features:
        init = initial_region_params(ctx)
        ctx.features["region_init"] = init
        ctx.features["region_priors"] = region_priors(init)
    objective = RefitObjective(ctx, effects, ctx.features["region_priors"])
    z, gauss_newton = find_map(objective, _start_point(objective, start), max_outer=max_outer, tol=tol)
    # the least squares leave out a dark threshold's truncation term (RefitObjective): Newton reaches its MAP
    z, hessian = newton_corrections(objective, z, hessian_steps(objective, gauss_newton),
                                    max_corrections=2 if ctx.dark is None else TRUNCATED_CORRECTIONS)
    hessian, hessian_kind, notes = _positive_definite(objective, hessian, gauss_newton)
    log_evidence, log_lik, log_prior = laplace_log_evidence(objective, z, hessian)
    draws = posterior_draws(objective, z, hessian, n_draws, seed)
    result = FitResult(effects=objective.effects, names=objective.names, priors=objective.priors, z=z,
                       hessian=hessian, log_evidence=log_evidence, log_lik=log_lik, log_prior=log_prior,
                       draws=draws.draws, draws_log_proposal=draws.log_proposal, draws_proposal=draws.note or "Laplace",
                       n_regions=ctx.n_regions,
                       seconds=round(time.perf_counter() - started, 3), hessian_kind=hessian_kind, notes=notes)
    result._cache["objective"] = objective
    return result


def predictions(fit: FitResult, draws=True):
    """Predicted means: at the MAP, or (S, N) over the draws."""
    objective = fit.objective
    if not draws:
        return objective.mean(fit.z)[0]
    return np.stack([objective.mean(d)[0] for d in fit.draws])


def posterior_mean_prediction(fit: FitResult):
    """E[mu] over the posterior draws (the fitted value the gap's residuals are taken from).

    Summed draw by draw: stacking the (S, N) predictions cost 1.1 GB per fit on the measured
    ball's 1.4 million observations."""
    def compute(fit):
        objective = fit.objective
        total = np.zeros_like(objective.mean(fit.z)[0])
        for draw in fit.draws:
            total += objective.mean(draw)[0]
        return total / len(fit.draws)
    return fit.cached("mean_prediction", compute)


def standardised_residuals(ctx, fit: FitResult):
    """``(y - E[mu]) / s_i``: the residuals of ``fit``'s posterior mean prediction on ``ctx`` (its
    context) in the units of the noise model (divided by its known scales; the plain residuals
    for 'constant' noise). With a camera response, on the linear scale at the MAP curve, in the
    data's units (:meth:`rjfit.diagnose.objective.RefitObjective.scaled_residuals`): the noise
    passes through the curve, so there it is the same everywhere."""
    if fit.objective.ctx is not ctx:
        raise ValueError("standardised_residuals: the fit was made on another context")
    return fit.objective.scaled_residuals(posterior_mean_prediction(fit), fit.effect_thetas())[0]


def template_columns(fit: FitResult, ctx, effect, eps=1e-4):
    """d predicted / d z_effect at the effect's init values, at the fit's parameters (N, k), in the
    units of :func:`standardised_residuals` of ``fit`` (divided by the noise model's scales; on the
    linear scale of ``fit``'s camera response where it has one)."""
    objective, z = objective_with(fit, ctx, effect)
    thetas = fit.effect_thetas()
    base = fit.objective.scaled_residuals(objective.mean(z)[0], thetas)[0]       # (y - mu) / s in those units
    start = 4 * ctx.n_regions + sum(objective.sizes[:objective.effects.index(effect)])
    columns = []
    for j in range(len(effect.params(ctx))):
        zz = z.copy()
        zz[start + j] += eps
        columns.append((base - fit.objective.scaled_residuals(objective.mean(zz)[0], thetas)[0]) / eps)
    return np.stack(columns, axis=1)


def objective_with(fit: FitResult, ctx, effect):
    """The objective of ``fit``'s model plus ``effect``, and the point of it at fit's parameters
    and effect's init: ``(RefitObjective, z)``."""
    objective = RefitObjective(ctx, tuple(fit.effects) + (effect,), ctx.features["region_priors"])
    z = np.zeros(objective.P)
    R = ctx.n_regions
    z[: 4 * R] = fit.z[: 4 * R]
    return objective, _place_effect_starts(objective, z, dict(zip(fit.effect_names, fit.effect_thetas())))


def moved_parameters(before, after):
    """The parameters whose MAP moved by more than 2 posterior sd (of ``after``) from ``before`` to
    ``after`` (two refits): ``(moved records, up to 8 (name, draws before or None, draws after) panels)``."""
    b_values = dict(zip(before.names, before.constrained()))
    b_draws = {n: d for n, d in zip(before.names, np.array([before.constrained(z) for z in before.draws]).T)}
    a_draws_all = np.array([after.constrained(z) for z in after.draws]).T
    moved, panels = [], []
    for name, value, draws in zip(after.names, after.constrained(), a_draws_all):
        sd = float(draws.std())
        if name not in b_values:
            panels.append((name, None, draws))
            continue
        if abs(value - b_values[name]) > 2.0 * max(sd, 1e-300):
            moved.append({"name": name, "before": float(b_values[name]), "after": float(value), "sd_after": sd})
            panels.append((name, b_draws[name], draws))
    return moved, panels[:8]
