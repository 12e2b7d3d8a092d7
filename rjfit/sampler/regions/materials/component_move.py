"""Component moves of material labels: a connected piece of a material moved whole to another material, or born.

Why: a chain's start can hold in a paint's material pixels of another appearance (the k-means start put psm-cat's
shadowed creases, 1,700 px in 17 pieces, with its dark nose), which the target does not want (+765 in log
posterior without them) but which the label sweeps erode pixel by pixel and the data-driven cluster moves cut
into small clusters (the features vary inside a shadow, so the bonds between its pixels are weak): the chains
held them for 500 iterations (docs/results/2026-11-28-local-gain.md).

One move is a Swendsen-Wang-cut cluster move (:mod:`rjfit.sampler.regions.materials.cluster_swc`) whose bonds do
not read the data: every edge between two labelled pixels is on, between pixels of one label, with Swendsen and
Wang's ``q = 1 - exp(-beta)``, so the cluster is, but for thin necks, the seed's connected piece of its material,
and the cut factor of its boundary (``1 - q`` per edge to the rest of its material, and to the new label in the
reverse move) cancels the Potts prior's change. Its seed is a material drawn uniformly among the K, then a pixel
of it uniformly: the ratio holds the reverse move's chance of a seed in V0 over this one's
(:func:`~rjfit.sampler.regions.materials.cluster_swc.seed_log_ratio` with material seeds only). The rest, the
label choice, births and deaths, is the cluster move's (:func:`~rjfit.sampler.regions.materials.cluster_swc
.propose_set_move`), so the move is exact for the target as a cluster move is for any bonds.
"""
from __future__ import annotations

import numpy as np

from rjfit.sampler.moves.proposal import Proposal
from rjfit.sampler.regions.materials.cluster_swc import propose_set_move, seed_log_ratio
from rjfit.sampler.regions.materials.passes.labels import grow_cluster

__all__ = ["COMPONENT_KINDS", "propose_component_move"]

#: the names a component move is counted under: moved, born, dying
COMPONENT_KINDS = ("component", "component_birth", "component_death")


def propose_component_move(work, rng, problem, prior, new_prob: float, proposals, potts, max_materials: int,
                           jumps: bool = True) -> Proposal:
    """One component move's proposal (module docstring; untested when there is no move to test).

    Draws, in order: the material, the seed pixel in it, the bonds' key, then as a cluster move (the label choice's
    uniform, the other label or, for a birth, the slot and the new parameters).
    """
    layout = work.layout
    n_mat = layout.n_materials
    height, width = problem.image_shape
    flat = layout.pixels.ravel()
    seed = int(rng.choice(np.flatnonzero(flat == int(rng.integers(n_mat)))))
    key = np.uint64(rng.integers(0, 2 ** 63))
    members, n_to, cut_to = grow_cluster(flat, flat >= 0, layout.bonds.potts_q, key, seed, height, width, n_mat)

    def seed_ratio(new, n_after):
        return seed_log_ratio(1.0, layout, members, flat, int(flat[seed]), new, n_after)

    return propose_set_move(work, rng, problem, prior, (members, n_to, cut_to, seed_ratio), new_prob, proposals,
                            potts, max_materials, jumps, COMPONENT_KINDS)
