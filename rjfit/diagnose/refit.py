"""Refit on a fixed segmentation: MAP, Laplace approximation, evidence, draws, PSIS-LOO.

Parameters (all unconstrained, see ``priors``): per region log I0, logit kd, log gamma,
log sigma^2, then each effect's parameters. The negative log posterior in those coordinates

    f(z) = - sum_i log N(y_i | m_i(z), sigma^2_r(i) s_i^2) - sum_j log p_zj(z_j)

(``p_z`` includes the transforms' log-Jacobians; ``s_i`` are the known scales of the fit's
noise model, :mod:`rjfit.data.noise`, all 1 for the default 'constant'; for a coarsened fit the sum of log N is
weighted by the context's ``likelihood_power`` zeta, as the sampler weighs it) is minimised by alternating a Levenberg-Marquardt
least-squares solve for the mean parameters (:func:`levenberg_marquardt`; the Gaussian priors are
extra residual rows, so the objective is exactly f at fixed sigma^2) with the closed-form
update of each region's log sigma^2, then one Newton correction with a finite-difference
Hessian. The Laplace approximation at the MAP z* with that Hessian H gives

    log Z = -f(z*) + d/2 log 2 pi - 1/2 log det H,

the marginal likelihood whose differences are log Bayes factors (they penalise extra
parameters through the Occam factor of their prior and posterior widths), and posterior
draws z ~ N(z*, H^-1) (seeded). PSIS-LOO (:mod:`rjfit.diagnose.psis`) on the pointwise log-likelihood of those
draws is the second opinion; its Pareto k-hat says where the draws are a poor proposal.
Region priors (shared by every model of a context, so they cancel in Bayes factors):
log I0 ~ N(log I0_init, 2^2) (empirical centre: the initial linear fit's median I0),
logit kd ~ N(0, 2^2), log gamma ~ N(log 10, 1.5^2), log sigma^2 ~ N(log s2_init, 2^2).
"""
from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from rjfit.diagnose.model import order_effects, predict
from rjfit.diagnose.priors import LogitNormal, LogNormal, Normal
from rjfit.diagnose.psis import psis_loo as vectorised_psis_loo
from rjfit.model.blinn import blinn_normalisation, log_cos_power

__all__ = ["FitResult", "refit", "initial_region_params", "region_priors"]

_LOG_2PI = math.log(2.0 * math.pi)


def initial_region_params(ctx):
    """Per region (I0, kd, gamma, sigma2) from linear least squares on a gamma grid (weighted
    by the noise model's scales: dividing y and the design by s_i)."""
    out = np.zeros((ctx.n_regions, 4))
    y_all = ctx.standardise(ctx.y)
    base_all = ctx.standardise(ctx.irradiance * np.maximum(ctx.cos_ln, 0.0))
    for r in range(ctx.n_regions):
        sel = ctx.region == r
        y, base = y_all[sel], base_all[sel]
        best = None
        for gamma in (1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0, 128.0):
            design = np.stack([base / np.pi, base * blinn_normalisation(gamma) * log_cos_power(ctx.cos_hn[sel], gamma)], 1)
            coef, *_ = np.linalg.lstsq(design, y, rcond=None)
            coef = np.maximum(coef, 1e-3 * max(abs(coef).max(), 1e-9))
            ss = float(np.sum((y - design @ coef) ** 2))
            if best is None or ss < best[0]:
                best = (ss, coef, gamma)
        ss, (a_d, a_s), gamma = best
        I0 = a_d + a_s
        out[r] = (I0, np.clip(a_d / I0, 0.02, 0.98), gamma, max(ss / max(sel.sum(), 1), 1e-8))
    return out


def region_priors(init):
    I0_centre = float(np.median(init[:, 0]))
    s2_centre = float(np.median(init[:, 3]))
    return [LogNormal(math.log(I0_centre), 2.0), LogitNormal(0.0, 2.0), LogNormal(math.log(10.0), 1.5),
            LogNormal(math.log(s2_centre), 2.0)]


