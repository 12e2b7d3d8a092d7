"""The effect move: global effect parameters sampled jointly with the regions' amplitudes (issue 26).

A problem with effects (:mod:`rjfit.sampler.forward`) is the data transformed by effect
parameters ``z`` (each effect's parameters in their unconstrained coordinates, Gaussian
priors of :mod:`rjfit.model.priors`). Once per ``every`` iterations, each effect (a block of
``z``) gets one Metropolis-Hastings move:

1. a random walk ``z_b' = z_b + exp(s_b) D_b n``, ``n`` standard normal, ``D_b`` per-parameter
   widths from a Laplace approximation (below) and ``s_b`` a scale adapted towards
   ``target_accept``;
2. the problem transformed at ``z'`` and every region's statistics recomputed on it (at the
   current labels and gammas: one compiled pass over the observations);
3. every region with enough observations for the (a, b) conditional redraws its amplitudes
   from it, given the new statistics (as the gamma moves do: effect parameters and the
   amplitudes are strongly correlated, an ambient term and kd, a white level and I0, and
   the redraw follows that ridge instead of stepping across it);
4. acceptance by the full target ratio: the log-likelihood of every region on the two
   transformed problems, the log-Jacobian of the transformation (weighted by the
   likelihood power like every log density), the effects' log prior in ``z``, the regions'
   prior in (a, b) coordinates, and both (a, b) proposal densities (the random walk is
   symmetric). Regions without a conditional keep their amplitudes; a proposal for which
   one of the redrawn regions has no conditional at either end is rejected.

Adaptation, during burn-in only (afterwards the move is a fixed MH kernel): every
``curvature_every`` iterations the widths ``D`` are set to the Laplace standard deviations
of each parameter's conditional (second differences of the log target with the regions
held), and ``s_b`` follows a Robbins-Monro step on the block's acceptance. The
(a, b) redraw makes the conditional widths too narrow, which the scale corrects.

Under the kernel's annealed warm-up the likelihood power grows geometrically (a factor of 10
per 50 iterations of a 2 x 1000 fit's), so widths measured ``curvature_every`` iterations
earlier no longer fit the tempered conditional they propose on (up to 3 times too wide as
the power nears 1). The widths therefore follow the power between refreshes: a conditional's
curvature is the likelihood's times the power (plus the prior's), so a width measured at
power ``p_w`` is used at power ``p`` times ``sqrt(p_w / p)``. Measured (issue 44, item 3:
docs/results/2026-11-28-loop.md): refits whose chains had ended the warm-up far from the
data's optimum and kept an extra change point end it near the optimum.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from rjfit.sampler.forward import Problem, transformed
from rjfit.sampler.likelihood import STAT_N, log_likelihood_from_stats, region_stats
from rjfit.sampler.moves.ab_conditional import ab_conditional, draw_ab, log_q_ab
from rjfit.sampler.moves.accept import accept
from rjfit.sampler.moves.region_terms import giesen_norm

__all__ = ["EffectSettings", "EffectState", "initial_effect_state", "move_effects", "laplace_widths",
           "LOG_SCALE_BOUNDS"]

LOG_SCALE_BOUNDS = (math.log(0.05), math.log(20.0))


@dataclass(frozen=True)
class EffectSettings:
    """How the effect move runs (used only for a problem with effects).

    Attributes
    ----------
    every : int
        Iterations between effect moves (1: every iteration); each move proposes once per effect.
    target_accept : float
        Acceptance rate the block's scale adapts to during burn-in.
    curvature_every : int
        Burn-in iterations between refreshes of the Laplace widths.
    jitter : float
        Standard deviation, in units of each parameter's prior sd, of the dispersed start
        around the effect's starting value.
    """

    every: int = 1
    target_accept: float = 0.3
    curvature_every: int = 50
    jitter: float = 0.05

    def __post_init__(self):
        if self.every < 1 or self.curvature_every < 1:
            raise ValueError(f"effect_every and curvature_every must be >= 1, got {self.every}, {self.curvature_every}")
        if not 0.0 < self.target_accept < 1.0:
            raise ValueError(f"effect target_accept must lie in (0, 1), got {self.target_accept}")
        if not self.jitter >= 0.0:
            raise ValueError(f"effect jitter must be >= 0, got {self.jitter}")


@dataclass(frozen=True, eq=False)
class EffectState:
    """The effect part of a chain's state (its arrays are never written to).

    ``z``: the effect parameters (unconstrained, flat); ``log_jacobian``: the transformation's
    log-Jacobian at ``z`` (likelihood power 1); ``widths``: the random walk's per-parameter
    widths; ``log_scale``: each block's log scale (both adapted during burn-in only);
    ``widths_power``: the likelihood power the widths were measured at (module docstring).
    """

    z: np.ndarray
    log_jacobian: float
    widths: np.ndarray
    log_scale: np.ndarray
    widths_power: float = 1.0


def initial_effect_state(problem: Problem, rng, settings: EffectSettings) -> tuple[EffectState, Problem]:
    """A dispersed start: each parameter's starting value plus ``jitter`` prior sd; with its transformed problem."""
    data = problem.effects
    scales = np.array([prior.scale for prior in data.priors()])
    z = data.initial_z() + settings.jitter * scales * rng.normal(size=data.n_params)
    new, log_jacobian = transformed(problem, z)
    state = EffectState(z=z, log_jacobian=log_jacobian, widths=scales.copy(), log_scale=np.zeros(len(data.blocks())))
    return state, new


