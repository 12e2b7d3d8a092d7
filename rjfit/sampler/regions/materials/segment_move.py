"""Segment moves of material labels: a data-driven region of the image moved to another material, or born.

Why: the cluster moves grow a cluster along bonds pixel by pixel; where a paint's per-pixel
features are noisy (measured stacks) the bonds cannot follow its outline, and a compact
region of a second paint is never proposed (psm-rock's pebble; docs/results/materials.md). A
segment move proposes a whole region that pooled features single out.

One move:

1. a set S from the fixed family of candidate sets
   (:func:`~rjfit.sampler.regions.materials.segments.segment_family`: the nodes of a Ward
   hierarchy of superpixels of the data), drawn with its fixed weight w_S;
2. if S's pixels do not all carry one label l, no move (counted as a rejection);
   otherwise V0 = S is moved as a cluster move moves its cluster
   (:func:`~rjfit.sampler.regions.materials.cluster_swc.propose_set_move`): to NEW with probability
   ``p_new(K)``, else to one of the K - 1 other labels uniformly; a birth when S is not all
   of l, a death when it is and the new label exists, no move when it is and the label is NEW.

The reverse of every move made is the same move on the same S (after it, S carries one label
again), drawn with the same w_S: the proposal's set probability cancels, and the bonds play
no part (no cut products). The ratio is then the cluster move's with ``cut_to = 0`` and no
seed term: the likelihood of S under both materials, the Potts change, ``rho^K``, ``1 / K!``,
and for a birth or death the label choice's and slot's probabilities and the born material's
proposal density.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rjfit.sampler.moves.proposal import Proposal
from rjfit.sampler.regions.materials.cluster_swc import propose_set_move
from rjfit.sampler.regions.materials.passes.labels import edges_to_labels as count_edges_to_labels

__all__ = ["SegmentSettings", "SEGMENT_KINDS", "edges_to_labels", "propose_segment_move"]

#: the names a segment move is counted under: moved, born, dying
SEGMENT_KINDS = ("segment", "segment_birth", "segment_death")


@dataclass(frozen=True)
class SegmentSettings:
    """How the segment moves run.

    Attributes
    ----------
    moves : int
        Segment moves per iteration (0: none, and no family is built).
    superpixel_size : int
        The family's superpixels' target size in pixels.
    max_regions : int
        The finest cut of the family's hierarchy that sets are drawn from.
    """

    moves: int = 2
    superpixel_size: int = 32
    max_regions: int = 64

    def __post_init__(self):
        if self.moves < 0:
            raise ValueError(f"segment moves per iteration must be >= 0, got {self.moves}")
        if self.superpixel_size < 1 or self.max_regions < 2:
            raise ValueError(f"segment superpixel_size must be >= 1 and max_regions >= 2, got "
                             f"{self.superpixel_size}, {self.max_regions}")


def edges_to_labels(pixels, members, n_labels: int) -> np.ndarray:
    """Per label, the number of 4-neighbour edges from the pixels ``members`` to labelled pixels of
    that label outside them (``pixels`` (H, W), -1 unlabelled)."""
    height, width = pixels.shape
    return count_edges_to_labels(np.ascontiguousarray(pixels).ravel(), np.asarray(members, np.int64), int(n_labels),
                                 height, width)


def _no_seed_term(new, n_after) -> float:
    return 0.0


def propose_segment_move(work, rng, problem, prior, new_prob: float, proposals, potts, max_materials: int,
                         jumps: bool = True):
    """One segment move's proposal (untested when there is no move to test: :meth:`Proposal.untested`).

    Its ``kind`` is one of :data:`SEGMENT_KINDS` (a birth and a death jump). Draws, in order: the set, then the cluster
    move's label choice (its uniform, the other label or the slot and the new parameters).
    """
    layout = work.layout
    members = layout.bonds.segments.draw(rng)
    flat = layout.pixels.ravel()
    labels = flat[members]
    if np.any(labels != labels[0]):
        return Proposal.untested(SEGMENT_KINDS[0])
    n_to = edges_to_labels(layout.pixels, members, layout.n_materials)
    return propose_set_move(work, rng, problem, prior, (members, n_to, np.zeros(layout.n_materials), _no_seed_term),
                            new_prob, proposals, potts, max_materials, jumps, SEGMENT_KINDS)