@dataclass
class FitResult:
    effects: tuple
    names: list
    priors: list
    z: np.ndarray
    hessian: np.ndarray
    log_evidence: float
    log_lik: float
    log_prior: float
    draws: np.ndarray                # (S, P) unconstrained
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

    def constrained(self, z=None):
        z = self.z if z is None else z
        return np.array([p.to_constrained(v) for p, v in zip(self.priors, z)], dtype=float)

    def region_params(self, z=None):
        """(R, 4) constrained I0, kd, gamma, sigma2."""
        return self.constrained(z)[: 4 * self.n_regions].reshape(self.n_regions, 4)

    def effect_thetas(self, z=None):
        values = self.constrained(z)[4 * self.n_regions:]
        out, start = [], 0
        for size in self._cache["sizes"]:
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


class _Problem:
    """The objective of one model (a set of effects) on one context."""

    def __init__(self, ctx, effects, priors_region):
        self.ctx = ctx
        self.effects = order_effects(effects)
        self.features = []
        params = []
        for effect in self.effects:
            self.features.append(effect.prepare(ctx))
            params.append(effect.params(ctx))
        self.effect_params = params
        self.sizes = [len(p) for p in params]
        R = ctx.n_regions
        self.names = [f"{n}[{r}]" for r in range(R) for n in ("I0", "kd", "gamma", "sigma2")]
        self.priors = [priors_region[k] for r in range(R) for k in range(4)]
        for effect, plist in zip(self.effects, params):
            self.names += [f"{effect.name}.{p.name}" for p in plist]
            self.priors += [p.prior for p in plist]
        self.P = len(self.priors)
        self.sigma_index = np.array([4 * r + 3 for r in range(R)])
        self.mean_index = np.array([i for i in range(self.P) if i not in set(self.sigma_index)])
        self.loc = np.array([p.loc for p in self.priors])
        self.scale = np.array([p.scale for p in self.priors])
        self.log_norm = float(-np.sum(np.log(self.scale)) - 0.5 * self.P * _LOG_2PI)
        self.zeta = float(ctx.likelihood_power)
        # the fit's noise model: residuals are standardised by its known scales s_i as well
        self.log_scale2 = None if ctx.noise_scale is None else 2.0 * np.log(ctx.noise_scale)
        self.region_rows = [np.flatnonzero(ctx.region == r) for r in range(R)]     # observations of each region
        # Every observation has one region: unless an effect couples regions, a parameter of one
        # region never meets another region's in a term (Hessian pairs, Jacobian columns)
        self.region_local = all(getattr(effect, "region_local", True) for effect in self.effects)
        self.owner = np.full(self.P, -1)            # the region of each parameter, -1: an effect's (shared)
        self.owner[: 4 * R] = np.arange(4 * R) // 4

    def split(self, z):
        theta = np.array([p.to_constrained(v) for p, v in zip(self.priors, z)], dtype=float)
        R = self.ctx.n_regions
        region = theta[: 4 * R].reshape(R, 4)
        thetas, start = [], 4 * R
        for size in self.sizes:
            thetas.append(theta[start:start + size])
            start += size
        return region, thetas

    def mean(self, z, light_values=None):
        """``(mu, region parameters)`` at ``z``; ``light_values`` {effect position: (L,) values}
        evaluates those per-light effects at the given values instead of at their parameters in
        ``z`` (``Effect.light_basis``: the coordinates of the Hessian and the Jacobian)."""
        region, thetas = self.split(z)
        effects = list(self.effects)
        for position, values in (light_values or {}).items():
            effects[position], thetas[position] = _AtLightValues(effects[position]), values
        return predict(self.ctx, effects, region, thetas, self.features), region

    def per_light_effects(self):
        """{effect position: (its indices in z, its light basis B (L, k))} of the per-light effects."""
        out, offset = {}, 4 * self.ctx.n_regions
        for position, (effect, size) in enumerate(zip(self.effects, self.sizes)):
            if effect.light_basis is not None and size:
                if not all(isinstance(prior, Normal) for prior in self.priors[offset:offset + size]):
                    raise TypeError(f"{effect.name}: a per-light effect's priors must be Normal (its values are "
                                    f"linear in z); see Effect.light_basis")
                out[position] = (np.arange(offset, offset + size), np.asarray(effect.light_basis(self.ctx), float))
            offset += size
        return out

    def scaled_residuals(self, mu):
        """``(y - mu) / s_i``: the residuals in units of the noise model's scales."""
        return self.ctx.standardise(self.ctx.y - mu)

    def log_lik_pointwise(self, z, light_values=None):
        """log N(y_i | mu_i, sigma^2 s_i^2) per observation; ``light_values`` {effect position:
        (L,) values} as in :meth:`mean`."""
        mu, region = self.mean(z, light_values)
        s2 = region[self.ctx.region, 3]
        values = -0.5 * (_LOG_2PI + np.log(s2) + self.scaled_residuals(mu) ** 2 / s2)
        return values if self.log_scale2 is None else values - 0.5 * self.log_scale2

    def log_prior(self, z):
        return float(-0.5 * np.sum(((z - self.loc) / self.scale) ** 2) + self.log_norm)

    def log_lik(self, z):
        """The log-likelihood the objective weighs: zeta times the sum of the pointwise terms."""
        return self.zeta * float(np.sum(self.log_lik_pointwise(z)))

    def f(self, z):
        value = -self.log_lik(z) - self.log_prior(z)
        return value if np.isfinite(value) else 1e300

    def mean_residuals(self, zm, z_full, light_values=None):
        z = z_full.copy()
        z[self.mean_index] = zm
        mu, region = self.mean(z, light_values)
        # zeta sum r^2 / 2 sigma^2 = sum (sqrt(zeta) r)^2 / 2 sigma^2
        r = self.scaled_residuals(mu) * np.sqrt(self.zeta / region[self.ctx.region, 3])
        prior = (zm - self.loc[self.mean_index]) / self.scale[self.mean_index]
        out = np.concatenate([r, prior])
        return np.where(np.isfinite(out), out, 1e10)

    def jacobian_groups(self):
        """The mean parameters (positions in ``mean_index``) whose residual columns one evaluation
        can difference together: the same parameter of every region (their rows never overlap:
        each observation has one region, each prior row one parameter), each effect's alone.
        A per-light effect's parameters are left out: :meth:`mean_jacobian` differences its
        light values instead."""
        per_light = {int(i) for index, _ in self.per_light_effects().values() for i in index}
        R = self.ctx.n_regions
        shared = [[position] for position in range(3 * R, self.mean_index.size)
                  if int(self.mean_index[position]) not in per_light]
        if not self.region_local:
            return [[position] for position in range(3 * R)] + shared
        return [[3 * r + k for r in range(R)] for k in range(3)] + shared     # I0, kd, gamma of each region

    def jacobian_parts(self, zm, z_full, r0=None):
        """Forward differences of :meth:`mean_residuals` at ``zm``, in parts: ``(r0, dense, columns,
        per_light)``. ``dense`` (N + M, len(columns)) holds the Jacobian's ``columns`` (every mean
        parameter but the per-light effects'), one evaluation per :meth:`jacobian_groups`
        group instead of one per parameter; steps as scipy's ``'2-point'`` (sqrt(eps) max(1,
        |z|), with z's sign). ``per_light`` lists, per per-light effect, ``(its columns, d, B)``:
        one evaluation with every light's value u_l moved gives each observation's derivative
        ``d_i`` by its own light's value (rows of two lights never overlap), so its columns are
        ``d_i B[light_i]`` by the chain rule (u = B theta), and its prior rows ``1 / scale``.
        ``r0``: the residuals at ``zm`` where the caller has them (the least squares do)."""
        r0 = self.mean_residuals(zm, z_full) if r0 is None else r0
        n_obs = self.ctx.n_obs
        groups = self.jacobian_groups()
        columns = np.array(sorted(position for group in groups for position in group), dtype=int)
        local = {int(position): k for k, position in enumerate(columns)}
        dense = np.zeros((r0.size, columns.size))
        steps = math.sqrt(np.finfo(float).eps) * np.where(zm >= 0, 1.0, -1.0) * np.maximum(1.0, np.abs(zm))
        for group in groups:
            shifted = zm.copy()
            shifted[group] += steps[group]
            change = self.mean_residuals(shifted, z_full) - r0
            for position in group:
                dx = shifted[position] - zm[position]
                if len(group) == 1:
                    dense[:, local[position]] = change / dx
                    continue
                rows = self.region_rows[self.owner[self.mean_index[position]]]
                dense[rows, local[position]] = change[rows] / dx
                dense[n_obs + position, local[position]] = change[n_obs + position] / dx    # its prior row
        position_of = {int(index): position for position, index in enumerate(self.mean_index)}
        z = z_full.copy()
        z[self.mean_index] = zm
        per_light = []
        for effect_position, (index, basis) in self.per_light_effects().items():
            values = basis @ z[index]
            step = math.sqrt(np.finfo(float).eps) * max(1.0, float(np.abs(values).max()))
            change = self.mean_residuals(zm, z_full, {effect_position: values + step})[:n_obs] - r0[:n_obs]
            per_light.append((np.array([position_of[int(i)] for i in index]), change / step, basis))
        return r0, dense, columns, per_light

    def mean_jacobian(self, zm, z_full):
        """The whole forward-difference Jacobian of :meth:`mean_residuals` (dense, (N + M, M)),
        assembled from :meth:`jacobian_parts` (the reference of :meth:`mean_normal_equations`)."""
        r0, dense, columns, per_light = self.jacobian_parts(zm, z_full)
        n_obs = self.ctx.n_obs
        jacobian = np.zeros((r0.size, zm.size))
        jacobian[:, columns] = dense
        for light_columns, derivative, basis in per_light:
            jacobian[:n_obs, light_columns] = derivative[:, None] * basis[self.ctx.light]
            jacobian[n_obs + light_columns, light_columns] = 1.0 / self.scale[self.mean_index[light_columns]]
        return jacobian

    def mean_normal_equations(self, zm, residuals, z_full):
        """``(J'J, J'r)`` of :meth:`mean_jacobian` at ``zm`` with ``residuals`` r, without forming
        a per-light effect's N x (L - 1) columns: their products go through per-light sums
        (``J_u' J_u`` is diagonal in the lights), so a light calibration of 96 lights adds
        96-entry sums, not 95 dense columns, to each step."""
        _, dense, columns, per_light = self.jacobian_parts(zm, z_full, residuals)
        n_obs, n_lights = self.ctx.n_obs, self.ctx.n_lights
        light = self.ctx.light
        normal = np.zeros((zm.size, zm.size))
        gradient = np.zeros(zm.size)
        normal[np.ix_(columns, columns)] = dense.T @ dense
        gradient[columns] = dense.T @ residuals
        for first, (columns_a, derivative_a, basis_a) in enumerate(per_light):
            # with the dense columns: sum over lights of B[l] times the light's sum of d_i J_i
            sums = np.stack([np.bincount(light, weights=derivative_a * dense[:n_obs, k], minlength=n_lights)
                             for k in range(columns.size)], axis=1)
            cross = basis_a.T @ sums
            normal[np.ix_(columns_a, columns)] += cross
            normal[np.ix_(columns, columns_a)] += cross.T
            for columns_b, derivative_b, basis_b in per_light[first:]:
                per_light_products = np.bincount(light, weights=derivative_a * derivative_b, minlength=n_lights)
                block = basis_a.T @ (per_light_products[:, None] * basis_b)
                normal[np.ix_(columns_a, columns_b)] += block
                if columns_b is not columns_a:
                    normal[np.ix_(columns_b, columns_a)] += block.T
            prior_scale = self.scale[self.mean_index[columns_a]]
            normal[columns_a, columns_a] += 1.0 / prior_scale ** 2
            gradient[columns_a] += (basis_a.T @ np.bincount(light, weights=derivative_a * residuals[:n_obs],
                                                             minlength=n_lights)
                                    + residuals[n_obs + columns_a] / prior_scale)
        return normal, gradient

    def update_sigma(self, z):
        mu, _ = self.mean(z)
        resid2 = self.scaled_residuals(mu) ** 2
        for r, index in enumerate(self.sigma_index):
            rows = self.region_rows[r]
            n, ss = self.zeta * float(rows.size), self.zeta * float(resid2[rows].sum())
            m, v = self.loc[index], self.scale[index] ** 2
            s = math.log(max(ss / max(n, 1.0), 1e-12))
            for _ in range(20):   # Newton on n/2 s + ss/2 e^-s + (s - m)^2 / 2v
                grad = 0.5 * n - 0.5 * ss * math.exp(-s) + (s - m) / v
                hess = 0.5 * ss * math.exp(-s) + 1.0 / v
                step = grad / hess
                s -= step
                if abs(step) < 1e-10:
                    break
            z[index] = s
        return z


