"""Scatter moves of material labels: a whole material dissolved into the others pixel by pixel, and its reverse, a
material born of pixels anywhere on the object.

Why: a material of a few scattered pieces (psm-horse's chains held one of 20 to 30 px in 2 to 4 pieces through
every draw, and four times the iterations left them there: docs/results/2026-12-03-extra-materials.md) dies only
when a move removes all of it at once. The label sweep keeps a material's last pixel, a cluster or component move
carries one connected piece, and a merge is the reverse of a split that must propose exactly those pieces from a
2-means of the merged material, which it does not. A dissolve's reverse reads the dying material's own parameters:
the pixels that chose it are the ones its parameters fit, wherever they lie. Both directions are sequential
allocations (after Jain and Neal 2004 and Dahl 2005, whose split-merge the merge/split move follows), here between
K and K + 1 materials without a guide:

- **Dissolve** (K + 1 -> K; kind 'dissolve'): a material m drawn with probability proportional to ``1 / n_m``
  (its pixels; the small ones are the ones a dissolve can remove), its pixels, in raster order, each joining
  material k != m with probability proportional to ``exp(zeta log p(y_p | theta_k) + beta n_k)``, n_k its
  4-neighbours carrying k in the partial state (:func:`~rjfit.sampler.regions.materials.passes.scatter
  .allocate_dissolve`); labels above m shift down; theta_m leaves the state, and each material that gains pixels
  has its parameters drawn afresh from the region proposal built from its pixels after the move (the births'
  Laplace / conditional proposal, :func:`~rjfit.sampler.colour.material_term`).
- **Scatter birth** (K -> K + 1; kind 'scatter_birth'): theta_new drawn from the region prior, a slot drawn
  uniformly among the K + 1 (labels at and above it shift up), and every labelled pixel, in raster order, joining
  the new material with probability ``sigma(zeta (log p(y_p | theta_new) - log p(y_p | theta_own))
  + beta (n_new - n_own))`` (:func:`~rjfit.sampler.regions.materials.passes.scatter.allocate_birth`); each material
  that loses pixels has its parameters drawn afresh as above. A birth that takes no pixel, or all of some
  material's, is rejected.

Why the redraw: on psm-horse the chain that kept a speck material held the body's lobe in another mode (gamma
about 210, kd 0.999, against about 12 and 0.988 in the chains at one material), where the speck's outline earned
82 nats of the edge term; a dissolve that kept the body's parameters lost them and was never accepted, though the
chains at one material sat 22 higher in log posterior. Each allocation reads the parameters of the state it starts
from; the redraws follow it.

theta_new is drawn from the prior, so the prior's density of the born material and its proposal density cancel;
the redrawn parameters swap places with the old ones, so nothing is mapped and the Jacobian is 1. The log ratio of
a birth from K materials (the dissolve's is its negative, read backwards):

    Delta log L + log pi_Potts(K + 1 state) - log pi_Potts(K state)     (the target: rho, beta B, 1 / K!)
    + sum over the redrawn k of term(theta_k new | its set after) - term(theta_k old | its set before)
    + log P(dissolve | K + 1) + log w_new + log q_dissolve               (the reverse's choices)
    - log P(birth | K) + log(K + 1) - log q_birth                        (this move's: its kind, slot, allocation)

``term``: :func:`~rjfit.sampler.colour.material_term`'s log prior minus log proposal density.

with w the dissolve's choice probabilities in the K + 1 state. Births from the prior are seldom accepted on a
large image: they are here as the dissolve's reverse. One channel only (a joint colour fit has a row per channel:
the move does not apply to it).
"""
from __future__ import annotations

import math

import numpy as np

from rjfit.sampler.colour import material_term
from rjfit.sampler.likelihood import log_likelihood_from_stats
from rjfit.sampler.moves.proposal import Proposal
from rjfit.sampler.regions.materials.cluster_swc import cluster_data, stats_rows, with_rows
from rjfit.sampler.regions.materials.passes.labels import pixel_log_lik
from rjfit.sampler.regions.materials.passes.scatter import allocate_birth, allocate_dissolve

__all__ = ["SCATTER_KINDS", "birth_probability", "dissolve_probability", "dissolve_weights", "propose_scatter_move"]

#: the names a scatter move is counted under: born, dissolved
SCATTER_KINDS = ("scatter_birth", "dissolve")
_NONE_FORCED = np.empty(0, np.int64)
_NONE_DRAWN = np.empty(0)


