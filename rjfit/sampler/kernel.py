"""The RJMCMC transition kernel: ``step(state, rng, problem, prior, config, context) -> (state, info)``.

One step (an "iteration") applies, in a fixed order, valid MH moves that each leave the
posterior invariant, so their composition does too:

1. within-region moves for every region (``config.within``, built into one object by
   :func:`rjfit.sampler.moves.within.within_moves`);
2. the region model's structure moves (``config.regions``; for the paper's change points:
   element sweeps, block shift, whole-vector redraw, birth/death,
   :mod:`rjfit.sampler.regions.changepoints`);
3. for a problem with effects (``problem.effects``), the effect move
   (:mod:`rjfit.sampler.moves.effects`): each effect's global parameters, with every region's
   amplitudes redrawn given them. Moves 1 and 2 then run on the problem transformed at the
   state's effect parameters (:func:`rjfit.sampler.forward.transformed`), which the chain's
   context keeps between steps.
4. for a problem whose normals are sampled (``problem.normals``), one Metropolis sweep of every
   pixel's normal given the labels and parameters (:mod:`rjfit.sampler.normals`). Moves 1 and 2
   then run on the problem at the state's normals, which the chain's context keeps between steps.

During the first ``config.kernel.burn_in`` iterations the gamma random-walk width adapts
(Robbins-Monro on its log towards ``config.within.target_accept``); afterwards it is
frozen, so the post-burn-in chain is a plain Metropolis-Hastings chain.

The kernel is pure: its result depends only on its arguments. What a chain's steps reuse
from one step to the next (each region's observations as runs of the problem's arrays)
lives in a :class:`ChainContext` the caller owns and passes in; without one a step builds
what it needs afresh (the same draws, somewhat slower).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from rjfit.sampler.colour import log_prior_phi, starting_theta
from rjfit.sampler.forward import Problem, transformed
from rjfit.sampler.likelihood import log_likelihood_from_stats, region_stats
from rjfit.sampler.moves.effects import initial_effect_state, move_effects
from rjfit.sampler.moves.within import adapt_log_g_scale, within_moves
from rjfit.sampler.normals import initial_normal_state, move_normals, normal_log_prior, normal_problem
from rjfit.sampler.pixel_sets import PixelSets
from rjfit.sampler.priors import PARAM_NAMES
from rjfit.sampler.regions.materials.edge_memo import BoundaryMemo
from rjfit.sampler.state import ChainState, KernelSettings, SamplerConfig, StepInfo, Work

__all__ = ["ChainContext", "make_state", "refresh", "step", "initial_state", "log_posterior", "anneal_power",
           "effect_log_likelihood"]


@dataclass
class ChainContext:
    """What one chain's steps derive from its state and reuse between steps; never part of the state.

    The within-region moves read each region's observations as runs of the problem's arrays
    (:class:`~rjfit.sampler.likelihood.RegionData`, which also remembers its last gamma
    moves' sums). Those depend only on the labels and the likelihood power, and a step whose
    structure moves leave the labels alone hands them on to the next step through this
    object, keyed by the labels array's identity (a state's arrays are never written to, so
    the same array means the same labels). For a problem with effects it also keeps the
    problem transformed at the state's effect parameters, keyed by their array's identity,
    and the label moves' pixel sets (:class:`~rjfit.sampler.pixel_sets.PixelSets`), and the edge term's last
    boundary sums (:class:`~rjfit.sampler.regions.materials.edge_memo.BoundaryMemo`).
    A fresh context gives the same draws.
    """

    labels: np.ndarray | None = None
    power: float | None = None
    y: np.ndarray | None = None
    C: np.ndarray | None = None
    region_index: dict = field(default_factory=dict)
    effect_z: np.ndarray | None = None
    effect_problem: Problem | None = None
    pixel_sets: PixelSets = field(default_factory=PixelSets)
    edge_memo: BoundaryMemo = field(default_factory=BoundaryMemo)
    normal_d: np.ndarray | None = None
    normal_problem: Problem | None = None

    def problem_at_normals(self, problem: Problem, normals) -> Problem:
        """``problem`` at the sampled normals of ``normals`` (a ``NormalState``), kept for the next step."""
        if self.normal_d is not normals.d or self.normal_problem is None \
                or self.normal_problem.normals is not problem.normals \
                or self.normal_problem.likelihood_power != problem.likelihood_power:
            self.normal_d, self.normal_problem = normals.d, normal_problem(problem, normals.d)
        return self.normal_problem

    def keep_normals(self, normals, problem: Problem) -> None:
        """Remember ``problem`` as the one at ``normals.d`` (after a sweep of the normals)."""
        self.normal_d, self.normal_problem = normals.d, problem

    def transformed_problem(self, problem: Problem, effects) -> Problem:
        """``problem`` transformed at the effect parameters of ``effects`` (an ``EffectState``), kept for the next step."""
        if self.effect_z is not effects.z or self.effect_problem is None \
                or self.effect_problem.effects is not problem.effects \
                or self.effect_problem.likelihood_power != problem.likelihood_power:
            self.effect_z, self.effect_problem = effects.z, transformed(problem, effects.z)[0]
        return self.effect_problem

    def keep_transformed(self, effects, problem: Problem) -> None:
        """Remember ``problem`` as the transformation at ``effects.z`` (after an effect move)."""
        self.effect_z, self.effect_problem = effects.z, problem

    def region_index_for(self, problem: Problem, labels) -> dict:
        """The region index (filled on first use by :meth:`Work.region_data`) of ``labels`` in ``problem``.

        A new one whenever the labels, the likelihood power (the regions' data carry it) or
        the problem's arrays differ from the last call's.
        """
        if self.labels is not labels or self.power != problem.likelihood_power or self.y is not problem.y \
                or self.C is not problem.C:
            self.labels, self.power, self.y, self.region_index = labels, problem.likelihood_power, problem.y, {}
            self.C = problem.C
        return self.region_index


def make_state(problem: Problem, layout, theta, *, log_g_scale: float = 0.0, iteration: int = 0) -> ChainState:
    """A state from a layout and parameters, with labels and statistics computed from scratch.

    Raises
    ------
    ValueError
        If ``theta`` has not one row per region of ``layout``.
    """
    theta = np.asarray(theta, float).reshape(-1, 4)
    if theta.shape[0] != layout.n_regions * problem.n_channels:
        raise ValueError(f"theta has {theta.shape[0]} rows, the layout makes {layout.n_regions} regions of "
                         f"{problem.n_channels} channel(s)")
    labels = layout.labels(problem)
    stats = region_stats(problem, labels, theta[:, 2], theta.shape[0])
    return ChainState(layout=layout, theta=theta, stats=stats, log_lik=log_likelihood_from_stats(stats, theta),
                      labels=labels, log_g_scale=float(log_g_scale), iteration=int(iteration))


def refresh(problem: Problem, state: ChainState) -> ChainState:
    """The same state with its cached statistics recomputed from scratch (drift reset)."""
    stats = region_stats(problem, state.labels, state.theta[:, 2], state.n_regions)
    return replace(state, stats=stats, log_lik=log_likelihood_from_stats(stats, state.theta))


def log_posterior(problem: Problem, prior, state: ChainState, config: SamplerConfig, edge_memo=None) -> float:
    """Log joint density (up to the constant model prior): likelihood, phi-space prior, layout prior, the region
    model's edge term (if any), effects' prior.

    For a problem with effects, ``state.log_lik`` is on the transformed problem; the
    log-Jacobian is left out here (:func:`effect_log_likelihood`). ``edge_memo``: the chain's memo of the edge
    term's sums (:attr:`ChainContext.edge_memo`; the same value without).
    """
    total = float(np.sum(state.log_lik) + log_prior_phi(prior, state.theta, problem.n_channels)
                  + config.regions.log_prior(problem, state.layout))
    edges = config.regions.edge_term(state.layout)
    if edges is not None:
        total += edges.total(state.layout.pixels, state.theta, edge_memo)
    if state.effects is not None:
        total += problem.effects.log_prior(state.effects.z)
    if state.normals is not None:
        total += normal_log_prior(problem, state.normals)
    return total


def effect_log_likelihood(problem: Problem, state: ChainState) -> float:
    """What the effects add to the log-likelihood of the raw data beside ``state.log_lik``: the
    transformation's log-Jacobian times the likelihood power (0 without effects).

    :func:`log_posterior` leaves it out like the noise scales' constant; a chain's records add both.
    """
    if state.effects is None:
        return 0.0
    return problem.likelihood_power * state.effects.log_jacobian


def initial_state(problem: Problem, prior, config: SamplerConfig, rng, *, theta=None, **layout_start) -> ChainState:
    """A dispersed starting state.

    Parameters
    ----------
    theta : ndarray (R, 4), optional
        Starting parameters; default the region model's own
        (:meth:`~rjfit.sampler.regions.base.RegionModel.start_theta`: a material model with the
        edge term starts at least-squares fits), else the prior's ``start`` (if any) or a dispersed draw:
        I0 near the prior's centre, kd uniform in (0.2, 0.8), gamma log-uniform in (2, 30),
        sigma^2 a tenth of var(y).
    **layout_start
        The region model's start (change points: ``model=(n_u, n_v)`` or
        ``changepoints=(u, v)``; :meth:`~rjfit.sampler.regions.changepoints.ChangepointRegions.initial_layout`).

    A problem with effects starts its effect parameters near their starting values
    (:func:`rjfit.sampler.moves.effects.initial_effect_state`, drawn after the rest), and its
    statistics are those of the problem transformed there.

    Raises
    ------
    ValueError
        If a starting parameter lies outside its prior's support: from a state of zero
        density every move's log ratio is ``-inf - (-inf)``, NaN, and the chain never moves.
    """
    layout = config.regions.initial_layout(problem, rng, **layout_start)
    R = layout.n_regions
    if theta is None:
        theta = config.regions.start_theta(problem, layout, prior)
    if theta is None:
        if prior.start is not None:
            theta = np.tile(prior.start, (R, 1))
        else:
            i0_centre = np.exp(prior.params[0].a) if prior.params[0].kind == "lognormal" else 1.0
            theta = np.stack([i0_centre * np.exp(rng.normal(0.0, 0.3, R)), rng.uniform(0.2, 0.8, R),
                              np.exp(rng.uniform(np.log(2.0), np.log(30.0), R)),
                              np.full(R, 0.1 * np.var(problem.y, dtype=np.float64) + 1e-12)], axis=1)
    theta = np.asarray(theta, float).reshape(-1, 4)
    if problem.n_channels > 1 and theta.shape[0] == R:     # one row per material: every channel starts there
        theta = starting_theta(theta, problem.n_channels)
    outside = [(r, k) for k, p in enumerate(prior.params) for r in np.flatnonzero(~np.isfinite(p.logpdf(theta[:, k])))]
    if outside:
        r, k = outside[0]
        raise ValueError(f"start of region {r}: {PARAM_NAMES[k]} = {theta[r, k]:.6g} lies outside its prior's support "
                         f"({prior.params[k].kind} {prior.params[k].a:.6g}, {prior.params[k].b:.6g}); a chain cannot "
                         "start where the posterior is zero")
    if problem.normals is not None:     # the given normals, the statistics on the columns the sweep computes
        normals = initial_normal_state(problem)
        return replace(make_state(normal_problem(problem, normals.d), layout, theta), normals=normals)
    if problem.effects is None:
        return make_state(problem, layout, theta)
    effects, effect_problem = initial_effect_state(problem, rng, config.effects)
    return replace(make_state(effect_problem, layout, theta), effects=effects)


def anneal_power(settings: KernelSettings, iteration: int) -> float:
    """The factor on the likelihood power at ``iteration``: geometric from ``anneal_start`` to 1, then 1.

    A tempered warm-up (simulated annealing of the burn-in): at a small power the
    posterior is nearly the prior, so chains from dispersed starts drop unsupported
    vectors and carry boundaries freely; as the power grows they settle into the modes
    the data support. Only burn-in iterations are annealed (``anneal`` <= ``burn_in``), so
    the kept draws come from the plain kernel.
    """
    if iteration < 0 or iteration >= settings.anneal:
        return 1.0
    return float(settings.anneal_start ** (1.0 - iteration / settings.anneal))


def step(state: ChainState, rng: np.random.Generator, problem: Problem, prior, config: SamplerConfig,
         context: ChainContext | None = None):
    """One iteration of the kernel; returns ``(new_state, StepInfo)``. ``state`` is not modified.

    During an annealed warm-up (``config.kernel.anneal``) the step runs on the problem with
    its likelihood power times :func:`anneal_power`; the state's statistics are linear in
    that power, so they are rescaled, not recomputed, when it changes. ``context``: the
    chain's :class:`ChainContext` (None: a fresh one, for this step only).
    """
    context = ChainContext() if context is None else context
    info = StepInfo()
    factor = anneal_power(config.kernel, state.iteration)
    previous = anneal_power(config.kernel, state.iteration - 1) if state.iteration > 0 else 1.0
    stats = state.stats if factor == previous else state.stats * (factor / previous)
    base = problem
    if problem.effects is not None:
        problem = context.transformed_problem(problem, state.effects)
    if problem.normals is not None:
        problem = context.problem_at_normals(problem, state.normals)
    if factor != 1.0:
        problem = replace(problem, likelihood_power=problem.likelihood_power * factor)
    log_lik = state.log_lik if factor == previous else log_likelihood_from_stats(stats, state.theta)
    work = Work(layout=state.layout, theta=state.theta.copy(), stats=stats.copy(), log_lik=np.array(log_lik, float),
                labels=state.labels, region_index=context.region_index_for(problem, state.labels),
                pixel_sets=context.pixel_sets.valid_for(problem), edges=config.regions.edge_term(state.layout),
                edge_memo=context.edge_memo)

    # 1. within-region moves for every region
    g_acc = within_moves(config.within, problem.n_channels).run(work, rng, problem, prior, info,
                                                                float(np.exp(state.log_g_scale)))
    log_g_scale = state.log_g_scale
    if state.iteration < config.kernel.burn_in and g_acc:
        log_g_scale = adapt_log_g_scale(log_g_scale, g_acc, state.iteration, config.within.target_accept)

    # 2. the region model's structure moves
    config.regions.structure_moves(work, rng, problem, prior, info)

    # 3. the effects' global parameters
    effects = state.effects
    if base.effects is not None:
        effects, problem = move_effects(work, effects, rng, prior, problem, config.effects,
                                        config.within.min_obs_conditional, state.iteration, config.kernel.burn_in, info)
        context.keep_transformed(effects, problem if factor == 1.0 else replace(problem,
                                                                                 likelihood_power=base.likelihood_power))

    # 4. the pixels' normals
    normals = state.normals
    if base.normals is not None:
        normals, problem = move_normals(work, normals, rng, problem, state.iteration, config.kernel.burn_in, info)
        context.keep_normals(normals, problem if factor == 1.0 else replace(problem,
                                                                            likelihood_power=base.likelihood_power))

    new_state = ChainState(layout=work.layout, theta=work.theta, stats=work.stats, log_lik=work.log_lik,
                           labels=work.labels, log_g_scale=float(log_g_scale), iteration=state.iteration + 1,
                           effects=effects, normals=normals)
    if config.kernel.refresh_every and new_state.iteration % config.kernel.refresh_every == 0:
        new_state = refresh(problem, new_state)
    return new_state, info
