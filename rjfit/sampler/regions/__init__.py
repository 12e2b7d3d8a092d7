"""Region models: what partitions the pixels into regions, and how the partition moves.

:mod:`~rjfit.sampler.regions.base` states the contract (:class:`RegionModel`); each model is one
package holding its layout, prior, moves and compiled passes:
:mod:`~rjfit.sampler.regions.changepoints` (the paper's change-point vectors,
:class:`ChangepointRegions`) and :mod:`~rjfit.sampler.regions.materials` (free-form materials
under a Potts prior, :class:`~rjfit.sampler.regions.materials.MaterialRegions`). A model's
summary, result files and printed line are the pipeline layer's (:mod:`rjfit.pipeline.regions`).
"""
from rjfit.sampler.regions.base import RegionModel
from rjfit.sampler.regions.changepoints import ChangepointPrior, ChangepointRegions, Changepoints

__all__ = ["RegionModel", "ChangepointPrior", "Changepoints", "ChangepointRegions"]
