"""The criticism workflow: fit the plain model, measure the gap, try every candidate effect,
name one only when the evidence is decisive, add it, refit, and repeat.

Decision rule (stated once, used everywhere): a candidate is DECISIVE when

    log BF = log Z(model + effect) - log Z(model) > ln 100 ~ 4.6      (Jeffreys: "decisive")
    and  delta ELPD_LOO > 4 SE(delta)                                  (PSIS-LOO agrees)

with Z the Laplace marginal likelihood (``refit``), which penalises extra parameters through
their Occam factor, and ELPD_LOO from PSIS-LOO on the Laplace draws (ArviZ's estimator,
vectorised in :mod:`rjfit.diagnose.psis`; a second opinion
that does not rest on the Laplace evidence; 4 SE because the pointwise differences of nested
models are skewed and a 2-SE rule names too eagerly). Among decisive candidates the largest
log BF is named. The loop stops when nothing is decisive or after ``max_steps``.
"""
from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path

import numpy as np

from rjfit.data.noise import DEFAULT_FLOOR
from rjfit.diagnose import report as figures
from rjfit.diagnose.context import build_context
from rjfit.diagnose.effects import ALL_EFFECTS, get_effect
from rjfit.diagnose.gap import gap, gap_breakdown, noise_variance
from rjfit.diagnose.psis import good_k_threshold
from rjfit.diagnose.refit import posterior_mean_prediction, psis_loo, refit, template_columns
from rjfit.io import publish, staging_dir, write_json_atomic
from rjfit.plotting import zoom_to_object

__all__ = ["diagnose", "LOG_BF_THRESHOLD", "LOO_SE_FACTOR", "GAP_DEFINITION", "DECISION_RULE"]

LOG_BF_THRESHOLD = math.log(100.0)
LOO_SE_FACTOR = 4.0
# An effect parameter whose MAP lies more than this many prior sd from its prior's centre (in
# the unconstrained coordinate: prior probability 0.27 % of being as far) is reported as a
# prior-data conflict: the data pull it where its physics is implausible, so the effect may
# be standing in for another with a similar signature.
PRIOR_CONFLICT_SD = 3.0
GAP_DEFINITION = ("gap = mean(r^2) / sigma_hat^2 - 1 with r = (y - E[mu]) / s (posterior mean of the model's prediction; "
                  "s the noise model's known scale, 1 for constant noise) "
                  "and sigma_hat^2 the noise variance from second differences of the final model's residual images "
                  "(robust MAD; one value for every gap of the report); ~0 when the model explains the data up to "
                  "noise")
#: names of the figures diagnose writes (``step{n}_{effect}_*.png``, ``signatures_step{n}.png``, the
#: Mitsuba simulation's): those of a previous diagnosis in the folder are removed by the next one
FIGURE_PATTERNS = ("step*_residuals.png", "step*_per_light.png", "step*_posteriors.png", "signatures_step*.png",
                   "mitsuba_residuals.png", "ppc_p_values.png", "mitsuba_per_image_*.png")
DECISION_RULE = (f"decisive when log Bayes factor (Laplace evidence) > ln 100 = {LOG_BF_THRESHOLD:.2f} and "
                 f"delta ELPD (PSIS-LOO) > {LOO_SE_FACTOR:g} SE; the decisive candidate with the largest log BF is named")


def _residuals(ctx, fit):
    """``(y - E[mu]) / s_i``: the residuals of the posterior mean prediction in the units of the
    noise model (divided by its known scales; the plain residuals for 'constant' noise)."""
    return ctx.standardise(ctx.y - posterior_mean_prediction(fit))


def _loo_difference(candidate, current):
    """``(delta ELPD, its SE, max k-hat, fraction of observations with an unreliable k-hat)``.

    An observation is unreliable where either model's k-hat exceeds the threshold for the
    number of draws (:func:`good_k_threshold`, 0.5 for 100): there its importance weights
    have too heavy a tail for the estimate to converge."""
    loo_c, loo_0 = psis_loo(candidate), psis_loo(current)
    diff = loo_c.pointwise - loo_0.pointwise
    khat = np.maximum(loo_c.pareto_k, loo_0.pareto_k)
    bad = float(np.mean(khat > good_k_threshold(min(len(candidate.draws), len(current.draws)))))
    return float(diff.sum()), float(math.sqrt(diff.size * np.var(diff))), float(khat.max()), bad


