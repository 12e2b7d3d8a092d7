"""The paper's region model: two-dimensional change points (sec. 3.3) and their structure moves.

Layout: :class:`~rjfit.sampler.regions.changepoints.grid.Changepoints` (u and v vectors; the
geometry, labels and prior are in :mod:`rjfit.sampler.regions.changepoints.grid`). Each
iteration's structure moves, in order:

1. sweeps of u change-point elements (one element per row; even rows, then odd rows) and
   likewise of v elements (:mod:`rjfit.sampler.regions.changepoints.sweeps`);
2. with probability ``block.prob`` a block shift (:mod:`rjfit.sampler.regions.changepoints.block_shift`);
3. with probability ``vector.prob`` a redraw of one whole vector
   (:mod:`rjfit.sampler.regions.changepoints.vector_redraw`);
4. with probability ``birth_death.prob``, one birth or death of a change-point vector: with
   probability ``birth_death.free_prob`` the pair whose vector may sit at any rank of each
   line (every region redrawn, :mod:`rjfit.sampler.regions.changepoints.birth_death_free`), otherwise the
   pair that keeps ranks (the regions the vector cuts redrawn or split,
   :mod:`rjfit.sampler.regions.changepoints.birth_death`).

Each is a valid Metropolis-Hastings move on its own, so their composition leaves the
posterior invariant.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rjfit.sampler.moves.accept import accept
from rjfit.sampler.regions.changepoints.birth_death import BirthDeathSettings, birth_probability, propose_birth, propose_death
from rjfit.sampler.regions.changepoints.birth_death_free import propose_birth_free, propose_death_free
from rjfit.sampler.regions.changepoints.block_shift import BlockSettings, propose_block_shift
from rjfit.sampler.moves.region_proposals import RegionProposalSettings
from rjfit.sampler.regions.changepoints.sweeps import SweepSettings, sweep_changepoints
from rjfit.sampler.regions.changepoints.vector_redraw import VectorSettings, accept_vector_redraw, propose_vector_redraw
from rjfit.sampler.regions.base import RegionModel
from rjfit.sampler.regions.changepoints.grid import ChangepointPrior, Changepoints, n_regions

__all__ = ["ChangepointRegions"]


def _axis(rng) -> str:
    return "u" if rng.random() < 0.5 else "v"


def _tested(rng, proposal, info, kind: str) -> bool:
    """Draw the proposal's uniform, decide, count: the test of a full proposal (an invalid one too)."""
    accepted = accept(np.log(rng.random()), proposal.log_ratio, info, kind)
    info.count(kind, accepted)
    return accepted


