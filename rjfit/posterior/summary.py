"""Posterior summaries of RJMCMC chains: model posterior, MAP model, regions, labels, diagnostics.

All functions take the chains' :class:`~rjfit.sampler.runner.ChainRecord` list and the
burn-in as a number of iterations; only post-burn-in draws enter a summary.
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from rjfit.posterior.misfit import residual_correlation
from rjfit.sampler.priors import PARAM_NAMES
from rjfit.sampler.regions.changepoints.grid import pixel_region_labels

__all__ = ["model_posterior", "map_model", "map_model_draws", "region_summaries", "diagnostics",
           "map_labels", "label_accuracy", "exact_truth_probability", "true_regions_probability",
           "object_region_count_probability", "model_key", "convergence_warnings",
           "chain_log_posterior_means",
           "RHAT_MAX", "ESS_PER_CHAIN_MIN", "TV_MAX", "chain_region_summaries",
           "posterior_mean_prediction"]

# Vehtari, Gelman, Simpson, Carpenter and Buerkner (2021), "Rank-normalization, folding, and
# localization: an improved R-hat", Bayesian Analysis 16(2): trust a posterior summary when
# split R-hat <= 1.01 and bulk and tail ESS >= 100 per chain.
RHAT_MAX = 1.01
ESS_PER_CHAIN_MIN = 100
# Chains whose model frequencies differ by more than this (total variation) have not mixed
# over models: half their mass sits on different models.
TV_MAX = 0.5


def _arviz():
    """ArviZ, imported without its 0.x FutureWarning about the 1.0 refactor.

    Every fit would otherwise print that notice in the middle of its own output (once a day:
    ArviZ keeps a stamp in the user's cache); it is about ArviZ's future API, not about
    anything rjfit calls (pinned in pyproject.toml). The notice starts with a line break,
    and a filter's message must match from the start.
    """
    import warnings

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r"\s*ArviZ is undergoing a major refactor", category=FutureWarning)
        import arviz
    return arviz


def model_key(n_u: int, n_v: int) -> str:
    """The key ``"(n_u,n_v)"`` of a model in :func:`model_posterior` and the summaries."""
    return f"({int(n_u)},{int(n_v)})"


def model_posterior(records, burn_in: int) -> dict:
    """Posterior probability of every visited model ``"(n_u,n_v)"`` (pooled over chains).

    Parameters
    ----------
    records : sequence of ChainRecord
        The chains; each draw's model is ``(record.n_u[i], record.n_v[i])``.
    burn_in : int
        Iterations discarded at the start of every chain.

    Returns
    -------
    dict
        ``{model_key(n_u, n_v): probability}`` over the models visited after burn-in, most
        probable first (ties in increasing ``(n_u, n_v)``), probabilities summing to 1.

    Raises
    ------
    ValueError
        If no chain has a draw after burn-in, or ``records`` is empty.
    """
    pairs = np.concatenate([np.stack([r.n_u[burn_in:], r.n_v[burn_in:]], axis=1) for r in records])
    if pairs.size == 0:
        raise ValueError("no draws after burn-in: lower the burn-in (--burn-in) or run more iterations (--iterations)")
    models, counts = np.unique(pairs, axis=0, return_counts=True)
    order = np.argsort(-counts, kind="stable")
    total = counts.sum()
    return {model_key(*models[i]): float(counts[i] / total) for i in order}


def map_model(records, burn_in: int) -> tuple[int, int]:
    """The most frequent model after burn-in as (n_u, n_v)."""
    key = next(iter(model_posterior(records, burn_in)))
    n_u, n_v = key.strip("()").split(",")
    return int(n_u), int(n_v)


def map_model_draws(records, burn_in: int, model) -> list:
    """Per chain, the post-burn-in parameter draws (T_c, R, 4) that are in ``model``."""
    n_u, n_v = model
    R = (n_u + 1) * (n_v + 1)
    out = []
    for r in records:
        keep = (r.n_u[burn_in:] == n_u) & (r.n_v[burn_in:] == n_v)
        out.append(r.theta[burn_in:][keep][:, :R])
    return out


def diagnostics(draws_per_chain) -> dict:
    """ArviZ split R-hat and bulk/tail ESS of the MAP model's parameters, and why R-hat is missing where it is.

    Chains are truncated to the shortest chain's number of MAP-model draws (ArviZ needs equal
    lengths); a chain with fewer than 4 such draws is left out. A parameter constant within
    a chain gets neither (NaN): R-hat compares the spread within chains with the spread
    between them, and a chain that never moved a parameter has no spread to compare
    (ArviZ would divide by zero). ``rhat_reason`` says why ``rhat_max`` is NaN (None when
    it is a number); ``rhat_missing`` lists each parameter without an R-hat and why.
    """
    az = _arviz()

    n_chains = len(draws_per_chain)
    usable = [d for d in draws_per_chain if len(d) >= 4]
    if len(usable) < 2:
        reason = ("one chain: R-hat compares chains (run two or more, --chains)" if n_chains < 2 else
                  f"only {len(usable)} of {n_chains} chains have 4 or more kept draws in the MAP model: the chains sit "
                  "in different models")
    if not usable:
        return {"rhat_max": float("nan"), "ess_bulk_min": float("nan"), "ess_tail_min": float("nan"),
                "ess_bulk_median": float("nan"), "chains_used": 0, "draws_per_chain": 0, "rhat_reason": reason,
                "rhat_missing": []}
    length = min(len(d) for d in usable)
    stacked = np.stack([d[:length] for d in usable])            # (chain, draw, region, param)
    constant = np.ptp(stacked, axis=1) == 0                      # (chain, region, param)
    varying = ~constant.any(axis=0)
    missing = [{"region": int(r), "parameter": PARAM_NAMES[k],
                "reason": f"constant within chain {', '.join(str(c) for c in np.flatnonzero(constant[:, r, k]))}"}
               for r, k in zip(*np.nonzero(~varying))]
    rhat, ess_bulk, ess_tail = (np.full(stacked.shape[2:], np.nan) for _ in range(3))
    if varying.any():
        data = az.convert_to_dataset({"theta": stacked[:, :, varying]}, dims={"theta": ["quantity"]})
        if len(usable) > 1:
            rhat[varying] = az.rhat(data)["theta"].values
        ess_bulk[varying] = az.ess(data, method="bulk")["theta"].values
        ess_tail[varying] = az.ess(data, method="tail")["theta"].values
    if len(usable) >= 2:
        reason = None if np.any(np.isfinite(rhat)) else "every parameter of the MAP model is constant within a chain"
    return {"rhat_max": float(np.nanmax(rhat)) if np.any(np.isfinite(rhat)) else float("nan"),
            "ess_bulk_min": _nan_min(ess_bulk), "ess_tail_min": _nan_min(ess_tail),
            "ess_bulk_median": float(np.nanmedian(ess_bulk)) if np.any(np.isfinite(ess_bulk)) else float("nan"),
            "rhat": rhat.tolist(), "ess_bulk": ess_bulk.tolist(),
            "chains_used": len(usable), "draws_per_chain": int(length), "rhat_reason": reason,
            "rhat_missing": missing}


def _nan_min(values) -> float:
    return float(np.nanmin(values)) if np.any(np.isfinite(values)) else float("nan")


def chain_log_posterior_means(records, burn: int) -> list:
    """Each chain's mean log posterior density over its kept draws (NaN for a chain with none)."""
    return [float(np.mean(r.log_post[burn:])) if len(r.log_post) > burn else float("nan") for r in records]