class _AtLightValues:
    """A per-light effect applied at given light values instead of at its parameters."""

    def __init__(self, effect):
        self.effect, self.stage = effect, effect.stage

    def apply(self, terms, values, features, ctx):
        self.effect.apply_light_values(terms, values, ctx)


def _hessian(problem, z, steps):
    """Finite-difference Hessian and gradient of ``problem.f`` at ``z``, and ``f(z)``:
    :func:`_block_hessian` where every effect is region-local, else :func:`_fd_hessian`."""
    if problem.region_local:
        return _block_hessian(problem, z, steps)
    return _fd_hessian(problem.f, z, steps, coupled_pairs(problem))


def _block_hessian(problem, z, steps):
    """The central-difference Hessian of :func:`_fd_hessian`, from a few evaluations summed per
    (region, light) block of observations instead of one evaluation per pair.

    An observation's term depends on its region's parameters, on the value of each per-light
    effect at its light (``Effect.light_basis``: the Hessian is taken over the L light values
    u = B theta and mapped back, H_z = B^T H_u B, exact for the linear map) and on the shared
    parameters of the other effects. So the parameters fall into types, each touching every
    block through at most one of its members: one type per region parameter (I0 of every
    region, ...), one per per-light effect (its L values), one per shared parameter. Perturbing
    two whole types at once, each block's four-point difference is the cross derivative of
    the pair that touches it (pairs that never meet in a block are 0, as in
    :func:`coupled_pairs`): 1 + 2 T + 2 T (T - 1) evaluations for T types, against one per
    parameter pair (a light calibration of 96 lights on the DiLiGenT ball: 22,706 evaluations
    of f before). The block sums difference fewer terms than f's total, so they carry less
    rounding. The prior is Gaussian in z: its Hessian and gradient are added in closed form.
    """
    ctx = problem.ctx
    n_regions, n_lights = ctx.n_regions, ctx.n_lights
    n_blocks = n_regions * n_lights
    block = np.asarray(ctx.region, dtype=np.int64) * n_lights + np.asarray(ctx.light, dtype=np.int64)
    block_region, block_light = np.divmod(np.arange(n_blocks), n_lights)
    # the coordinates w: z's entries, with each per-light effect's parameters replaced by its L values
    per_light = problem.per_light_effects()
    in_light = np.zeros(problem.P, bool)
    for index, _ in per_light.values():
        in_light[index] = True
    plain = np.flatnonzero(~in_light)
    n_w = plain.size + n_lights * len(per_light)
    to_w = np.zeros((n_w, problem.P))             # dw = to_w dz
    to_w[np.arange(plain.size), plain] = 1.0
    w_steps = np.empty(n_w)
    w_steps[: plain.size] = steps[plain]
    types = []                                    # per type: the w entry touching each block
    where = {int(i): k for k, i in enumerate(plain)}
    for kind in range(4):
        types.append(np.array([where[4 * r + kind] for r in block_region]))
    for i in plain[plain >= 4 * n_regions]:
        types.append(np.full(n_blocks, where[int(i)]))
    light_w = {}
    for number, (position, (index, basis)) in enumerate(per_light.items()):
        first = plain.size + number * n_lights
        to_w[first:first + n_lights, index] = basis
        w_steps[first:first + n_lights] = steps[index].min()
        light_w[position] = (first, basis @ z[index])
        types.append(first + block_light)

    def blocks(delta):
        z_at = z.copy()
        z_at[plain] += delta[: plain.size]
        values = {position: u + delta[first:first + n_lights] for position, (first, u) in light_w.items()}
        terms = problem.log_lik_pointwise(z_at, values)
        return -problem.zeta * np.bincount(block, weights=terms, minlength=n_blocks)

    def shift(kind):
        delta = np.zeros(n_w)
        delta[types[kind]] = w_steps[types[kind]]
        return delta

    H = np.zeros((n_w, n_w))
    gradient = np.zeros(n_w)
    centre = blocks(np.zeros(n_w))
    for kind, owner in enumerate(types):
        up, down = blocks(shift(kind)), blocks(-shift(kind))
        h = w_steps[owner]
        np.add.at(H, (owner, owner), (up - 2.0 * centre + down) / h ** 2)
        np.add.at(gradient, owner, (up - down) / (2.0 * h))
    for first in range(len(types)):
        for second in range(first + 1, len(types)):
            a, b = shift(first), shift(second)
            difference = blocks(a + b) - blocks(a - b) - blocks(b - a) + blocks(-a - b)
            o1, o2 = types[first], types[second]
            values = difference / (4.0 * w_steps[o1] * w_steps[o2])
            np.add.at(H, (o1, o2), values)
            np.add.at(H, (o2, o1), values)
    prior_precision = 1.0 / problem.scale ** 2
    H_z = to_w.T @ H @ to_w + np.diag(prior_precision)
    gradient_z = to_w.T @ gradient + (z - problem.loc) * prior_precision
    return H_z, gradient_z, problem.f(z)


