"""The text of a diagnosis: ``diagnosis.md`` and the lines the workflow and ``rjfit diagnose``
print, each number written one way (the figures are :mod:`rjfit.diagnose.figures`')."""
from __future__ import annotations

import math

from rjfit.diagnose.candidates import loo_support_text
from rjfit.diagnose.proposal import POOR_DRAWS_KHAT

__all__ = ["markdown", "gap_text", "candidate_line", "gap_lines", "named_text", "prior_conflict_text",
           "not_told_apart_text", "revision_text", "trial_offer_line", "NORMALS"]

#: diagnosis.json "normals": which normals the refits use (by whether the fit's posterior mean ones were given)
NORMALS = {False: "the data set's (given) normals",
           True: "the fit's posterior mean normals (it sampled them: rjfit fit --normals sample; its maps.exr "
                 "normal_dx, normal_dy), as its prediction; the observations and the noise model's scales are those "
                 "of the given normals, as the fit kept and weighed them; a Mitsuba simulation renders the mesh's "
                 "own normals"}


def _fmt(value, spec=".3g"):
    if value is None:
        return "-"
    if isinstance(value, float):
        return format(value, spec)
    return str(value)


def _percent(fraction) -> str:
    return "-" if fraction is None else f"{100.0 * float(fraction):.2g} %"


def prior_conflict_text(conflict: dict) -> str:
    """One prior-data conflict of an effect parameter (workflow ``PRIOR_CONFLICT_SD``), in words."""
    return (f"prior-data conflict: {conflict['param']} = {conflict['map']:.3g} lies "
            f"{conflict['prior_sd_from_centre']:.1f} prior sd from its prior's centre")


def not_told_apart_text(effect: str, log_bf: float, runners_up: list) -> str:
    """Why a named effect's choice is not decisive: runners-up whose log BF is within the threshold of its own."""
    others = ", ".join(f"{r['effect']} (log BF {r['log_bayes_factor']:.1f})" for r in runners_up)
    return (f"{effect} (log BF {log_bf:.1f}) is not told apart from {others} by the evidence (within ln 100): "
            f"either explains the data about as well")


def revision_text(revision: dict, brief: bool = False) -> str:
    """One revision of an earlier choice (:mod:`rjfit.diagnose.revisit`), in words; ``brief``:
    what changed only ("camera_gamma swapped for camera_srgb"), for one-line summaries."""
    if brief:
        replaced = f" for {revision['replacement']}" if revision["action"] == "swapped" else ""
        return f"{revision['effect']} {revision['action']}{replaced}"
    when = ("before step 1 (an effect the fit sampled, on its segmentation)" if revision["after_step"] is None
            else f"after step {revision['after_step'] + 1}")
    if revision["action"] == "swapped":
        close = "; not told apart: within ln 100" if revision.get("not_told_apart") else ""
        return (f"{when}: {revision['effect']} swapped for {revision['replacement']} "
                f"(log BF {revision['log_bayes_factor']:.1f} with the other effects present{close})")
    return (f"{when}: {revision['effect']} dropped (log BF {revision['log_bayes_factor']:.1f} "
            f"for keeping it, not decisive: the other effects or the regions explain its part)")


def gap_text(value) -> str:
    """How every gap is written (terminal, diagnosis.md): 4 significant digits."""
    return "-" if value is None else format(float(value), ".4g")


def named_text(result: dict) -> str:
    """The named effects, or why there are none (nothing decisive, or no search at all)."""
    named = result["named_effects"]
    unexplained = result.get("unexplained_misfit")
    if named:
        return ", ".join(named) + (f"; then {unexplained['text']}" if unexplained else "")
    stopped = result.get("search", {}).get("stopped", "")
    if stopped.startswith("search skipped"):
        return f"none ({stopped})"
    if unexplained:
        return f"none ({stopped}); {unexplained['text']}"
    return f"none: no missing effect was found ({stopped})" if stopped else "none: no missing effect was found"


def trial_offer_line(trial: dict) -> str:
    """The line that says a diagnosis' trial (:func:`rjfit.diagnose.pairs.trial_candidates`), with its LOO support
    where it is not decisive."""
    support = "" if trial.get("decisive", True) else f" (supported: its LOO gain {loo_support_text(trial)})"
    return f"  to try with the regions (rjfit refine): {' + '.join(trial['effects'])}{support}"


def _decisive_cell(row: dict) -> str:
    """The "decisive" column of a candidate: yes, no, "no (supported)" (a possible trial), or its failure."""
    if "error" in row:
        return "failed: " + row["error"]
    return "yes" if row.get("decisive") else ("no (supported)" if row.get("supported") else "no")


