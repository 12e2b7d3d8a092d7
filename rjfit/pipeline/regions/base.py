"""What a fit asks of a region model: :class:`RegionFit`, the pipeline's side of the region-model seam.

The sampler's side is :class:`rjfit.sampler.regions.base.RegionModel` (layout, prior, start,
structure moves, records); its package under ``rjfit/sampler/regions/`` cannot hold what
needs the posterior layer (summaries, ArviZ files, figures), so each model has a module here
too, registered by name in :data:`rjfit.pipeline.regions.REGION_FITS`. :func:`rjfit.pipeline.fit.fit`
and the command line's printed summary know only this interface.

A region fit gives, for :class:`~rjfit.pipeline.options.FitOptions` ``options``: the sampler's
settings (:meth:`RegionFit.sampler_config`), each chain's start (:meth:`RegionFit.chain_start`),
the summary of the chains (:meth:`RegionFit.summarise`: a :class:`FitResult`), the files it
writes beside ``labels.exr`` and ``maps.exr`` (:meth:`RegionFit.write_files`) and its part of
the printed summary (:meth:`RegionFit.printed_line`).
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import numpy as np

from rjfit.data.coarsen import misfit_warning
from rjfit.posterior import summary as post
from rjfit.sampler.forward import Problem

__all__ = ["RegionFit", "FitResult", "fit_warnings", "truth_summary"]


@dataclass
class FitResult:
    """A fit's results in memory: the summary and what its files are made of."""

    summary: dict
    labels: np.ndarray          # MAP labels (H, W), -1 off the object
    prediction: dict            # posterior mean prediction (rjfit.posterior.summary.posterior_mean_prediction)
    problem: Problem
    burn: int
    model: tuple
    extra: dict = field(default_factory=dict)   # the region model's own results (materials: map_probability, draws)


def fit_warnings(problem, prior, suggestion) -> list:
    """The warnings of the data and prior that every region model's summary carries."""
    warnings = []
    misfit = misfit_warning((suggestion or {}).get("most_misfit_channel", suggestion), float(problem.likelihood_power))
    if misfit:
        warnings.append(misfit)
    if prior.caveat:
        warnings.append(prior.caveat)
    return warnings


def truth_summary(records, burn, labels, truth_labels) -> dict:
    """How the fit compares with the ground truth of a synthetic data set."""
    accuracy = post.label_accuracy(labels, truth_labels)
    n_true = int(len(np.unique(np.asarray(truth_labels)[np.asarray(truth_labels) >= 0])))
    return {"label_accuracy": accuracy["accuracy"], "label_matching": accuracy["matching"],
            "exact_truth_probability": post.exact_truth_probability(records, burn),
            "true_region_count": n_true,
            "four_region_probability": post.object_region_count_probability(records, burn, n_true),
            "true_regions_probability": post.true_regions_probability(records, burn),
            "chain_true_regions_probability": [post.true_regions_probability([r], burn) for r in records]}


class RegionFit(ABC):
    """One region model's part of a fit. Built per fit by :meth:`for_fit` (a model may read files there)."""

    #: the name ``--regions`` gives it
    name: str = ""
    #: the options of :class:`~rjfit.pipeline.options.FitOptions` only this model reads: a given one is refused
    #: under any other model (:func:`rjfit.pipeline.resolve.resolve_options`)
    reads: frozenset = frozenset()
    #: what the report calls one of its regions ('region', 'material', 'label')
    noun: str = "region"
    #: whether a measured stack is fitted with this model by default (one model says so)
    measured_default: bool = False
    #: whether it fits a colour image's channels jointly (``--channel rgb``, with the adaptive sampler)
    joint_colour: bool = False

    @staticmethod
    def edge_term_applies(values: dict) -> bool:
        """Whether the edge term (``--edge-power``) applies to a fit with the resolved option ``values``."""
        return False

    @staticmethod
    def preset_values(values: dict, data) -> dict:
        """What ``--preset measured`` sets for this model beyond the common preset, from the option ``values``
        resolved so far and the data's :class:`~rjfit.pipeline.resolve.DataFacts` ``data`` (a value here replaces
        a given one only where the model's rule says so)."""
        return {}

    @staticmethod
    def describe(summary: dict, options: dict) -> str:
        """The model in words for the report's settings (``options``: the summary's recorded fit options)."""
        return ""

    @staticmethod
    def settings_rows(summary: dict, options: dict) -> list:
        """The model's own settings for the report, ``(setting, value in words)`` (None: not recorded)."""
        return []

    @staticmethod
    def result_rows(summary: dict) -> list:
        """The model's headline results for the report, ``(quantity, value, what it means)``."""
        return []

    @staticmethod
    def report_notes(summary: dict) -> list:
        """Sentences the report states below the headline results (the model's own findings)."""
        return []

    @classmethod
    def region_title(cls, region: dict, index: int) -> str:
        """The name of the report's row of ``region``, the ``index``-th of the summary's ``regions``."""
        return f"{cls.noun} {region.get('region', index)}"

    @classmethod
    def for_fit(cls, options) -> RegionFit:
        """The region fit of one fit with ``options``.

        Raises
        ------
        ValueError
            If the options ask for something the model cannot do (one line, naming the option or file).
        """
        return cls()

    @abstractmethod
    def sampler_config(self, options, *, burn: int, fixed: bool = False, problem=None):
        """The :class:`~rjfit.sampler.state.SamplerConfig` of the chains (``burn`` iterations of burn-in;
        ``fixed``: the segmentation held fixed; ``problem``: None where only the settings are wanted)."""

    def shared_start(self, config, problem) -> dict:
        """What every chain of the fit starts from, built once (:meth:`~rjfit.sampler.regions.base.RegionModel
        .shared_start` of ``config.regions``)."""
        return config.regions.shared_start(problem)

    def chain_start(self, options, chain: int, start: dict, fixed_segmentation=None) -> dict:
        """Chain ``chain``'s start (keywords of :func:`rjfit.sampler.kernel.initial_state`): the caller's ``start``
        with what the model adds (``fixed_segmentation``: the model's layout to hold fixed, or None)."""
        return start

    @abstractmethod
    def summarise(self, records, problem, prior, config, options, run: dict, warnings: list, truth_labels,
                  observations) -> FitResult:
        """The chains' kept draws summarised: the model's entries, ``run`` (the entries every model shares: the
        settings, acceptance and timing) and its warnings, then ``warnings`` (the data's and prior's)."""

    @staticmethod
    def place_by_view(result: FitResult, view_angle, records) -> None:
        """Add to ``result.summary`` where its regions lie by how steeply the object is seen there (``view_angle``,
        (H, W) degrees from each pixel's normal), with warnings. Nothing by default."""

    @abstractmethod
    def write_files(self, staging, result: FitResult, records, options, attributes: dict) -> None:
        """The model's own result files (``chains.nc``, its layout snapshots, figures) into ``staging``, each with
        ``attributes`` (:func:`rjfit.pipeline.fit_folder.file_attributes`: version, schema, options)."""

    @staticmethod
    @abstractmethod
    def printed_line(summary: dict) -> str:
        """The model's part of the printed summary of a fit (its MAP model, from ``summary``)."""

    @staticmethod
    def printed_notes(summary: dict) -> list:
        """Lines the printed summary adds after the model's (each a caveat too long for that line); none by
        default."""
        return []