def coupled_pairs(problem) -> np.ndarray:
    """(P, P) bool: which second derivatives of ``problem``'s objective can be non-zero.

    Every observation belongs to one region and the priors are independent, so two
    parameters of different regions never meet in one term, unless an effect couples
    regions (``Effect.region_local`` False): then every pair may.
    """
    if not problem.region_local:
        return np.ones((problem.P, problem.P), bool)
    owner = problem.owner
    shared = owner < 0
    return (owner[:, None] == owner[None, :]) | shared[:, None] | shared[None, :]


def _fd_hessian(f, z, steps, coupled=None):
    """Central finite-difference Hessian of ``f`` at ``z`` and gradient; pairs where
    ``coupled`` is False are structurally 0 and not evaluated (4 calls of f each saved)."""
    P = z.size
    f0 = f(z)
    H = np.zeros((P, P))
    fp = np.empty(P)
    fm = np.empty(P)
    for i in range(P):
        e = np.zeros(P)
        e[i] = steps[i]
        fp[i], fm[i] = f(z + e), f(z - e)
        H[i, i] = (fp[i] - 2 * f0 + fm[i]) / steps[i] ** 2
    for i in range(P):
        for j in range(i + 1, P):
            if coupled is not None and not coupled[i, j]:
                continue
            ei = np.zeros(P)
            ej = np.zeros(P)
            ei[i] = steps[i]
            ej[j] = steps[j]
            value = (f(z + ei + ej) - f(z + ei - ej) - f(z - ei + ej) + f(z - ei - ej)) / (4 * steps[i] * steps[j])
            H[i, j] = H[j, i] = value
    gradient = (fp - fm) / (2 * steps)
    return H, gradient, f0


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


