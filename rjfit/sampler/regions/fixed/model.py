"""A fixed label map as the region model: one region per label, the layout never moves.

The layout (:class:`FixedLabels`) is a label per pixel, 0 .. K - 1 (-1: no label, allowed only
where a pixel has no observation); its prior is a constant, so it adds nothing to the target;
there are no structure moves, and the chain records no model key and no snapshot (the layout
is the same in every draw). What the sampler does is the kernel's within-region moves: the
posterior of each label's BRDF parameters given the labels.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from rjfit.sampler.regions.base import RegionModel, pixel_labels_per_observation

__all__ = ["FixedLabels", "FixedRegions"]


class FixedLabels(NamedTuple):
    """The layout: ``pixels`` (H, W) label per pixel (-1 unlabelled) and the number of labels K."""

    pixels: np.ndarray
    n_labels: int

    @property
    def n_regions(self) -> int:
        return int(self.n_labels)

    @property
    def model_key(self) -> tuple:
        """Empty: every draw has the same layout."""
        return ()

    def labels(self, problem) -> np.ndarray:
        """The label of every observation of ``problem`` (its pixel's, repeated per observation); for a
        joint colour fit its parameter row, ``label C + channel``."""
        return pixel_labels_per_observation(self.pixels, self.n_labels, problem)


@dataclass(frozen=True)
class FixedRegions(RegionModel):
    """Regions given by a label map, held fixed.

    Attributes
    ----------
    n_labels : int
        K, the number of labels (the width of the recorded parameter arrays); the map itself
        is each chain's start (``pixel_labels``), so the settings stay small.
    """

    n_labels: int = 1

    key_names = ()

    def __post_init__(self):
        if self.n_labels < 1:
            raise ValueError(f"a fixed label map needs at least one label, got {self.n_labels}")

    @property
    def max_regions(self) -> int:
        return self.n_labels

    def initial_layout(self, problem, rng, *, pixel_labels=None) -> FixedLabels:
        """The layout of ``pixel_labels`` (H, W): labels 0 .. n_labels - 1, -1 where a pixel has no observation.

        Raises
        ------
        ValueError
            If ``pixel_labels`` is missing, not of the images' shape, holds a label outside
            -1 .. n_labels - 1, or gives no label to a pixel with observations.
        """
        if pixel_labels is None:
            raise ValueError("the fixed region model needs its label map (pixel_labels)")
        pixels = np.asarray(pixel_labels)
        if pixels.shape != tuple(problem.image_shape):
            raise ValueError(f"the label map has shape {pixels.shape}, the images {tuple(problem.image_shape)}")
        if pixels.min() < -1 or pixels.max() >= self.n_labels:
            raise ValueError(f"the label map's labels must lie in -1 .. {self.n_labels - 1}")
        observed = np.diff(problem.pixel_start) > 0
        unlabelled = np.flatnonzero(observed & (pixels.ravel() < 0))
        if unlabelled.size:
            row, col = divmod(int(unlabelled[0]), problem.width)
            raise ValueError(f"the label map leaves {unlabelled.size} pixels with observations unlabelled "
                             f"(the first at row {row}, column {col})")
        return FixedLabels(pixels.astype(np.int16), self.n_labels)

    def log_prior(self, problem, layout) -> float:
        return 0.0

    def schedule(self) -> list:
        """No structure move: the labels are the user's."""
        return []

    def snapshot(self, layout) -> dict:
        return {}

    def snapshot_shapes(self, problem) -> dict:
        return {}
