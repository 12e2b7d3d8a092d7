"""The RJMCMC transition kernel: ``step(state, rng, problem, prior, config) -> (state, info)``.

One step (an "iteration") applies, in a fixed order, valid MH moves that each leave the
posterior invariant, so their composition does too:

1. within-model moves for every region (``config.sampler``);
2. sweeps of u change-point elements (one element per row; even rows, then odd rows) and
   likewise of v elements; with probability ``config.block_prob`` a block shift; with
   probability ``config.vector_prob`` a redraw of one whole vector;
3. with probability ``config.jump_prob``, one birth or death of a change-point vector: with
   probability ``config.free_jump_prob`` the pair whose vector may sit at any rank of each
   line (every region redrawn), otherwise the pair that keeps ranks (the regions the
   vector cuts redrawn or split).

During the first ``config.burn_in`` iterations the gamma random-walk width adapts
(Robbins-Monro on its log towards ``config.target_accept``); afterwards it is frozen, so
the post-burn-in chain is a plain Metropolis-Hastings chain.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from rjfit.sampler.changepoints import n_regions, obs_region_labels
from rjfit.sampler.likelihood import Problem, log_likelihood_from_stats, region_stats
from rjfit.sampler.moves import (Work, accept_vector_redraw, birth_probability, log_posterior, propose_birth, propose_birth_free,
                                 propose_block_shift, propose_death, propose_death_free, propose_vector_redraw,
                                 sweep_changepoints, update_region_adaptive, update_region_paper)
from rjfit.sampler.state import ChainState, SamplerConfig, StepInfo

__all__ = ["make_state", "refresh", "step", "initial_state", "log_posterior_of"]

LOG_G_SCALE_BOUNDS = (np.log(0.2), np.log(50.0))

# One-entry memo of region -> observation indices for the labels array last seen. Keyed by
# identity (``is``), so it can never serve indices of another labelling.
_REGION_INDEX_MEMO: dict = {"labels": None, "index": None}
_TEMPERED_MEMO: dict = {}


def make_state(problem: Problem, u, v, theta, *, log_g_scale: float = 0.0, iteration: int = 0) -> ChainState:
    """A state from change points and parameters, with labels and statistics computed from scratch."""
    u = np.sort(np.asarray(u, float).reshape(problem.height, -1), axis=1)
    v = np.sort(np.asarray(v, float).reshape(problem.width, -1), axis=1)
    theta = np.asarray(theta, float).reshape(-1, 4)
    if theta.shape[0] != n_regions(u.shape[1], v.shape[1]):
        raise ValueError(f"theta has {theta.shape[0]} regions, change points make {n_regions(u.shape[1], v.shape[1])}")
    labels = obs_region_labels(u, v, problem.row, problem.col, pixel_start=problem.pixel_start)
    stats = region_stats(problem, labels, theta[:, 2], theta.shape[0])
    return ChainState(u=u, v=v, theta=theta, stats=stats, log_lik=log_likelihood_from_stats(stats, theta),
                      labels=labels, log_g_scale=float(log_g_scale), iteration=int(iteration))


def refresh(problem: Problem, state: ChainState) -> ChainState:
    """The same state with its cached statistics recomputed from scratch (drift reset)."""
    stats = region_stats(problem, state.labels, state.theta[:, 2], state.n_regions)
    return ChainState(u=state.u, v=state.v, theta=state.theta, stats=stats,
                      log_lik=log_likelihood_from_stats(stats, state.theta), labels=state.labels,
                      log_g_scale=state.log_g_scale, iteration=state.iteration)


def log_posterior_of(problem, prior, state: ChainState, config: SamplerConfig | None = None) -> float:
    return log_posterior(problem, prior, state.u, state.v, state.theta, state.log_lik, config)


def initial_state(problem: Problem, prior, config: SamplerConfig, rng, *, model=None, changepoints=None,
                  theta=None) -> ChainState:
    """A dispersed starting state.

    Parameters
    ----------
    model : (n_u, n_v), optional
        Starting model; default a random one from {0, 1} x {0, 1} within the maxima.
    changepoints : (u, v), optional
        Starting change points; default straight vectors at uniform positions across the
        object's bounding box.
    theta : ndarray (R, 4), optional
        Starting parameters; default the prior's ``start`` (if any) or a dispersed draw:
        I0 near the prior's centre, kd uniform in (0.2, 0.8), gamma log-uniform in (2, 30),
        sigma^2 a tenth of var(y).
    """
    height, width = problem.image_shape
    if changepoints is not None:
        u, v = (np.asarray(c, float) for c in changepoints)
        u, v = u.reshape(height, -1), v.reshape(width, -1)
    else:
        if model is None:
            model = (int(rng.integers(min(1, config.max_u) + 1)), int(rng.integers(min(1, config.max_v) + 1)))
        n_u, n_v = model
        if n_u > config.max_u or n_v > config.max_v:
            raise ValueError(f"start model {model} exceeds max_u={config.max_u}, max_v={config.max_v}")
        rows, cols = np.nonzero(problem.object_mask)
        if rows.size == 0:
            rows, cols = np.arange(height), np.arange(width)
        u = np.tile(np.sort(rng.uniform(cols.min(), cols.max() + 1.0, n_u)), (height, 1))
        v = np.tile(np.sort(rng.uniform(rows.min(), rows.max() + 1.0, n_v)), (width, 1))
    R = n_regions(u.shape[1], v.shape[1])
    if theta is None:
        if prior.start is not None:
            theta = np.tile(prior.start, (R, 1))
        else:
            i0_centre = np.exp(prior.params[0].a) if prior.params[0].kind == "lognormal" else 1.0
            theta = np.stack([i0_centre * np.exp(rng.normal(0.0, 0.3, R)), rng.uniform(0.2, 0.8, R),
                              np.exp(rng.uniform(np.log(2.0), np.log(30.0), R)),
                              np.full(R, 0.1 * np.var(problem.y, dtype=np.float64) + 1e-12)], axis=1)
    return make_state(problem, u, v, theta)


def _region_index(labels, power):
    # the gathered region data carry the likelihood power: a new power needs new data
    if _REGION_INDEX_MEMO["labels"] is labels and _REGION_INDEX_MEMO.get("power") == power:
        return _REGION_INDEX_MEMO["index"]
    index = {}
    _REGION_INDEX_MEMO["labels"], _REGION_INDEX_MEMO["index"], _REGION_INDEX_MEMO["power"] = labels, index, power
    return index


def anneal_power(config: SamplerConfig, iteration: int) -> float:
    """The factor on the likelihood power at ``iteration``: geometric from ``anneal_start`` to 1, then 1.

    A tempered warm-up (simulated annealing of the burn-in): at a small power the
    posterior is nearly the prior, so chains from dispersed starts drop unsupported
    vectors and carry boundaries freely; as the power grows they settle into the modes
    the data support. Only burn-in iterations are annealed (``anneal`` <= ``burn_in``), so
    the kept draws come from the plain kernel.
    """
    if iteration < 0 or iteration >= config.anneal:
        return 1.0
    return float(config.anneal_start ** (1.0 - iteration / config.anneal))


def _tempered(problem: Problem, factor: float) -> Problem:
    if factor == 1.0:
        return problem
    memo = _TEMPERED_MEMO
    if memo.get("problem") is not problem or memo.get("factor") != factor:
        memo.update(problem=problem, factor=factor,
                    tempered=replace(problem, likelihood_power=problem.likelihood_power * factor))
    return memo["tempered"]


def step(state: ChainState, rng: np.random.Generator, problem: Problem, prior, config: SamplerConfig):
    """One iteration of the kernel; returns ``(new_state, StepInfo)``. ``state`` is not modified.

    During an annealed warm-up (``config.anneal``) the step runs on the problem with its
    likelihood power times :func:`anneal_power`; the state's statistics are linear in that
    power, so they are rescaled, not recomputed, when it changes.
    """
    info = StepInfo()
    factor = anneal_power(config, state.iteration)
    previous = anneal_power(config, state.iteration - 1) if state.iteration > 0 else 1.0
    stats = state.stats if factor == previous else state.stats * (factor / previous)
    problem = _tempered(problem, factor)
    log_lik = state.log_lik if factor == previous else log_likelihood_from_stats(stats, state.theta)
    work = Work(u=state.u, v=state.v, theta=state.theta.copy(), stats=stats.copy(), log_lik=np.array(log_lik, float),
                labels=state.labels, region_index=_region_index(state.labels, problem.likelihood_power))

    # 1. within-model moves
    g_acc = []
    g_step = float(np.exp(state.log_g_scale))
    for r in range(work.theta.shape[0]):
        if config.sampler == "adaptive":
            g_acc += update_region_adaptive(work, r, rng, prior, problem, config, g_step, info)
        else:
            update_region_paper(work, r, rng, prior, problem, info, config.full_recompute)
    log_g_scale = state.log_g_scale
    if state.iteration < config.burn_in and g_acc:
        log_g_scale += (np.mean(g_acc) - config.target_accept) * 2.0 / (state.iteration + 1.0) ** 0.6
        # Bounded: rejections caused by the (a, b) > 0 constraint (kd near 0 or 1) must not
        # shrink the step to nothing and freeze gamma.
        log_g_scale = float(np.clip(log_g_scale, LOG_G_SCALE_BOUNDS[0], LOG_G_SCALE_BOUNDS[1]))

    # 2. change-point element sweeps
    if config.update_changepoints:
        for axis in ("u", "v"):
            for parity in (0, 1):
                sweep_changepoints(work, rng, problem, config, axis, info, parity)

    # 2b. block shift of a run of one vector's elements, with the changed regions redrawn
    if config.update_changepoints and config.block_prob > 0 and rng.random() < config.block_prob:
        axis = "u" if rng.random() < 0.5 else "v"
        if (work.u if axis == "u" else work.v).shape[1] > 0:
            u, v, theta, labels, stats, log_lik, log_ratio = propose_block_shift(work, rng, problem, prior, config, axis)
            accept = np.log(rng.random()) < log_ratio
            info.count(f"block_{axis}", accept)
            if accept:
                work = Work(u=u, v=v, theta=theta.copy(), stats=stats.copy(), log_lik=np.array(log_lik, float),
                            labels=labels, labels_owned=True)

    # 2c. redraw of one whole vector from (an approximation of) its conditional
    if config.update_changepoints and config.vector_prob > 0 and rng.random() < config.vector_prob:
        axis = "u" if rng.random() < 0.5 else "v"
        if (work.u if axis == "u" else work.v).shape[1] > 0:
            cps, shift, log_ratio = propose_vector_redraw(work, rng, problem, prior, config, axis)
            accept = shift is not None and np.log(rng.random()) < log_ratio
            info.count(f"vector_{axis}", accept)
            if accept:
                accept_vector_redraw(work, problem, axis, cps, shift)

    # 3. birth / death of one change-point vector
    if config.jumps and rng.random() < config.jump_prob:
        axis = "u" if rng.random() < 0.5 else "v"
        n, n_max = (work.u.shape[1], config.max_u) if axis == "u" else (work.v.shape[1], config.max_v)
        if n_max > 0:
            free = rng.random() < config.free_jump_prob
            birth = rng.random() < birth_probability(n, n_max)
            propose = ((propose_birth_free if birth else propose_death_free) if free
                       else (propose_birth if birth else propose_death))
            u, v, theta, labels, stats, log_lik, log_ratio = propose(work, rng, problem, prior, config, axis)
            accept = np.log(rng.random()) < log_ratio
            kind = f"{'birth' if birth else 'death'}{'_free' if free else ''}_{axis}"
            info.count(kind, accept)
            info.jump = kind
            if accept:
                work = Work(u=u, v=v, theta=theta, stats=stats, log_lik=log_lik, labels=labels, labels_owned=True)

    new_state = ChainState(u=work.u, v=work.v, theta=work.theta, stats=work.stats, log_lik=work.log_lik,
                           labels=work.labels, log_g_scale=float(log_g_scale), iteration=state.iteration + 1)
    if config.refresh_every and new_state.iteration % config.refresh_every == 0:
        new_state = refresh(problem, new_state)
    return new_state, info


