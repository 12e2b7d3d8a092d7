"""Baselines side by side: k-means, multichannel k-means, GMM with pixel positions, normalized cuts.

- :mod:`rjfit.baselines.methods`: the segmentations, pure functions over arrays;
- :mod:`rjfit.baselines.metrics`: pixel accuracy, adjusted Rand index, boundary F1 after
  Hungarian matching;

``rjfit compare`` (:mod:`rjfit.pipeline.compare`) runs them on a data set beside a fit.
"""
from rjfit.baselines.methods import (
                                     gmm_position_segmentation,
                                     kmeans_segmentation,
                                     multichannel_kmeans,
                                     normalized_cuts,
                                     pick_ncut_image,
)
from rjfit.baselines.metrics import (
                                     adjusted_rand,
                                     boundary_f1,
                                     boundary_map,
                                     match_labels,
                                     pixel_accuracy,
                                     segmentation_metrics,
)

__all__ = ["kmeans_segmentation", "multichannel_kmeans",
           "gmm_position_segmentation", "normalized_cuts", "pick_ncut_image", "match_labels", "pixel_accuracy",
           "adjusted_rand", "boundary_map", "boundary_f1", "segmentation_metrics"]