def candidate_line(row: dict) -> str:
    """One candidate's evidence at one step, as the workflow prints it while it searches."""
    head = f"  step {row['step'] + 1} {row['effect']:18s}"
    if "error" in row:
        return f"{head} failed: {row['error']}"
    text = f"{head} log BF {row['log_bayes_factor']:10.1f}  "
    if "delta_elpd_loo" in row:
        text += f"dLOO {row['delta_elpd_loo']:9.1f} +- {row['delta_elpd_loo_se']:6.1f}"
        if row.get("khat_unreliable_fraction"):
            text += f" (k-hat too high for {_percent(row['khat_unreliable_fraction'])})"
    else:
        text += f"dLOO skipped: {row['loo_skipped']}" if "loo_skipped" in row else "dLOO not computed"
    text += "".join(f"  [{prior_conflict_text(c)}]" for c in row.get("prior_conflict", ()))
    return text + ("  decisive" if row.get("decisive") else ("  supported" if row.get("supported") else ""))


def gap_lines(result: dict) -> list[str]:
    """The gaps of a diagnosis, each exactly as ``diagnosis.json`` holds it (one noise estimate)."""
    lines = [f"gaps, all with one noise estimate (variance {result['noise_variance_estimate']:.4g}, from the final "
             f"model's residuals), as in diagnosis.json:",
             f"  plain model: gap {gap_text(result['gap_plain'])}"]
    for index, step in enumerate(result["steps"]):
        lines.append(f"  step {index + 1} + {step['effect']}: gap {gap_text(step['gap_before'])} -> "
                     f"{gap_text(step['gap_after'])}")
    lines.append(f"  final model ({' + '.join(['plain'] + result['named_effects'])}): gap {gap_text(result['gap_final'])}")
    return lines


def markdown(result: dict) -> str:
    """``diagnosis.md`` of the diagnosis ``result`` (the contents of ``diagnosis.json``)."""
    lines = _head_lines(result) + _step_lines(result) + _candidate_lines(result) + _pair_lines(result)
    lines += _warning_lines(result)
    lines += _signature_lines(result) + _simulation_lines(result)
    lines += ["", "## Where the disagreement concentrates (closed form, before -> after)", ""]
    lines.append("| region | gap plain | gap final |")
    lines.append("|---|---|---|")
    for k, (a, b) in enumerate(zip(result["per_region_gap"]["plain"], result["per_region_gap"]["final"])):
        lines.append(f"| {k} | {gap_text(a)} | {gap_text(b)} |")
    return "\n".join(lines) + "\n"


def _decisive_gain(result: dict) -> float:
    """The plain log-likelihood gain a candidate needs to be decisive at the fit's power (Occam factor aside)."""
    threshold = (result.get("thresholds") or {}).get("log_bayes_factor", math.log(100.0))
    return float(threshold) / float(result["likelihood_power"])


def _head_lines(result: dict) -> list[str]:
    """The title, named effects, definitions, likelihood power and noise model, gaps, skipped candidates."""
    lines = [f"# Diagnosis of `{result['dataset']}`", ""]
    lines.append(f"**Named effects:** {named_text(result)}")
    lines += ["", f"Gap: {result['gap_definition']}", "",
              f"Decision rule: {result['decision_rule']}", "",
              *([f"Naming rule: {result['naming_rule']}", ""] if result.get("naming_rule") else []),
              *([f"Likelihood power: {result['likelihood_power']:.4g} (the fit's coarsened likelihood; log Bayes "
                 f"factors weigh the data as the fit did: a candidate is decisive only where it raises the plain "
                 f"log-likelihood by more than about the log Bayes factor threshold over zeta, "
                 f"{_decisive_gain(result):,.0f} nats, plus its Occam factor)", ""]
                if result.get("likelihood_power", 1.0) != 1.0 else []),
              *([f"Noise model: {result['noise']['model']}, {result['noise']['formula']} (the fit's; the refits weigh "
                 f"each observation by its known scale)", ""]
                if (result.get("noise") or {}).get("model", "constant") != "constant" else []),
              *([f"Normals: {result['normals']}.", ""] if result.get("normals") == NORMALS[True] else []),
              f"Plain model gap: {gap_text(result['gap_plain'])}; final gap: {gap_text(result['gap_final'])} "
              f"(noise variance estimate {_fmt(result['noise_variance_estimate'], '.4g')}).", ""]
    if result.get("skipped"):
        lines += ["Candidates not tried on this data set:", ""]
        lines += [f"- `{name}`: skipped, {why}" for name, why in result["skipped"].items()]
        lines.append("")
    return lines