def _best_chain_note(chain_log_posteriors, modal) -> str:
    """Which chain's draws sit highest in the target, and how far above the lowest (empty if not finite)."""
    values = np.asarray(chain_log_posteriors, dtype=float)
    if values.size < 2 or not np.all(np.isfinite(values)):
        return ""
    best, worst = int(np.argmax(values)), int(np.argmin(values))
    return (f"; chain {best}'s draws (model {modal[best]}) have the highest mean log posterior, "
            f"{values[best] - values[worst]:.4g} above chain {worst}'s (model {modal[worst]}): a chain that never "
            "reached that mode counts against it in the pooled posterior")


def convergence_warnings(diagnostics_result: dict, chain_model_posteriors, n_chains: int,
                         chain_log_posteriors=None) -> list:
    """Plain-language warnings where the chains do not support the fit's summaries.

    Checks, in order: that there are at least two chains (R-hat needs them); that no two
    chains' model frequencies differ by more than :data:`TV_MAX` in total variation (chains
    stuck in different models make the pooled model posterior an artefact of the starts);
    that at least two chains visit the
    MAP model, so that R-hat exists, and that no parameter is constant within a chain (R-hat
    is then missing for it); split R-hat <= :data:`RHAT_MAX` and bulk and tail ESS
    >= :data:`ESS_PER_CHAIN_MIN` per chain for the MAP model's parameters (Vehtari et al.
    2021).

    Parameters
    ----------
    diagnostics_result : dict
        :func:`diagnostics` of the MAP model's draws.
    chain_model_posteriors : list of dict
        :func:`model_posterior` of each chain alone.
    n_chains : int
    chain_log_posteriors : list of float, optional
        :func:`chain_log_posterior_means`: when the chains disagree, the warning says which
        chain's model sits highest in the target (a density, so a guide across models whose
        dimensions differ by a few parameters, not a Bayes factor).

    Returns
    -------
    list of str
        Empty when every check passes.
    """
    warnings = []
    if n_chains < 2:
        warnings.append("one chain only: R-hat needs at least two; run several chains from dispersed starts "
                        "(--chains 4) before trusting the model posterior")
    models = sorted({m for p in chain_model_posteriors for m in p})
    masses = np.array([[p.get(m, 0.0) for m in models] for p in chain_model_posteriors])
    # total variation between two chains' model frequencies: 1 for chains stuck in different
    # models, near 0 for chains that each visit every model (even a 50/50 pair of them)
    tv_max = max((0.5 * np.abs(masses[i] - masses[j]).sum() for i in range(len(masses)) for j in range(i)), default=0.0)
    if tv_max > TV_MAX:
        modal = [max(p, key=p.get) for p in chain_model_posteriors]
        per_chain = ", ".join(f"chain {c}: {m} ({p[m]:.2f})" for c, (m, p) in enumerate(zip(modal, chain_model_posteriors)))
        best = "" if chain_log_posteriors is None else _best_chain_note(chain_log_posteriors, modal)
        warnings.append(f"the chains disagree on the model ({per_chain}): the pooled model posterior reflects "
                        f"where they started, not the data{best}; run longer (--iterations) or with more chains")
    used = diagnostics_result.get("chains_used", 0)
    if n_chains >= 2 and used < 2:
        warnings.append(f"only {used} of {n_chains} chains visit the MAP model after burn-in (4 draws needed): "
                        "R-hat of its parameters cannot be computed")
    missing = diagnostics_result.get("rhat_missing", [])
    if used >= 2 and missing:
        listed = "; ".join(f"region {m['region']} {m['parameter']} ({m['reason']})" for m in missing[:8])
        more = f" and {len(missing) - 8} more" if len(missing) > 8 else ""
        warnings.append(f"R-hat not computable for {len(missing)} of the MAP model's parameters: {listed}{more}: a "
                        "chain that never moved a parameter over its kept draws is stuck there (every proposal "
                        "rejected), and R-hat has no spread within it to compare")
    rhat = diagnostics_result.get("rhat_max", float("nan"))
    if np.isfinite(rhat) and rhat > RHAT_MAX:
        warnings.append(f"R-hat max {rhat:.4f} > {RHAT_MAX}: the chains have not mixed over the MAP model's parameters")
    ess = min(diagnostics_result.get("ess_bulk_min", np.nan), diagnostics_result.get("ess_tail_min", np.nan))
    if used >= 1 and np.isfinite(ess) and ess < ESS_PER_CHAIN_MIN * used:
        chains = "the chain" if used == 1 else f"the {used} chains"
        warnings.append(f"ESS min {ess:.0f} < {ESS_PER_CHAIN_MIN * used} ({ESS_PER_CHAIN_MIN} per chain, {chains} at "
                        "the MAP model): too few effective draws for the quantiles; run longer")
    return warnings


