"""The paper's region model: two-dimensional change points (sec. 3.3) and their structure moves.

Layout: :class:`~rjfit.sampler.regions.changepoints.grid.Changepoints` (u and v vectors; the
geometry, labels and prior are in :mod:`rjfit.sampler.regions.changepoints.grid`). Each
iteration's structure moves (:meth:`ChangepointRegions.schedule`, the moves of
:mod:`rjfit.sampler.regions.changepoints.moves`), in order:

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

from rjfit.sampler.moves.base import Scheduled
from rjfit.sampler.moves.region_proposals import RegionProposalSettings
from rjfit.sampler.regions.base import RegionModel
from rjfit.sampler.regions.changepoints.birth_death import BirthDeathSettings
from rjfit.sampler.regions.changepoints.block_shift import BlockSettings
from rjfit.sampler.regions.changepoints.grid import ChangepointPrior, Changepoints, n_regions
from rjfit.sampler.regions.changepoints.moves import BirthDeath, BlockShift, ElementSweep, VectorRedraw
from rjfit.sampler.regions.changepoints.sweeps import SweepSettings
from rjfit.sampler.regions.changepoints.vector_redraw import VectorSettings

__all__ = ["ChangepointRegions"]


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

    def schedule(self) -> list:
        """Element sweeps (u rows of each parity, then v), then by chance a block shift, a vector redraw and a
        birth or death (each chance's uniform drawn every iteration while the move is on)."""
        schedule = []
        if self.update_changepoints:
            schedule += [Scheduled(ElementSweep(self.sweep, self.prior, axis, parity))
                         for axis in ("u", "v") for parity in (0, 1)]
            if self.block.prob > 0:
                schedule.append(Scheduled(BlockShift(self.block, self.proposals, self.prior), chance=self.block.prob))
            if self.vector.prob > 0:
                schedule.append(Scheduled(VectorRedraw(self.prior), chance=self.vector.prob))
        if self.jumps:
            schedule.append(Scheduled(BirthDeath(self.birth_death, self.proposals, self.prior, self.max_u, self.max_v),
                                      chance=self.birth_death.prob))
        return schedule

    def snapshot(self, layout) -> dict:
        return {"cp_u": layout.u, "cp_v": layout.v}

    def snapshot_shapes(self, problem) -> dict:
        return {"cp_u": (problem.height, self.max_u), "cp_v": (problem.width, self.max_v)}