def _moved(before, after, ctx):
    """Parameters whose MAP moved by more than 2 posterior sd (after), with draws for figures."""
    b_values = dict(zip(before.names, before.constrained()))
    b_draws = {n: d for n, d in zip(before.names, np.array([before.constrained(z) for z in before.draws]).T)}
    a_draws_all = np.array([after.constrained(z) for z in after.draws]).T
    moved, panels = [], []
    for name, value, draws in zip(after.names, after.constrained(), a_draws_all):
        sd = float(draws.std())
        if name not in b_values:
            panels.append((name, None, draws))
            continue
        if abs(value - b_values[name]) > 2.0 * max(sd, 1e-300):
            moved.append({"name": name, "before": float(b_values[name]), "after": float(value), "sd_after": sd})
            panels.append((name, b_draws[name], draws))
    return moved, panels[:8]


def _candidate_bar(progress, total, step):
    if not progress or total == 0:
        return None
    from tqdm import tqdm
    return tqdm(total=total, desc=f"step {step + 1}", unit="refit", leave=False, disable=None)


def _bar_say(bar, say, line):
    """A candidate's line above the bar (the bar is redrawn below it), then one step of the bar."""
    if bar is None or bar.disable:
        say(line)
    else:
        bar.clear()
        say(line)
        bar.refresh()
    if bar is not None:
        bar.update(1)


def diagnose(dataset, labels, out_dir, *, candidates=ALL_EFFECTS, seed=0, max_steps=3,
             threshold=LOG_BF_THRESHOLD, loo_se_factor=LOO_SE_FACTOR, simulate=None, n_sim_draws=3,
             channel="mean", make_figures=True, progress=False, provenance=None, likelihood_power=1.0,
             noise="constant", noise_floor=DEFAULT_FLOOR, jobs=None):
    """Run the criticism workflow on a data set with a FIXED segmentation.

    Parameters
    ----------
    dataset : path or Dataset
    labels : ndarray (H, W)
        Region index per pixel (-1 off the object): the fit's MAP labels, or truth labels.
    out_dir : path
        Receives ``diagnosis.json``, ``diagnosis.md`` and the figures (created). They are written
        into a staging folder inside it and published together, ``diagnosis.json`` last
        (:func:`rjfit.io.publish`): the previous diagnosis's files, figures included, are
        removed first, and an interrupted diagnosis leaves the previous one whole.
    candidates : sequence of Effect or names
    simulate : bool or None
        Posterior predictive rendering with Mitsuba of the plain and final models (default:
        when the data set has a mesh).
    provenance : dict, optional
        Entries recorded in ``diagnosis.json`` as they are (``fit_dir``, ``fit_id`` of the
        fit diagnosed), so a report can tell a diagnosis of another fit.
    likelihood_power : float in (0, 1]
        The power zeta of a coarsened fit (``rjfit fit --likelihood-power``): the refits raise
        the likelihood to it, so the Bayes factors weigh the data as that fit did (the
        plain likelihood of a million observations whose misfit neighbours share would make
        nearly any candidate "decisive"). 1: the plain likelihood.
    noise, noise_floor : str, float
        The fit's noise model and floor (``rjfit fit --noise``, :mod:`rjfit.data.noise`): the
        refits weigh each observation by its known scale, as the sampler did.
    jobs : int, optional
        Candidates refitted at once, on threads (default: the cores this process may use).
        The result does not depend on it; the memory does: each refit in flight holds arrays
        of the size of the observations and its LOO draws (on the 1.4 million observations of
        the DiLiGenT ball the peak rose from 8.0 to 8.8 GB with a second job, measured).

    Returns
    -------
    dict
        The contents of ``diagnosis.json``.

    Raises
    ------
    ValueError
        If ``max_steps`` is not an integer >= 0, ``jobs`` not an integer >= 1, a candidate name
        is unknown, ``labels`` does not have the images' shape, ``likelihood_power`` is not in
        (0, 1], ``channel`` is not one of :data:`rjfit.data.formats.CHANNELS`, or the noise model
        is unknown or its floor not positive.
    FileNotFoundError, DatasetError
        When ``dataset`` is a path: as :func:`rjfit.render.datasets.load_dataset`.
    """
    if isinstance(max_steps, bool) or not isinstance(max_steps, (int, np.integer)) or max_steps < 0:
        raise ValueError(f"max_steps must be an integer >= 0 (0: measure the plain model's gap only), got {max_steps!r}")
    if jobs is None:
        from rjfit.sampler.runner import available_cores

        jobs = available_cores()
    if isinstance(jobs, bool) or not isinstance(jobs, (int, np.integer)) or jobs < 1:
        raise ValueError(f"jobs (candidates refitted at once) must be an integer >= 1, got {jobs!r}")
    out_dir = Path(out_dir)
    with staging_dir(out_dir) as staging:
        result = _search(dataset, labels, staging, candidates=candidates, seed=seed, max_steps=max_steps,
                         threshold=threshold, loo_se_factor=loo_se_factor, simulate=simulate, n_sim_draws=n_sim_draws,
                         channel=channel, make_figures=make_figures, progress=progress, provenance=provenance,
                         likelihood_power=likelihood_power, noise=noise, noise_floor=noise_floor, jobs=int(jobs))
        write_json_atomic(staging / "diagnosis.json", result)
        (staging / "diagnosis.md").write_text(figures.markdown(result), encoding="utf-8")
        publish(staging, out_dir, manifest="diagnosis.json", remove=_previous_results(out_dir))
    return result


