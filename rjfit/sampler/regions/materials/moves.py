"""The material model's label moves as objects with their settings (the move protocol:
:mod:`rjfit.sampler.moves.base`); :meth:`MaterialRegions.schedule
<rjfit.sampler.regions.materials.model.MaterialRegions.schedule>` lists them.
"""
from __future__ import annotations

from dataclasses import dataclass

from rjfit.sampler.moves.base import Move, Sweep
from rjfit.sampler.moves.proposal import Proposal
from rjfit.sampler.moves.region_proposals import RegionProposalSettings
from rjfit.sampler.regions.materials.cluster_swc import ClusterSettings, propose_cluster_move
from rjfit.sampler.regions.materials.component_move import propose_component_move
from rjfit.sampler.regions.materials.label_gibbs import sweep_labels
from rjfit.sampler.regions.materials.layout import PottsPrior
from rjfit.sampler.regions.materials.merge_split import MergeSplitSettings, propose_merge_split
from rjfit.sampler.regions.materials.scatter_move import propose_scatter_move
from rjfit.sampler.regions.materials.segment_move import propose_segment_move

__all__ = ["LabelSweep", "ClusterMove", "ComponentMove", "SegmentMove", "MergeSplit", "SpatialMergeSplit",
           "ScatterMove"]


@dataclass(frozen=True)
class LabelSweep(Sweep):
    """A checkerboard Gibbs sweep of the labels over the existing materials (kind 'label_gibbs')."""

    potts: PottsPrior

    def run(self, work, rng, problem, prior, info) -> None:
        sweep_labels(work, rng, problem, self.potts, info)


@dataclass(frozen=True)
class ClusterMove(Move):
    """A Swendsen-Wang-cut cluster moved to another material or a new one, or a whole material moved (kinds
    'cluster', 'cluster_birth', 'cluster_death')."""

    settings: ClusterSettings
    proposals: RegionProposalSettings
    potts: PottsPrior
    max_materials: int
    jumps: bool

    def propose(self, work, rng, problem, prior) -> Proposal:
        return propose_cluster_move(work, rng, problem, prior, self.settings, self.proposals, self.potts,
                                    self.max_materials, self.jumps)


@dataclass(frozen=True)
class _WholeSetMove(Move):
    """A set of pixels that one material holds moved whole to another material or a new one: the settings the
    component and segment moves share; a subclass names how the set is drawn (``propose_set``, the signature of
    :func:`propose_component_move` and :func:`propose_segment_move`)."""

    new_prob: float
    proposals: RegionProposalSettings
    potts: PottsPrior
    max_materials: int
    jumps: bool

    def propose(self, work, rng, problem, prior) -> Proposal:
        return self.propose_set(work, rng, problem, prior, self.new_prob, self.proposals, self.potts,
                                self.max_materials, self.jumps)


@dataclass(frozen=True)
class ComponentMove(_WholeSetMove):
    """A connected piece of a material moved whole to another material or a new one, or a whole material moved
    (kinds 'component', 'component_birth', 'component_death')."""

    propose_set = staticmethod(propose_component_move)


@dataclass(frozen=True)
class SegmentMove(_WholeSetMove):
    """A segment of the data-driven family, when one material holds all of it, moved to another material or a new
    one (kinds 'segment', 'segment_birth', 'segment_death')."""

    propose_set = staticmethod(propose_segment_move)


@dataclass(frozen=True)
class MergeSplit(Move):
    """A merge of two whole materials or a split of one (kinds 'merge', 'split')."""

    settings: MergeSplitSettings
    proposals: RegionProposalSettings
    potts: PottsPrior
    max_materials: int

    def propose(self, work, rng, problem, prior) -> Proposal:
        return propose_merge_split(work, rng, problem, prior, self.settings, self.proposals, self.potts,
                                   self.max_materials)


@dataclass(frozen=True)
class SpatialMergeSplit(MergeSplit):
    """A split of one material into the two spatial halves of its pixels, or the merge of two that are the halves of
    their union (kinds 'spatial_split', 'spatial_merge')."""

    def propose(self, work, rng, problem, prior) -> Proposal:
        return propose_merge_split(work, rng, problem, prior, self.settings, self.proposals, self.potts,
                                   self.max_materials, spatial=True)


@dataclass(frozen=True)
class ScatterMove(Move):
    """A whole material dissolved into the others pixel by pixel, or a material born of pixels anywhere (kinds
    'dissolve', 'scatter_birth'; one channel)."""

    proposals: RegionProposalSettings
    potts: PottsPrior
    max_materials: int

    def propose(self, work, rng, problem, prior) -> Proposal | None:
        return propose_scatter_move(work, rng, problem, prior, self.potts, self.proposals, self.max_materials)
