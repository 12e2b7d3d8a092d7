"""Swendsen-Wang-cut cluster moves of material labels, with births and deaths of materials.

After Barbu and Zhu, "Generalizing Swendsen-Wang to sampling arbitrary posterior
probabilities", IEEE PAMI 27(8), 2005. One move:

1. a seed pixel p, drawn with fixed data-driven weights (half uniform over the labelled
   pixels, half by the weakness of their bonds:
   :func:`~rjfit.sampler.regions.materials.layout.seed_weights`); its cluster V0: the pixels
   of its label l joined to it by bonds that are on, each edge between two pixels of one label on
   with its data-driven probability q_e (:class:`~rjfit.sampler.regions.materials.layout.Bonds`;
   :func:`rjfit.sampler.regions.materials.passes.labels.grow_cluster`);
2. a new label for V0: NEW with probability ``p_new(K)`` (0 at K = K_max, 1 at K = 1,
   else ``new_prob``), otherwise one of the K - 1 other labels, uniformly
   (:func:`label_choice`);
3. the acceptance ratio

       pi(B) / pi(A)  x  prod_{C(V0, V_l')} (1 - q_e) / prod_{C(V0, V_l \\ V0)} (1 - q_e)
                      x  q(l | V0, B) / q(l' | V0, A)

   with C(V, W) the edges between V and W: the probability of cutting V0 out of its label
   in the reverse move over that in this one (the bonds inside V0 and the seed's chance
   to fall in V0, the sum of the seed weights over V0, are the same both ways and cancel).
   pi holds the likelihood of V0's
   observations under the two materials (to the likelihood power zeta), the Potts term
   ``-beta dB`` (dB = n_l - n_l', the edges from V0 to the rest of l and to l'), ``rho^K``
   and ``1 / K!`` (the labelled state's density).

A move of V0 to NEW when V0 is not all of l is a **birth**: the new material's parameters
are drawn from the region proposal built from V0's data (the change-point births' Laplace /
conditional proposal, :func:`~rjfit.sampler.moves.region_proposals.region_term`), and it
takes a slot drawn uniformly among the K + 1 (the labels at and above it shift up). A move
of V0 to an existing label when V0 is all of l is a **death**: material l is removed (the
labels above shift down) and its parameters are evaluated under the same proposal built
from V0's data. Parameters are drawn afresh, so the Jacobian is 1, as in the change-point
'conditional' split map. A birth's reverse is the death that picks V0's new label's
cluster (all of it) and its old label; the slot's 1 / (K + 1) and the prior's K! / (K + 1)!
cancel, and both are written out. V0 equal to all of l sent to NEW only renames a material:
no move.

A joint colour fit (:mod:`rjfit.sampler.colour`): a material is its C parameter rows, the
likelihood of V0 under it the sum over channels, a born material's rows drawn given one
gamma (:func:`~rjfit.sampler.colour.material_term`).

With ``jumps`` off (K fixed) NEW is never chosen and a move that would empty a material
is not made (the target has no mass there).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rjfit.sampler.colour import material_log_lik, material_rows, material_term, pixel_set_data
from rjfit.sampler.likelihood import log_likelihood_from_stats
from rjfit.sampler.moves.proposal import Proposal
from rjfit.sampler.regions.materials.passes.labels import grow_cluster

__all__ = ["ClusterSettings", "label_choice", "cluster_data", "stats_rows", "with_rows", "propose_cluster_move",
           "propose_set_move", "seed_log_ratio", "CLUSTER_KINDS"]

#: the names a cluster move is counted under: moved, born, dying
CLUSTER_KINDS = ("cluster", "cluster_birth", "cluster_death")


@dataclass(frozen=True)
class ClusterSettings:
    """How the cluster moves run.

    Attributes
    ----------
    moves : int
        Cluster moves per iteration.
    new_prob : float
        Probability of proposing a NEW material for the cluster when 1 < K < K_max.
    bond_q_max : float or None
        The bond probabilities' ceiling; None (default): ``1 - exp(-beta)``, Swendsen and
        Wang's bond for the Potts prior, at which the cut factor of a boundary edge,
        ``1 - q``, and its Potts factor, ``exp(-beta)``, cancel: a cluster whose neighbours
        across its boundary look alike is then moved as readily as the Potts prior alone
        allows (a higher ceiling makes every merge of two materials of one appearance
        improbable, a lower one the clusters small).
    bond_tau : float
        The bond probabilities' width in units of the features' spread
        (:func:`~rjfit.sampler.regions.materials.layout.bond_probabilities`).
    material_seed : float
        Probability that a move's seed is drawn as a material (uniformly among the K) and
        then a pixel of it (uniformly), instead of by the fixed seed weights. Why: a
        material of one pixel that the posterior does not want (a start's leftover) dies
        only by a cluster move seeded on that pixel, which the fixed weights pick once in
        about 2N proposals (measured on psm-horse: such a material outlived 250 iterations).
        The seed probability then depends on the state, so the ratio holds the reverse
        move's chance of a seed in V0 over this one's (:func:`seed_log_ratio`). 0 (default): the
        fixed weights alone, and the draws of before.
    """

    moves: int = 4
    new_prob: float = 0.3
    bond_q_max: float | None = None
    bond_tau: float = 2.0
    material_seed: float = 0.0

    def __post_init__(self):
        if self.moves < 0:
            raise ValueError(f"cluster moves per iteration must be >= 0, got {self.moves}")
        if not 0.0 <= self.material_seed < 1.0:
            raise ValueError(f"material_seed must lie in [0, 1), got {self.material_seed}")
        if not 0.0 < self.new_prob < 1.0:
            raise ValueError(f"new_prob must lie in (0, 1), got {self.new_prob}")

    def q_max(self, beta: float) -> float:
        """The bonds' ceiling under Potts strength ``beta`` (see ``bond_q_max``)."""
        return float(-np.expm1(-beta)) if self.bond_q_max is None else float(self.bond_q_max)


def label_choice(n_materials: int, max_materials: int, new_prob: float, jumps: bool = True) -> tuple[float, float]:
    """``(P(NEW), P(one given other existing label))`` of a cluster of a state with K materials."""
    p_new = 0.0 if (not jumps or n_materials >= max_materials) else (1.0 if n_materials == 1 else new_prob)
    p_other = (1.0 - p_new) / (n_materials - 1) if n_materials > 1 else 0.0
    return p_new, p_other


def cluster_data(problem, members, pixel_sets=None):
    """The observations of the pixels ``members`` (ascending) as runs of the problem's arrays: a
    :class:`~rjfit.sampler.likelihood.RegionData`, or for a joint colour fit one per channel
    (:func:`rjfit.sampler.colour.pixel_set_data`); from ``pixel_sets`` (the chain's
    :class:`~rjfit.sampler.pixel_sets.PixelSets`, where the step has one) the one handed out before."""
    return pixel_set_data(problem, members) if pixel_sets is None else pixel_sets.data(problem, members)


def stats_rows(data, gamma) -> np.ndarray:
    """The statistics rows (C, 7) of a pixel set's observations at ``gamma`` (one row per channel)."""
    return data.stats_at(gamma).reshape(-1, 7)


def with_rows(array, at: int, rows) -> np.ndarray:
    """``array`` with ``rows`` inserted before row ``at``."""
    return np.concatenate([array[:at], rows, array[at:]])


def _proposal(work, problem, pixels, n_materials, theta, stats, log_ratio) -> Proposal:
    layout = work.layout.with_pixels(pixels, n_materials)
    return Proposal(layout, theta, layout.labels(problem), stats, log_likelihood_from_stats(stats, theta),
                    float(log_ratio))


def propose_cluster_move(work, rng, problem, prior, settings: ClusterSettings, proposals, potts, max_materials: int,
                         jumps: bool = True):
    """One cluster move's proposal (untested when there is no move to test: :meth:`Proposal.untested`).

    Its ``kind`` is 'cluster', 'cluster_birth' or 'cluster_death' (those two jumps). Draws, in order: the seed,
    the bonds' key, the label choice's uniform, the other label or (birth) the slot and the
    new parameters.
    """
    layout = work.layout
    n_mat = layout.n_materials
    height, width = problem.image_shape
    flat = layout.pixels.ravel()
    if settings.material_seed > 0.0 and rng.random() < settings.material_seed:
        seed = int(rng.choice(np.flatnonzero(flat == int(rng.integers(n_mat)))))
    else:
        seed = layout.bonds.draw_seed(rng)
    key = np.uint64(rng.integers(0, 2 ** 63))
    members, n_to, cut_to = grow_cluster(flat, flat >= 0, layout.bonds.q, key, seed, height, width, n_mat)

    def seed_ratio(new, n_after):
        return seed_log_ratio(settings.material_seed, layout, members, flat, int(flat[seed]), new, n_after)

    return propose_set_move(work, rng, problem, prior, (members, n_to, cut_to, seed_ratio), settings.new_prob,
                            proposals, potts, max_materials, jumps, CLUSTER_KINDS)


def propose_set_move(work, rng, problem, prior, pixel_set, new_prob: float, proposals, potts, max_materials: int,
                     jumps: bool, kinds=None):
    """A set V0 of pixels of one label moved to another label or to a NEW material: its proposal (untested when
    there is no move to test), of kind ``kinds[0]`` (moved), ``kinds[1]`` (a birth) or ``kinds[2]`` (a death).

    ``pixel_set`` is ``(members, n_to, cut_to, seed_ratio)``: V0's pixels (ascending), per
    label the number of edges from V0 to that label's pixels outside it and the sum of their
    ``log(1 - q)`` (zeros for a set drawn without bonds), and a function ``(new, n_after)``
    giving the log of the reverse move's chance of drawing V0 over this move's (``new`` None
    for a birth). The label choice, births and deaths are the cluster moves' (module
    docstring); ``kinds`` names the moved, born and dying cases (default the cluster moves').
    """
    kinds = CLUSTER_KINDS if kinds is None else kinds
    members, n_to, cut_to, seed_ratio = pixel_set
    layout = work.layout
    n_mat = layout.n_materials
    height, width = layout.pixels.shape
    flat = layout.pixels.ravel()
    old = int(flat[members[0]])
    p_new, p_other = label_choice(n_mat, max_materials, new_prob, jumps)
    if p_new == 0.0 and n_mat == 1:
        return Proposal.untested(kinds[0])
    birth = rng.random() < p_new
    whole = members.size == int(np.count_nonzero(flat == old))
    if birth and whole:
        return Proposal.untested(kinds[1])    # a renaming of material `old`: the same partition
    if not birth and whole and not jumps:
        return Proposal.untested(kinds[2])    # K fixed: a material may not be emptied
    n_ch = problem.n_channels
    rows_old = material_rows(old, n_ch)
    data = cluster_data(problem, members, work.pixel_sets)
    stats_old = stats_rows(data, work.theta[old * n_ch, 2])
    log_lik_old = material_log_lik(stats_old, work.theta[rows_old])
    if birth:
        return _birth(work, rng, problem, prior, new_prob, proposals, potts, max_materials,
                      (members, n_to, cut_to, old, data, stats_old, log_lik_old, p_new),
                      seed_ratio(None, n_mat + 1)).named(kinds[1], jump=True)
    pick = int(rng.integers(n_mat - 1))
    new = pick if pick < old else pick + 1
    log_seed = seed_ratio(new, n_mat - 1 if whole else n_mat)
    rows_new = material_rows(new, n_ch)
    stats_new = stats_rows(data, work.theta[new * n_ch, 2])
    delta_lik = material_log_lik(stats_new, work.theta[rows_new]) - log_lik_old
    # Potts: V0's edges to the rest of `old` become cut, those to `new` join
    delta_potts = -potts.beta * (n_to[old] - n_to[new])
    cut_ratio = cut_to[new] - cut_to[old]
    pixels = layout.pixels.copy().ravel()
    pixels[members] = new
    if not whole:
        stats = work.stats.copy()
        stats[rows_old] -= stats_old
        stats[rows_new] += stats_new
        return _proposal(work, problem, pixels.reshape(height, width), n_mat, work.theta.copy(), stats,
                         delta_lik + delta_potts + cut_ratio + log_seed).named(kinds[0])
    # death of `old`: its parameters evaluated under the proposal built from V0's data
    _, term = material_term(data, work.theta[rows_old], prior, proposals)
    p_new_back = label_choice(n_mat - 1, max_materials, new_prob, jumps)[0]
    log_ratio = (delta_lik + delta_potts + cut_ratio + log_seed
                 - math.log(potts.rho) + math.log(n_mat)          # rho^K and the labelled state's 1 / K!
                 - term
                 + math.log(p_new_back) - math.log(n_mat)         # the reverse birth: NEW, then slot `old` of K
                 - math.log(p_other))
    stats = work.stats.copy()
    stats[rows_new] += stats_new
    pixels[pixels > old] -= 1
    keep = np.repeat(np.arange(n_mat) != old, n_ch)
    return _proposal(work, problem, pixels.reshape(height, width), n_mat - 1, work.theta[keep].copy(), stats[keep],
                     log_ratio).named(kinds[2], jump=True)


def seed_log_ratio(share: float, layout, members, flat, old, new, n_after) -> float:
    """log of the reverse move's chance of a seed in V0 over this move's (0 without material seeds).

    A seed in V0 grows V0 whichever pixel of it it is, so the chance is
    ``(1 - e) W(V0) / W + e |V0| / (K n_l)``: W the fixed seed weights, e the ``share`` of material seeds
    (``material_seed``; 1: the component moves'), n_l the size of V0's material, K the number of materials; after
    the move V0 belongs to ``new`` (None: a newborn material holding V0 alone) among ``n_after`` materials.
    """
    if share == 0.0:
        return 0.0
    cdf = layout.bonds.seed_cdf
    weights = 0.0 if share == 1.0 else (1.0 - share) * float(np.sum(np.diff(cdf, prepend=0.0)[members])) / float(
        cdf[-1])
    size = members.size
    n_old = int(np.count_nonzero(flat == old))
    n_new = size if new is None else int(np.count_nonzero(flat == new)) + size
    forward = weights + share * size / (layout.n_materials * n_old)
    reverse = weights + share * size / (n_after * n_new)
    return math.log(reverse) - math.log(forward)


def _birth(work, rng, problem, prior, new_prob, proposals, potts, max_materials, cluster, seed_ratio) -> Proposal:
    """The birth of a material for the cluster (see the module docstring)."""
    members, n_to, cut_to, old, data, stats_old, log_lik_old, p_new = cluster
    layout = work.layout
    n_mat = layout.n_materials
    slot = int(rng.integers(n_mat + 1))
    n_ch = problem.n_channels
    theta_born, term = material_term(data, None, prior, proposals, draw_rng=rng)
    pixels = layout.pixels.copy().ravel()
    pixels[pixels >= slot] += 1
    pixels[members] = slot
    pixels = pixels.reshape(layout.pixels.shape)
    if theta_born is None:
        return Proposal.invalid(layout.with_pixels(pixels, n_mat + 1))
    stats_born = stats_rows(data, theta_born[0, 2])
    p_other_back = label_choice(n_mat + 1, max_materials, new_prob)[1]
    log_ratio = (material_log_lik(stats_born, theta_born) - log_lik_old + seed_ratio
                 - potts.beta * n_to[old]                        # every edge from V0 to `old` is cut
                 + math.log(potts.rho) - math.log(n_mat + 1)      # rho^K and the labelled state's 1 / K!
                 + term
                 - cut_to[old]                                    # the reverse cuts nothing: V0 is all its material
                 + math.log(p_other_back)                         # the reverse death picks `old` back
                 - math.log(p_new) + math.log(n_mat + 1))         # NEW, and the slot's 1 / (K + 1)
    stats = work.stats.copy()
    stats[material_rows(old, n_ch)] -= stats_old
    stats = with_rows(stats, slot * n_ch, stats_born)
    theta = with_rows(work.theta, slot * n_ch, theta_born)
    return _proposal(work, problem, pixels, n_mat + 1, theta, stats, log_ratio)
