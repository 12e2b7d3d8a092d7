"""Fit a stack: run the RJMCMC chains and write the results (summary, labels, chains, figures).

``fit(observations, out_dir, ...)`` is what ``rjfit fit DATASET`` calls once the data set has
passed the cross-check gate (the gate is the caller's business).

Outputs in ``out_dir`` (each written atomically):

- ``summary.json``: model_posterior, map_model {n_u, n_v, m}, regions, rhat_max, ess_min,
  iterations, seconds, noise (the noise model, its floor and scale range), chain_model_posterior (per chain), and with ground truth
  label_accuracy, true_regions_probability and exact_truth_probability;
- ``labels.exr``: MAP labels (channel ``labels``, -1 off the object);
- ``chains.nc``: full chains as ArviZ InferenceData (dims chain, draw, region, parameter);
- ``changepoints.npz``: thinned change-point snapshots per chain;
- ``figures/*.png``: the paper's figures (see :mod:`rjfit.posterior.figures`).

Change points that cut no object pixel. Regions with no observation contribute only their
prior (proper), and split/merge is exactly balanced for them, so models with such regions
get exactly the posterior mass the prior gives them: per row, an extra u element that cuts
no object pixel must fall in the off-object part of that row, so such models carry the
product over rows of the off-object fractions of [-1, W+1], which is tiny for an object
that spans many rows. Reported beside the raw ``model_posterior``:
``true_regions_probability`` (the issue's "the object's pixels fall into exactly the four
true regions", whatever the model: one region holding object pixels per true region, and
the optimal one-to-one matching agrees with the truth on >= 99 % of the observed object
pixels), ``four_region_probability`` (only the count: as many regions holding object
pixels as the truth has) and ``exact_truth_probability`` (stricter: the partition equals
the true one pixel for pixel; the ~0.2 % of pixels at the silhouette whose few grazing
observations cannot tell two regions apart make it ~0 even for a good fit).
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import os
import time
from pathlib import Path

import numpy as np

from rjfit.data.coarsen import misfit_warning, suggest_likelihood_power
from rjfit.data.noise import DEFAULT_FLOOR, NOISE_MODELS, describe_noise, noise_scale
from rjfit.io import publish, staging_dir, write_json_atomic
from rjfit.posterior import summary as post
from rjfit.sampler.forward import Problem
from rjfit.sampler.moves.birth_death import BirthDeathSettings
from rjfit.sampler.priors import PRESETS, make_prior
from rjfit.sampler.regions.changepoint_grid import model_number
from rjfit.sampler.runner import ChainSpec, run_chains
from rjfit.sampler.state import SamplerConfig

__all__ = ["fit"]


RESULT_FILES = ("labels.exr", "chains.nc", "changepoints.npz", "maps.exr", "figures")
# Results derived from a fit by later commands; those of a replaced fit no longer describe it.
DERIVED_RESULTS = ("report.html",)


def results_digest(summary: dict) -> str:
    """A short digest of a fit's results (models, regions, seed, settings): it identifies the
    fit that a diagnosis or comparison was made from, so a report can tell a stale one."""
    keys = ("model_posterior", "map_model", "regions", "iterations", "burn_in", "n_chains", "seed", "n_observations",
            "likelihood_power", "prior")
    text = json.dumps({key: summary.get(key) for key in keys}, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def publish_results(staging: Path, out_dir: Path) -> None:
    """Move a finished fit's files from ``staging`` into ``out_dir``, replacing the previous fit's.

    The previous ``summary.json`` goes first and the new one comes last: a folder without
    ``summary.json`` is an incomplete fit, never a mixture of two. Previous result files
    the new fit does not write are removed too. Every file is on disk (fsync) before the
    new ``summary.json`` appears (see :func:`rjfit.io.publish`).
    """
    publish(staging, out_dir, manifest="summary.json", names=RESULT_FILES, remove=RESULT_FILES + DERIVED_RESULTS)


def fit(observations, out_dir, *, truth_labels=None, truth_params=None, seed: int = 0, n_chains: int = 4,
        iterations: int = 20000, burn_in: float = 0.5, max_u: int = 3, max_v: int = 3, sampler: str = "adaptive",
        prior: str = "default", split_map: str = "conditional", cp_prior: str = "smooth",
        drop_jacobian: bool = False, jump_prob: float = 0.2, likelihood_power: float | str = 1.0,
        noise: str = "constant", noise_floor: float = DEFAULT_FLOOR, anneal: float = 0.5,
        cp_thin: int = 10, checkpoint_every: int = 2000, processes: int | None = None, threads: int | None = None,
        start=None, fixed_segmentation=None, figures: bool = True, progress: bool = True, chain_runner=None,
        before_publish=None) -> dict:
    """Run the RJMCMC fit of ``observations`` and write results to ``out_dir``.

    Parameters
    ----------
    observations : rjfit.data.observations.Observations
    out_dir : path
    truth_labels : ndarray (H, W), optional
        Ground-truth region per pixel (-1 off the object): adds label_accuracy and
        exact_truth_probability.
    truth_params : list of dict, optional
        Ground-truth parameters per true label (written beside the estimates).
    seed : int
        User seed; chain c draws from ``SeedSequence(seed).spawn(n_chains)[c]``.
    n_chains, iterations : int
    burn_in : float
        Fraction of iterations discarded (paper: 0.5 synthetic, 0.2 real); the gamma step
        adapts during it only.
    max_u, max_v : int
        Maximum numbers of u and v change-point vectors.
    sampler : {'adaptive', 'paper'}
    prior : {'default', 'paper-synthetic', 'paper-real'}
    anneal : float
        Fraction of the burn-in run as a tempered warm-up (likelihood power rising
        geometrically from 1e-3 of its value to all of it; see
        :func:`rjfit.sampler.kernel.anneal_power`); 0 for none. Only burn-in is tempered.
    likelihood_power : float or 'auto'
        zeta in (0, 1]: the coarsened posterior (likelihood ** zeta; Miller and Dunson, JASA
        2019) for a model known to miss part of measured data; see
        :class:`rjfit.sampler.forward.Problem`. 1 (default): the plain posterior.
        'auto': the effective fraction of independent observations, from the spatial
        correlation of per-pixel-fit residuals (:func:`rjfit.data.coarsen.suggest_likelihood_power`).
    noise : {'constant', 'shot', 'relative'}
        Noise model, ``y_i ~ N(mu_i, sigma_r^2 s_i^2)`` with known scales ``s_i``
        (:func:`rjfit.data.noise.noise_scale`): 'constant' (default, the paper's) ``s_i = 1``;
        'shot' ``s_i^2 = (m_i + c) / ybar``; 'relative' ``s_i = (m_i + c) / ybar``, with
        ``m_i`` a per-pixel fit's prediction, ``ybar`` the mean observed value and
        ``c = noise_floor * ybar``. With 'auto' likelihood power, zeta is measured on the
        standardised residuals.
    noise_floor : float
        ``c / ybar`` of the 'shot' and 'relative' models (default 0.05); unused for 'constant'.
    split_map, cp_prior, drop_jacobian, jump_prob : see :class:`rjfit.sampler.state.SamplerConfig`
        (``cp_prior='paper'`` and ``split_map='paper'`` with ``drop_jacobian=True`` give the
        paper's own choices).
    cp_thin : int
        Keep a change-point snapshot every ``cp_thin`` iterations (fewer when a short run
        would keep under 50 after burn-in).
    checkpoint_every : int
        Iterations between checkpoints (``out_dir/checkpoints/chain_<c>.pkl``); an existing
        checkpoint of the same run (same data, prior, settings, seed and sampler code) is
        resumed, one of another run is refused with an error. They are deleted once the
        results are written.
    processes : int, optional
        Worker processes for the chains (default: one per chain, at most one per core).
    threads : int, optional
        Numba threads per chain for its large passes (default: the cores left to each chain
        that runs at once). The samples are the same for any number.
    start : list of dict, optional
        Per chain keyword arguments of :func:`rjfit.sampler.kernel.initial_state`.
    fixed_segmentation : (u, v), optional
        Fix the change points (no element moves, no births/deaths).
    chain_runner : callable, optional
        ``chain_runner(specs) -> records``: runs :func:`rjfit.sampler.runner.run_chain` over
        the chain specs elsewhere (e.g. on Dask); default: local worker processes.
    before_publish : callable, optional
        ``before_publish(summary, staging_dir, prediction)``: adds files (any of
        :data:`RESULT_FILES`) and summary keys before the results replace the folder's
        previous ones; ``prediction`` is
        :func:`rjfit.posterior.summary.posterior_mean_prediction` of the fit.

    Returns
    -------
    dict
        The summary written to ``summary.json``.

    Raises
    ------
    ValueError
        Before any chain runs: if ``burn_in`` is not in [0, 1) or leaves no iteration to
        keep; ``n_chains < 1`` or ``iterations < 10``; ``prior`` or ``noise`` is unknown;
        ``likelihood_power`` is neither ``'auto'`` nor a number in (0, 1] (the range is
        checked by :class:`rjfit.sampler.forward.Problem`); ``'auto'`` cannot be measured
        (no two adjacent pixels under one light have a residual); ``truth_labels`` does not
        have the images' shape (H, W); ``noise_floor`` is not positive and finite for the
        'shot' / 'relative' models (:func:`rjfit.data.noise.noise_scale`); the observations are
        unusable (none, some with ``<l.n> <= 0``, or a mean value that is not positive under
        the 'shot' / 'relative' models); or a sampler setting is out of range
        (:class:`rjfit.sampler.state.SamplerConfig`: ``sampler``, ``split_map``,
        ``cp_prior``, ``max_u``/``max_v``, ``jump_prob``). While the chains start: if a
        ``start`` entry does not fit ``max_u``/``max_v``, or a checkpoint in
        ``out_dir/checkpoints`` is unreadable, of another checkpoint version or of another
        run (the message says to delete it).
    """
    if not 0.0 <= burn_in < 1.0:
        raise ValueError(f"burn_in (--burn-in) is a fraction in [0, 1), got {burn_in}")
    if n_chains < 1 or iterations < 10:
        raise ValueError(f"need n_chains >= 1 (--chains) and iterations >= 10 (--iterations), got {n_chains}, "
                         f"{iterations}")
    if prior not in PRESETS:
        raise ValueError(f"unknown prior {prior!r}: choose one of {', '.join(PRESETS)}")
    if noise not in NOISE_MODELS:
        raise ValueError(f"unknown noise model {noise!r}: choose one of {', '.join(NOISE_MODELS)}")
    if likelihood_power != "auto":
        try:
            likelihood_power = float(likelihood_power)
        except (TypeError, ValueError):
            raise ValueError(f"likelihood_power must be a number in (0, 1] or 'auto', got {likelihood_power!r}") from None
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    scale = noise_scale(observations, noise, noise_floor)
    # measured always (a fraction of a second): a misfit shared by neighbouring pixels is
    # worth a warning whatever power the fit uses
    try:
        power_suggestion = suggest_likelihood_power(observations, noise_scale=scale)
    except ValueError:
        if likelihood_power == "auto":
            raise
        power_suggestion = None      # too few adjacent pixels to measure it
    if likelihood_power == "auto":
        likelihood_power = power_suggestion["likelihood_power"]
    problem = Problem.from_observations(observations, likelihood_power=float(likelihood_power), noise_scale=scale)
    noise_record = describe_noise(noise, noise_floor, scale)
    del scale
    prior_obj = make_prior(prior, y=problem.y, diffuse_scale=problem.A)
    burn = int(round(burn_in * iterations))
    if iterations - burn < 1:
        raise ValueError(f"burn-in {burn_in} leaves no iteration of {iterations} to keep; lower --burn-in")
    # at least ~50 change-point snapshots after burn-in, so a short run still has its MAP labels
    cp_thin = max(1, min(cp_thin, (iterations - burn) // 50))
    fixed = fixed_segmentation is not None
    config = SamplerConfig.from_flat(max_u=max_u, max_v=max_v, sampler=sampler, split_map=split_map,
                                     cp_prior=cp_prior, drop_jacobian=drop_jacobian, burn_in=burn, jump_prob=jump_prob,
                                     anneal=int(round(anneal * burn)),
                                     # reproducing the paper's omission: every jump must use its map
                                     free_jump_prob=0.0 if drop_jacobian else BirthDeathSettings.free_prob,
                                     update_changepoints=not fixed, jumps=not fixed)
    if truth_labels is not None and np.shape(truth_labels) != tuple(problem.image_shape):
        raise ValueError(f"truth_labels has shape {np.shape(truth_labels)}, images are {problem.image_shape}")
    specs = []
    for c in range(n_chains):
        chain_start = dict(start[c]) if start is not None else {}
        if fixed:
            chain_start.setdefault("changepoints", fixed_segmentation)
        specs.append(ChainSpec(problem=problem, prior=prior_obj, config=config, seed=seed, chain=c, n_chains=n_chains,
                               iterations=iterations, checkpoint_path=str(out_dir / "checkpoints" / f"chain_{c}.pkl"),
                               checkpoint_every=checkpoint_every, cp_thin=cp_thin, truth_labels=truth_labels,
                               start=chain_start, progress=progress))
    records = (list(chain_runner(specs)) if chain_runner is not None
               else run_chains(specs, processes=processes, threads=threads))

    model_post = post.model_posterior(records, burn)
    n_u, n_v = post.map_model(records, burn)
    draws = post.map_model_draws(records, burn, (n_u, n_v))
    labels = post.map_labels(records, burn, (n_u, n_v), problem.image_shape, problem.object_mask)
    # what the figures and residual maps show: averaged draw by draw, each with its own segmentation
    prediction = post.posterior_mean_prediction(records, burn, problem)
    diag = post.diagnostics(draws)
    summary = {
        "model_posterior": model_post,
        "map_model": {"n_u": n_u, "n_v": n_v, "m": model_number(n_u, n_v, max_v)},
        "model_number_convention": "m = n_u * (max_v + 1) + n_v + 1",
        "regions": post.region_summaries(draws, labels),
        "rhat_max": diag["rhat_max"],
        "ess_min": min(diag["ess_bulk_min"], diag["ess_tail_min"]),
        "ess_bulk_min": diag["ess_bulk_min"], "ess_tail_min": diag["ess_tail_min"],
        "diagnostics": diag,
        "iterations": iterations, "burn_in": burn, "n_chains": n_chains, "seed": seed,
        "n_observations": problem.n_obs,
        "sampler": sampler, "prior": prior_obj.to_json(), "max_u": max_u, "max_v": max_v,
        "split_map": split_map, "cp_prior": cp_prior, "drop_jacobian": drop_jacobian,
        "likelihood_power": float(likelihood_power), "likelihood_power_suggestion": power_suggestion,
        "noise": noise_record,
        "anneal_iterations": int(round(anneal * burn)),
        "acceptance": {k: sum(r.accepted.get(k, 0) for r in records) / max(1, sum(r.proposed.get(k, 0) for r in records))
                       for k in sorted({k for r in records for k in r.proposed})},
        "chain_seconds": [r.seconds for r in records],
        "chain_threads": [r.threads for r in records],
        "chain_resumed_from": [list(r.resumed_from) for r in records],
        "chain_model_posterior": [post.model_posterior([r], burn) for r in records],
        "chain_regions": post.chain_region_summaries(records, draws, burn, (n_u, n_v), problem.image_shape,
                                                     problem.object_mask),
    }
    summary["warnings"] = post.convergence_warnings(diag, summary["chain_model_posterior"], n_chains)
    misfit = misfit_warning(power_suggestion, float(likelihood_power))
    if misfit:
        summary["warnings"].append(misfit)
    if prior_obj.caveat:
        summary["warnings"].append(prior_obj.caveat)
    if truth_labels is not None:
        acc = post.label_accuracy(labels, truth_labels)
        summary["label_accuracy"] = acc["accuracy"]
        summary["label_matching"] = acc["matching"]
        summary["exact_truth_probability"] = post.exact_truth_probability(records, burn)
        n_true = int(len(np.unique(np.asarray(truth_labels)[np.asarray(truth_labels) >= 0])))
        summary["true_region_count"] = n_true
        summary["four_region_probability"] = post.object_region_count_probability(records, burn, n_true)
        summary["true_regions_probability"] = post.true_regions_probability(records, burn)
        summary["chain_true_regions_probability"] = [post.true_regions_probability([r], burn) for r in records]
    if truth_params is not None:
        summary["truth_params"] = truth_params

    from rjfit.data.exr import write_exr

    # Every result goes into a staging folder first and is published together (summary.json
    # last), so an interrupted run leaves the previous results whole or none: never labels of
    # one run beside the summary of another.
    # (staging_dir removes the staging folders of runs killed while they wrote their results)
    with staging_dir(out_dir) as staging:
        write_exr(staging / "labels.exr", {"labels": labels.astype(np.float32)})
        summary["fit_id"] = results_digest(summary)
        idata = post.to_inference_data(records, burn, max_v)
        idata.posterior.attrs.update({
            "rjfit_fit_id": summary["fit_id"], "seed": seed, "burn_in_iterations": burn,
            "regions": f"region r of a draw is cell r of its model (n_u, n_v); slots past (n_u + 1)(n_v + 1) "
                       f"are NaN (the region dimension has room for the largest model, {max_u}, {max_v})",
            "parameters": "I0 (intensity), kd (diffuse fraction), gamma (Blinn-Phong exponent), sigma2 (noise "
                          "variance), in the units of the observations"})
        idata.to_netcdf(str(staging / "chains.nc"))
        cp_payload = {f"chain{c}_{k}": getattr(r, k) for c, r in enumerate(records)
                      for k in ("cp_iteration", "cp_u", "cp_v", "n_u", "n_v")}
        with open(staging / "changepoints.npz", "wb") as handle:
            np.savez_compressed(handle, **cp_payload)
        if figures:
            from rjfit.posterior import figures as figs

            written = figs.write_all(staging / "figures", records=records, burn_in=burn, model=(n_u, n_v),
                                     labels=labels, problem=problem, prediction=prediction, max_v=max_v)
            summary["figures"] = {name: f"figures/{Path(path).name}" for name, path in written.items()}
        if before_publish is not None:
            before_publish(summary, staging, prediction)
        summary["seconds"] = time.perf_counter() - started
        write_json_atomic(staging / "summary.json", summary)
        publish_results(staging, out_dir)
    # The results are written: the checkpoints (for resuming an interrupted run) have
    # served, and a later run into this directory must start afresh, not resume them.
    for spec in specs:
        if os.path.exists(spec.checkpoint_path):
            os.remove(spec.checkpoint_path)
    with contextlib.suppress(OSError):      # only when empty: a folder the user keeps files in stays
        (out_dir / "checkpoints").rmdir()
    return summary
