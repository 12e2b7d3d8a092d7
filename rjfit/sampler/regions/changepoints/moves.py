"""The change-point model's structure moves as objects with their settings (the move protocol:
:mod:`rjfit.sampler.moves.base`); :meth:`ChangepointRegions.schedule
<rjfit.sampler.regions.changepoints.model.ChangepointRegions.schedule>` lists them.

Each axis-choosing move draws its axis first ('u' or 'v' with probability 1/2); a move on an
axis without vectors does not apply (None: nothing counted).
"""
from __future__ import annotations

from dataclasses import dataclass

from rjfit.sampler.moves.base import Move, Sweep
from rjfit.sampler.moves.proposal import Proposal
from rjfit.sampler.moves.region_proposals import RegionProposalSettings
from rjfit.sampler.regions.changepoints.birth_death import (
    BirthDeathSettings,
    birth_probability,
    propose_birth,
    propose_death,
)
from rjfit.sampler.regions.changepoints.birth_death_free import propose_birth_free, propose_death_free
from rjfit.sampler.regions.changepoints.block_shift import BlockSettings, propose_block_shift
from rjfit.sampler.regions.changepoints.grid import ChangepointPrior
from rjfit.sampler.regions.changepoints.sweeps import SweepSettings, sweep_changepoints
from rjfit.sampler.regions.changepoints.vector_redraw import accept_vector_redraw, propose_vector_redraw

__all__ = ["ElementSweep", "BlockShift", "VectorRedraw", "BirthDeath"]


def _axis(rng) -> str:
    return "u" if rng.random() < 0.5 else "v"


def _vectors(layout, axis: str) -> int:
    return (layout.u if axis == "u" else layout.v).shape[1]


@dataclass(frozen=True)
class ElementSweep(Sweep):
    """One element of every other row (``axis`` 'u') or column ('v') of one ``parity`` moved at once (kind 'cp_u')."""

    settings: SweepSettings
    cp_prior: ChangepointPrior
    axis: str
    parity: int

    def run(self, work, rng, problem, prior, info) -> None:
        sweep_changepoints(work, rng, problem, self.settings, self.cp_prior, self.axis, info, self.parity)


@dataclass(frozen=True)
class BlockShift(Move):
    """A block of lines' elements shifted together, the regions it changes redrawn (kind 'block_u', 'block_v')."""

    settings: BlockSettings
    proposals: RegionProposalSettings
    cp_prior: ChangepointPrior

    def propose(self, work, rng, problem, prior) -> Proposal | None:
        axis = _axis(rng)
        if _vectors(work.layout, axis) == 0:
            return None
        return propose_block_shift(work, rng, problem, prior, self.settings, self.proposals, self.cp_prior,
                                   axis).named(f"block_{axis}")


@dataclass(frozen=True)
class VectorRedraw(Move):
    """One whole vector redrawn by forward filtering, backward sampling (kind 'vector_u', 'vector_v'); applied in
    place (only the observations that change region move between statistics)."""

    cp_prior: ChangepointPrior

    def propose(self, work, rng, problem, prior) -> Proposal | None:
        axis = _axis(rng)
        if _vectors(work.layout, axis) == 0:
            return None
        proposal = propose_vector_redraw(work, rng, problem, self.cp_prior, axis)
        # no path: nothing to test, and no uniform drawn
        return Proposal.untested(f"vector_{axis}") if proposal is None else proposal.named(f"vector_{axis}")

    def apply(self, work, problem, proposal: Proposal) -> None:
        accept_vector_redraw(work, problem, proposal.kind.removeprefix("vector_"), proposal)


@dataclass(frozen=True)
class BirthDeath(Move):
    """One birth or death of a change-point vector (kinds 'birth_u', 'death_free_v', ...): with probability
    ``settings.free_prob`` the pair at any rank of each line, otherwise the pair that keeps ranks."""

    settings: BirthDeathSettings
    proposals: RegionProposalSettings
    cp_prior: ChangepointPrior
    max_u: int
    max_v: int

    def propose(self, work, rng, problem, prior) -> Proposal | None:
        axis = _axis(rng)
        n, n_max = (work.layout.n_u, self.max_u) if axis == "u" else (work.layout.n_v, self.max_v)
        if n_max == 0:
            return None
        free = rng.random() < self.settings.free_prob
        birth = rng.random() < birth_probability(n, n_max)
        propose = ((propose_birth_free if birth else propose_death_free) if free
                   else (propose_birth if birth else propose_death))
        proposal = propose(work, rng, problem, prior, self.settings, self.proposals, self.cp_prior, n_max, axis)
        return proposal.named(f"{'birth' if birth else 'death'}{'_free' if free else ''}_{axis}", jump=True)