def _evaluate(problem: Problem, work, z):
    """``(transformed problem, statistics, log-Jacobian)`` at ``z`` with the current labels and gammas, or None."""
    try:
        new, log_jacobian = transformed(problem, z)
    except (ValueError, FloatingPointError):
        return None
    if not math.isfinite(log_jacobian):
        return None
    stats = region_stats(new, work.labels, work.theta[:, 2], work.theta.shape[0])
    if not np.all(np.isfinite(stats)):
        return None
    return new, stats, log_jacobian


def _conditional_target(problem: Problem, work, z) -> float:
    """Log target at ``z`` with every region's parameters held: likelihood, log-Jacobian, effects' prior."""
    evaluated = _evaluate(problem, work, z)
    if evaluated is None:
        return -math.inf
    _, stats, log_jacobian = evaluated
    return (float(np.sum(log_likelihood_from_stats(stats, work.theta)))
            + problem.likelihood_power * log_jacobian + problem.effects.log_prior(z))


def laplace_widths(problem: Problem, work, state: EffectState) -> np.ndarray:
    """Per parameter, ``1 / sqrt(-d^2 log target / dz^2)`` with the regions held (second differences).

    The step of each difference starts at the current width and is widened or narrowed by
    10 until the target changes by between 0.05 and 1e4 nats (so float32 rounding of the
    transformed data does not dominate, and the step stays where the target is finite);
    where the curvature is not negative the prior sd is kept.
    """
    data = problem.effects
    f0 = _conditional_target(problem, work, state.z)
    widths = state.widths.copy()
    for k, prior in enumerate(data.priors()):
        step = min(float(state.widths[k]) * math.sqrt(state.widths_power / problem.likelihood_power)
                   * math.exp(float(np.max(state.log_scale))), 3.0 * prior.scale)
        for _ in range(8):
            plus, minus = state.z.copy(), state.z.copy()
            plus[k] += step
            minus[k] -= step
            f_plus, f_minus = _conditional_target(problem, work, plus), _conditional_target(problem, work, minus)
            change = max(abs(f_plus - f0), abs(f_minus - f0))
            if not math.isfinite(change) or change > 1e4:
                step /= 10.0
            elif change < 0.05 and step < prior.scale:
                step *= 10.0
            else:
                break
        curvature = (f_plus + f_minus - 2.0 * f0) / step ** 2
        widths[k] = 1.0 / math.sqrt(-curvature) if math.isfinite(curvature) and curvature < 0 else prior.scale
    return widths


