"""Hessians of a refit's objective (:class:`rjfit.diagnose.objective.RefitObjective`) at its MAP:
the curvature the Laplace evidence and the posterior draws rest on.

:func:`objective_hessian` picks the cheapest exact scheme: :func:`block_hessian` (a few
evaluations summed per (region, light) block) where every effect is region-local, else
:func:`finite_difference_hessian` over the pairs that can meet (:func:`coupled_pairs`).
:func:`hessian_steps` sets the difference steps from the least squares' Gauss-Newton
curvature, and :func:`gauss_newton_hessian` is the fallback where the finite-difference
Hessian is not positive definite.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["objective_hessian", "block_hessian", "finite_difference_hessian", "coupled_pairs", "hessian_steps",
           "gauss_newton_hessian"]


def objective_hessian(objective, z, steps):
    """Finite-difference Hessian and gradient of ``objective.f`` at ``z``, and ``f(z)``:
    :func:`block_hessian` where every effect is region-local, else
    :func:`finite_difference_hessian` over the :func:`coupled_pairs`."""
    if objective.region_local:
        return block_hessian(objective, z, steps)
    return finite_difference_hessian(objective.f, z, steps, coupled_pairs(objective))


def block_hessian(objective, z, steps):
    """The central-difference Hessian of :func:`finite_difference_hessian`, from a few evaluations summed per
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
    ctx = objective.ctx
    n_regions, n_lights = ctx.n_regions, ctx.n_lights
    n_blocks = n_regions * n_lights
    block = np.asarray(ctx.region, dtype=np.int64) * n_lights + np.asarray(ctx.light, dtype=np.int64)
    block_region, block_light = np.divmod(np.arange(n_blocks), n_lights)
    # the coordinates w: z's entries, with each per-light effect's parameters replaced by its L values
    per_light = objective.per_light_effects()
    in_light = np.zeros(objective.P, bool)
    for index, _ in per_light.values():
        in_light[index] = True
    plain = np.flatnonzero(~in_light)
    n_w = plain.size + n_lights * len(per_light)
    to_w = np.zeros((n_w, objective.P))             # dw = to_w dz
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
        terms = objective.log_lik_pointwise(z_at, values)
        return -objective.zeta * np.bincount(block, weights=terms, minlength=n_blocks)

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
    prior_precision = 1.0 / objective.scale ** 2
    H_z = to_w.T @ H @ to_w + np.diag(prior_precision)
    gradient_z = to_w.T @ gradient + (z - objective.loc) * prior_precision
    return H_z, gradient_z, objective.f(z)


def coupled_pairs(objective) -> np.ndarray:
    """(P, P) bool: which second derivatives of ``objective.f`` can be non-zero.

    Every observation belongs to one region and the priors are independent, so two
    parameters of different regions never meet in one term, unless an effect couples
    regions (``Effect.region_local`` False): then every pair may.
    """
    if not objective.region_local:
        return np.ones((objective.P, objective.P), bool)
    owner = objective.owner
    shared = owner < 0
    return (owner[:, None] == owner[None, :]) | shared[:, None] | shared[None, :]


def finite_difference_hessian(f, z, steps, coupled=None):
    """Central finite-difference Hessian of ``f`` at ``z``, its gradient and ``f(z)``: ``(H,
    gradient, f(z))``, with step ``steps[i]`` along parameter i. Pairs where ``coupled`` (P, P)
    bool is False are structurally 0 and not evaluated (4 calls of f each saved); None: all
    pairs (the reference the block Hessian is tested against)."""
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


def hessian_steps(objective, gauss_newton):
    """Difference steps for the Hessian: 5 % of each parameter's posterior sd (at most 0.05),
    the sd from the Gauss-Newton curvature ``gauss_newton`` (J'J of the last least-squares
    solve, over ``objective.mean_index``) for the mean parameters and from sigma^2's
    closed-form curvature zeta n_r / 2 for each region's log sigma^2."""
    sd = np.empty(objective.P)
    sd[objective.mean_index] = 1.0 / np.sqrt(np.maximum(np.diag(gauss_newton), 1e-12))
    for r, index in enumerate(objective.sigma_index):
        sd[index] = math.sqrt(2.0 / max(objective.zeta * float(objective.region_rows[r].size), 1.0))
    return np.minimum(0.05 * sd, 0.05)


def gauss_newton_hessian(objective, gauss_newton):
    """The Gauss-Newton curvature as a (P, P) Hessian: ``gauss_newton`` (J'J over the mean
    parameters, prior rows included) and, per region, log sigma^2's expected curvature
    zeta n_r / 2 plus its prior's; cross terms between the two groups 0."""
    hessian = np.zeros((objective.P, objective.P))
    mean_index = objective.mean_index
    hessian[np.ix_(mean_index, mean_index)] = gauss_newton
    for r, index in enumerate(objective.sigma_index):
        hessian[index, index] = (0.5 * objective.zeta * float(objective.region_rows[r].size)
                                 + 1.0 / objective.scale[index] ** 2)
    return hessian
