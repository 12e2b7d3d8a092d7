"""The criticism workflow: fit the plain model, measure the gap, try every candidate effect,
name one only when the evidence is decisive, add it, refit, and repeat.

The decision rule is stated once, in :mod:`rjfit.diagnose.candidates` (:data:`DECISION_RULE`):
log Bayes factor > ln 100 and delta ELPD (PSIS-LOO) > 4 SE; among decisive candidates the
largest log BF is named. The loop stops when nothing is decisive or after ``max_steps``.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rjfit.data.noise import DEFAULT_FLOOR
from rjfit.diagnose import document, figures
from rjfit.diagnose.candidates import (
    DECISION_RULE,
    LOG_BF_THRESHOLD,
    LOO_SE_FACTOR,
    PRIOR_CONFLICT_SD,
    candidate_row,
    converge_base,
    fit_prior_conflicts,
    try_candidates,
)
from rjfit.diagnose.context import build_context
from rjfit.diagnose.figures import FIGURE_PATTERNS
from rjfit.effects import ALL_EFFECTS, get_effect
from rjfit.diagnose.gap import gap, gap_breakdown, noise_variance
from rjfit.diagnose.misfit import UNEXPLAINED_GAP, describe_misfit
from rjfit.diagnose.naming import NAMING_RULE, judge_candidates
from rjfit.diagnose.pairs import step_trials
from rjfit.diagnose.refit import moved_parameters, refit, standardised_residuals
from rjfit.diagnose.revisit import REVISION_RULE, revisit
from rjfit.diagnose.simulate import simulation_record
from rjfit.io import publish, staging_dir, write_json_atomic
from rjfit.progress import progress

__all__ = ["diagnose", "SearchSettings", "LOG_BF_THRESHOLD", "LOO_SE_FACTOR", "PRIOR_CONFLICT_SD", "GAP_DEFINITION",
           "DECISION_RULE", "FIGURE_PATTERNS"]

GAP_DEFINITION = ("gap = mean(r^2) / sigma_hat^2 - 1 with r = (y - E[mu]) / s (posterior mean of the model's prediction; "
                  "s the noise model's known scale, 1 for constant noise) "
                  "and sigma_hat^2 the noise variance from second differences of the final model's residual images "
                  "(robust MAD; one value for every gap of the report); ~0 when the model explains the data up to "
                  "noise")


def _check_count(value, name, minimum, meaning):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}{meaning}, got {value!r}")


@dataclass(frozen=True)
class SearchSettings:
    """The options of one diagnosis' search, as :func:`diagnose` takes them (it documents each);
    ``candidates`` are :class:`rjfit.effects.Effect` objects, ``jobs`` an int >= 1."""

    candidates: tuple
    seed: int = 0
    max_steps: int = 3
    threshold: float = LOG_BF_THRESHOLD
    loo_se_factor: float = LOO_SE_FACTOR
    simulate: bool | None = None
    n_sim_draws: int = 3
    channel: str = "mean"
    make_figures: bool = True
    progress: bool = False
    provenance: dict | None = None
    likelihood_power: float = 1.0
    noise: str = "constant"
    noise_floor: float = DEFAULT_FLOOR
    jobs: int = 1
    base_effects: tuple = ()
    normals: np.ndarray | None = None

    def __post_init__(self):
        """Raises ValueError if ``max_steps`` is not an integer >= 0 or ``jobs`` not an integer >= 1."""
        _check_count(self.max_steps, "max_steps", 0, " (0: measure the plain model's gap only)")
        _check_count(self.jobs, "jobs (candidates refitted at once)", 1, "")
        object.__setattr__(self, "jobs", int(self.jobs))

    def simulates(self, ctx) -> bool:
        """Whether Mitsuba simulates on this search of ``ctx`` (``simulate`` None: when the data set has a mesh)."""
        return bool(ctx.has_mesh and (self.simulate is None or self.simulate))

    def say(self, *args, **kwargs):
        """Print a line when ``progress`` is on (flushed: a long search is followed as it goes)."""
        if self.progress:
            print(*args, **kwargs, flush=True)


@dataclass
class _SearchTrace:
    """What the search found so far: the current model and why the search stopped (or will)."""

    current: object                                       # the current model's FitResult
    stopped: str
    plain: object = None                                  # the plain model's refit (replaced if refitted better)
    base_refits: list = field(default_factory=list)       # each refit of the current model from a candidate's point
    steps: list = field(default_factory=list)             # a record per named effect (diagnosis.json "steps")
    named: list = field(default_factory=list)             # per named effect: (residuals before, after, posterior panels)
    rows: list = field(default_factory=list)              # a row per candidate and step (diagnosis.json "candidates")
    searched: list = field(default_factory=list)          # per step searched: the current model's residuals
    signatures: dict = field(default_factory=dict)        # (step, effect name) -> (signature score, map)
    candidate_residuals: dict = field(default_factory=dict)   # (step, effect name) -> the candidate's residuals
    revisions: list = field(default_factory=list)         # each earlier effect swapped or dropped (rjfit.diagnose.revisit)
    pairs: list = field(default_factory=list)             # a row per pair of candidates tried (rjfit.diagnose.pairs)
    trials: list = field(default_factory=list)            # what a refit of the regions may try, best first


def _candidate_bar(show, total, step):
    """The candidates' progress (a bar on a terminal, plain lines in a log), or None."""
    if not show or total == 0:
        return None
    return progress(total, f"step {step + 1}", "refit", leave=False)