def birth_probability(n_materials: int, max_materials: int) -> float:
    """P(scatter birth) in a state of K materials: 0 at K_max, else 1/2 (at K = 1 the other half proposes nothing)."""
    return 0.0 if n_materials >= max_materials else 0.5


def dissolve_probability(n_materials: int, max_materials: int) -> float:
    """P(dissolve) in a state of K materials: 0 at K = 1, else what a birth leaves."""
    return 0.0 if n_materials <= 1 else 1.0 - birth_probability(n_materials, max_materials)


def dissolve_weights(counts) -> np.ndarray:
    """The dissolve's choice probabilities of the materials, proportional to ``1 / pixels``."""
    inverse = 1.0 / np.asarray(counts, float)
    return inverse / inverse.sum()


def propose_scatter_move(work, rng, problem, prior, potts, proposals, max_materials: int) -> Proposal | None:
    """One scatter move's proposal (module docstring): a birth or a dissolve, untested where there is neither; None
    for a joint colour fit.

    Draws, in order: the kind's uniform (at K = 1 a birth or, half the time, nothing: the birth is there as the
    dissolve's reverse, and at K = 1, where the ball spends nearly all its draws, it is the move's whole cost); for
    a birth the new parameters, the slot, one uniform per pixel, then the redrawn materials' parameters
    (ascending); for a dissolve the material's uniform, one uniform per pixel of it, then the redrawn materials'
    parameters.
    """
    if problem.n_channels != 1:
        return None
    n_mat = work.layout.n_materials
    p_birth, p_dissolve = birth_probability(n_mat, max_materials), dissolve_probability(n_mat, max_materials)
    u = rng.random()
    if u < p_birth:
        return _birth(work, rng, problem, prior, potts, proposals, max_materials,
                      p_birth).named("scatter_birth", jump=True)
    if u < p_birth + p_dissolve:
        return _dissolve(work, rng, problem, prior, potts, proposals, max_materials,
                         p_dissolve).named("dissolve", jump=True)
    return None     # one material (or K_max = 1): half the time, no move


def _pixel_log_lik(problem, theta, data=None) -> np.ndarray:
    """(R, H W): each pixel's log-likelihood (untempered) under each row of ``theta``; with ``data`` (a pixel set's
    observations, :func:`~rjfit.sampler.regions.materials.cluster_swc.cluster_data`) only its pixels' (the other
    columns 0)."""
    n_pix = problem.height * problem.width
    if data is None:
        return pixel_log_lik(problem.y, problem.C, problem.log_cos_hn, problem.pixel, theta, n_pix, problem.lobe)
    idx = data.idx
    lobe = None if problem.lobe is None else problem.lobe.take(idx)
    return pixel_log_lik(problem.y[idx], problem.C[idx], problem.log_cos_hn[idx], problem.pixel[idx], theta, n_pix,
                         lobe)


def _own_log_lik(log_lik, labels) -> np.ndarray:
    """Each labelled pixel's row of ``log_lik`` at its label (0 where unlabelled)."""
    own = np.zeros(labels.size)
    labelled = np.flatnonzero(labels >= 0)
    own[labelled] = log_lik[labels[labelled], labelled]
    return own


def _redrawn(work, rng, problem, prior, proposals, theta, changed, before, after):
    """``theta`` with the rows ``changed`` drawn afresh from the proposals built from their pixels in ``after``, the
    sum of their terms minus the old rows' terms under the proposals built from their pixels in ``before``, and
    ``{row: its pixels' data in after}``; (None, -inf, None) where a draw fails."""
    theta, log_term, sets = theta.copy(), 0.0, {}
    for k in changed:
        sets[int(k)] = cluster_data(problem, np.flatnonzero(after == k), work.pixel_sets)
        drawn, term_new = material_term(sets[int(k)], None, prior, proposals, draw_rng=rng)
        if drawn is None:
            return None, -math.inf, None
        _, term_old = material_term(cluster_data(problem, np.flatnonzero(before == k), work.pixel_sets),
                                    theta[k:k + 1], prior, proposals)
        theta[k] = drawn[0]
        log_term += term_new - term_old
    return theta, log_term, sets


def _proposal(work, problem, after, n_materials, theta, stats, sets, log_ratio) -> Proposal:
    """The proposed state: the rows of ``sets`` (``{row: its pixels' data}``) of ``stats`` summed afresh."""
    for k, data in sets.items():
        stats[k] = stats_rows(data, theta[k, 2])[0]
    layout = work.layout.with_pixels(after.reshape(work.layout.pixels.shape).astype(work.layout.pixels.dtype),
                                     n_materials)
    log_lik = log_likelihood_from_stats(stats, theta)
    return Proposal(layout, theta, layout.labels(problem), stats, log_lik,
                    float(log_ratio + np.sum(log_lik) - np.sum(work.log_lik)))