def refit(ctx, effects=(), *, start=None, seed=0, n_draws=100, max_outer=6, tol=1e-3) -> FitResult:
    """Fit region parameters and effect parameters on ``ctx``'s fixed segmentation.

    Parameters
    ----------
    effects : sequence of Effect
    start : FitResult, optional
        Warm start: region parameters and shared effects' parameters from a previous fit;
        new effects start at their ``init`` values.
    n_draws : int
        Posterior draws from the Laplace approximation (seeded by ``seed``).
    """
    started = time.perf_counter()
    if "region_priors" not in ctx.features:
        init = initial_region_params(ctx)
        ctx.features["region_init"] = init
        ctx.features["region_priors"] = region_priors(init)
    problem = _Problem(ctx, effects, ctx.features["region_priors"])
    z = np.zeros(problem.P)
    R = ctx.n_regions
    region0 = ctx.features["region_init"] if start is None else start.region_params()
    for r in range(R):
        for k in range(4):
            z[4 * r + k] = problem.priors[4 * r + k].to_unconstrained(region0[r, k])
    offset = 4 * R
    previous = {}
    if start is not None:
        for effect, theta in zip(start.effects, start.effect_thetas()):
            previous[effect.name] = theta
    for effect, plist in zip(problem.effects, problem.effect_params):
        for j, p in enumerate(plist):
            value = previous[effect.name][j] if effect.name in previous else p.init
            z[offset + j] = p.prior.to_unconstrained(value)
        offset += len(plist)
    z = problem.update_sigma(z)
    f_old = problem.f(z)
    notes = []
    for _ in range(max_outer):
        z[problem.mean_index], gn = levenberg_marquardt(problem.mean_residuals, problem.mean_normal_equations,
                                                        z[problem.mean_index], args=(z,))
        z = problem.update_sigma(z)
        f_new = problem.f(z)
        if abs(f_old - f_new) < tol:
            f_old = f_new
            break
        f_old = f_new
    # Step sizes for the Hessian from the Gauss-Newton curvature of the last solve.
    sd = np.empty(problem.P)
    sd[problem.mean_index] = 1.0 / np.sqrt(np.maximum(np.diag(gn), 1e-12))
    for r, index in enumerate(problem.sigma_index):
        sd[index] = math.sqrt(2.0 / max(problem.zeta * float(problem.region_rows[r].size), 1.0))
    steps = np.minimum(0.05 * sd, 0.05)
    H, g, f0 = _hessian(problem, z, steps)
    hessian_kind = "finite differences"
    for _ in range(2):   # Newton corrections while they help
        try:
            step = np.linalg.solve(H, g)
        except np.linalg.LinAlgError:
            break
        if not np.all(np.isfinite(step)) or float(g @ step) < 1e-6:
            break
        candidate = z - step
        if problem.f(candidate) < f0:
            z = candidate
            H, g, f0 = _hessian(problem, z, steps)
        else:
            break
    eigenvalues = np.linalg.eigvalsh(0.5 * (H + H.T))
    if eigenvalues.min() <= 0:
        notes.append("finite-difference Hessian not positive definite; Gauss-Newton curvature used")
        hessian_kind = "Gauss-Newton"
        Hgn = np.zeros((problem.P, problem.P))
        mi = problem.mean_index
        Hgn[np.ix_(mi, mi)] = gn
        for r, index in enumerate(problem.sigma_index):
            Hgn[index, index] = 0.5 * problem.zeta * float(problem.region_rows[r].size) + 1.0 / problem.scale[index] ** 2
        H = Hgn
    H = 0.5 * (H + H.T)
    sign, logdet = np.linalg.slogdet(H)
    log_lik = problem.log_lik(z)
    log_prior = problem.log_prior(z)
    log_evidence = log_lik + log_prior + 0.5 * problem.P * _LOG_2PI - 0.5 * logdet
    rng = np.random.default_rng(seed)
    cov = np.linalg.inv(H)
    chol = np.linalg.cholesky(0.5 * (cov + cov.T))
    draws = z + rng.standard_normal((n_draws, problem.P)) @ chol.T
    result = FitResult(effects=problem.effects, names=problem.names, priors=problem.priors, z=z, hessian=H,
                       log_evidence=float(log_evidence), log_lik=log_lik, log_prior=log_prior, draws=draws,
                       n_regions=R, seconds=round(time.perf_counter() - started, 3), hessian_kind=hessian_kind,
                       notes=notes)
    result._cache["sizes"] = problem.sizes
    result._cache["problem"] = problem
    return result