def _redraw_amplitudes(work, stats_new, prior, rng, min_obs: int):
    """New parameters with (a, b) redrawn from their conditionals, and the move's log ratio of the (a, b) parts.

    Returns ``(theta_new, log_ratio)``; ``log_ratio`` is -inf where a redrawn region has no
    conditional at either end or draws a non-positive amplitude.
    """
    theta_new = work.theta.copy()
    log_ratio = 0.0
    for r in range(work.theta.shape[0]):
        if work.stats[r, STAT_N] < min_obs:
            continue
        I0, kd, g, s2 = (float(v) for v in work.theta[r])
        cond_old, cond_new = ab_conditional(work.stats[r], s2), ab_conditional(stats_new[r], s2)
        if cond_old is None or cond_new is None:
            return theta_new, -math.inf
        a_new, b_new = draw_ab(cond_new, rng)
        if a_new <= 0 or b_new <= 0:
            return theta_new, -math.inf
        norm = giesen_norm(g)
        I0_new = a_new + b_new / norm
        kd_new = a_new / I0_new
        theta_new[r, 0], theta_new[r, 1] = I0_new, kd_new
        a_old, b_old = I0 * kd, I0 * (1.0 - kd) * norm
        # the target in (a, b) coordinates is p(I0, kd) / (I0 N(g)); N(g) is the same at both ends
        log_ratio += (prior.logpdf_scalar(I0_new, kd_new, g, s2) - math.log(I0_new)
                      - prior.logpdf_scalar(I0, kd, g, s2) + math.log(I0)
                      + log_q_ab(a_old, b_old, cond_old) - log_q_ab(a_new, b_new, cond_new))
    return theta_new, log_ratio


def _move_block(work, state: EffectState, b: int, block: slice, rng, prior, problem: Problem, min_obs: int, info):
    """One effect block's move (module docstring); returns ``(state, problem, accepted)``."""
    data = problem.effects
    z_new = state.z.copy()
    width = block.stop - block.start
    widths = state.widths[block] * math.sqrt(state.widths_power / problem.likelihood_power)
    z_new[block] += math.exp(float(state.log_scale[b])) * widths * rng.normal(size=width)
    kind = f"effect_{data.effects[b].name}"
    evaluated = _evaluate(problem, work, z_new)
    if evaluated is None:
        accept(math.log(rng.random()), -math.inf, info, kind)
        return state, problem, False
    new_problem, stats_new, log_jacobian_new = evaluated
    theta_new, log_ratio = _redraw_amplitudes(work, stats_new, prior, rng, min_obs)
    log_u = math.log(rng.random())
    if log_ratio > -math.inf:
        log_lik_new = log_likelihood_from_stats(stats_new, theta_new)
        log_ratio += (float(np.sum(log_lik_new)) - float(np.sum(work.log_lik))
                      + problem.likelihood_power * (log_jacobian_new - state.log_jacobian)
                      + data.log_prior(z_new) - data.log_prior(state.z))
    if not accept(log_u, log_ratio, info, kind):
        return state, problem, False
    work.theta = theta_new
    work.stats = stats_new
    work.log_lik = np.asarray(log_lik_new, float)
    work.region_index = None        # the regions' data are runs of the old problem's arrays
    return replace(state, z=z_new, log_jacobian=log_jacobian_new), new_problem, True


def move_effects(work, state: EffectState, rng, prior, problem: Problem, settings: EffectSettings, min_obs: int,
                 iteration: int, burn_in: int, info) -> tuple[EffectState, Problem]:
    """The effect moves of one iteration (one per effect, every ``settings.every`` iterations).

    ``problem`` is the transformed problem at ``state.z`` (with the iteration's likelihood
    power); returns the new effect state and the problem transformed at its ``z``. During
    burn-in (``iteration < burn_in``) the widths and scales adapt (module docstring).
    """
    if iteration % settings.every:
        return state, problem
    adapting = iteration < burn_in
    if adapting and iteration % settings.curvature_every == 0:
        state = replace(state, widths=laplace_widths(problem, work, state), widths_power=problem.likelihood_power)
    log_scale = state.log_scale.copy()
    for b, block in enumerate(problem.effects.blocks()):
        state, problem, accepted = _move_block(work, state, b, block, rng, prior, problem, min_obs, info)
        info.count(f"effect_{problem.effects.effects[b].name}", accepted)
        if adapting:
            step = (float(accepted) - settings.target_accept) * 2.0 / (iteration + 1.0) ** 0.6
            log_scale[b] = float(np.clip(log_scale[b] + step, *LOG_SCALE_BOUNDS))
    if adapting:
        state = replace(state, log_scale=log_scale)
    return state, problem