@dataclass(frozen=True)
class ChangepointRegions(RegionModel):
    """Regions from change-point vectors, with the settings of their structure moves.

    Attributes
    ----------
    max_u, max_v : int
        Maximum numbers of u and v change-point vectors (the model space).
    prior : ChangepointPrior
        Prior of change-point elements (flat options ``cp_prior``, ``cp_smooth_sd``).
    update_changepoints, jumps : bool
        Whether change-point elements move (sweeps, block shifts, vector redraws) and
        whether births/deaths are tried (both False: the segmentation is fixed).
    sweep, block, vector, birth_death : settings
        Of each structure move (see their modules).
    proposals : RegionProposalSettings
        Of the proposals of whole regions' parameters that block shifts and births/deaths use.
    """

    max_u: int = 3
    max_v: int = 3
    prior: ChangepointPrior = field(default_factory=ChangepointPrior)
    update_changepoints: bool = True
    jumps: bool = True
    sweep: SweepSettings = field(default_factory=SweepSettings)
    block: BlockSettings = field(default_factory=BlockSettings)
    vector: VectorSettings = field(default_factory=VectorSettings)
    birth_death: BirthDeathSettings = field(default_factory=BirthDeathSettings)
    proposals: RegionProposalSettings = field(default_factory=RegionProposalSettings)

    key_names = ("n_u", "n_v")

    def __post_init__(self):
        if self.max_u < 0 or self.max_v < 0:
            raise ValueError(f"max_u and max_v must be >= 0, got {self.max_u}, {self.max_v}")

    @property
    def max_regions(self) -> int:
        return n_regions(self.max_u, self.max_v)

    def initial_layout(self, problem, rng, *, model=None, changepoints=None) -> Changepoints:
        """A dispersed start: ``changepoints`` (u, v) if given, else straight vectors of ``model`` (n_u, n_v).

        The default model is a random one from {0, 1} x {0, 1} within the maxima; the
        straight vectors sit at uniform positions across the object's bounding box.

        Raises
        ------
        ValueError
            If ``model`` exceeds ``max_u`` or ``max_v``.
        """
        height, width = problem.image_shape
        if changepoints is not None:
            u, v = (np.asarray(c, float) for c in changepoints)
            return Changepoints.from_arrays(u.reshape(height, -1), v.reshape(width, -1), problem.image_shape)
        if model is None:
            model = (int(rng.integers(min(1, self.max_u) + 1)), int(rng.integers(min(1, self.max_v) + 1)))
        n_u, n_v = model
        if n_u > self.max_u or n_v > self.max_v:
            raise ValueError(f"start model {model} exceeds max_u={self.max_u}, max_v={self.max_v}")
        rows, cols = np.nonzero(problem.object_mask)
        if rows.size == 0:
            rows, cols = np.arange(height), np.arange(width)
        u = np.tile(np.sort(rng.uniform(cols.min(), cols.max() + 1.0, n_u)), (height, 1))
        v = np.tile(np.sort(rng.uniform(rows.min(), rows.max() + 1.0, n_v)), (width, 1))
        return Changepoints.from_arrays(u, v, problem.image_shape)

    def log_prior(self, problem, layout) -> float:
        return self.prior.log_density(layout.u, layout.v, problem.image_shape)

    def structure_moves(self, work, rng, problem, prior, info) -> None:
        if self.update_changepoints:
            for axis in ("u", "v"):
                for parity in (0, 1):
                    sweep_changepoints(work, rng, problem, self.sweep, self.prior, axis, info, parity)
        if self.update_changepoints and self.block.prob > 0 and rng.random() < self.block.prob:
            self._block_shift(work, rng, problem, prior, info)
        if self.update_changepoints and self.vector.prob > 0 and rng.random() < self.vector.prob:
            self._vector_redraw(work, rng, problem, info)
        if self.jumps and rng.random() < self.birth_death.prob:
            self._birth_death(work, rng, problem, prior, info)

    def _block_shift(self, work, rng, problem, prior, info):
        axis = _axis(rng)
        if (work.layout.u if axis == "u" else work.layout.v).shape[1] > 0:
            proposal = propose_block_shift(work, rng, problem, prior, self.block, self.proposals, self.prior, axis)
            if _tested(rng, proposal, info, f"block_{axis}"):
                work.take(proposal)

    def _vector_redraw(self, work, rng, problem, info):
        axis = _axis(rng)
        if (work.layout.u if axis == "u" else work.layout.v).shape[1] > 0:
            proposal = propose_vector_redraw(work, rng, problem, self.prior, axis)
            # no path (None): nothing to test, and no uniform drawn
            accepted = proposal is not None and accept(np.log(rng.random()), proposal.log_ratio, info,
                                                       f"vector_{axis}")
            info.count(f"vector_{axis}", accepted)
            if accepted:
                accept_vector_redraw(work, problem, axis, proposal)

    def _birth_death(self, work, rng, problem, prior, info):
        axis = _axis(rng)
        n, n_max = (work.layout.n_u, self.max_u) if axis == "u" else (work.layout.n_v, self.max_v)
        if n_max == 0:
            return
        free = rng.random() < self.birth_death.free_prob
        birth = rng.random() < birth_probability(n, n_max)
        propose = ((propose_birth_free if birth else propose_death_free) if free
                   else (propose_birth if birth else propose_death))
        proposal = propose(work, rng, problem, prior, self.birth_death, self.proposals, self.prior, n_max, axis)
        kind = f"{'birth' if birth else 'death'}{'_free' if free else ''}_{axis}"
        if _tested(rng, proposal, info, kind):
            work.take(proposal)
        info.jump = kind

    def snapshot(self, layout) -> dict:
        return {"cp_u": layout.u, "cp_v": layout.v}

    def snapshot_shapes(self, problem) -> dict:
        return {"cp_u": (problem.height, self.max_u), "cp_v": (problem.width, self.max_v)}
