"""The region model: what partitions the pixels into regions, and how that partition moves.

A step of the kernel (:func:`rjfit.sampler.kernel.step`) runs, in this order:

1. the within-region moves for every region (:mod:`rjfit.sampler.moves.within`), shared by
   every region model: they see only the observation labels, each region's sufficient
   statistics and its parameters ``(I0, kd, gamma, sigma^2)``, never the layout;
2. the region model's structure moves (:meth:`RegionModel.structure_moves`), which change
   the layout and, with it, the labels, the statistics and (for moves that create or remove
   regions) the parameters.

A region model owns: its **layout** type (the structure stored in the chain state, for
change points the u and v vectors); the **prior** of layouts; how a chain **starts**; its
**structure moves** and their settings; and what the chain **records** per draw (a model
key such as ``(n_u, n_v)``) and per snapshot (the layout itself, padded to fixed shapes).

Contract
--------
Layout objects are immutable (a move builds a new one) and provide

- ``n_regions`` (int): the number R of regions; regions are numbered 0 .. R - 1 and
  ``theta``, ``stats`` and ``log_lik`` of the state have one row per region (a region may
  hold no observation: its statistics are zero and its log-likelihood 0);
- ``model_key`` (tuple of ints): the model the layout belongs to, recorded per draw under
  :attr:`RegionModel.key_names` (the posterior over models counts these keys);
- ``labels(problem)``: the region of every observation of the
  :class:`~rjfit.sampler.forward.Problem` (an int array of the smallest type that holds
  R - 1, in the problem's observation order).

The structure moves act on the step's working copy (:class:`rjfit.sampler.state.Work`:
``layout``, ``theta``, ``stats``, ``log_lik``, ``labels``). They follow the move protocol
(:mod:`rjfit.sampler.moves.base`): each is an object with its settings, a
:class:`~rjfit.sampler.moves.base.Move` that proposes a
:class:`~rjfit.sampler.moves.proposal.Proposal` (its kind, whether it changes the model's
dimension, its complete log ratio: the target ratio, the layout prior's ratio, both proposal
densities and any Jacobian), decided by the one test
(:func:`~rjfit.sampler.moves.base.decide`) and applied by :meth:`~rjfit.sampler.moves.base.Move.apply`
(:meth:`~rjfit.sampler.state.Work.take`, or in place: then it drops ``work.region_index``, and
sets ``work.labels_owned`` before writing into a labels array it does not own), or a
:class:`~rjfit.sampler.moves.base.Sweep` of many tests at once. Each must leave the posterior
invariant on its own. :meth:`RegionModel.schedule` lists one iteration's moves, a weighted list
(:class:`~rjfit.sampler.moves.base.Scheduled`: so many times, or by chance). Every random draw
comes from ``rng``, in an order fixed by the code, so a seed fixes the chain.

The models: :mod:`rjfit.sampler.regions.changepoints` (the paper's), :mod:`rjfit.sampler.regions.materials`
(free-form materials under a Potts prior, issue 27) and :mod:`rjfit.sampler.regions.fixed` (the
user's label map). A new model is a package beside them: a layout with the three members above;
a class of this contract whose fields are its settings (so that ``SamplerConfig(regions=...)``
selects it); its ``key_names`` and ``snapshot`` (the recorder keeps snapshots as float32 arrays
with NaN padding, exact for label values; :class:`~rjfit.sampler.runner.ChainRecord` holds the
change-point and material names as optional fields, so a model records those names or none, as
the fixed one does); and its part of a fit in the pipeline layer
(:class:`rjfit.pipeline.regions.base.RegionFit`), registered in
:data:`rjfit.pipeline.regions.REGION_FITS`.
"""
from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from rjfit.sampler.likelihood import index_dtype
from rjfit.sampler.moves.base import run_schedule

__all__ = ["RegionModel", "pixel_labels_per_observation"]


def pixel_labels_per_observation(pixels, n_labels: int, problem) -> np.ndarray:
    """The label of every observation of ``problem``: its pixel's in ``pixels`` (H, W; labels 0 .. n_labels - 1),
    repeated per observation, in the smallest int type that holds them; for a joint colour fit its parameter row,
    ``label C + channel``."""
    n_ch = problem.n_channels
    flat = pixels.ravel().astype(index_dtype(max(n_labels * n_ch - 1, 0)))
    labels = np.repeat(flat, np.diff(problem.pixel_start))
    if n_ch > 1:
        labels = labels * n_ch + problem.channel
    return labels


class RegionModel(ABC):
    """What partitions the pixels into regions: layouts, their prior, start, structure moves and records.

    Implementations are frozen dataclasses whose fields are their settings (see the module
    docstring for the contract a layout and the moves keep).
    """

    #: Names under which :attr:`layout.model_key <model_key>`'s entries are recorded per draw.
    key_names: tuple = ()

    @property
    @abstractmethod
    def max_regions(self) -> int:
        """The largest number of regions a layout may have (the width of the recorded parameter arrays)."""

    @abstractmethod
    def initial_layout(self, problem, rng, **start):
        """A starting layout: from ``start`` (model-specific keywords) where given, else drawn from ``rng``.

        Raises
        ------
        ValueError
            If ``start`` asks for a layout outside the model space.
        """

    def shared_start(self, problem) -> dict:
        """What every chain's :meth:`initial_layout` would build from the data alone, built once for all of a
        fit's chains (keywords of :meth:`initial_layout`); none here."""
        return {}

    @abstractmethod
    def log_prior(self, problem, layout) -> float:
        """Log prior density of ``layout`` (up to a constant the same for every layout of every model)."""

    def start_theta(self, problem, layout, prior):
        """A chain's starting parameters for ``layout`` where the model needs its own (None: the kernel's
        dispersed draws; :func:`rjfit.sampler.kernel.initial_state`)."""
        return None

    def edge_term(self, layout):
        """A term of the target beside the layout prior that the parameter moves must hold (the material
        model's edge term, :mod:`rjfit.sampler.regions.materials.edges`); None (the default): none."""
        return None

    @abstractmethod
    def schedule(self) -> list:
        """The structure moves of one iteration: a weighted list of moves with their settings
        (:class:`~rjfit.sampler.moves.base.Scheduled` entries, run in order)."""

    def structure_moves(self, work, rng, problem, prior, info) -> None:
        """Run one iteration's structure moves (:meth:`schedule`) on the working copy ``work`` (in place)."""
        run_schedule(self.schedule(), work, rng, problem, prior, info)

    @abstractmethod
    def snapshot(self, layout) -> dict:
        """The layout as named arrays for the chain record (each at most :meth:`snapshot_shapes`' shape)."""

    @abstractmethod
    def snapshot_shapes(self, problem) -> dict:
        """Name -> shape of the padded arrays :meth:`snapshot` fills (NaN padding)."""