def _step_lines(result: dict) -> list[str]:
    """The steps' table, then each step's warnings, figures and moved parameters."""
    lines = ["## Steps", "", "| step | effect | log BF | dLOO (SE) | gap before | gap after |", "|---|---|---|---|---|---|"]
    for i, step in enumerate(result["steps"]):
        ev = step["evidence"]
        lines.append(f"| {i + 1} | {step['effect']} | {_fmt(ev['log_bayes_factor'], '.1f')} | "
                     f"{_fmt(ev.get('delta_elpd_loo'), '.1f')} ({_fmt(ev.get('delta_elpd_loo_se'), '.1f')}) | "
                     f"{gap_text(step['gap_before'])} | {gap_text(step['gap_after'])} |")
    if not result["steps"]:
        stopped = result.get("search", {}).get("stopped", "")
        lines.append(f"| - | {'no search' if stopped.startswith('search skipped') else 'none decisive'} | | | | |")
    if result.get("revisions"):
        lines += ["", "Earlier choices revisited (" + result.get("revision_rule", "") + "):", ""]
        lines += [f"- {revision_text(r)}" for r in result["revisions"]]
    for i, step in enumerate(result["steps"]):
        lines += ["", f"### Step {i + 1}: {step['effect']}", ""]
        if step.get("not_told_apart"):
            lines += [f"**Caveat**: {not_told_apart_text(step['effect'], step['evidence']['log_bayes_factor'], step['not_told_apart'])}.", ""]
        lines += [f"**Warning**, {prior_conflict_text(c)}: the effect may stand in for another with a similar "
                  f"signature.\n" for c in step.get("prior_conflict", ())]
        figs = step.get("figures", {})
        for key in ("residuals", "per_light", "posteriors"):
            if key in figs:
                lines.append(f"![{key}]({figs[key]})")
        moved = step.get("moved_parameters", [])
        if moved:
            lines += ["", "Parameters that moved (more than 2 posterior sd):", ""]
            lines += [f"- {m['name']}: {_fmt(m['before'])} -> {_fmt(m['after'])} (sd {_fmt(m['sd_after'])})" for m in moved]
    return lines


