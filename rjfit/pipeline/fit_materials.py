"""The material region model's part of a fit (``rjfit fit --regions materials``): its summary and files.

:func:`summarise_materials` turns the chains into the summary entries of the material model
(:data:`rjfit.pipeline.fit_folder.SUMMARY_FIELDS`): the posterior over K
(``materials_posterior``), the MAP K, per-material parameter summaries with pixel counts
(``regions``, one entry per material, after relabelling: :mod:`rjfit.posterior.materials`),
their R-hat and ESS, the cap warning, and the truth comparison of synthetic data.
:func:`write_material_files` writes what differs from a change-point fit's folder:
``chains.nc`` (dims chain, draw, material, parameter: the relabelled draws),
``materials.npz`` (every chain's label snapshots and K per iteration) and the figures
(``materials.png``, the MAP material map, a distinct colour per material however many;
``materials_histogram.png``; ``reflectance.png``). ``labels.exr`` holds the MAP material
per pixel and ``maps.exr`` gains ``map_probability``, the posterior probability of that
material (written by :func:`rjfit.pipeline.fit.write_results`).
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from rjfit.data.coarsen import suggest_likelihood_power
from rjfit.data.noise import weighted_observations
from rjfit.data.pixelfit import per_pixel_residuals
from rjfit.pipeline.fit_folder import PARAMETERS_ATTR, save_chain_arrays
from rjfit.posterior import materials as mat
from rjfit.posterior import summary as post

__all__ = ["summarise_materials", "write_material_files", "EMPTY_MATERIALS_NOTE", "power_suggestion"]

EMPTY_MATERIALS_NOTE = ("no material is ever empty: every state's K materials each hold at least one pixel (the label "
                        "sweep keeps a material's last pixel, a cluster move that empties a material removes it)")


def summarise_materials(records, problem, options, burn: int):
    """The material model's summary entries and results: ``(summary, MAP labels, prediction, extra)``.

    ``extra`` holds ``map_probability`` (H, W) and the relabelled ``draws``
    (:class:`rjfit.posterior.materials.RelabelledDraws`).
    """
    posterior = mat.materials_posterior(records, burn)
    k = int(next(iter(posterior)))
    draws = mat.relabelled_draws(records, burn, k, problem.n_channels)
    labels, probability = draws.map_labels()
    summaries, diag = mat.material_summaries(draws, labels)
    chain_posteriors = [mat.materials_posterior([r], burn) for r in records]
    summary = {
        "materials_posterior": posterior, "map_materials": k, "regions": summaries,
        "material_relabelling": mat.RELABELLING, "empty_materials": EMPTY_MATERIALS_NOTE,
        "map_probability_mean": float(np.nanmean(probability)),
        "rhat_max": diag["rhat_max"], "rhat_reason": diag.get("rhat_reason"),
        "ess_min": min(diag["ess_bulk_min"], diag["ess_tail_min"]),
        "ess_bulk_min": diag["ess_bulk_min"], "ess_tail_min": diag["ess_tail_min"], "diagnostics": diag,
        "max_materials": options.max_materials, "potts_beta": options.potts_beta, "potts_rho": options.potts_rho,
        "chain_materials_posterior": chain_posteriors,
    }
    summary["warnings"] = post.convergence_warnings(diag, chain_posteriors, options.n_chains)
    cap = mat.cap_warning(posterior, options.max_materials)
    if cap:
        summary["warnings"].append(cap)
    prediction = post.posterior_mean_prediction(records, burn, problem)
    return summary, labels, prediction, {"map_probability": probability, "draws": draws}


def write_material_files(staging: Path, result, records, options) -> None:
    """``chains.nc``, ``materials.npz`` and (with ``options.figures``) the figures, into ``staging``."""
    summary, burn = result.summary, result.burn
    idata = mat.to_inference_data(records, burn, result.extra["draws"])
    idata.posterior.attrs.update({
        "rjfit_fit_id": summary["fit_id"], "seed": options.seed, "burn_in_iterations": burn,
        "materials": f"the kept draws with a label snapshot and K = {summary['map_materials']} (the MAP K), "
                     f"relabelled: {mat.RELABELLING}",
        "parameters": PARAMETERS_ATTR})
    idata.to_netcdf(str(staging / "chains.nc"))
    save_chain_arrays(staging / "materials.npz", records, ("cp_iteration", "material_labels", "n_materials"))
    if options.figures:
        from rjfit.posterior import figures as figs  # matplotlib: only when figures are drawn

        folder = staging / "figures"
        written = {"materials": figs.material_map(result.labels, folder / "materials.png"),
                   "materials_histogram": figs.materials_histogram(summary["materials_posterior"],
                                                                   folder / "materials_histogram.png"),
                   "reflectance": figs.reflectance(result.labels, result.prediction, folder / "reflectance.png")}
        summary["figures"] = {name: f"figures/{Path(path).name}" for name, path in written.items()}


def power_suggestion(observations, scale):
    """:func:`~rjfit.data.coarsen.suggest_likelihood_power`; for a joint colour fit measured per channel, with
    each channel's under ``channels``: the smallest (the most misfit) divided by the design effect of the
    channels, ``1 + (C - 1) r``, r the mean correlation between channels of the per-pixel fits' residuals
    of one observation (clipped to [0, 1]).

    Why: the misfit of a pixel (a normal a few degrees off, a lobe the model lacks) is shared
    by its channels, so C channels then hold about as many independent discrepancies as one
    (r near 1: the power divided by C; psm-rock, docs/materials.md: the matrix split along
    shading at the channels' power, one material at a third of it), while independent noise
    per channel (r near 0) is C times the information and keeps the channels' power (Kish's
    design effect for clusters of C equally correlated observations)."""
    if observations.channel is None:
        return suggest_likelihood_power(observations, noise_scale=scale)
    per_channel, residuals = [], []
    for c in range(observations.n_channels):
        mine = observations.channel == c
        single = dataclasses.replace(observations.subset(mine), channel=None, n_channels=1)
        weighed = single if scale is None else weighted_observations(single, scale[mine])
        per_channel.append(suggest_likelihood_power(single, noise_scale=None if scale is None else scale[mine]))
        by_observation = np.full(int(np.prod(single.image_shape)) * single.n_lights, np.nan)
        by_observation[np.asarray(single.pixel, np.int64) * single.n_lights + np.asarray(single.light)] = \
            per_pixel_residuals(weighed)
        residuals.append(by_observation)
    correlation = _channel_correlation(residuals)
    most_misfit = min(per_channel, key=lambda s: s["likelihood_power"])
    suggestion = dict(most_misfit)
    design_effect = 1.0 + (observations.n_channels - 1) * min(max(correlation, 0.0), 1.0)
    suggestion["likelihood_power"] /= design_effect
    # the misfit warning reads the spatial part (channels that repeat each other are no misfit)
    suggestion.update(channels=per_channel, most_misfit_channel=most_misfit, channel_correlation=correlation,
                      channel_design_effect=design_effect,
                      rule="the smallest channel's power divided by the channels' design effect 1 + (C - 1) r, r the "
                           "residuals' mean correlation between channels")
    return suggestion


def _channel_correlation(residuals) -> float:
    """Mean Pearson correlation over channel pairs of the residuals of the observations every
    channel has (``residuals``: per channel, an array over (pixel, light), NaN where none or not
    fitted); 0 with fewer than 3 such observations."""
    shared = np.all(np.isfinite(residuals), axis=0)
    if shared.sum() < 3:
        return 0.0
    columns = [r[shared] for r in residuals]
    pairs = [np.corrcoef(columns[i], columns[j])[0, 1] for i in range(len(columns)) for j in range(i + 1, len(columns))]
    finite = [p for p in pairs if np.isfinite(p)]
    return float(np.mean(finite)) if finite else 0.0