def region_summaries(draws_per_chain, labels=None) -> list:
    """Per region: pixel count (from ``labels``) and mean, sd, 2.5 % and 97.5 % quantiles of each parameter."""
    pooled = np.concatenate([d for d in draws_per_chain if len(d)], axis=0)
    out = []
    for r in range(pooled.shape[1]):
        entry = {"region": r}
        if labels is not None:
            entry["pixels"] = int(np.sum(labels == r))
        for k, name in enumerate(PARAM_NAMES):
            x = pooled[:, r, k]
            entry[name] = {"mean": float(np.mean(x)), "sd": float(np.std(x, ddof=1)) if len(x) > 1 else 0.0,
                           "q2.5": float(np.quantile(x, 0.025)), "q97.5": float(np.quantile(x, 0.975))}
        out.append(entry)
    return out


def chain_region_summaries(records, draws_per_chain, burn_in: int, model, image_shape, object_mask=None) -> list:
    """:func:`region_summaries` of each chain on its own, with its own MAP labels' pixel counts.

    Region r of model (n_u, n_v) is a cell of the change points, so chains that settled in
    different modes (the change points elsewhere, one region on a highlight in one chain and
    on a half of the object in another) give region r different pixels and parameters; pooled,
    their draws make a mixture whose mean and sd describe neither. Each chain's own summary
    is what a reader can compare when the chains disagree. Chains with fewer than 2 draws in
    the model are left out.

    Returns
    -------
    list of dict
        ``{"chain": c, "draws": n, "regions": [...]}`` per chain, ``regions`` as in
        :func:`region_summaries`.
    """
    out = []
    for chain, (record, draws) in enumerate(zip(records, draws_per_chain)):
        if len(draws) < 2:
            continue
        try:
            labels = map_labels([record], burn_in, model, image_shape, object_mask)
        except ValueError:          # no change-point snapshot of the model after burn-in in this chain
            labels = None
        out.append({"chain": chain, "draws": int(len(draws)), "regions": region_summaries([draws], labels)})
    return out