def predictions(fit: FitResult, draws=True):
    """Predicted means: at the MAP, or (S, N) over the draws."""
    problem = fit._cache["problem"]
    if not draws:
        return problem.mean(fit.z)[0]
    return np.stack([problem.mean(d)[0] for d in fit.draws])


def _cached(fit: FitResult, key, compute):
    """``fit._cache[key]``, computed once by ``compute(fit)`` even when several threads ask at
    once (the diagnosis' candidate refits all ask for the current model's LOO)."""
    lock = fit._cache.setdefault("lock", threading.Lock())        # setdefault is atomic
    with lock:
        if key not in fit._cache:
            fit._cache[key] = compute(fit)
    return fit._cache[key]


def posterior_mean_prediction(fit: FitResult):
    """E[mu] over the posterior draws (the fitted value the gap's residuals are taken from).

    Summed draw by draw: stacking the (S, N) predictions cost 1.1 GB per fit on the measured
    ball's 1.4 million observations."""
    def compute(fit):
        problem = fit._cache["problem"]
        total = np.zeros_like(problem.mean(fit.z)[0])
        for draw in fit.draws:
            total += problem.mean(draw)[0]
        return total / len(fit.draws)
    return _cached(fit, "mean_prediction", compute)


def pointwise_log_lik(fit: FitResult):
    """(S, N) log-likelihood of every observation under every draw (not cached: S N floats)."""
    problem = fit._cache["problem"]
    return np.stack([problem.log_lik_pointwise(d) for d in fit.draws])