def _birth(work, rng, problem, prior, potts, proposals, max_materials, p_birth) -> Proposal:
    n_mat = work.layout.n_materials
    power, beta, (height, width) = float(problem.likelihood_power), float(potts.beta), problem.image_shape
    invalid = Proposal.invalid(work.layout.with_pixels(work.layout.pixels, n_mat + 1))
    theta_new = np.asarray(prior.sample(rng), float).reshape(1, 4)
    slot = int(rng.integers(n_mat + 1))
    before = work.layout.pixels.ravel().astype(np.int64)
    before[before >= slot] += 1
    theta = with_rows(work.theta, slot, theta_new)
    log_lik = _pixel_log_lik(problem, theta)
    after = before.copy()
    log_q = allocate_birth(after, _own_log_lik(log_lik, before), log_lik[slot], power, beta, height, width, slot,
                           rng.random(before.size), _NONE_FORCED)
    members = np.flatnonzero(after == slot)
    counts = np.bincount(after[after >= 0], minlength=n_mat + 1)
    if members.size == 0 or np.any(counts == 0):
        return invalid
    theta, log_term, sets = _redrawn(work, rng, problem, prior, proposals, theta, np.unique(before[members]), before,
                                     after)
    if theta is None:
        return invalid
    sets[slot] = cluster_data(problem, members, work.pixel_sets)
    log_q_back = allocate_dissolve(after.copy(), members, slot, _pixel_log_lik(problem, theta, sets[slot]), power,
                                   beta, height, width, _NONE_DRAWN, before[members])
    log_ratio = (potts.log_density(after.reshape(work.layout.pixels.shape), n_mat + 1)
                 - potts.log_density(work.layout.pixels, n_mat) + log_term
                 + math.log(dissolve_probability(n_mat + 1, max_materials))
                 + math.log(dissolve_weights(counts)[slot]) + log_q_back
                 - math.log(p_birth) + math.log(n_mat + 1) - log_q)
    stats = with_rows(work.stats, slot, np.zeros((1, work.stats.shape[1])))
    return _proposal(work, problem, after, n_mat + 1, theta, stats, sets, log_ratio)


def _dissolve(work, rng, problem, prior, potts, proposals, max_materials, p_dissolve) -> Proposal:
    n_mat = work.layout.n_materials
    power, beta, (height, width) = float(problem.likelihood_power), float(potts.beta), problem.image_shape
    before = work.layout.pixels.ravel().astype(np.int64)
    weights = dissolve_weights(np.bincount(before[before >= 0], minlength=n_mat))
    dying = min(int(np.searchsorted(np.cumsum(weights), rng.random(), side="right")), n_mat - 1)
    members = np.flatnonzero(before == dying)
    after = before.copy()
    log_q = allocate_dissolve(after, members, dying,
                              _pixel_log_lik(problem, work.theta, cluster_data(problem, members, work.pixel_sets)),
                              power, beta, height, width, rng.random(members.size), _NONE_FORCED)
    theta, log_term, sets = _redrawn(work, rng, problem, prior, proposals, work.theta, np.unique(after[members]),
                                     before, after)
    if theta is None:
        return Proposal.invalid(work.layout.with_pixels(work.layout.pixels, n_mat - 1))
    # the reverse birth, from the state after the dissolve (numbered with the dying material's slot still empty)
    log_lik = _pixel_log_lik(problem, theta)
    joined = np.zeros(before.size, np.int64)
    joined[members] = 1
    log_q_back = allocate_birth(after.copy(), _own_log_lik(log_lik, after), log_lik[dying], power, beta, height,
                                width, dying, _NONE_DRAWN, joined)
    shifted = after.copy()
    shifted[shifted > dying] -= 1
    log_ratio = (potts.log_density(shifted.reshape(work.layout.pixels.shape), n_mat - 1)
                 - potts.log_density(work.layout.pixels, n_mat) + log_term
                 + math.log(birth_probability(n_mat - 1, max_materials)) - math.log(n_mat) + log_q_back
                 - math.log(p_dissolve) - math.log(weights[dying]) - log_q)
    keep = np.arange(n_mat) != dying
    sets = {k - (k > dying): data for k, data in sets.items()}       # numbered without the dying material
    return _proposal(work, problem, shifted, n_mat - 1, theta[keep], work.stats[keep].copy(), sets, log_ratio)