def draw_labels(record, snapshot: int, problem) -> tuple[int, np.ndarray]:
    """(number of regions, region of every observation of ``problem``) of a chain's layout snapshot
    (change points, or material labels per pixel; for a joint colour fit parameter rows,
    ``material C + channel``, and their number)."""
    from rjfit.sampler.regions.changepoints.grid import obs_region_labels

    t = record.cp_iteration[snapshot]
    if getattr(record, "n_materials", None) is not None:      # materials: the snapshot holds the labels
        pixels = np.nan_to_num(record.material_labels[snapshot], nan=0.0).astype(np.int64).ravel()
        labels = np.repeat(pixels, np.diff(problem.pixel_start))
        if problem.n_channels > 1:
            return int(record.n_materials[t]) * problem.n_channels, labels * problem.n_channels + problem.channel
        return int(record.n_materials[t]), labels
    n_u, n_v = int(record.n_u[t]), int(record.n_v[t])
    labels = obs_region_labels(record.cp_u[snapshot, :, :n_u].astype(float),
                               record.cp_v[snapshot, :, :n_v].astype(float), problem.row, problem.col,
                               pixel_start=problem.pixel_start)
    return (n_u + 1) * (n_v + 1), labels


def posterior_mean_prediction(records, burn_in: int, problem, max_draws: int = 100, labels_of=None) -> dict:
    """Per-pixel maps of the posterior mean prediction, averaged draw by draw over kept draws of every model.

    For each kept draw with a layout snapshot (change points or material labels; at most ``max_draws``, evenly spaced
    over the chains' snapshots after ``burn_in``) every observation's radiance ``mu_i`` is
    computed from that draw's own segmentation and parameters, then averaged. Unlike
    radiance at pooled region means on the MAP labels, this is the posterior's prediction
    also when chains sit in different modes (region r then holds other pixels, and other
    parameters, in each chain) or the model is uncertain.

    Returns
    -------
    dict
        ``radiance``: mean over a pixel's lights of E[mu_i]; ``observed``: mean over its
        lights of y_i; ``abs_error``: mean over its lights of ``|y_i - E[mu_i]|``, all three
        in the data's units; ``residual_rms``: RMS over
        its lights of ``(y_i - E[mu_i]) / (sqrt(E[sigma_i^2]) s_i)`` (``s_i`` the known noise
        scales, 1 for constant noise); each (H, W), NaN at pixels without observations;
        ``draws``, the number of draws averaged. A joint colour fit (every channel's
        observations, averaged together above) adds ``radiance_rgb`` and ``observed_rgb``
        (H, W, C), each channel's mean over lights.

    ``labels_of(record, snapshot, problem) -> (number of regions, region of every observation)``: a draw's
    segmentation (default :func:`draw_labels`, which reads change-point or material snapshots).

    Raises
    ------
    ValueError
        If no change-point snapshot lies after ``burn_in``.
    """
    from rjfit.model.blinn import radiance_of_rows

    labels_of = draw_labels if labels_of is None else labels_of

    kept = [(rec, s) for rec in records for s in np.flatnonzero(rec.cp_iteration >= burn_in)]
    if not kept:
        raise ValueError("no change-point snapshot after burn-in: run more iterations (or keep snapshots more often)")
    picks = np.unique(np.linspace(0, len(kept) - 1, min(max_draws, len(kept))).round().astype(int))
    if problem.effects is not None:      # each draw on the problem transformed at its effect parameters
        from rjfit.posterior.effects import effects_prediction

        def picks_of(_):
            return [(kept[i][0], kept[i][0].cp_iteration[kept[i][1]], labels_of(*kept[i], problem)[1]) for i in picks]
        return effects_prediction(records, burn_in, problem, picks_of)
    C = problem.C.astype(np.float64)
    log_cos_hn = problem.log_cos_hn.astype(np.float64)
    mu_sum = np.zeros(problem.n_obs)
    sigma2_sum = np.zeros(problem.n_obs)
    for index in picks:
        rec, s = kept[index]
        n_regions, labels = labels_of(rec, s, problem)
        theta = rec.theta[rec.cp_iteration[s], :n_regions]
        # the Problem's y and C are divided by the known noise scales s, so mu here is mu / s too
        mu_sum += radiance_of_rows(theta, labels, C, log_cos_hn)
        sigma2_sum += theta[:, 3][labels]
    mu, sigma2 = mu_sum / len(picks), sigma2_sum / len(picks)
    scale = 1.0 if problem.noise_scale is None else problem.noise_scale.astype(np.float64)
    y = problem.y.astype(np.float64)
    n_pix = problem.height * problem.width
    count = np.bincount(problem.pixel, minlength=n_pix).astype(float)

    def per_pixel(values):
        with np.errstate(invalid="ignore", divide="ignore"):
            return (np.bincount(problem.pixel, weights=values, minlength=n_pix) / count).reshape(problem.image_shape)

    out = {"radiance": per_pixel(mu * scale), "observed": per_pixel(y * scale),
           "abs_error": per_pixel(np.abs(y - mu) * scale),
           "residual_rms": np.sqrt(per_pixel((y - mu) ** 2 / sigma2)), "draws": int(len(picks)),
           "residual_correlation": residual_correlation(problem, (y - mu) / np.sqrt(sigma2))}
    if problem.n_channels > 1:        # a joint colour fit: the radiances per channel as well, (H, W, C)
        for name, values in (("radiance_rgb", mu * scale), ("observed_rgb", y * scale)):
            out[name] = np.stack([_channel_mean(problem, values, c) for c in range(problem.n_channels)], axis=-1)
    return out


