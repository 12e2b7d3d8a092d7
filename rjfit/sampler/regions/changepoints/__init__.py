"""The paper's region model, change points (sec. 3.3), in one place: layout, prior, moves, compiled passes.

- :mod:`~rjfit.sampler.regions.changepoints.model`: :class:`ChangepointRegions` (its settings,
  start, prior, structure moves, records);
- :mod:`~rjfit.sampler.regions.changepoints.grid`: the layout (:class:`Changepoints`, the u and
  v vectors), its geometry, labels and prior;
- its structure moves, one family per module with its settings:
  :mod:`~rjfit.sampler.regions.changepoints.sweeps` (element sweeps),
  :mod:`~rjfit.sampler.regions.changepoints.block_shift`,
  :mod:`~rjfit.sampler.regions.changepoints.vector_redraw` (forward filtering, backward sampling),
  :mod:`~rjfit.sampler.regions.changepoints.birth_death` (births/deaths keeping ranks, split/merge maps),
  :mod:`~rjfit.sampler.regions.changepoints.birth_death_free` (births/deaths at any rank);
- :mod:`~rjfit.sampler.regions.changepoints.passes`: its compiled (Numba) passes (the sweep's
  proposals; forward filtering, backward sampling and rank chains).

The per-cell sums (:mod:`rjfit.sampler.passes.cells`) and the element shifts
(:mod:`rjfit.sampler.passes.shifts`) stay with the shared passes: the material model's label
passes use them too. The summary, result files and printed line of a change-point fit are the
pipeline layer's (:mod:`rjfit.pipeline.regions.changepoints`), which may import the posterior.
"""
from rjfit.sampler.regions.changepoints.grid import ChangepointPrior, Changepoints, model_number, pixel_region_labels
from rjfit.sampler.regions.changepoints.model import ChangepointRegions

__all__ = ["ChangepointPrior", "ChangepointRegions", "Changepoints", "model_number", "pixel_region_labels"]
