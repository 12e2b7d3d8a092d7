"""Two-dimensional change points (paper, sec. 3.3) and the regions they induce.

A u change point is a vector of ``H`` column positions, one per image row; a v change point
is a vector of ``W`` row positions, one per column. Positions are continuous with prior
U(-1, W+1) (resp. U(-1, H+1)) per element. Pixel ``(r, c)`` has its centre at
``(r + 0.5, c + 0.5)``; an element ``x`` of row ``r`` is *left of* the pixel when
``x < c + 0.5`` (and a v element ``y`` of column ``c`` is *above* it when ``y < r + 0.5``).
The region of a pixel is ``(iu, iv)`` = (number of u elements left of it in its row,
number of v elements above it in its column), indexed ``iu * (n_v + 1) + iv``
(the paper's indicator matrix, eq. 9).

Crossing vectors. The region of a pixel depends only on those counts, never on which
vector an element belongs to, so the change points of one row form a multiset. The
sampler stores each row's (column's) elements sorted: vector k is the k-th order
statistic of every row. Vectors therefore never cross; an element move that passes a
neighbour just reorders the row. The prior of the sorted representation is the density of
order statistics of iid uniforms, ``n! / (W + 2)^n`` per row (:func:`log_prior_changepoints`).

Change-point priors. ``'paper'``: every element iid U(-1, size + 1) (sorted: order
statistics, :func:`log_prior_changepoints`); rows are independent, so a vector is free to
zig-zag and an extra vector can follow the noise row by row, or hide in the off-object part
of each row, at little prior cost. ``'smooth'`` (rjfit's default): the first element of
vector k is U(-1, size + 1) and each further element is the previous one plus N(0, s^2),
``log f = sum_k [-log(size + 2) + sum_r log N(x_{r,k} - x_{r-1,k}; 0, s^2)]`` restricted to
[-1, size + 1] (vector k = rank k). This density is left unnormalised over the sorted,
truncated set: the model prior over (n_u, n_v) is then the uniform one times those
normalisers, a proper prior all the same (finite for every model), and the sampler needs
only ratios. Boundaries of real regions are continuous curves, so this prior puts its mass
where they are, and extra vectors pay for their freedom.

The layout of a chain state (:class:`Changepoints`) is the pair (u, v); the prior of the
elements, with its settings, is :class:`ChangepointPrior`.

Model numbers. Models are named ``(n_u, n_v)``; the paper's model number is reported as
``m = n_u * (max_v + 1) + n_v + 1`` (1-based, n_v fastest). This convention is ours: the
paper's exact numbering could not be read in the session that wrote this module.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.special import gammaln

from rjfit.sampler.likelihood import index_dtype

__all__ = ["Changepoints", "ChangepointPrior", "model_number", "model_from_number", "obs_region_labels",
           "pixel_region_labels", "log_prior_changepoints", "log_prior_cp_state", "n_regions"]


def n_regions(n_u: int, n_v: int) -> int:
    return (n_u + 1) * (n_v + 1)


def model_number(n_u: int, n_v: int, max_v: int) -> int:
    """The model number ``m = n_u (max_v + 1) + n_v + 1`` (see module docstring)."""
    return int(n_u) * (int(max_v) + 1) + int(n_v) + 1


def model_from_number(m: int, max_v: int) -> tuple[int, int]:
    return divmod(int(m) - 1, int(max_v) + 1)


def _counts_before(cps, n_pos, dtype):
    """(n_lines, n_pos): per line and position p, the number of elements ``x < p + 0.5``.

    ``x < p + 0.5`` for an integer p is ``p >= floor(x - 0.5) + 1`` (the first position
    past the element), the convention the change-point sweeps use.
    """
    n_lines = cps.shape[0]
    first = np.clip(np.floor(cps - 0.5) + 1, 0, n_pos).astype(np.intp)
    marks = np.zeros((n_lines, n_pos + 1), dtype)
    np.add.at(marks, (np.repeat(np.arange(n_lines), cps.shape[1]), first.ravel()), 1)
    return np.cumsum(marks, axis=1, dtype=dtype)[:, :n_pos]


def obs_region_labels(u, v, row, col, n_v=None, pixel_start=None):
    """Region index of observations at pixels ``(row, col)`` given sorted change points.

    The region of every pixel is found on the (H, W) grid first, then gathered per
    observation: one pass over the observations, whatever the number of change points.
    Labels have the smallest integer type that holds the model's regions (int8 up to 127).

    Parameters
    ----------
    u : ndarray (H, n_u)
    v : ndarray (W, n_v)
    row, col : int arrays (N,)
    pixel_start : int array (H * W + 1,), optional
        When the observations are stored pixel by pixel in row-major order (a
        :class:`rjfit.sampler.forward.Problem`), the first observation of each pixel: the
        pixel labels are then repeated per pixel instead of gathered by (row, col), four
        times faster.
    """
    n_v = v.shape[1] if n_v is None else n_v
    height, width = u.shape[0], v.shape[0]
    dtype = index_dtype(n_regions(u.shape[1], n_v) - 1)
    grid = _counts_before(u, width, dtype)
    grid *= n_v + 1
    grid += _counts_before(v, height, dtype).T
    if pixel_start is not None:
        return np.repeat(grid.ravel(), np.diff(pixel_start))
    return grid[row, col]


def pixel_region_labels(u, v, image_shape):
    """Region index of every pixel, shape (H, W)."""
    height, width = image_shape
    rows, cols = np.meshgrid(np.arange(height), np.arange(width), indexing="ij")
    return obs_region_labels(u, v, rows.ravel(), cols.ravel()).reshape(height, width)


def log_prior_changepoints(n_u: int, n_v: int, image_shape) -> float:
    """Log density of sorted change points: per row ``log n_u! - n_u log(W + 2)``, same for v."""
    height, width = image_shape
    return float(height * (gammaln(n_u + 1) - n_u * np.log(width + 2.0))
                 + width * (gammaln(n_v + 1) - n_v * np.log(height + 2.0)))


def _log_normal(d, sd):
    return -0.5 * (d / sd) ** 2 - np.log(sd) - 0.5 * np.log(2 * np.pi)


def log_prior_cp_state(u, v, image_shape, cp_prior: str = "paper", sd: float = 2.0) -> float:
    """Log prior density of sorted change points ``u`` (H, n_u), ``v`` (W, n_v)."""
    height, width = image_shape
    if cp_prior == "paper":
        return log_prior_changepoints(u.shape[1], v.shape[1], image_shape)
    total = 0.0
    for cps, size in ((u, width), (v, height)):
        if cps.shape[1]:
            total += -cps.shape[1] * np.log(size + 2.0) + float(np.sum(_log_normal(np.diff(cps, axis=0), sd)))
    return total


class Changepoints(NamedTuple):
    """The layout of the change-point region model: u (H, n_u) and v (W, n_v), each line's elements sorted."""

    u: np.ndarray
    v: np.ndarray

    @classmethod
    def from_arrays(cls, u, v, image_shape) -> Changepoints:
        """From any arrays of u and v elements (reshaped to one row per line, each line sorted)."""
        height, width = image_shape
        return cls(np.sort(np.asarray(u, float).reshape(height, -1), axis=1),
                   np.sort(np.asarray(v, float).reshape(width, -1), axis=1))

    @property
    def n_u(self) -> int:
        return int(self.u.shape[1])

    @property
    def n_v(self) -> int:
        return int(self.v.shape[1])

    @property
    def n_regions(self) -> int:
        return n_regions(self.u.shape[1], self.v.shape[1])

    @property
    def model_key(self) -> tuple[int, int]:
        """``(n_u, n_v)``: the model this layout belongs to."""
        return self.n_u, self.n_v

    def labels(self, problem) -> np.ndarray:
        """Region of every observation of ``problem`` (:func:`obs_region_labels`)."""
        return obs_region_labels(self.u, self.v, problem.row, problem.col, pixel_start=problem.pixel_start)

    def with_axis(self, axis: str, cps) -> Changepoints:
        """This layout with the ``axis`` ('u' or 'v') vectors replaced by ``cps``."""
        return Changepoints(cps, self.v) if axis == "u" else Changepoints(self.u, cps)


@dataclass(frozen=True)
class ChangepointPrior:
    """The prior of change-point elements (see the module docstring).

    Attributes
    ----------
    kind : {'smooth', 'paper'}
        'paper': iid uniform elements; 'smooth' (default): a random walk along each vector
        with step sd ``smooth_sd`` pixels.
    smooth_sd : float
    """

    kind: str = "smooth"
    smooth_sd: float = 2.0

    def __post_init__(self):
        if self.kind not in ("smooth", "paper"):
            raise ValueError(f"cp_prior must be 'smooth' or 'paper', got {self.kind!r}")

    def log_density(self, u, v, image_shape) -> float:
        """Log prior density of sorted change points (:func:`log_prior_cp_state`)."""
        return log_prior_cp_state(u, v, image_shape, self.kind, self.smooth_sd)