def _channel_mean(problem, values, channel: int) -> np.ndarray:
    """(H, W): the mean over a pixel's observations of ``channel`` (NaN without any)."""
    n_pix = problem.height * problem.width
    mine = problem.channel == channel
    count = np.bincount(problem.pixel[mine], minlength=n_pix).astype(float)
    with np.errstate(invalid="ignore", divide="ignore"):
        return (np.bincount(problem.pixel[mine], weights=values[mine], minlength=n_pix) / count).reshape(
            problem.image_shape)


def map_labels(records, burn_in: int, model, image_shape, object_mask=None) -> np.ndarray:
    """Per-pixel posterior mode of the region label over the MAP model's change-point snapshots.

    Off-object pixels get -1 when ``object_mask`` is given.
    """
    n_u, n_v = model
    R = (n_u + 1) * (n_v + 1)
    counts = np.zeros((R,) + tuple(image_shape), np.int64)
    for rec in records:
        for s in np.flatnonzero(rec.cp_iteration >= burn_in):
            t = rec.cp_iteration[s]
            if rec.n_u[t] != n_u or rec.n_v[t] != n_v:
                continue
            labels = pixel_region_labels(rec.cp_u[s, :, :n_u].astype(float), rec.cp_v[s, :, :n_v].astype(float),
                                         image_shape)
            np.add.at(counts, (labels, *np.indices(image_shape)), 1)
    if counts.sum() == 0:
        raise ValueError("no change-point snapshot of the MAP model after burn-in: run more iterations "
                         "(or keep snapshots more often: cp_thin)")
    labels = np.argmax(counts, axis=0)
    if object_mask is not None:
        labels = np.where(object_mask, labels, -1)
    return labels


