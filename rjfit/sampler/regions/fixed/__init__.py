"""The user's own label map as the regions (``rjfit fit --regions fixed --labels FILE``): nothing but the BRDFs sampled.

:class:`~rjfit.sampler.regions.fixed.model.FixedRegions` holds one region per label of a map
the user gives; the layout never moves, so only the kernel's within-region moves run (each
label's (I0, kd, gamma, sigma^2)). Its summary, result files and printed line are
:mod:`rjfit.pipeline.regions.fixed`'s.
"""
from rjfit.sampler.regions.fixed.model import FixedLabels, FixedRegions

__all__ = ["FixedLabels", "FixedRegions"]
