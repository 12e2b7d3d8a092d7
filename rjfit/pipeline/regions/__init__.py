"""The pipeline's part of each region model: its summary, result files and printed line, by name.

Each region model is a package in the sampler layer (``rjfit/sampler/regions/<model>/``: its
layout, prior, moves and compiled passes) and a module here (``rjfit/pipeline/regions/<model>.py``:
its :class:`~rjfit.pipeline.regions.base.RegionFit`), because the summary and the result files
need the posterior layer, which the sampler layer may not import. :data:`REGION_FITS` registers
each by its ``--regions`` name; :func:`rjfit.pipeline.fit.fit` and the command line know only
:class:`~rjfit.pipeline.regions.base.RegionFit`.
"""
from rjfit.pipeline.regions.base import FitResult, RegionFit
from rjfit.pipeline.regions.changepoints import ChangepointFit
from rjfit.pipeline.regions.fixed import FixedFit
from rjfit.pipeline.regions.materials import MaterialFit

__all__ = ["REGION_FITS", "FitResult", "RegionFit", "region_fit", "region_fit_of", "printed_line",
           "printed_notes"]

#: the region models by their ``--regions`` name
REGION_FITS = {fit.name: fit for fit in (ChangepointFit, MaterialFit, FixedFit)}


def region_fit(options) -> RegionFit:
    """The region fit of ``options.regions`` for one fit.

    Raises
    ------
    ValueError
        For an unknown region model, or options the model refuses (:meth:`RegionFit.for_fit`).
    """
    if options.regions not in REGION_FITS:
        raise ValueError(f"unknown region model {options.regions!r} (--regions): choose one of "
                         f"{', '.join(REGION_FITS)}")
    return REGION_FITS[options.regions].for_fit(options)


def region_fit_of(summary: dict) -> type[RegionFit]:
    """The region model of a fit's ``summary`` (its class: its report hooks and printed line). A summary without
    ``region_model`` is an older change-point fit's; one of a model this rjfit does not know gets the interface's
    plain defaults (its report states no model-specific row)."""
    return REGION_FITS.get(summary.get("region_model", ChangepointFit.name), RegionFit)


def printed_line(summary: dict) -> str:
    """The region model's part of a fit's printed summary (a summary without ``region_model``: change points)."""
    return REGION_FITS[summary.get("region_model", ChangepointFit.name)].printed_line(summary)


def printed_notes(summary: dict) -> list:
    """The region model's lines after :func:`printed_line` in a fit's printed summary."""
    return REGION_FITS[summary.get("region_model", ChangepointFit.name)].printed_notes(summary)
