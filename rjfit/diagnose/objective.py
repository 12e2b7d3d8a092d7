"""The objective of a criticism refit: one model (a set of effects) on one context.

Parameters (all unconstrained, see :mod:`rjfit.model.priors`): per region log I0, logit kd,
log gamma, log sigma^2, then each effect's parameters. The negative log posterior in those
coordinates

    f(z) = - sum_i log N(y_i | m_i(z), sigma^2_r(i) s_i^2) - sum_j log p_zj(z_j)

(``p_z`` includes the transforms' log-Jacobians; ``s_i`` are the known scales of the fit's
noise model, :mod:`rjfit.data.noise`, all 1 for the default 'constant'; for a coarsened fit
the sum of log N is weighted by the context's ``likelihood_power`` zeta, as the sampler
weighs it). With a camera response ``f`` in the model the noise is a sensor's, added before
the curve (:class:`rjfit.effects.base.CameraResponse`), and the likelihood is the fit's:
``f^-1(y_i) ~ N(m_i, sigma^2 G^2 s_i^2)`` times ``J_i = (f^-1)'(y_i)``, with ``m_i`` the mean on
the linear scale and ``G`` the geometric mean of the ``J_i``, so that sigma^2 stays a
variance on the data's scale (the standardised residual ``e_i = (f^-1(y_i) - m_i) / (G s_i)``,
and the log-Jacobian terms ``log J_i - log G`` sum to 0: the least squares on ``e`` are the
objective itself, the white level included). :class:`RefitObjective` evaluates it, its
least-squares residuals at fixed sigma^2 (the Gaussian priors are extra residual rows, so
their half sum of squares is f up to a constant), their Jacobian and normal equations, and
the closed-form sigma^2 update;

Where the data set declares a dark threshold t (:attr:`rjfit.diagnose.context.Context.dark`),
an observation was kept only because its value was above t, so the likelihood of a kept
observation is the truncated normal, its density over P(y_i > t) = Phi((m_i - f^-1(t)) /
(sigma G s_i)) on the linear scale (t itself without a camera response). Without it the
kept observations whose mean is within a few sd of t are an upward-biased sample that an
effect raising the dim end (ambient light, the sRGB curve's toe) absorbs: on a power-law
camera stack with its negative sums clipped and declared dark, ambient + sRGB won over the
true power law by log BF 161, and lost by 87 with the truncation
(docs/results/2026-11-28-loop-seeds.md). The term is exact for one channel or equal ones;
``dark`` flags an observation only when every channel is at or below t. The least squares
leave it out (it is no square); the Newton corrections of the MAP and the Laplace Hessian,
which difference f, carry it.
:mod:`rjfit.diagnose.optimise` minimises it, :mod:`rjfit.diagnose.hessian` differences it.
"""
from __future__ import annotations

import math

import numpy as np

from scipy.special import log_ndtr

from rjfit.diagnose.model import order_effects, predict
from rjfit.model.priors import Normal

__all__ = ["RefitObjective", "AtLightValues", "LOG_2PI"]

LOG_2PI = math.log(2.0 * math.pi)


class RefitObjective:
    """The negative log posterior of one model (a set of effects) on one context, in the
    unconstrained coordinates z (module docstring), with what minimising it needs.

    Not :class:`rjfit.sampler.likelihood.Problem`: that is the sampler's data container
    (observations sorted by pixel, compact, with sufficient statistics linear in each
    region's (a, b) for any segmentation the sampler proposes). This is a function of z on a
    FIXED segmentation and an extended model (effects that are not linear in anything), with
    the residuals, Jacobians and sigma^2 updates of the criticism's MAP search and Laplace
    approximation.
    """

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
        self.log_norm = float(-np.sum(np.log(self.scale)) - 0.5 * self.P * LOG_2PI)
        self.zeta = float(ctx.likelihood_power)
        # the fit's noise model: residuals are standardised by its known scales s_i as well
        self.log_scale2 = None if ctx.noise_scale is None else 2.0 * np.log(ctx.noise_scale)
        self.region_rows = [np.flatnonzero(ctx.region == r) for r in range(R)]     # observations of each region
        # Every observation has one region: unless an effect couples regions, a parameter of one
        # region never meets another region's in a term (Hessian pairs, Jacobian columns)
        self.region_local = all(getattr(effect, "region_local", True) for effect in self.effects)
        self.owner = np.full(self.P, -1)            # the region of each parameter, -1: an effect's (shared)
        self.owner[: 4 * R] = np.arange(4 * R) // 4
        # the camera response, whose curve the noise passes through (a fit takes one; None: linear)
        self.camera = next((position for position, effect in enumerate(self.effects) if effect.stage == "camera"), None)

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
            effects[position], thetas[position] = AtLightValues(effects[position]), values
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

    def scaled_residuals(self, mu, thetas, values=None):
        """``(e_i, log J_i - log G or None)`` of predictions ``mu`` at effect parameters ``thetas`` (those
        of :meth:`split`): ``e = (y - mu) / s_i``, the residuals in units of the noise model's scales;
        with a camera response, on the linear scale (module docstring). ``values`` in place of the
        data ``y`` in ``e`` (G stays the data's)."""
        values = self.ctx.y if values is None else values
        if self.camera is None:
            return self.ctx.standardise(values - mu), None
        camera, theta, white = self.effects[self.camera], thetas[self.camera], self.features[self.camera]
        log_slope = camera.inverse_log_slope(self.ctx.y, theta, white)
        log_mean_slope = float(np.mean(log_slope))
        linear = camera.inverse(values, theta, white) - camera.inverse(mu, theta, white)
        return self.ctx.standardise(linear * math.exp(-log_mean_slope)), log_slope - log_mean_slope

    def residuals(self, z, light_values=None):
        """``(e, log J - log G or None, region parameters)`` at ``z`` (:meth:`scaled_residuals` of :meth:`mean`)."""
        mu, region = self.mean(z, light_values)
        e, log_jacobian = self.scaled_residuals(mu, self.split(z)[1])
        return e, log_jacobian, region

    def log_lik_pointwise(self, z, light_values=None):
        """log N(y_i | mu_i, sigma^2 s_i^2) per observation (with a camera response, the density of y_i
        on the linear scale: module docstring); ``light_values`` {effect position: (L,) values} as in
        :meth:`mean`."""
        mu, region = self.mean(z, light_values)
        thetas = self.split(z)[1]
        e, log_jacobian = self.scaled_residuals(mu, thetas)
        s2 = region[self.ctx.region, 3]
        values = -0.5 * (LOG_2PI + np.log(s2) + e ** 2 / s2)
        if log_jacobian is not None:
            values = values + log_jacobian
        if self.ctx.dark is not None:
            # the truncation at the dark threshold: minus log P(kept) = log Phi(-(t - m) / sd)
            threshold = self.scaled_residuals(mu, thetas, np.full_like(self.ctx.y, self.ctx.dark))[0]
            values = values - log_ndtr(-threshold / np.sqrt(s2))
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
        e, _, region = self.residuals(z, light_values)
        # zeta sum r^2 / 2 sigma^2 = sum (sqrt(zeta) r)^2 / 2 sigma^2
        r = e * np.sqrt(self.zeta / region[self.ctx.region, 3])
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
        resid2 = self.residuals(z)[0] ** 2
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


class AtLightValues:
    """A per-light effect applied at given light values instead of at its parameters
    (``Effect.light_basis``): what :meth:`RefitObjective.mean` puts in its place."""

    def __init__(self, effect):
        self.effect, self.stage = effect, effect.stage

    def apply(self, terms, values, features, ctx):
        self.effect.apply_light_values(terms, values, ctx)
