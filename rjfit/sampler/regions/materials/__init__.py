"""Free-form materials under a Potts prior (issue 27), in one place: layout, prior, moves, compiled passes.

- :mod:`~rjfit.sampler.regions.materials.model`: :class:`MaterialRegions` (its settings, start,
  prior, label moves, records);
- :mod:`~rjfit.sampler.regions.materials.layout`: the layout (:class:`MaterialLabels`), the
  Potts prior, the bonds and the start's k-means labels;
  :mod:`~rjfit.sampler.regions.materials.segments`: the segment moves' family of candidate sets;
  :mod:`~rjfit.sampler.regions.materials.kmeans`: the k-means of pixel features (start, split guide);
  :mod:`~rjfit.sampler.regions.materials.edges`: the edge term of the target (``--edge-power``);
- its label moves, one family per module with its settings:
  :mod:`~rjfit.sampler.regions.materials.label_gibbs` (checkerboard Gibbs sweeps),
  :mod:`~rjfit.sampler.regions.materials.cluster_swc` (Swendsen-Wang-cut cluster moves),
  :mod:`~rjfit.sampler.regions.materials.segment_move` (segment moves),
  :mod:`~rjfit.sampler.regions.materials.merge_split` (merges and splits of whole materials);
- :mod:`~rjfit.sampler.regions.materials.passes`: its compiled (Numba) passes (label sweeps,
  the edge term's sums, Lloyd's iterations).

The joint colour fit (:mod:`rjfit.sampler.colour`, :mod:`rjfit.sampler.moves.colour_within`)
and the pixel-set memo (:mod:`rjfit.sampler.pixel_sets`) stay beside the kernel: the forward
model, the kernel's start and its within-region moves read them, whatever the region model.
The summary, result files and printed line of a material fit are the pipeline layer's
(:mod:`rjfit.pipeline.regions.materials`), which may import the posterior.
"""
from rjfit.sampler.regions.materials.layout import MaterialLabels, PottsPrior
from rjfit.sampler.regions.materials.model import START_MATERIALS, MaterialRegions

__all__ = ["MaterialLabels", "MaterialRegions", "PottsPrior", "START_MATERIALS"]