def psis_loo(fit: FitResult):
    """PSIS-LOO on the Laplace draws: a :class:`rjfit.diagnose.psis.LooResult` (elpd, se,
    pointwise elpd, pointwise k-hat).

    :func:`rjfit.diagnose.psis.psis_loo` (ArviZ's estimator, vectorised); a coarsened refit's
    draws leave an observation out with its likelihood to the refit's power. Only the result
    is kept: the (S, N) pointwise log-likelihood it is computed from is dropped at once, so a
    diagnosis holds one such array per candidate refitting at that moment, not one per fit.
    """
    return _cached(fit, "loo", lambda fit: vectorised_psis_loo(pointwise_log_lik(fit),
                                                               likelihood_power=fit._cache["problem"].zeta))


def evidence_by_importance_sampling(fit: FitResult, n_draws=2000, seed=0, inflate=1.2):
    """Check of the Laplace evidence: importance sampling from the Laplace Gaussian (covariance
    inflated by ``inflate^2`` for heavier coverage), log Z = log mean p(y, z) / q(z).

    Returns ``(log_Z_is, its Monte Carlo standard error in log units, effective sample size)``.
    Agreement with ``fit.log_evidence`` to a fraction of a nat says the Laplace approximation
    is adequate for Bayes factors of this model.
    """
    problem = fit._cache["problem"]
    rng = np.random.default_rng(seed)
    cov = np.linalg.inv(fit.hessian) * inflate ** 2
    chol = np.linalg.cholesky(0.5 * (cov + cov.T))
    eps = rng.standard_normal((n_draws, fit.z.size))
    z = fit.z + eps @ chol.T
    log_q = (-0.5 * np.sum(eps ** 2, axis=1) - np.sum(np.log(np.diag(chol))) - 0.5 * fit.z.size * _LOG_2PI)
    log_joint = np.array([-problem.f(zz) for zz in z])
    log_w = log_joint - log_q
    top = log_w.max()
    w = np.exp(log_w - top)
    log_z = float(top + np.log(w.mean()))
    ess = float(w.sum() ** 2 / np.sum(w ** 2))
    se = float(w.std() / (w.mean() * math.sqrt(n_draws)))
    return log_z, se, ess


