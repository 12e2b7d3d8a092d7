"""The move protocol: a move is an object with its settings that proposes a :class:`Proposal`; one test decides.

A structure move (:class:`Move`) proposes a :class:`~rjfit.sampler.moves.proposal.Proposal`
that says its ``kind`` (its name in the step's acceptance counts) and whether it changes the
model's dimension (``jump``: a birth, death, merge or split); :func:`decide` is the one
Metropolis-Hastings test of every proposal, and :meth:`Move.apply` makes an accepted one the
current state (:meth:`~rjfit.sampler.state.Work.take`, or in place for an incremental one).
A sweep (many elements or pixels tested at once, each with its own ratio) is a move whose
:meth:`Move.run` is the sweep; its tests use the same accept (:func:`rjfit.sampler.moves.accept.accept`).
A within-region move proposes a :class:`~rjfit.sampler.moves.proposal.RowProposal` (one parameter row,
its uniform already drawn) that :func:`decide_row` tests with the same accept.

A region model's structure moves are a schedule, a weighted list of moves (as emcee's move
schedule, but run in a fixed order, so that a seed fixes the chain): each :class:`Scheduled`
entry runs its move ``times`` times per iteration, or, with a ``chance``, once with that
probability (its uniform drawn every iteration). :func:`run_schedule` runs one iteration's.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from typing import NamedTuple

import numpy as np

from rjfit.sampler.moves.accept import accept
from rjfit.sampler.moves.proposal import Proposal, RowProposal
from rjfit.sampler.moves.region_terms import set_region

__all__ = ["Move", "Sweep", "Scheduled", "decide", "decide_row", "run_schedule"]


def decide(work, rng, proposal: Proposal, info) -> bool:
    """The one test of a proposal on ``work``: draw its uniform, decide, count it under ``proposal.kind``.

    A proposal with nothing to test (``proposal.tested`` False) is counted as a rejection and
    draws nothing. The region model's edge term in the target (``work.edges``) adds its change
    to a valid proposal's ratio. A NaN ratio is a counted rejection
    (:func:`~rjfit.sampler.moves.accept.accept`).
    """
    if not proposal.tested:
        info.count(proposal.kind, False)
        return False
    log_ratio = proposal.log_ratio
    if work.edges is not None and log_ratio > -np.inf:      # the target's edge term (materials)
        log_ratio += (work.edges.total(proposal.layout.pixels, proposal.theta, work.edge_memo)
                      - work.edges.total(work.layout.pixels, work.theta, work.edge_memo))
    accepted = accept(np.log(rng.random()), log_ratio, info, proposal.kind)
    info.count(proposal.kind, accepted)
    return accepted


def decide_row(work, proposal: RowProposal, info) -> bool:
    """The one test of a within-region move's ``proposal`` (its uniform already drawn); makes an accepted one
    its row's in ``work``. Counting is the move's (some count a family's tests together)."""
    if accept(proposal.log_u, proposal.log_ratio, info, proposal.kind):
        set_region(work, proposal.r, proposal.theta, proposal.stats, proposal.log_lik)
        return True
    return False


class Move(ABC):
    """A move of the region layout with its settings (the subclass's fields)."""

    @abstractmethod
    def propose(self, work, rng, problem, prior) -> Proposal | None:
        """A proposal from the working copy ``work`` (not changed), or None where the move does not apply to it
        (nothing drawn after that point, nothing counted)."""

    def apply(self, work, problem, proposal: Proposal) -> None:
        """Make the accepted ``proposal`` the current state of ``work``."""
        work.take(proposal)

    def run(self, work, rng, problem, prior, info) -> None:
        """Propose, test, apply if accepted; an accepted jump is the step's (``info.jump``)."""
        proposal = self.propose(work, rng, problem, prior)
        if proposal is not None and decide(work, rng, proposal, info):
            self.apply(work, problem, proposal)
            if proposal.jump:
                info.jump = proposal.kind


class Sweep(ABC):
    """A move that tests many elements (rows of change points, pixels' labels) at once, each with its own ratio;
    its settings are the subclass's fields."""

    @abstractmethod
    def run(self, work, rng, problem, prior, info) -> None:
        """One sweep over ``work`` (in place), its tests counted in ``info``."""


class Scheduled(NamedTuple):
    """One entry of a region model's move schedule: ``move`` run ``times`` times per iteration or, with a
    ``chance``, once with that probability."""

    move: Move | Sweep
    times: int = 1
    chance: float | None = None


def run_schedule(schedule, work, rng, problem, prior, info) -> None:
    """Run one iteration of ``schedule`` (a list of :class:`Scheduled`) on ``work``, in order."""
    for entry in schedule:
        if entry.chance is not None:
            if rng.random() < entry.chance:
                entry.move.run(work, rng, problem, prior, info)
            continue
        for _ in range(entry.times):
            entry.move.run(work, rng, problem, prior, info)