def _bar_say(bar, say, line):
    """A candidate's line (above the bar on a terminal), then one step of the progress."""
    if bar is None:
        say(line)
        return
    bar.write(line, say)
    bar.update(1)


def diagnose(dataset, labels, out_dir, *, candidates=ALL_EFFECTS, seed=0, max_steps=3,
             threshold=LOG_BF_THRESHOLD, loo_se_factor=LOO_SE_FACTOR, simulate=None, n_sim_draws=3,
             channel="mean", make_figures=True, progress=False, provenance=None, likelihood_power=1.0,
             noise="constant", noise_floor=DEFAULT_FLOOR, jobs=None, base_effects=(), normals=None):
    """Run the criticism workflow on a data set with a FIXED segmentation.

    Parameters
    ----------
    dataset : path or Dataset
    labels : ndarray (H, W)
        Region index per pixel (-1 off the object): the fit's MAP labels, or truth labels.
    out_dir : path
        Receives ``diagnosis.json``, ``diagnosis.md`` and the figures (created). They are written into a staging
        folder inside it and published together, ``diagnosis.json`` last (:func:`rjfit.io.publish`): the previous
        diagnosis's files, figures included, are removed first, and an interrupted diagnosis leaves it whole.
    candidates : sequence of Effect or names
    seed : int
        Seed of the refits' Laplace draws, the Monte Carlo features and the simulations.
    max_steps : int >= 0
        Most effects to name (0: measure the plain model's gap only).
    threshold, loo_se_factor : float
        The decision rule's log Bayes factor and LOO bounds (:mod:`rjfit.diagnose.candidates`).
    simulate : bool or None
        Posterior predictive rendering with Mitsuba of the plain and final models (default:
        when the data set has a mesh).
    n_sim_draws : int
        Posterior draws rendered by that simulation.
    channel : str
        The colour channel diagnosed (the fit's).
    make_figures, progress : bool
        Write the figures; print the search as it goes.
    provenance : dict, optional
        Entries recorded in ``diagnosis.json`` as they are (``fit_dir``, ``fit_id`` of the
        fit diagnosed), so a report can tell a diagnosis of another fit.
    likelihood_power : float in (0, 1]
        The power zeta of a coarsened fit (``rjfit fit --likelihood-power``): the refits raise the likelihood to
        it, so the Bayes factors weigh the data as that fit did (the plain likelihood of a million observations
        whose misfit neighbours share would make nearly any candidate "decisive"). 1: the plain likelihood.
    noise, noise_floor : str, float
        The fit's noise model and floor (``rjfit fit --noise``, :mod:`rjfit.data.noise`): the
        refits weigh each observation by its known scale, as the sampler did.
    jobs : int, optional
        Candidates refitted at once, on threads (default: the cores this process may use). The result does not
        depend on it; the memory does: each refit in flight holds arrays of the size of the observations and its
        LOO draws (on the 1.4 million observations of the DiLiGenT ball the peak rose from 8.0 to 8.8 GB with a
        second job, measured).
    normals : ndarray (H, W, 3), optional
        A fit's posterior mean normals (``--normals sample``) for the refits, on its observations and noise scales
        (:func:`rjfit.diagnose.context.build_context`); ``diagnosis.json`` "normals" says which normals were used.

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
    from rjfit.sampler.runner import available_cores  # the sampler's processes: imported only here

    jobs = available_cores() if jobs is None else jobs
    settings = SearchSettings(candidates=tuple(get_effect(c) for c in candidates), seed=seed, max_steps=max_steps,
                              threshold=threshold, loo_se_factor=loo_se_factor, simulate=simulate, normals=normals,
                              n_sim_draws=n_sim_draws, channel=channel, make_figures=make_figures, progress=progress,
                              provenance=provenance, likelihood_power=likelihood_power, noise=noise, jobs=jobs,
                              noise_floor=noise_floor, base_effects=tuple(get_effect(e) for e in base_effects))
    out_dir = Path(out_dir)
    with staging_dir(out_dir) as staging:
        result = _search(dataset, labels, staging, settings)
        write_json_atomic(staging / "diagnosis.json", result)
        (staging / "diagnosis.md").write_text(document.markdown(result), encoding="utf-8")
        publish(staging, out_dir, manifest="diagnosis.json", remove=figures.previous_results(out_dir))
    return result


def _search(dataset, labels, figure_dir, settings):
    """The search of :func:`diagnose`: its result, with the figures written into ``figure_dir``."""
    started = time.perf_counter()
    ctx = build_context(dataset, labels, channel=settings.channel, seed=settings.seed,
                        likelihood_power=settings.likelihood_power, noise=settings.noise,
                        noise_floor=settings.noise_floor, normals=settings.normals)
    weighed = "" if ctx.likelihood_power == 1.0 else f", the likelihood to the fit's power {ctx.likelihood_power:.4g}"
    weighed += "" if settings.noise == "constant" else f", '{settings.noise}' noise ({ctx.noise['formula']})"
    weighed += "" if settings.normals is None else ", at the fit's posterior mean normals (it sampled them)"
    settings.say(f"diagnosing {ctx.y.size:,} observations in {ctx.n_regions} regions{weighed}: the plain model's "
                 f"refit, then one refit per candidate effect and step (each a few seconds to minutes, growing with "
                 f"the observations)")
    with_indirect = any(effect.renders_fitted_model for effect in settings.base_effects)
    # interreflection's feature: the plain model's indirect light, then (as in _name_effect) the refit's
    ctx.features["fit_region_params"] = refit(ctx, (), seed=settings.seed).region_params() if with_indirect else None
    plain = refit(ctx, settings.base_effects, seed=settings.seed)
    ctx.features["fit_region_params"] = plain.region_params()
    if with_indirect:
        plain = refit(ctx, plain.effects, start=plain, seed=settings.seed)
    # The noise estimate of the plain model's residuals only scores the candidates' signatures
    # during the search; every gap reported (printed, in diagnosis.json and diagnosis.md) uses
    # the final model's estimate, computed once the search is over (see GAP_DEFINITION).
    sigma2_plain = noise_variance(ctx, standardised_residuals(ctx, plain))
    settings.say(f"plain model: log Z {plain.log_evidence:.1f} (gaps follow at the end, with the final noise estimate)")
    usable, skipped = _usable_candidates(ctx, settings)
    trace = _run_steps(ctx, plain, usable, sigma2_plain, settings)
    plain = trace.plain          # refitted from a candidate's point where that found a better optimum
    # The noise estimate, final: second differences of the FINAL model's residuals (the best
    # model leaves the smoothest misfit, so its estimate is the least inflated); every gap of
    # the report uses it.
    sigma2_hat = noise_variance(ctx, standardised_residuals(ctx, trace.current))
    _add_gaps(ctx, trace, sigma2_hat, figure_dir if settings.make_figures else None)
    signature_figures = (figures.signature_figures(ctx, trace.searched, trace.signatures, sigma2_hat, figure_dir)
                         if settings.make_figures else [])
    result = _result(ctx, dataset, settings, plain, trace, skipped, signature_figures, sigma2_hat, sigma2_plain)
    if result["gap_final"] > UNEXPLAINED_GAP and not trace.stopped.startswith(("stopped after", "search skipped")):
        # nothing (more) qualified, yet the final model misses more than noise: say where,
        # instead of listing effects
        result["unexplained_misfit"] = describe_misfit(ctx, standardised_residuals(ctx, trace.current), sigma2_hat)
        settings.say(result["unexplained_misfit"]["text"])
    simulate = ctx.has_mesh if settings.simulate is None else settings.simulate
    if simulate and ctx.has_mesh:
        result["simulation"] = simulation_record(ctx, plain, trace.current, sigma2_hat, n_draws=settings.n_sim_draws,
                                                 seed=settings.seed, progress=settings.progress,
                                                 figure_dir=figure_dir if settings.make_figures else None)
    elif simulate:
        result["simulation_skipped"] = "no mesh: Mitsuba cannot render this data set's object"
    result["seconds"] = round(time.perf_counter() - started, 2)
    for line in document.gap_lines(result):
        settings.say(line)
    return result


def _usable_candidates(ctx, settings):
    """``(the candidates that can be tried on ctx, {name: why not} of the others)``, the others printed."""
    skipped = {}
    usable = []
    for effect in settings.candidates:
        ok, why = effect.available(ctx)
        if ok:
            usable.append(effect)
        else:
            skipped[effect.name] = why
    for name, why in skipped.items():
        settings.say(f"  {name:18s} skipped: {why}")
    return usable, skipped


def _run_steps(ctx, plain, usable, sigma2_plain, settings) -> _SearchTrace:
    """The step loop: at each step every usable candidate not yet in the model (nor of a kind in
    it) is refitted and scored; the decisive one with the largest log BF is named and becomes
    part of the current model, and the earlier effects are revisited
    (:func:`rjfit.diagnose.revisit.revisit`). The fit's own effects (``base_effects``) are
    revisited before the first step. Stops when none is decisive or after ``max_steps`` steps."""
    max_steps = settings.max_steps
    if max_steps == 0:
        stopped = "search skipped: max_steps is 0, so no candidate effect was tried; only the plain model's gap is measured"
    elif not usable:
        stopped = "search skipped: no candidate effect can be tried on this data set (see the skipped candidates)"
    else:
        stopped = (f"stopped after {max_steps} step{'s' if max_steps > 1 else ''} (max_steps): "
                   f"further missing effects were not searched for")
    trace = _SearchTrace(current=plain, stopped=stopped, plain=plain)
    if plain.effects and max_steps > 0 and usable:
        # the effects the fit sampled were chosen on another segmentation (rjfit refine's earlier
        # round): revisit them on this one before searching for further effects
        trace.current, trace.revisions = revisit(ctx, plain, None, usable, step=None, seed=settings.seed,
                                                 threshold=settings.threshold, say=settings.say)
    for step in range(max_steps if usable else 0):
        found = _search_step(ctx, step, usable, sigma2_plain, settings, trace)
        if found is None:
            break
        _name_effect(ctx, step, *found, settings, trace)
        if len(trace.current.effects) > 1:
            newest = next(e for e in trace.current.effects if e.name == found[0]["effect"])
            trace.current, revisions = revisit(ctx, trace.current, newest, usable, step=step, seed=settings.seed,
                                               threshold=settings.threshold, say=settings.say)
            trace.revisions += revisions
    settings.say(trace.stopped)
    return trace


#: most times one step refits the current model from a candidate's point and tries the candidates again
BASE_REFITS = 2


def _search_step(ctx, step, usable, sigma2_plain, settings, trace):
    """One step: refit and score the candidates (rows added to ``trace``). Returns ``(the best
    decisive row, its refit, the current model's residuals)``, or None (``trace.stopped`` says why).

    Where a candidate's point shows that the current model was not at its optimum
    (:func:`rjfit.diagnose.candidates.converge_base`), the current model is replaced by its refit
    from there and the candidates are tried again (at most :data:`BASE_REFITS` times), so that
    each log Bayes factor measures its candidate, not the current refit's shortfall."""
    present_kinds = {e.kind for e in trace.current.effects}
    to_try = [e for e in usable if e not in trace.current.effects and e.kind not in present_kinds]
    for attempt in range(BASE_REFITS + 1):
        tried = _try_step(ctx, step, trace.current, to_try, sigma2_plain, settings)
        better = (converge_base(ctx, trace.current, list(tried["fits"].values()), seed=settings.seed)
                  if attempt < BASE_REFITS else None)
        if better is None:
            break
        gain = trace.current.objective.f(trace.current.z) - better.objective.f(better.z)
        settings.say(f"  the current model was not at its optimum (a refit from the best candidate's point gains "
                     f"{gain:.1f} in log posterior): refitted, and the candidates tried again")
        trace.base_refits.append({"step": step, "log_posterior_gain": gain})
        if trace.current is trace.plain:
            trace.plain = better
        trace.current = better
    residuals, step_rows = tried["residuals"], tried["rows"]
    trace.searched.append(residuals)
    trace.signatures.update(tried["signatures"])
    trace.candidate_residuals.update(tried["candidate_residuals"])
    trace.rows += step_rows
    decisive = [row for row in step_rows if row.get("decisive")]
    by_name = {name: value for (_, name), value in tried["candidate_residuals"].items()}
    qualified = judge_candidates(ctx, decisive, tried["fits"], by_name, trace.current, residuals, sigma2_plain,
                                 simulate=settings.simulates(ctx), n_sim_draws=settings.n_sim_draws,
                                 seed=settings.seed)
    for row in decisive:
        if not row["qualifies"]:
            settings.say(f"  {row['effect']:18s} decisive but not named: {row['why_not']}")
    if not qualified:
        trace.stopped = (f"no candidate effect qualified at step {step + 1}: "
                         + "; ".join(f"{row['effect']} {row['why_not']}" for row in decisive) if decisive else
                         f"no candidate effect was decisive at step {step + 1}" if step_rows
                         else f"no candidate effect left to try at step {step + 1}")
        pairs, trace.trials = step_trials(ctx, (step, trace.current, step_rows), (tried["fits"], by_name),
                                          residuals, sigma2_plain, settings)
        trace.pairs += pairs
        if trace.trials:
            settings.say(document.trial_offer_line(trace.trials[0]))
        return None
    best = max(qualified, key=lambda row: row["log_bayes_factor"])
    # a runner-up within the threshold is not told apart from the winner by the evidence: say so
    best["not_told_apart"] = [{"effect": row["effect"], "log_bayes_factor": row["log_bayes_factor"]}
                              for row in qualified if row is not best
                              and best["log_bayes_factor"] - row["log_bayes_factor"] <= settings.threshold]
    return best, tried["fits"][best["effect"]], residuals


def _try_step(ctx, step, current, to_try, sigma2_plain, settings) -> dict:
    """Refit and score ``to_try`` against ``current``: ``{"residuals" (current's), "rows" (in the
    candidates' order), "fits", "signatures", "candidate_residuals"}`` (the last three by effect)."""
    residuals = standardised_residuals(ctx, current)
    # one refit per candidate can take minutes on a large data set: progress on stderr (a bar,
    # or lines in a log) says how many are left, and a line per candidate as it finishes
    bar = _candidate_bar(settings.progress, len(to_try), step)
    tried = {"residuals": residuals, "fits": {}, "signatures": {}, "candidate_residuals": {}}
    finished_rows = {}

    def on_finished(effect, outcome):       # as each candidate finishes (on this thread)
        row = finished_rows[effect.name] = candidate_row(step, effect, outcome, current, settings.threshold,
                                                         settings.loo_se_factor)
        if "error" not in row:
            candidate, candidate_residuals, signature, _ = outcome
            tried["fits"][effect.name] = candidate
            tried["signatures"][step, effect.name] = signature
            tried["candidate_residuals"][step, effect.name] = candidate_residuals
        _bar_say(bar, settings.say, document.candidate_line(row))

    try_candidates(ctx, current, to_try, residuals, sigma2_plain, seed=settings.seed, threshold=settings.threshold,
                   jobs=settings.jobs, report=on_finished)
    if bar is not None:
        bar.close()
    tried["rows"] = [finished_rows[effect.name] for effect in to_try]     # in the candidates' order
    return tried


def _name_effect(ctx, step, best, new, residuals, settings, trace):
    """Name ``best``'s effect: its refit ``new`` becomes the current model, its step record is added."""
    if get_effect(best["effect"]).renders_fitted_model:
        # The indirect feature came from the model without it; render it again from the
        # refitted materials (whose albedos no longer absorb the indirect light) and refit.
        ctx.features["fit_region_params"] = new.region_params()
        new = refit(ctx, new.effects, start=new, seed=settings.seed)
    moved, panels = moved_parameters(trace.current, new)
    step_record = {"effect": best["effect"], "kind": best["kind"],
                   "evidence": {k: best.get(k) for k in ("log_bayes_factor", "delta_elpd_loo", "delta_elpd_loo_se",
                                                          "max_khat", "khat_unreliable_fraction", "signature_score")},
                   "prior_conflict": fit_prior_conflicts(new, best["effect"]),
                   "effect_params": {k: v for k, v in new.summary().items() if k.startswith(best["effect"] + ".")},
                   "moved_parameters": moved, "figures": {}}
    if best.get("not_told_apart"):
        step_record["not_told_apart"] = best["not_told_apart"]
        settings.say(f"  caveat: {document.not_told_apart_text(best['effect'], best['log_bayes_factor'], best['not_told_apart'])}")
    settings.say(f"named {best['effect']} at step {step + 1} (log BF {best['log_bayes_factor']:.1f})"
                 + "".join(f"; {document.prior_conflict_text(c)}" for c in step_record["prior_conflict"]))
    trace.steps.append(step_record)
    trace.named.append((residuals, standardised_residuals(ctx, new), panels))
    trace.current = new


def _add_gaps(ctx, trace, sigma2_hat, figure_dir):
    """Every candidate's and step's gap with the final noise estimate ``sigma2_hat`` (in place), and
    each step's figures where ``figure_dir`` is given."""
    for row in trace.rows:
        key = (row["step"], row["effect"])
        if key in trace.candidate_residuals:
            row["gap_with_effect"] = gap(trace.candidate_residuals[key], sigma2_hat)
    for index, (step_record, (before, after, panels)) in enumerate(zip(trace.steps, trace.named)):
        gap_before, gap_after = gap(before, sigma2_hat), gap(after, sigma2_hat)
        before_b, after_b = gap_breakdown(ctx, before, sigma2_hat), gap_breakdown(ctx, after, sigma2_hat)
        step_record.update(gap_before=gap_before, gap_after=gap_after,
                           gap_ratio=gap_after / gap_before if gap_before > 0 else None,
                           per_light_gap_before=before_b["per_light"], per_light_gap_after=after_b["per_light"],
                           per_region_gap_before=before_b["per_region"], per_region_gap_after=after_b["per_region"])
        if figure_dir is not None:
            figures.step_figures(ctx, index, step_record, (before, after, panels), (before_b, after_b), sigma2_hat,
                          figure_dir)


def _result(ctx, dataset, settings, plain, trace, skipped, signature_figures, sigma2_hat, sigma2_plain) -> dict:
    """The contents of ``diagnosis.json`` (less the simulation and the seconds)."""
    plain_residuals = standardised_residuals(ctx, plain)
    final_residuals = standardised_residuals(ctx, trace.current)
    current = trace.current
    return {
        **(settings.provenance or {}),
        "dataset": str(getattr(ctx.dataset, "path", dataset)),
        "channel": settings.channel,
        "signature_figures": signature_figures,
        "base_effects": [e.name for e in settings.base_effects],
        # the final model's effects beyond the fit's own: the steps' names after any revision
        "named_effects": [e.name for e in current.effects if e.name not in {b.name for b in settings.base_effects}],
        "revisions": trace.revisions,
        "revision_rule": REVISION_RULE,
        "pairs": trace.pairs,
        "trial": trace.trials[0] if trace.trials else None,
        "trials": trace.trials,
        "steps": trace.steps,
        "candidates": trace.rows,
        "skipped": skipped,
        "search": {"max_steps": int(settings.max_steps), "stopped": trace.stopped,
                   "base_refits": trace.base_refits},
        "gap_definition": GAP_DEFINITION,
        "decision_rule": DECISION_RULE,
        "naming_rule": NAMING_RULE,
        "thresholds": {"log_bayes_factor": settings.threshold, "loo_se_factor": settings.loo_se_factor,
                       "prior_conflict_sd": PRIOR_CONFLICT_SD},
        "likelihood_power": ctx.likelihood_power,
        "noise": ctx.noise,
        "normals": document.NORMALS[settings.normals is not None],
        "noise_variance_estimate": sigma2_hat,
        "noise_variance_estimate_plain_residuals": sigma2_plain,
        "gap_plain": gap(plain_residuals, sigma2_hat),
        "gap_final": gap(final_residuals, sigma2_hat),
        "per_region_gap": {"plain": gap_breakdown(ctx, plain_residuals, sigma2_hat)["per_region"],
                           "final": gap_breakdown(ctx, final_residuals, sigma2_hat)["per_region"]},
        "final_model": {"effects": [e.name for e in current.effects], "log_evidence": current.log_evidence,
                        "parameters": current.summary(), "laplace_hessian": current.hessian_kind,
                        "posterior_draws": {"proposal": current.draws_proposal}},
        "plain_model": {"log_evidence": plain.log_evidence, "parameters": plain.summary()},
        "n_observations": ctx.n_obs, "n_regions": ctx.n_regions, "seed": settings.seed,
        "method": {"refit": "MAP (least squares + sigma^2 updates + Newton) and Laplace approximation with a "
                            "finite-difference Hessian in unconstrained coordinates",
                   "evidence": "Laplace log marginal likelihood; PSIS-LOO (ArviZ's estimator, vectorised) on 100 "
                               "draws as second opinion: the Laplace Gaussian's, or a split normal's along "
                               "its axes where the posterior is not Gaussian",
                   "segmentation": "fixed (given labels)"},
    }
