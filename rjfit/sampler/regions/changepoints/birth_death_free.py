"""Birth and death of a change-point vector at any rank: every region redrawn.

The free birth draws a new vector over whole lines (the birth proposal's straight or
prior-shaped vectors, unconstrained by gaps) and inserts each element into its line's
sorted elements, so it may cross existing vectors. The free death removes from each line
the element of a rank drawn by a chain along the lines (:func:`rank_transitions`; compiled
in :mod:`rjfit.sampler.regions.changepoints.passes.paths`) that favours the element whose removal costs the least
likelihood (:func:`removal_log_emit`) and rarely switches rank. This undoes two vectors
that each hold half of one true boundary and an unneeded half elsewhere, which no single
vector's death can remove. Every region of the new model is drawn from its conditional
proposal (:mod:`rjfit.sampler.moves.region_proposals`) and the reverse move's density of
the current parameters enters the ratio (Jacobian 1).
"""
from __future__ import annotations

import math

import numpy as np

from rjfit.sampler.likelihood import log_likelihood_from_stats, region_stats
from rjfit.sampler.regions.changepoints.birth_death import BirthDeathSettings, birth_probability, draw_vector, vector_log_q
from rjfit.sampler.moves.proposal import Proposal
from rjfit.sampler.moves.region_proposals import regions_term
from rjfit.sampler.passes import cells
from rjfit.sampler.regions.changepoints.passes import paths

__all__ = ["propose_birth_free", "propose_death_free", "removal_log_emit", "rank_transitions"]


def removal_log_emit(problem, labels, theta, n, n_v, axis):
    """(L, n): how well each line's observations fit when its element of rank k is removed.

    Removing element k of a line merges the line's columns k and k + 1 (regions along the
    axis). The score is the log-likelihood change of the better of the two ways to merge
    with the current parameters: column k + 1's pixels given column k's parameters, or
    column k's given column k + 1's. Only a proposal ingredient: any function of the state
    keeps the move exact.
    """
    n_lines = problem.height if axis == "u" else problem.width
    step = (n_v + 1) if axis == "u" else 1
    sums = np.zeros((3, n_lines * (n + 1)))   # current labels, column's pixels moved down, moved up
    cells.removal_sums(problem.y, problem.C, problem.log_cos_hn, problem.row if axis == "u" else problem.col, labels,
                       np.ascontiguousarray(theta, dtype=float), n, n_v, step, axis == "u", sums, problem.lobe)
    sums *= problem.likelihood_power
    current, down, up = (x.reshape(n_lines, n + 1) for x in sums)
    return np.maximum(down[:, 1:] - current[:, 1:], up[:, :-1] - current[:, :-1])


def rank_transitions(n_lines, n):
    """Log transitions (n, n) of the rank chain: keep the rank with probability 1 - 1/L, else any other."""
    eps = 1.0 / n_lines if n > 1 else 0.0
    with np.errstate(divide="ignore"):
        log_t = np.full((n, n), np.log(eps / max(n - 1, 1)))
        np.fill_diagonal(log_t, np.log1p(-eps))
    return log_t


def _rank_path_log_prob(problem, layout, theta, labels, axis, ranks):
    cps = layout.u if axis == "u" else layout.v
    log_emit = removal_log_emit(problem, labels, theta, cps.shape[1], layout.v.shape[1], axis)
    log_t = rank_transitions(*log_emit.shape)
    return paths.rank_path_log_prob(paths.rank_forward(log_emit, log_t), np.asarray(ranks, np.int64), log_t)


def _free_birth_ratio(problem, settings, cp_prior, small, big, axis, x, log_q_ranks, n, n_max, theta_term):
    """Log acceptance ratio of the free birth small -> big (the element x_r inserted in line r).

    ``log_q_ranks``: log probability that the reverse death draws the inserted elements' ranks.
    """
    (small_layout, ll_s), (big_layout, ll_b) = small, big
    size = problem.width if axis == "u" else problem.height
    bounds = np.full(x.size, -1.0), np.full(x.size, size + 1.0)
    return (ll_b - ll_s
            + cp_prior.log_density(big_layout.u, big_layout.v, problem.image_shape)
            - cp_prior.log_density(small_layout.u, small_layout.v, problem.image_shape)
            + math.log(1.0 - birth_probability(n + 1, n_max)) - math.log(birth_probability(n, n_max))
            + log_q_ranks - vector_log_q(x, *bounds, size, settings, cp_prior) + theta_term)