def _previous_results(out_dir) -> list[str]:
    """The files of the diagnosis in ``out_dir`` (if any), which a new one replaces: ``diagnosis.md``,
    the figures its ``diagnosis.json`` names, and any file named as diagnose names its figures."""
    out_dir = Path(out_dir)
    names = {"diagnosis.md"}
    names |= {path.name for pattern in FIGURE_PATTERNS for path in out_dir.glob(pattern) if path.is_file()}
    try:
        previous = json.loads((out_dir / "diagnosis.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        # none there (the first diagnosis) or unreadable: the patterns above still find every
        # figure diagnose writes; only names it no longer uses would stay
        previous = None
    if isinstance(previous, dict):
        names |= {name for name in figures.listed_figures(previous) if Path(name).name == name}
    return sorted(names)


def _try_candidate(ctx, current, effect, residuals, sigma2_hat, seed, threshold):
    """Refit ``current`` plus ``effect`` and score it: ``(candidate, its residuals, (signature score,
    signature map), (delta ELPD, SE, max k-hat) or None)``; LOO only where the log Bayes factor
    exceeds ``threshold`` (below it the candidate cannot be decisive). Runs on a worker thread:
    it reads ``ctx`` and ``current`` and writes nothing they share (its features are cached
    before, see :func:`_try_candidates`)."""
    candidate = refit(ctx, tuple(current.effects) + (effect,), start=current, seed=seed)
    columns = ctx.standardise(template_columns(current, ctx, effect))
    signature = effect.signature(ctx, residuals, sigma2_hat, columns)
    loo = _loo_difference(candidate, current) if candidate.log_evidence - current.log_evidence > threshold else None
    return candidate, _residuals(ctx, candidate), signature, loo


def _try_candidates(ctx, current, effects, residuals, sigma2_hat, *, seed, threshold, jobs, report):
    """:func:`_try_candidate` for each of ``effects``, ``jobs`` at a time on threads: effect name ->
    its outcome, or the exception it raised (raised instead with ``RJFIT_DEBUG`` set).

    Threads, not processes: a refit's time goes to NumPy passes over every observation, which
    release the GIL (two threads refit the ball's candidates 1.5 to 1.8 times faster on 2
    cores, measured), and a thread shares the context's arrays and cached features instead of
    copying them. BLAS runs on one thread meanwhile, for every ``jobs``, so the outcomes do not
    depend on it (BLAS's own threads gave these small products nothing, measured). Mitsuba
    features (interreflection, cast shadows) are rendered first, here, one effect at a time:
    a render uses every core itself and drjit's state is per thread. ``report(effect, outcome)``
    is called on this thread as each candidate finishes.
    """
    from concurrent.futures import ThreadPoolExecutor, as_completed

    from threadpoolctl import threadpool_limits

    debug = bool(os.environ.get("RJFIT_DEBUG"))     # a programming error then shows its traceback
    outcomes = {}
    ready = []
    for effect in effects:
        try:
            if effect.needs_mitsuba:
                effect.prepare(ctx)        # caches its rendered feature in ctx (ctx.feature)
            ready.append(effect)
        except Exception as error:
            if debug:
                raise
            outcomes[effect.name] = error
            report(effect, error)
    if not ready:
        return outcomes
    with threadpool_limits(1), ThreadPoolExecutor(max_workers=max(1, min(jobs, len(ready)))) as pool:
        futures = {pool.submit(_try_candidate, ctx, current, effect, residuals, sigma2_hat, seed, threshold): effect
                   for effect in ready}
        for future in as_completed(futures):
            effect = futures[future]
            try:
                outcomes[effect.name] = future.result()
            except Exception as error:
                if debug:
                    raise
                outcomes[effect.name] = error
            report(effect, outcomes[effect.name])
    return outcomes


def _towards_null(param, z) -> bool:
    """Whether ``z`` lies between the prior's centre and the parameter's null (where the effect
    vanishes): a parameter pulled there says the effect is absent, not that it stands in for another."""
    if param.null is None:          # no value of it alone removes the effect: no side to tell
        return False
    with np.errstate(divide="ignore"):
        z_null = float(param.prior.to_unconstrained(param.null))      # +-inf at a bound
    return (z - param.prior.loc) * (z_null - param.prior.loc) > 0 and abs(z - param.prior.loc) <= abs(z_null - param.prior.loc)


def _prior_conflicts(fit, effect_name):
    """The parameters of ``effect_name`` in ``fit`` whose MAP lies beyond ``PRIOR_CONFLICT_SD``
    prior sd of the prior's centre, away from the effect's null: ``[{"param", "map",
    "prior_sd_from_centre"}]``."""
    problem = fit._cache["problem"]
    conflicts, offset = [], 4 * problem.ctx.n_regions
    for effect, params in zip(problem.effects, problem.effect_params):
        for k, param in enumerate(params if effect.name == effect_name else ()):
            z = float(fit.z[offset + k])
            distance = abs(z - param.prior.loc) / param.prior.scale
            if distance > PRIOR_CONFLICT_SD and not _towards_null(param, z):
                conflicts.append({"param": f"{effect.name}.{param.name}", "map": float(param.prior.to_constrained(z)),
                                  "prior_sd_from_centre": distance})
        offset += len(params)
    return conflicts


def _candidate_row(step, effect, outcome, current, threshold, loo_se_factor):
    """A candidate's row of ``diagnosis.json``: its error, or its evidence, signature score,
    parameters and whether it is decisive."""
    row = {"step": step, "effect": effect.name, "kind": effect.kind}
    if isinstance(outcome, Exception):
        # A failing candidate (a refit that does not converge, a Mitsuba feature that cannot
        # be rendered) is reported in its row and the search goes on
        row["error"] = f"{type(outcome).__name__}: {outcome}"
        return row
    candidate, _, (score, _), loo = outcome
    row.update(log_evidence=candidate.log_evidence, log_bayes_factor=candidate.log_evidence - current.log_evidence,
               n_params_added=candidate.n_params - current.n_params, signature_score=score,
               effect_params={k: v for k, v in candidate.summary().items() if k.startswith(effect.name + ".")},
               hessian=candidate.hessian_kind, seconds=candidate.seconds)
    conflicts = _prior_conflicts(candidate, effect.name)
    if conflicts:
        row["prior_conflict"] = conflicts
    if loo is not None:
        row.update(delta_elpd_loo=loo[0], delta_elpd_loo_se=loo[1], max_khat=loo[2], khat_unreliable_fraction=loo[3])
    else:
        bound = "ln 100" if math.isclose(threshold, LOG_BF_THRESHOLD) else f"{threshold:.4g}"
        row["loo_skipped"] = f"log BF <= {bound}, cannot be decisive"
    row["decisive"] = bool(row["log_bayes_factor"] > threshold and row.get("delta_elpd_loo", -np.inf)
                           > loo_se_factor * row.get("delta_elpd_loo_se", np.inf))
    return row


def _search(dataset, labels, figure_dir, *, candidates, seed, max_steps, threshold, loo_se_factor, simulate,
            n_sim_draws, channel, make_figures, progress, provenance, likelihood_power, noise, noise_floor, jobs):
    """The search of :func:`diagnose`: its result, with the figures written into ``figure_dir``."""
    started = time.perf_counter()
    def say(*args, **kwargs):
        if progress:
            print(*args, **kwargs, flush=True)      # flushed: a long search is followed as it goes
    candidates = [get_effect(c) for c in candidates]
    ctx = build_context(dataset, labels, channel=channel, seed=seed, likelihood_power=likelihood_power, noise=noise,
                        noise_floor=noise_floor)
    weighed = "" if ctx.likelihood_power == 1.0 else f", the likelihood to the fit's power {ctx.likelihood_power:.4g}"
    weighed += "" if noise == "constant" else f", '{noise}' noise ({ctx.noise['formula']})"
    say(f"diagnosing {ctx.y.size:,} observations in {ctx.n_regions} regions{weighed}: the plain model's refit, then "
        f"one refit per candidate effect and step (each a few seconds to minutes, growing with the observations)")
    plain = refit(ctx, (), seed=seed)
    ctx.features["fit_region_params"] = plain.region_params()
    # The noise estimate of the plain model's residuals only scores the candidates' signatures
    # during the search; every gap reported (printed, in diagnosis.json and diagnosis.md) uses
    # the final model's estimate, computed once the search is over (see GAP_DEFINITION).
    sigma2_hat = noise_variance(ctx, _residuals(ctx, plain))
    say(f"plain model: log Z {plain.log_evidence:.1f} (gaps follow at the end, with the final noise estimate)")
    skipped = {}
    usable = []
    for effect in candidates:
        ok, why = effect.available(ctx)
        (usable.append(effect) if ok else skipped.__setitem__(effect.name, why))
    for name, why in skipped.items():
        say(f"  {name:18s} skipped: {why}")
    if max_steps == 0:
        stopped = "search skipped: max_steps is 0, so no candidate effect was tried; only the plain model's gap is measured"
    elif not usable:
        stopped = "search skipped: no candidate effect can be tried on this data set (see the skipped candidates)"
    else:
        stopped = (f"stopped after {max_steps} step{'s' if max_steps > 1 else ''} (max_steps): "
                   f"further missing effects were not searched for")
    if max_steps == 0 or not usable:
        say(stopped)
    current = plain
    steps, rows = [], []
    stored = {}            # residual vectors (-> gaps once the noise estimate is final), signatures
    step_residuals = []
    for step in range(max_steps if usable else 0):
        residuals = _residuals(ctx, current)
        step_residuals.append(residuals)
        fits = {}
        present_kinds = {e.kind for e in current.effects}
        to_try = [e for e in usable if e not in current.effects and e.kind not in present_kinds]
        # one refit per candidate can take minutes on a large data set: a bar (stderr, off in
        # logs) says how many are left, and a line per candidate as it finishes
        bar = _candidate_bar(progress, len(to_try), step)
        finished = {}

        def record(effect, outcome):       # as each candidate finishes (on this thread)
            row = finished[effect.name] = _candidate_row(step, effect, outcome, current, threshold, loo_se_factor)
            if "error" not in row:
                candidate, candidate_residuals, (score, signature_map), _ = outcome
                fits[effect.name] = candidate
                stored[("signature", step, effect.name)] = (score, signature_map)
                stored[("candidate", step, effect.name)] = candidate_residuals
            _bar_say(bar, say, figures.candidate_line(row))

        _try_candidates(ctx, current, to_try, residuals, sigma2_hat, seed=seed, threshold=threshold, jobs=jobs,
                        report=record)
        step_rows = [finished[effect.name] for effect in to_try]     # in the candidates' order
        if bar is not None:
            bar.close()
        rows += step_rows
        decisive = [r for r in step_rows if r.get("decisive")]
        if not decisive:
            stopped = (f"no candidate effect was decisive at step {step + 1}" if step_rows
                       else f"no candidate effect left to try at step {step + 1}")
            say(stopped)
            break
        best = max(decisive, key=lambda r: r["log_bayes_factor"])
        new = fits[best["effect"]]
        if best["effect"] == "interreflection":
            # The indirect feature came from the model without it; render it again from the
            # refitted materials (whose albedos no longer absorb the indirect light) and refit.
            ctx.features["fit_region_params"] = new.region_params()
            new = refit(ctx, new.effects, start=new, seed=seed)
        after_residuals = _residuals(ctx, new)
        moved, panels = _moved(current, new, ctx)
        record = {"effect": best["effect"], "kind": best["kind"],
                  "evidence": {k: best.get(k) for k in ("log_bayes_factor", "delta_elpd_loo", "delta_elpd_loo_se",
                                                         "max_khat", "khat_unreliable_fraction", "signature_score")},
                  "prior_conflict": _prior_conflicts(new, best["effect"]),
                  "effect_params": {k: v for k, v in new.summary().items() if k.startswith(best["effect"] + ".")},
                  "moved_parameters": moved, "figures": {}, "_residuals": (residuals, after_residuals),
                  "_panels": panels}
        say(f"named {best['effect']} at step {step + 1} (log BF {best['log_bayes_factor']:.1f})"
            + "".join(f"; {figures.prior_conflict_text(c)}" for c in record["prior_conflict"]))
        steps.append(record)
        current = new
    else:
        if max_steps and usable:
            say(stopped)
    # The noise estimate, final: second differences of the FINAL model's residuals (the best
    # model leaves the smoothest misfit, so its estimate is the least inflated); every gap of
    # the report uses it.
    final_residuals = _residuals(ctx, current)
    sigma2_plain_estimate = sigma2_hat
    sigma2_hat = noise_variance(ctx, final_residuals)
    gap_plain = gap(_residuals(ctx, plain), sigma2_hat)
    for row in rows:
        key = ("candidate", row["step"], row["effect"])
        if key in stored:
            row["gap_with_effect"] = gap(stored[key], sigma2_hat)
    for index, record in enumerate(steps):
        before, after = record.pop("_residuals")
        panels = record.pop("_panels")
        gap_before, gap_after = gap(before, sigma2_hat), gap(after, sigma2_hat)
        before_b, after_b = gap_breakdown(ctx, before, sigma2_hat), gap_breakdown(ctx, after, sigma2_hat)
        record.update(gap_before=gap_before, gap_after=gap_after,
                      gap_ratio=gap_after / gap_before if gap_before > 0 else None,
                      per_light_gap_before=before_b["per_light"], per_light_gap_after=after_b["per_light"],
                      per_region_gap_before=before_b["per_region"], per_region_gap_after=after_b["per_region"])
        if make_figures:
            tag = f"step{index + 1}_{record['effect']}"
            record["figures"]["residuals"] = figures.residual_pair_figure(
                figure_dir / f"{tag}_residuals.png", ctx.per_pixel_mean(before) / math.sqrt(sigma2_hat),
                ctx.per_pixel_mean(after) / math.sqrt(sigma2_hat),
                f"before (gap {gap_before:.3g})", f"after + {record['effect']} (gap {gap_after:.3g})")
            record["figures"]["per_light"] = figures.per_light_figure(
                figure_dir / f"{tag}_per_light.png", before_b["per_light"], after_b["per_light"],
                f"gap per light, step {index + 1}: + {record['effect']}")
            if panels:
                record["figures"]["posteriors"] = figures.posterior_figure(figure_dir / f"{tag}_posteriors.png",
                                                                          panels)
    signature_figures = []
    if make_figures:
        for step, residuals in enumerate(step_residuals):
            maps = sorted(((v[0], name, v[1]) for (kind, st, name), v in stored.items()
                           if kind == "signature" and st == step), key=lambda t: -t[0])[:5]
            if maps:
                signature_figures.append(figures.signature_figure(
                    figure_dir / f"signatures_step{step + 1}.png", ctx.per_pixel_mean(residuals) / math.sqrt(sigma2_hat),
                    [(f"{name}\nscore {score:.2f}", image) for score, name, image in maps],
                    f"step {step + 1}: residual and what each missing effect would leave (fitted signature)"))
    result = {
        **(provenance or {}),
        "dataset": str(getattr(ctx.dataset, "path", dataset)),
        "channel": channel,
        "signature_figures": signature_figures,
        "named_effects": [s["effect"] for s in steps],
        "steps": steps,
        "candidates": rows,
        "skipped": skipped,
        "search": {"max_steps": int(max_steps), "stopped": stopped},
        "gap_definition": GAP_DEFINITION,
        "decision_rule": DECISION_RULE,
        "thresholds": {"log_bayes_factor": threshold, "loo_se_factor": loo_se_factor,
                       "prior_conflict_sd": PRIOR_CONFLICT_SD},
        "likelihood_power": ctx.likelihood_power,
        "noise": ctx.noise,
        "noise_variance_estimate": sigma2_hat,
        "noise_variance_estimate_plain_residuals": sigma2_plain_estimate,
        "gap_plain": gap_plain,
        "gap_final": gap(final_residuals, sigma2_hat),
        "per_region_gap": {"plain": gap_breakdown(ctx, _residuals(ctx, plain), sigma2_hat)["per_region"],
                           "final": gap_breakdown(ctx, final_residuals, sigma2_hat)["per_region"]},
        "final_model": {"effects": [e.name for e in current.effects], "log_evidence": current.log_evidence,
                        "parameters": current.summary(), "laplace_hessian": current.hessian_kind},
        "plain_model": {"log_evidence": plain.log_evidence, "parameters": plain.summary()},
        "n_observations": ctx.n_obs, "n_regions": ctx.n_regions, "seed": seed,
        "method": {"refit": "MAP (least squares + sigma^2 updates + Newton) and Laplace approximation with a "
                            "finite-difference Hessian in unconstrained coordinates",
                   "evidence": "Laplace log marginal likelihood; PSIS-LOO (ArviZ's estimator, vectorised) on 100 Laplace draws as second opinion",
                   "segmentation": "fixed (given labels)"},
    }
    if simulate is None:
        simulate = ctx.has_mesh
    if simulate and ctx.has_mesh:
        from rjfit.diagnose.simulate import simulate_fit

        sim = {"plain": simulate_fit(ctx, plain, sigma2_hat, n_draws=n_sim_draws, seed=seed)}
        if current is not plain:
            sim["final"] = simulate_fit(ctx, current, sigma2_hat, n_draws=n_sim_draws, seed=seed)
        sim_figs = {}
        if make_figures:
            final = sim.get("final", sim["plain"])
            sim_figs["mitsuba_residuals"] = figures.residual_pair_figure(
                figure_dir / "mitsuba_residuals.png", sim["plain"]["mean_z_map"], final["mean_z_map"], f"Mitsuba, plain (gap {sim['plain']['gap']:.3g})",
                f"Mitsuba, final (gap {final['gap']:.3g})", label="mean standardised residual over lights")
            sim_figs["ppc"] = figures.map_figure(figure_dir / "ppc_p_values.png", final["ppc_p_values"],
                                                 "posterior predictive p-value per pixel (final model)", vmin=0, vmax=1)
            for label, s in sim.items():
                sim_figs[f"per_image_{label}"] = _per_image_figure(figure_dir / f"mitsuba_per_image_{label}.png",
                                                                   s["standardised"], f"{label}: standardised residual per image")
        result["simulation"] = {label: {k: v for k, v in s.items() if not isinstance(v, np.ndarray)}
                                for label, s in sim.items()}
        result["simulation"]["figures"] = sim_figs
    elif simulate:
        result["simulation_skipped"] = "no mesh: Mitsuba cannot render this data set's object"
    result["seconds"] = round(time.perf_counter() - started, 2)
    for line in figures.gap_lines(result):
        say(line)
    return result


def _per_image_figure(path, stack, title):
    plt = figures._plt()
    L = stack.shape[0]
    cols = min(L, 5)
    rows = int(math.ceil(L / cols))
    limit = max(float(np.nanpercentile(np.abs(stack), 99)), 1e-6)
    figure, axes = plt.subplots(rows, cols, figsize=(2.0 * cols, 2.0 * rows + 0.4), squeeze=False)
    for i, axis in enumerate(axes.ravel()):
        axis.axis("off")
        if i < L:
            axis.imshow(stack[i], cmap="RdBu_r", vmin=-limit, vmax=limit)
            zoom_to_object(axis, np.isfinite(stack).any(axis=0))
            axis.set_title(f"light {i}", fontsize=7)
    figure.suptitle(title + f" (colour range +-{limit:.2g})", fontsize=9)
    return figures.save_figure(figure, path)