def _candidate_lines(result: dict) -> list[str]:
    """The table of every candidate at every step."""
    lines = ["", "## Candidates per step", "",
             "| step | effect | log BF | dLOO | SE | max k-hat | k-hat > threshold | signature | gap with effect | decisive |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for row in result["candidates"]:
        loo = (f"{_fmt(row.get('delta_elpd_loo'), '.1f')} | {_fmt(row.get('delta_elpd_loo_se'), '.1f')}"
               if "delta_elpd_loo" in row else (f"skipped ({row['loo_skipped']}) | -" if "loo_skipped" in row else "- | -"))
        lines.append(f"| {row['step'] + 1} | {row['effect']} | {_fmt(row.get('log_bayes_factor'), '.1f')} | {loo} | "
                     f"{_fmt(row.get('max_khat'), '.2f')} | {_percent(row.get('khat_unreliable_fraction'))} | "
                     f"{_fmt(row.get('signature_score'), '.2f')} | "
                     f"{gap_text(row.get('gap_with_effect'))} | "
                     f"{_decisive_cell(row)} |")
    if not result["candidates"]:
        lines.append(f"| - | {result.get('search', {}).get('stopped', 'none tried')} | | | | | | | | |")
    return lines


def _pair_lines(result: dict) -> list[str]:
    """The pairs of decisive candidates tried where none qualified alone, and the trial offered to ``rjfit refine``."""
    lines = []
    if result.get("pairs"):
        lines += ["", "## Pairs tried (no single candidate qualified)", "",
                  "| step | effects | log BF | dLOO (SE) | gap share | decisive | not named because |", "|---|---|---|---|---|---|---|"]
        lines += [f"| {row['step'] + 1} | {row['effect']} | {_fmt(row['log_bayes_factor'], '.1f')} | "
                  f"{_fmt(row.get('delta_elpd_loo'), '.1f')} ({_fmt(row.get('delta_elpd_loo_se'), '.1f')}) | "
                  f"{_percent(row.get('gap_share'))} | {'yes' if row['decisive'] else 'no'} | "
                  f"{row.get('why_not', '-' if not row['decisive'] else 'qualifies')} |" for row in result["pairs"]]
    trial = result.get("trial")
    if trial:
        why = ("but this segmentation leaves little gap for it to close" if trial.get("within_floor") else
               f"but closes only {_percent(trial['gap_share'])} of the gap on this segmentation")
        keeps = ("the new segmentation has fewer regions and its gap stays within the naming rule's floor"
                 if trial.get("within_floor") else "the gap on the new segmentation is at most half of this one")
        support = ("is decisive" if trial.get("decisive", True) else
                   f"is supported (its LOO gain {loo_support_text(trial)}, short of the decision rule's bar)")
        lines += ["", f"**To try with the regions:** {' + '.join(trial['effects'])} (log BF "
                  f"{trial['log_bayes_factor']:.1f}) {support} and physical {why}: its regions may have split to "
                  f"absorb what it explains; `rjfit refine` fits again with it and keeps it only where {keeps}."]
    return lines


def _warning_lines(result: dict) -> list[str]:
    """Prior-data conflicts and observations whose PSIS-LOO is unreliable, where there are any."""
    lines = []
    conflicted = [row for row in result["candidates"] if row.get("prior_conflict")]
    if conflicted:
        lines += ["", f"Prior-data conflicts (an effect parameter's MAP more than "
                  f"{result.get('thresholds', {}).get('prior_conflict_sd', '?')} prior sd from its prior's centre: "
                  "the data pull it where the effect's physics is implausible, so a decisive effect may be standing "
                  "in for another with a similar signature):", ""]
        lines += [f"- step {row['step'] + 1}, {row['effect']}{' (decisive)' if row.get('decisive') else ''}: "
                  f"{prior_conflict_text(c)}" for row in conflicted for c in row["prior_conflict"]]
    unreliable = [row for row in result["candidates"] if (row.get("khat_unreliable_fraction") or 0.0) > 0.0]
    if unreliable:
        worst = max(unreliable, key=lambda row: row["khat_unreliable_fraction"])
        lines += ["", f"PSIS-LOO is unreliable for some observations: their Pareto k-hat exceeds the threshold for "
                  f"the refits' draws (min(1 - 1/log10 S, 0.7), Vehtari et al. 2024), for up to "
                  f"{_percent(worst['khat_unreliable_fraction'])} of them (step {worst['step'] + 1}, {worst['effect']}). "
                  f"There dLOO and its SE are rough; the log Bayes factor (Laplace evidence) is the primary evidence."]
    return lines + _draws_lines(result)


def _draws_lines(result: dict) -> list[str]:
    """Refits with a LOO whose draws came from a split normal, and those whose draws cover their posterior poorly."""
    rows = [row for row in result["candidates"] if "weights_khat" in (row.get("posterior_draws") or {})]
    split = [row for row in rows if row["posterior_draws"]["proposal"] != "Laplace"]
    poor = [row for row in rows if row["posterior_draws"]["weights_khat"] > POOR_DRAWS_KHAT]
    lines = []
    if split:
        steps = sorted({row["step"] for row in split})
        lines += ["", "Where a refit's log posterior is not Gaussian along an axis of its Laplace approximation, its "
                  "LOO draws came from a split normal with the scales the log posterior shows (Geweke 1989): "
                  + "; ".join(f"step {step + 1}: " + ", ".join(row["effect"] for row in split if row["step"] == step)
                              for step in steps) + "."]
    if poor:
        worst = max(poor, key=lambda row: row["posterior_draws"]["weights_khat"])
        lines += ["", f"The draws of {len(poor)} refit(s) still represent their posterior poorly: the Pareto k-hat of "
                  f"their importance weights exceeds {POOR_DRAWS_KHAT} (up to "
                  f"{worst['posterior_draws']['weights_khat']:.2f}, step {worst['step'] + 1}, {worst['effect']}). "
                  f"Their dLOO is rough."]
    return lines


def _signature_lines(result: dict) -> list[str]:
    if not result.get("signature_figures"):
        return []
    lines = ["", "## Signatures", "",
             "Each candidate's signature: the derivative of the predictions with respect to its parameters "
             "(from geometry and Mitsuba features), fitted to the standardised residuals by least squares; "
             "score = share of the residual sum of squares it explains.", ""]
    return lines + [f"![signatures]({name})" for name in result["signature_figures"]]


def _simulation_lines(result: dict) -> list[str]:
    sim = result.get("simulation")
    if not sim:
        return []
    lines = ["", "## Posterior predictive simulation with Mitsuba", ""]
    for label in ("plain", "final"):
        if label in sim:
            s = sim[label]
            lines.append(f"- {label} model: Mitsuba gap {_fmt(s['gap'])}, {s['n_draws']} draws, fraction of pixels "
                         f"with PPC p < 0.01: {_fmt(s['ppc_fraction_below_0.01'])}")
    for key, fig in sim.get("figures", {}).items():
        lines.append(f"\n![{key}]({fig})")
    return lines