def _redraw_all(problem, prior, proposals, new_layout, work, rng):
    """The new layout's labels, fresh conditional parameters for every region, and their statistics.

    Returns ``(labels, theta, log term new - old, stats, log_lik)``; theta is None when a
    draw was invalid.
    """
    labels = new_layout.labels(problem)
    n_new = new_layout.n_regions
    theta_new, term_new = regions_term(problem, prior, proposals, labels, np.ones((n_new, 4)), range(n_new),
                                       draw_rng=rng)
    if theta_new is None:
        return labels, None, -np.inf, None, None
    _, term_old = regions_term(problem, prior, proposals, work.labels, work.theta, range(work.theta.shape[0]))
    stats = region_stats(problem, labels, theta_new[:, 2], n_new)
    return labels, theta_new, term_new - term_old, stats, log_likelihood_from_stats(stats, theta_new)


def propose_birth_free(work, rng, problem, prior, settings: BirthDeathSettings, proposals, cp_prior, n_max: int,
                       axis: str) -> Proposal:
    """Birth of a vector whose elements may fall at any rank of their lines; every region redrawn.

    The reverse move is :func:`propose_death_free`; the probability that it draws the
    inserted elements' ranks enters the ratio.
    """
    layout = work.layout
    cps = layout.u if axis == "u" else layout.v
    size = problem.width if axis == "u" else problem.height
    n, n_lines = cps.shape[1], cps.shape[0]
    x = draw_vector(rng, np.full(n_lines, -1.0), np.full(n_lines, size + 1.0), size, settings, cp_prior)
    ranks = np.sum(cps < x[:, None], axis=1)
    new_layout = layout.with_axis(axis, np.sort(np.concatenate([cps, x[:, None]], axis=1), axis=1))
    if np.any(x < -1.0) or np.any(x > size + 1.0):
        return Proposal.invalid(new_layout)
    labels, theta_new, theta_term, stats, log_lik = _redraw_all(problem, prior, proposals, new_layout, work, rng)
    if theta_new is None:
        return Proposal.invalid(new_layout, labels)
    log_q_ranks = _rank_path_log_prob(problem, new_layout, theta_new, labels, axis, ranks)
    log_ratio = _free_birth_ratio(problem, settings, cp_prior, (layout, float(np.sum(work.log_lik))),
                                  (new_layout, float(np.sum(log_lik))), axis, x, log_q_ranks, n, n_max, theta_term)
    return Proposal(new_layout, theta_new, labels, stats, log_lik, float(log_ratio))


def propose_death_free(work, rng, problem, prior, settings: BirthDeathSettings, proposals, cp_prior, n_max: int,
                       axis: str) -> Proposal:
    """Death that removes from each line the element of a rank drawn along the lines (reverse of the free birth)."""
    layout = work.layout
    cps = layout.u if axis == "u" else layout.v
    n_lines, n = cps.shape
    log_emit = removal_log_emit(problem, work.labels, work.theta, n, layout.v.shape[1], axis)
    log_t = rank_transitions(*log_emit.shape)
    alpha = paths.rank_forward(log_emit, log_t)
    ranks = paths.rank_backward_sample(alpha, log_t, rng.random(n_lines))   # compiled twins of reference.rank_chain
    rows = np.arange(n_lines)
    x = cps[rows, ranks]
    keep = np.ones(cps.shape, bool)
    keep[rows, ranks] = False
    new_layout = layout.with_axis(axis, cps[keep].reshape(n_lines, n - 1))
    labels, theta_new, term, stats, log_lik = _redraw_all(problem, prior, proposals, new_layout, work, rng)
    if theta_new is None:
        return Proposal.invalid(new_layout, labels)
    birth_ratio = _free_birth_ratio(problem, settings, cp_prior, (new_layout, float(np.sum(log_lik))),
                                    (layout, float(np.sum(work.log_lik))), axis, x,
                                    paths.rank_path_log_prob(alpha, ranks, log_t), n - 1, n_max, -term)
    return Proposal(new_layout, theta_new, labels, stats, log_lik, float(-birth_ratio))
