"""The change-point region model's part of a fit (``rjfit fit``, the default ``--regions changepoints``).

Its summary entries (:data:`rjfit.pipeline.fit_folder.SUMMARY_FIELDS`): the posterior over
models (n_u, n_v) (``model_posterior``), the MAP model, the regions of its MAP labels with
their R-hat and ESS, each chain's own summaries and the caveats of those numbers. Its files:
``chains.nc`` (dims chain, draw, region, parameter; regions past the draw's model NaN),
``changepoints.npz`` (every chain's change-point snapshots and model per iteration) and the
paper's figures (:mod:`rjfit.posterior.figures`). The sampler's side is
:mod:`rjfit.sampler.regions.changepoints`.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from rjfit.pipeline.fit_chains import write_chains
from rjfit.pipeline.fit_folder import save_chain_arrays
from rjfit.pipeline.fit_settings import assemble
from rjfit.pipeline.regions.base import FitResult, RegionFit, truth_summary
from rjfit.pipeline.report_numbers import probability
from rjfit.posterior import caveats
from rjfit.posterior import summary as post
from rjfit.posterior.inference_data import changepoint_draws
from rjfit.sampler.regions.changepoints import ChangepointRegions
from rjfit.sampler.regions.changepoints.grid import model_number
from rjfit.sampler.state import SamplerConfig

__all__ = ["ChangepointFit", "number_warnings", "write_changepoint_files"]


class ChangepointFit(RegionFit):
    """The paper's change points: models (n_u, n_v), regions the cells of the change-point vectors."""

    name = "changepoints"
    reads = frozenset({"max_u", "max_v", "split_map", "cp_prior", "drop_jacobian", "jump_prob"})

    @staticmethod
    def describe(summary: dict, options: dict) -> str:
        return (f"change points: the paper's grid of at most {options.get('max_u', '?')} u and "
                f"{options.get('max_v', '?')} v change-point vectors, one BRDF per cell")

    @staticmethod
    def settings_rows(summary: dict, options: dict) -> list:
        return [("split map", options.get("split_map")), ("change-point prior", options.get("cp_prior"))]

    @staticmethod
    def result_rows(summary: dict) -> list:
        model = summary.get("map_model") if isinstance(summary.get("map_model"), dict) else {}
        rows = [("MAP model (n_u, n_v)", f"({model.get('n_u')}, {model.get('n_v')})" if model else None,
                 "the change-point model of highest posterior probability: n_u vectors cut the rows, n_v the columns")]
        if "true_regions_probability" in summary:
            rows.append(("probability of the true regions", probability(summary["true_regions_probability"]),
                         "share of kept draws whose object pixels fall into exactly the true regions (one region per "
                         "true region, >= 99 % of pixels matched); good near 1"))
        if "four_region_probability" in summary:
            rows.append(("probability of the true number of regions", probability(summary["four_region_probability"]),
                         "share of kept draws with as many regions holding object pixels as the truth has (the count "
                         "only)"))
        if "exact_truth_probability" in summary:
            rows.append(("probability of the exact true partition", probability(summary["exact_truth_probability"]),
                         "share of kept draws whose partition equals the truth pixel for pixel: stricter, near 0 even "
                         "for a good fit (see the note below)"))
        return rows

    def sampler_config(self, options, *, burn: int, fixed: bool = False, problem=None) -> SamplerConfig:
        model = ChangepointRegions()
        # reproducing the paper's omission (--drop-jacobian): every jump must use its map
        free_prob = 0.0 if options.drop_jacobian else model.birth_death.free_prob
        regions = replace(model, max_u=options.max_u, max_v=options.max_v,
                          prior=replace(model.prior, kind=options.cp_prior),
                          birth_death=replace(model.birth_death, prob=options.jump_prob, split_map=options.split_map,
                                              drop_jacobian=options.drop_jacobian, free_prob=free_prob),
                          update_changepoints=not fixed, jumps=not fixed)
        return assemble(options, regions, burn)

    def chain_start(self, options, chain: int, start: dict, fixed_segmentation=None) -> dict:
        if fixed_segmentation is not None:      # (u, v) change points
            start.setdefault("changepoints", fixed_segmentation)
        return start

    def summarise(self, records, problem, prior, config, options, run: dict, warnings: list, truth_labels,
                  observations) -> FitResult:
        burn = config.kernel.burn_in
        n_u, n_v = post.map_model(records, burn)
        draws = post.map_model_draws(records, burn, (n_u, n_v))
        labels = post.map_labels(records, burn, (n_u, n_v), problem.image_shape, problem.object_mask)
        # what the figures and residual maps show: averaged draw by draw, each with its own segmentation
        prediction = post.posterior_mean_prediction(records, burn, problem)
        diag = post.diagnostics(draws)
        summary = {
            "model_posterior": post.model_posterior(records, burn),
            "map_model": {"n_u": n_u, "n_v": n_v, "m": model_number(n_u, n_v, options.max_v)},
            "model_number_convention": "m = n_u * (max_v + 1) + n_v + 1",
            "regions": post.region_summaries(draws, labels),
            "rhat_max": diag["rhat_max"], "rhat_reason": diag["rhat_reason"],
            "ess_min": min(diag["ess_bulk_min"], diag["ess_tail_min"]),
            "ess_bulk_min": diag["ess_bulk_min"], "ess_tail_min": diag["ess_tail_min"],
            "diagnostics": diag,
            "max_u": options.max_u, "max_v": options.max_v,
            "split_map": options.split_map, "cp_prior": options.cp_prior, "drop_jacobian": options.drop_jacobian,
            "chain_model_posterior": [post.model_posterior([r], burn) for r in records],
            "chain_regions": post.chain_region_summaries(records, draws, burn, (n_u, n_v), problem.image_shape,
                                                         problem.object_mask),
        }
        summary.update(run)
        summary["warnings"] = (post.convergence_warnings(diag, summary["chain_model_posterior"], options.n_chains,
                                                         post.chain_log_posterior_means(records, burn))
                               + number_warnings(summary, labels, problem, prior, config))
        summary["warnings"] += warnings
        if truth_labels is not None:
            summary.update(truth_summary(records, burn, labels, truth_labels))
        return FitResult(summary=summary, labels=labels, prediction=prediction, problem=problem, burn=burn,
                         model=(n_u, n_v))

    def write_files(self, staging, result: FitResult, records, options, attributes: dict) -> None:
        write_changepoint_files(staging, result, records, options, attributes)

    @staticmethod
    def printed_line(summary: dict) -> str:
        map_model = summary["map_model"]
        return (f"MAP model (n_u, n_v) = ({map_model['n_u']}, {map_model['n_v']}), m = {map_model['m']}, "
                f"{len(summary['regions'])} regions")