def template_columns(fit: FitResult, ctx, effect, eps=1e-4):
    """d predicted / d z_effect at the effect's init values, at the fit's parameters (N, k)."""
    augmented = refit_problem_with(fit, ctx, effect)
    problem, z = augmented
    base = problem.mean(z)[0]
    start = 4 * ctx.n_regions + sum(problem.sizes[:problem.effects.index(effect)])
    columns = []
    for j in range(len(effect.params(ctx))):
        zz = z.copy()
        zz[start + j] += eps
        columns.append((problem.mean(zz)[0] - base) / eps)
    return np.stack(columns, axis=1)


def refit_problem_with(fit: FitResult, ctx, effect):
    """The objective of ``fit``'s model plus ``effect``, at fit's parameters and effect's init."""
    problem = _Problem(ctx, tuple(fit.effects) + (effect,), ctx.features["region_priors"])
    z = np.zeros(problem.P)
    R = ctx.n_regions
    z[: 4 * R] = fit.z[: 4 * R]
    previous = dict(zip([e.name for e in fit.effects], fit.effect_thetas()))
    offset = 4 * R
    for eff, plist in zip(problem.effects, problem.effect_params):
        for j, p in enumerate(plist):
            value = previous[eff.name][j] if eff.name in previous else p.init
            z[offset + j] = p.prior.to_unconstrained(value)
        offset += len(plist)
    return problem, z