def label_accuracy(labels, truth_labels) -> dict:
    """Fraction of object pixels whose label matches the truth after optimal one-to-one matching.

    Object pixels are those with ``truth_labels >= 0``. Matching is the Hungarian assignment
    (``scipy.optimize.linear_sum_assignment``) on the confusion matrix.
    """
    truth = np.asarray(truth_labels)
    mask = truth >= 0
    est, tru = np.asarray(labels)[mask], truth[mask]
    if est.size == 0:
        raise ValueError("truth labels mark no object pixel (all < 0)")
    est_ids, est_idx = np.unique(est, return_inverse=True)
    tru_ids, tru_idx = np.unique(tru, return_inverse=True)
    confusion = np.zeros((len(est_ids), len(tru_ids)), np.int64)
    np.add.at(confusion, (est_idx, tru_idx), 1)
    rows, cols = linear_sum_assignment(-confusion)
    return {"accuracy": float(confusion[rows, cols].sum() / est.size),
            "matching": {int(est_ids[r]): int(tru_ids[c]) for r, c in zip(rows, cols)}}


def exact_truth_probability(records, burn_in: int) -> float | None:
    """Posterior probability that object pixels fall into exactly the true regions (None without truth)."""
    flags = np.concatenate([r.exact_truth[burn_in:] for r in records])
    if flags.size == 0 or np.any(flags < 0):
        return None
    return float(np.mean(flags))


def true_regions_probability(records, burn_in: int) -> float | None:
    """Posterior probability that the object's pixels fall into exactly the true regions (None without truth).

    One region per true region, and the optimal one-to-one matching agrees on at least 99 %
    of the observed object pixels (see :meth:`rjfit.sampler.runner.ChainRecorder.exact`): a
    few rim pixels whose grazing observations cannot tell two regions apart do not count
    against it, an extra region holding object pixels or a misplaced boundary does.
    """
    flags = np.concatenate([r.true_regions[burn_in:] for r in records])
    if flags.size == 0 or np.any(flags < 0):
        return None
    return float(np.mean(flags))


def object_region_count_probability(records, burn_in: int, n_regions: int) -> float:
    """Posterior probability that the observed object pixels fall into exactly ``n_regions`` non-empty regions."""
    counts = np.concatenate([r.object_regions[burn_in:] for r in records])
    return float(np.mean(counts == n_regions))