def number_warnings(summary: dict, labels, problem, prior, config: SamplerConfig) -> list:
    """The caveats of the summary's own numbers (:mod:`rjfit.posterior.caveats`): NaN rejections, regions without
    data, parameters beyond their prior's plausible range, pooled means outside their intervals, a binding model
    cap (not for a fixed segmentation, whose model cannot move)."""
    observed = np.zeros(problem.height * problem.width, bool)
    observed[problem.pixel] = True
    out = (caveats.nan_rejection_warnings(summary["acceptance_counts"])
           + caveats.empty_region_warnings(labels, observed.reshape(problem.image_shape), len(summary["regions"]))
           + caveats.prior_range_warnings(summary["regions"], prior)
           + caveats.support_bound_warnings(summary["regions"], prior)
           + caveats.pooled_interval_warnings(summary["regions"]))
    if getattr(config.regions, "jumps", True):     # a region model without the switch always jumps
        out += caveats.model_cap_warnings(summary["model_posterior"], {"n_u": (summary["max_u"], "--max-u"),
                                                                      "n_v": (summary["max_v"], "--max-v")})
    return out


def write_changepoint_files(staging: Path, result: FitResult, records, options, attributes: dict) -> None:
    """A change-point fit's ``chains.nc``, ``changepoints.npz`` and (``options.figures``) figures, all attributed."""
    summary, burn, max_v = result.summary, result.burn, options.max_v
    write_chains(staging / "chains.nc", records, result, changepoint_draws(records, burn, result.model), options,
                 attributes, region_dim="region", key_names=("n_u", "n_v"), max_v=max_v,
                 about=f"the kept draws of the MAP model (n_u, n_v) = {result.model}, region r its cell r; every other "
                       f"draw's model is in sample_stats (n_u, n_v, model_number), its regions in no group")
    save_chain_arrays(staging / "changepoints.npz", records, ("cp_iteration", "cp_u", "cp_v", "n_u", "n_v"), attributes)
    if options.figures:
        from rjfit.posterior import figures as figs  # matplotlib: only when figures are drawn

        written = figs.write_all(staging / "figures", records=records, burn_in=burn, model=result.model,
                                 labels=result.labels, problem=result.problem, prediction=result.prediction,
                                 max_v=max_v)
        summary["figures"] = {name: f"figures/{Path(path).name}" for name, path in written.items()}
