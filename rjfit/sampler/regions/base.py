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
``layout``, ``theta``, ``stats``, ``log_lik``, ``labels``). Each move must leave the
posterior invariant on its own (a Metropolis-Hastings move whose log ratio holds the target
ratio, the layout prior's ratio, both proposal densities and any Jacobian); it draws its
uniform from ``rng``, decides with :func:`rjfit.sampler.moves.accept.accept`, counts itself
in ``info`` (:class:`rjfit.sampler.state.StepInfo`) and, when it accepts, either replaces the
working copy's parts (:meth:`~rjfit.sampler.state.Work.take` of a
:class:`~rjfit.sampler.moves.proposal.Proposal`) or updates labels and statistics in place
(then it drops ``work.region_index``, and sets ``work.labels_owned`` before writing into a
labels array it does not own). Every random draw comes from ``rng``, in an order fixed by
the code, so a seed fixes the chain.

What a second model needs (as free-form materials with a Potts prior do, issue 27:
:mod:`rjfit.sampler.regions.materials`)
------------------------------------------------------------------------------
- Layout: per-pixel material labels (H, W) with K materials in use, K unknown, and the
  Potts strength if it is sampled; ``n_regions`` = K (one BRDF per material, shared by every
  pixel that carries it, connected or not), ``model_key`` = (K,), ``labels(problem)`` =
  the pixel labels repeated per observation (``np.repeat(pixel_labels.ravel(),
  np.diff(problem.pixel_start))``, as :func:`~rjfit.sampler.regions.changepoints.grid.obs_region_labels`
  does).
- :meth:`log_prior`: the Potts energy times its strength, plus the prior over K with the
  labels' exchangeability settled (materials numbered in a canonical order, or a 1/K!
  factor). The Potts normaliser depends on the strength and K only: with both fixed it is
  a constant; a sampled strength needs a move that avoids it (an exchange algorithm,
  Murray, Ghahramani and MacKay 2006) or a stated approximation.
- :meth:`structure_moves`: Swendsen-Wang-type cluster moves (bonds between equal
  neighbours, clusters relabelled given the materials' parameters), split/merge of
  materials for K (their parameters proposed afresh from their data with
  :mod:`rjfit.sampler.moves.region_proposals`, as the change-point births do), a compiled
  pass for the label sweeps beside :mod:`rjfit.sampler.passes` and the observation terms
  moved between statistics like :func:`rjfit.sampler.passes.shifts.shift_stats`.
- Records: ``key_names = ("n_materials",)`` and ``snapshot`` = ``{"material_labels": (H, W)}``
  (the recorder keeps snapshots as float32 arrays with NaN padding, exact for label
  values), with fields of those names in :class:`~rjfit.sampler.runner.ChainRecord` (which
  holds each model's names as optional fields: ``n_u``, ``n_v``, ``cp_u``, ``cp_v`` for
  change points, ``n_materials``, ``material_labels`` for materials).
- Its settings as fields of its dataclass, like :class:`~rjfit.sampler.regions.changepoints.ChangepointRegions`,
  so that ``SamplerConfig(regions=MaterialRegions(...))`` selects it.
"""
from __future__ import annotations

from abc import ABC, abstractmethod

__all__ = ["RegionModel"]


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
    def structure_moves(self, work, rng, problem, prior, info) -> None:
        """Run one iteration's structure moves on the working copy ``work`` (in place)."""

    @abstractmethod
    def snapshot(self, layout) -> dict:
        """The layout as named arrays for the chain record (each at most :meth:`snapshot_shapes`' shape)."""

    @abstractmethod
    def snapshot_shapes(self, problem) -> dict:
        """Name -> shape of the padded arrays :meth:`snapshot` fills (NaN padding)."""
