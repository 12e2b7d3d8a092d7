"""A fit's ``chains.nc`` (either region model): the InferenceData of :mod:`rjfit.posterior.inference_data`,
with the fit's attributes, and the size of its log_likelihood group in the summary."""
from __future__ import annotations

from pathlib import Path

from rjfit.pipeline.fit_folder import PARAMETERS_ATTR
from rjfit.posterior.inference_data import chains_inference_data, log_likelihood_entry

__all__ = ["write_chains"]


def write_chains(path: Path, records, result, draws, options, attributes: dict, *, region_dim: str, key_names,
                 about: str, max_v=None, pixel_labels=None) -> None:
    """Write ``chains.nc`` of ``result`` (a :class:`rjfit.pipeline.fit.FitResult`) to ``path``.

    ``draws``: per chain the MAP model's parameter draws and their iterations; ``attributes``
    (:func:`rjfit.pipeline.fit_folder.file_attributes`) go into every group, ``about`` (what
    the region dimension holds) into the posterior's; ``region_dim``, ``key_names`` and
    ``max_v`` and ``pixel_labels`` (a layout that never changes) as
    :func:`rjfit.posterior.inference_data.chains_inference_data`. Adds the
    summary's ``log_likelihood`` entry.
    """
    effects = result.problem.effects
    idata = chains_inference_data(records, result.burn, result.problem, draws, region_dim=region_dim,
                                  key_names=key_names, max_v=max_v, attrs=attributes,
                                  effect_names=() if effects is None else effects.names,
                                  log_likelihood=effects is None, pixel_labels=pixel_labels)
    idata.posterior.attrs.update({"seed": options.seed, "burn_in_iterations": result.burn, f"{region_dim}s": about,
                                  "parameters": PARAMETERS_ATTR})
    result.summary["log_likelihood"] = log_likelihood_entry(idata)
    idata.to_netcdf(str(path))
