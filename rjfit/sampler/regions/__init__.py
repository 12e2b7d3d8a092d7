"""Region models: what partitions the pixels into regions, and how the partition moves.

:mod:`~rjfit.sampler.regions.base` states the contract (:class:`RegionModel`);
:mod:`~rjfit.sampler.regions.changepoints` is the paper's model (change-point vectors,
:class:`ChangepointRegions`), whose geometry and prior are in
:mod:`~rjfit.sampler.regions.changepoint_grid`.
"""
from rjfit.sampler.regions.base import RegionModel
from rjfit.sampler.regions.changepoint_grid import ChangepointPrior, Changepoints
from rjfit.sampler.regions.changepoints import ChangepointRegions

__all__ = ["RegionModel", "ChangepointPrior", "Changepoints", "ChangepointRegions"]
