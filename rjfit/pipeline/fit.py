"""Fit a stack: run the RJMCMC chains and write the results (summary, labels, chains, figures).

``fit(observations, out_dir, options)`` is what ``rjfit fit DATASET`` calls once the data set has
passed the cross-check gate (the gate and the data set are :mod:`rjfit.pipeline.fit_dataset`'s
business). Its options are a :class:`rjfit.pipeline.options.FitOptions`.

Outputs in ``out_dir`` (each written atomically):

- ``summary.json``: see :data:`rjfit.pipeline.fit_folder.SUMMARY_FIELDS`;
- ``labels.exr``: MAP labels (channel ``labels``, -1 off the object);
- ``chains.nc``: the chains as ArviZ InferenceData (:mod:`rjfit.posterior.inference_data`);
- ``changepoints.npz``: thinned change-point snapshots per chain;
- with ``--regions materials`` (:mod:`rjfit.pipeline.regions.materials`): labels.exr holds the
  MAP material, chains.nc the relabelled draws (dims chain, draw, material, parameter),
  ``materials.npz`` the label snapshots instead of changepoints.npz, and maps.exr the
  per-pixel probability of the MAP material (``map_probability``);
- ``maps.exr``: per-pixel parameters, labels, valid-images count and residual RMS
  (:func:`write_parameter_maps`);
- ``figures/*.png``: the paper's figures (see :mod:`rjfit.posterior.figures`).

Change points that cut no object pixel. Regions with no observation contribute only their prior (proper), and
split/merge is exactly balanced for them, so models with such regions get exactly the posterior mass the prior
gives them: per row, an extra u element that cuts no object pixel must fall in the off-object part of that row, so
such models carry the product over rows of the off-object fractions of [-1, W+1], which is tiny for an object that
spans many rows. Reported beside the raw ``model_posterior``: ``true_regions_probability`` (the issue's "the
object's pixels fall into exactly the four true regions", whatever the model: one region holding object pixels per
true region, and the optimal one-to-one matching agrees with the truth on >= 99 % of the observed object pixels),
``four_region_probability`` (only the count: as many regions holding object pixels as the truth has) and
``exact_truth_probability`` (stricter: the partition equals the true one pixel for pixel; the ~0.2 % of pixels at
the silhouette whose few grazing observations cannot tell two regions apart make it ~0 even for a good fit).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rjfit.data.exr import read_exr, write_exr
from rjfit.data.noise import describe_noise, noise_scale
from rjfit.io import check_writable, staging_dir
from rjfit.model.blinn import radiance
from rjfit.pipeline.fit_folder import kept_chains, publish_results, relative_paths, remove_checkpoints, stamp, write_summary
from rjfit.pipeline.fit_power import misfit_tile_warnings, noise_and_power, normal_prior_sd
from rjfit.pipeline.fit_settings import burn_in_iterations
from rjfit.pipeline.options import FitOptions
from rjfit.pipeline.regions import FitResult, RegionFit, region_fit
from rjfit.pipeline.regions.base import fit_warnings
from rjfit.pipeline.resolve import resolve_options
from rjfit.posterior import caveats
from rjfit.posterior.effects import effect_summaries
from rjfit.progress import phase
from rjfit.sampler.forward import LambertBlinnPhong, Problem
from rjfit.sampler.normals import normal_direction_maps, normal_moments, normal_problem, normals_summary
from rjfit.sampler.priors import make_prior
from rjfit.sampler.runner import ChainSpec, run_chains
from rjfit.sampler.state import SamplerConfig

__all__ = ["fit", "FitSource", "write_parameter_maps"]


@dataclass(frozen=True)
class FitSource:
    """What a fit records of the data set it was made from (written into its summary).

    ``entries`` are summary.json entries (dataset, dataset_sha256, channel, crop, validation);
    ``warnings`` go before the fit's own; ``exclusion_counts`` (per rule, (H, W)),
    ``object_mask`` and ``n_lights`` draw the valid-images figure; ``view_angle`` (H, W), degrees between each
    pixel's normal and its view direction, places the fit's regions (:meth:`RegionFit.place_by_view`).
    """

    entries: dict
    warnings: tuple = ()
    exclusion_counts: dict | None = None
    object_mask: np.ndarray | None = None
    n_lights: int = 0
    view_angle: np.ndarray | None = None


def fit(observations, out_dir, options: FitOptions | None = None, *, truth_labels=None, truth_params=None,
        start=None, fixed_segmentation=None, chain_runner=None, source: FitSource | None = None,
        before_publish=None, sampler_effects=(), effect_source=None, **option_keywords) -> dict:
    """Run the RJMCMC fit of ``observations`` and write results to ``out_dir``.

    Parameters
    ----------
    observations : rjfit.data.observations.Observations
    out_dir : path
    options : FitOptions, optional
        The fit's options (``option_keywords``, e.g. ``seed=1, n_chains=2``, build or change them);
        not yet resolved, they are resolved as a rendered data set's (:mod:`rjfit.pipeline.resolve`).
    truth_labels : ndarray (H, W), optional
        Ground-truth region per pixel (-1 off the object): adds label_accuracy and exact_truth_probability.
    truth_params : list of dict, optional
        Ground-truth parameters per true label (written beside the estimates).
    start : list of dict, optional
        Per chain keyword arguments of :func:`rjfit.sampler.kernel.initial_state`.
    fixed_segmentation : optional
        The region model's layout held fixed ((u, v) change points, (H, W) material labels): no structure moves.
    chain_runner : callable, optional
        ``chain_runner(specs) -> records``: runs :func:`rjfit.sampler.runner.run_chain` elsewhere (Dask).
    source : FitSource, optional
        The data set the observations come from (recorded in the summary).
    before_publish : callable, optional
        ``before_publish(staging_dir, summary)``, called once every result is staged and
        before it replaces the folder's previous results (tests use it to interrupt a fit there).
    sampler_effects : sequence of rjfit.effects.base.FitForm, optional
        Effects sampled with the regions, their features in the order of ``observations``
        (:func:`rjfit.pipeline.fit_effects.fit_effects` builds them from the data set for
        ``options.effects`` and ``options.effects_from``); ``effect_source`` says where each
        one's features came from (recorded in the summary).

    Returns
    -------
    dict
        The summary written to ``summary.json``, its paths absolute (the file's are relative to ``out_dir``).

    Raises
    ------
    TypeError
        For a keyword that is not a fit option.
    ValueError
        Before any chain runs: for an option out of range (:class:`FitOptions`); ``likelihood_power='auto'`` that
        cannot be measured (no two adjacent pixels under one light have a residual); ``truth_labels`` not of the
        images' shape (H, W); unusable observations (none, some with ``<l.n> <= 0``, or a mean value that is not
        positive under the 'shot' / 'relative' noise models); a burn-in that leaves no iteration; or effects named in
        the options but not given (they need the data set: ``fit_dataset``). While the chains start: if a ``start``
        entry does not fit ``max_u``/``max_v``, or a checkpoint in ``out_dir/checkpoints`` is unreadable, of another
        checkpoint version or of another run (the message says to delete it).
    """
    options = FitOptions.build(options, **option_keywords)
    options = options if options.resolved else resolve_options(options)
    region = region_fit(options)        # the region model's part (it may read its own input: refused early)
    if (options.effects or options.effects_from is not None) and not sampler_effects:
        raise ValueError("effects (--effects, --effects-from) need the data set's geometry: fit the data set "
                         "(rjfit fit DATASET, rjfit.pipeline.fit_dataset.fit_dataset), or pass sampler_effects=")
    out_dir = Path(out_dir)
    check_writable(out_dir, keep=True)        # before any chain runs, not after
    started = time.perf_counter()
    problem, suggestion, noise_record = prepare_problem(observations, options, sampler_effects)
    if truth_labels is not None and np.shape(truth_labels) != tuple(problem.image_shape):
        raise ValueError(f"truth_labels has shape {np.shape(truth_labels)}, images are {problem.image_shape}")
    prior = make_prior(options.prior, y=problem.y, diffuse_scale=problem.A)
    config = sampler_config(options, fixed=fixed_segmentation is not None, problem=problem, region=region)
    specs = chain_specs(problem, prior, config, options, out_dir, truth_labels, start, fixed_segmentation, region)
    records = (list(chain_runner(specs)) if chain_runner is not None
               else run_chains(specs, processes=options.processes, threads=options.threads))
    with phase("summarising the chains (MAP labels, posterior mean prediction, checks)", options.progress):
        result = summarise_normals(records, problem, prior, config, options, suggestion, noise_record,
                                   truth_labels, observations, region)
    if problem.effects is not None:
        result.summary["effects"] = effect_summaries(records, config.kernel.burn_in, problem.effects, effect_source)
        result.summary["warnings"] += effect_warnings(result.summary["effects"])
    if truth_params is not None:
        result.summary["truth_params"] = truth_params
    result.summary["fit_options"] = options.to_json()        # what `rjfit refine` fits again with
    write_results(out_dir, result, records, observations, options, source, before_publish, started,
                  [spec.checkpoint_path for spec in specs], region)
    return result.summary


def effect_warnings(effects) -> list:
    """A warning per effect whose parameters' chains disagree (R-hat > 1.1) or have few effective draws (< 100):
    one line for the effect however many of its parameters are flagged (light_calibration has one per light)."""
    out = []
    for effect in effects:
        flagged = [param for param in effect["parameters"] if _uncertain(param.get("rhat"), param.get("ess_bulk"))]
        if len(flagged) == 1:
            (param,) = flagged
            out.append(f"effect {effect['name']}: its parameter {param['name']} has R-hat "
                       f"{_figure(param.get('rhat'), '.3f')} and bulk ESS {_figure(param.get('ess_bulk'), '.0f')}: "
                       f"its posterior summary is uncertain; run longer")
        elif flagged:
            names = ", ".join(param["name"] for param in flagged[:4]) + (", ..." if len(flagged) > 4 else "")
            out.append(f"effect {effect['name']}: {len(flagged)} of its {len(effect['parameters'])} parameters "
                       f"({names}) have R-hat {_span([p.get('rhat') for p in flagged], '.3f')} and bulk ESS "
                       f"{_span([p.get('ess_bulk') for p in flagged], '.0f')}: their posterior summaries are "
                       f"uncertain; run longer")
    return out


def _uncertain(rhat, ess) -> bool:
    return (rhat is not None and rhat > 1.1) or (ess is not None and ess < 100)


def _figure(value, spec) -> str:
    return "n/a" if value is None else format(value, spec)


def _span(values, spec) -> str:
    """``low to high`` of the known values (n/a where none is known; one figure where they agree at ``spec``)."""
    known = [value for value in values if value is not None]
    if not known:
        return "n/a"
    low, high = format(min(known), spec), format(max(known), spec)
    return low if low == high else f"{low} to {high}"


def prepare_problem(observations, options: FitOptions, effects=()):
    """The sampler's :class:`~rjfit.sampler.likelihood.Problem` of ``observations`` under the
    options' noise model and likelihood power (with ``effects``: the forward model's, see
    :class:`rjfit.sampler.forward.LambertBlinnPhong`); with the measured power suggestion and the
    noise model's record.

    The suggestion is measured always (a fraction of a second): a misfit shared by
    neighbouring pixels is worth a warning whatever power the fit uses.
    """
    scale, suggestion, power, normal_error = noise_and_power(observations, options)
    prior_sd = normal_prior_sd(options, normal_error)
    if effects:
        problem = LambertBlinnPhong(effects).problem(observations, likelihood_power=float(power), noise_scale=scale)
    else:
        problem = Problem.from_observations(observations, likelihood_power=float(power), noise_scale=scale,
                                            normal_prior_sd=prior_sd)
    record = describe_noise(options.noise, options.noise_floor, scale)
    if normal_error is not None:
        record["normal_error"] = normal_error
    if prior_sd is not None and options.noise == "normals":
        record["normals_sampled"] = ("--normals sample: the inflation 1 + k g^2 is kept, its scales computed at the "
                                     "given normals and held while the normals move")
    return problem, suggestion, record


def sampler_config(options: FitOptions, *, fixed: bool = False, problem=None,
                   region: RegionFit | None = None) -> SamplerConfig:
    """The kernel's settings from resolved options (``fixed``: no segmentation moves; ``problem``: measures what
    the region model measures on the data, such as the edge term's power; ``region``: the options' region fit).

    Raises
    ------
    ValueError
        If the burn-in leaves no iteration, or a settings class refuses a value.
    """
    region = region_fit(options) if region is None else region
    return region.sampler_config(options, burn=burn_in_iterations(options), fixed=fixed, problem=problem)


def chain_specs(problem, prior, config, options: FitOptions, out_dir: Path, truth_labels, start, fixed_segmentation,
                region: RegionFit | None = None):
    """One :class:`~rjfit.sampler.runner.ChainSpec` per chain (its seed, start (the region model's,
    :meth:`~rjfit.pipeline.regions.base.RegionFit.chain_start`) and checkpoint file)."""
    region = region_fit(options) if region is None else region
    # at least ~50 change-point snapshots after burn-in, so a short run still has its MAP labels
    cp_thin = max(1, min(options.cp_thin, (options.iterations - config.kernel.burn_in) // 50))
    paths = [out_dir / "checkpoints" / f"chain_{c}.pkl" for c in range(options.n_chains)]
    shared = None
    if not all(path.exists() for path in paths):     # a resumed chain's state holds them already
        with phase("chains: what every chain starts from, built once", options.progress):
            shared = region.shared_start(config, problem)
    specs = []
    for c in range(options.n_chains):
        chain_start = region.chain_start(options, c, dict(start[c]) if start is not None else {},
                                         fixed_segmentation)
        specs.append(ChainSpec(problem=problem, prior=prior, config=config, seed=options.seed, chain=c,
                               n_chains=options.n_chains, iterations=options.iterations,
                               checkpoint_path=str(paths[c]), shared=shared,
                               checkpoint_every=options.checkpoint_every, cp_thin=cp_thin, truth_labels=truth_labels,
                               start=chain_start, progress=options.progress))
    return specs


def summarise_normals(records, problem, prior, config, options: FitOptions, suggestion, noise_record, truth_labels,
                      observations, region: RegionFit) -> FitResult:
    """:func:`summarise`; with sampled normals (``--normals sample``) at the posterior mean normals (the prediction
    and the model's own misfit), with their ``normals`` entry and maps."""
    if problem.normals is None:
        return summarise(records, problem, prior, config, options, suggestion, noise_record, truth_labels,
                         observations, region)
    moments = normal_moments(records, problem)
    result = summarise(records, normal_problem(problem, moments["d_mean"]), prior, config, options, suggestion,
                       noise_record, truth_labels, observations, region)
    result.summary["normals"] = normals_summary(moments, problem, result.summary["acceptance"].get("normals"))
    result.extra.update(normal_shift_deg=moments["shift_deg"], normal_sd_deg=moments["sd_deg"],
                        **normal_direction_maps(moments, problem))
    return result


def run_entries(records, problem, prior, options: FitOptions, burn: int, suggestion, noise_record) -> dict:
    """The summary entries every region model shares: the settings a fit ran with, acceptance and timing."""
    counts = caveats.acceptance_counts(records)
    return {
        "iterations": options.iterations, "burn_in": burn, "n_chains": options.n_chains, "seed": options.seed,
        "n_observations": problem.n_obs, "region_model": options.regions,
        "sampler": options.sampler, "prior": prior.to_json(),
        "likelihood_power": float(problem.likelihood_power), "likelihood_power_suggestion": suggestion,
        "noise": noise_record,
        "anneal_iterations": int(round(options.anneal * burn)),
        "acceptance": {k: c["accepted"] / max(1, c["proposed"]) for k, c in counts.items()},
        "acceptance_counts": counts,
        "chain_seconds": [r.seconds for r in records],
        "chain_threads": [r.threads for r in records],
        "chain_resumed_from": [list(r.resumed_from) for r in records],
    }


def summarise(records, problem, prior, config, options: FitOptions, suggestion, noise_record, truth_labels,
              observations, region: RegionFit | None = None) -> FitResult:
    """The chains' kept draws summarised by the region model, with the settings every model records."""
    region = region_fit(options) if region is None else region
    run = run_entries(records, problem, prior, options, config.kernel.burn_in, suggestion, noise_record)
    result = region.summarise(records, problem, prior, config, options, run,
                              fit_warnings(problem, prior, suggestion) + misfit_tile_warnings(noise_record),
                              truth_labels, observations)
    if result.prediction is not None and result.prediction.get("residual_correlation") is not None:
        # the misfit the fitted model itself leaves (the power above was measured on per-pixel fits, before it)
        result.summary["model_misfit"] = result.prediction["residual_correlation"]
    return result


def write_results(out_dir: Path, result: FitResult, records, observations, options: FitOptions,
                  source: FitSource | None, before_publish, started: float, checkpoints,
                  region: RegionFit | None = None) -> None:
    """Stage every result file and publish them together, ``summary.json`` last; then remove the
    chains' ``checkpoints``, which have served.

    An interrupted run leaves the previous results whole or none: never labels of one run
    beside the summary of another. (``staging_dir`` removes the staging folders of runs
    killed while they wrote their results.) A run whose results cannot be written keeps the
    checkpoints and raises :class:`rjfit.errors.OutputError` saying how to publish them.
    """
    with kept_chains(checkpoints, out_dir):
        _stage_and_publish(out_dir, result, records, observations, options, source, before_publish, started,
                           region_fit(options) if region is None else region)
    remove_checkpoints(checkpoints, out_dir)


def _stage_and_publish(out_dir: Path, result: FitResult, records, observations, options: FitOptions,
                       source: FitSource | None, before_publish, started: float, region: RegionFit) -> None:
    summary = result.summary
    with staging_dir(out_dir) as staging, phase("writing the results and figures", options.progress):
        attributes = stamp(summary)         # fit_id, version and schema: in every file
        write_exr(staging / "labels.exr", {"labels": result.labels.astype(np.float32)}, attributes)
        region.write_files(staging, result, records, options, attributes)
        extra = {name: result.extra[name] for name in ("map_probability", "edge_group", "extra_material_share",
                                                       "normal_shift_deg", "normal_sd_deg", "normal_dx", "normal_dy")
                 if name in result.extra} or None
        summary["maps"] = write_parameter_maps(observations, summary, staging, result.prediction, extra, attributes)
        if source is not None:
            record_source(summary, source, staging, options)
            if source.view_angle is not None:
                region.place_by_view(result, source.view_angle, records)
        if before_publish is not None:
            before_publish(staging, summary)
        summary["seconds"] = time.perf_counter() - started
        write_summary(staging / "summary.json", relative_paths(summary, out_dir))     # the returned one: absolute
        publish_results(staging, out_dir)


def record_source(summary: dict, source: FitSource, staging: Path, options: FitOptions) -> None:
    """Add the data set's entries and warnings to ``summary``, and its valid-images figure to ``staging``."""
    if options.figures and source.exclusion_counts is not None:
        from rjfit.plotting import exclusion_figure  # matplotlib: only when figures are drawn

        # which observations the stated rules left out, and why (the valid-images map)
        exclusion_figure(staging / "figures" / "valid_images.png", source.exclusion_counts,
                         source.object_mask, source.n_lights)
        summary.setdefault("figures", {})["valid_images"] = "figures/valid_images.png"
    summary.update(source.entries)
    summary["warnings"][:0] = list(source.warnings)


def write_parameter_maps(observations, summary, out_dir: Path, prediction=None, extra_channels=None,
                         attributes=None) -> str:
    """Per-pixel maps of the MAP segmentation as one EXR: each region's posterior mean and sd
    of I0, kd, gamma, sigma^2, the label, the valid-images count (paper, Fig. 8) and the RMS
    over lights of the standardised residual ``(y - mu) / (sigma s)`` (``s`` the known noise
    scales of the summary's noise model, 1 for 'constant').

    The residual is ``prediction["residual_rms"]`` when given (the posterior mean prediction,
    averaged draw by draw: :func:`rjfit.posterior.summary.posterior_mean_prediction`, what a
    fit passes), else computed at the summary's region means on these labels (a plug-in that
    mixes modes when chains disagree). ``attributes`` go into the file's header."""
    labels = np.rint(np.nan_to_num(read_exr(out_dir / "labels.exr")["labels"], nan=-1)).astype(int)
    names = ("I0", "kd", "gamma", "sigma2")
    colour = bool(summary["regions"]) and "channels" in summary["regions"][0]
    if colour:      # a joint colour fit: gamma per material, the rest per channel (I0_R, kd_R, ..., sigma2_B)
        names = ("gamma",) + tuple(f"{name}_{channel}" for channel in summary["regions"][0]["channels"]
                                   for name in ("I0", "kd", "sigma2"))
    table = np.full((max(len(summary["regions"]), int(labels.max()) + 1) + 1, 2 * len(names)), np.nan)
    for index, region in enumerate(summary["regions"]):
        row = int(region.get("region", index))
        table[row] = [_region_value(region, name)[stat] for name in names for stat in ("mean", "sd")]
    region_of_pixel = np.where(labels >= 0, labels, table.shape[0] - 1)      # last row stays NaN
    channels = {f"{name}{suffix}": table[region_of_pixel, 2 * k + j]
                for k, name in enumerate(names) for j, suffix in enumerate(("", "_sd"))}
    size = labels.size
    count = np.bincount(observations.pixel, minlength=size)
    if prediction is not None:
        rms = prediction["residual_rms"]
    elif colour:
        raise ValueError("a joint colour fit's residual map needs its posterior mean prediction")
    else:
        obs_params = table[region_of_pixel.ravel()[observations.pixel]]
        mu = radiance(obs_params[:, 0], obs_params[:, 2], obs_params[:, 4], observations.cos_ln, observations.cos_hn,
                      observations.irradiance)
        standardised = (observations.y - mu) / np.sqrt(obs_params[:, 6])
        noise = summary.get("noise") or {"model": "constant"}
        if noise["model"] != "constant":
            standardised /= noise_scale(observations, noise["model"], noise["floor"])
        sum_squares = np.bincount(observations.pixel, weights=np.nan_to_num(standardised) ** 2, minlength=size)
        rms = np.where(count > 0, np.sqrt(sum_squares / np.maximum(count, 1)), np.nan).reshape(labels.shape)
    channels.update(label=labels, valid_images=count.reshape(labels.shape), residual_rms=rms)
    channels.update(extra_channels or {})
    write_exr(out_dir / "maps.exr", channels, attributes)
    return "maps.exr"


def _region_value(region: dict, name: str) -> dict:
    """A region's summary of parameter ``name``; ``I0_R`` etc.: channel R's I0 of a joint colour fit."""
    if name in region:
        return region[name]
    parameter, channel = name.rsplit("_", 1)
    return region["channels"][channel][parameter]
