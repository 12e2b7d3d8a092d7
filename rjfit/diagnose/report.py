"""Figures and the Markdown report of a diagnosis."""
from __future__ import annotations


import numpy as np

from rjfit.plotting import map_figure as _map_figure
from rjfit.plotting import pyplot, zoom_to_object
from rjfit.plotting import save_figure as _save_figure

__all__ = ["save_figure", "residual_pair_figure", "per_light_figure", "posterior_figure", "map_figure", "markdown",
           "gap_text", "candidate_line", "gap_lines", "named_text", "listed_figures"]


def _plt():
    return pyplot()


def save_figure(figure, path):
    return _save_figure(figure, path).name


def residual_pair_figure(path, before, after, title_before, title_after, label="mean standardised residual"):
    plt = _plt()
    limit = float(np.nanpercentile(np.abs(np.concatenate([before[np.isfinite(before)], after[np.isfinite(after)]])), 99))
    limit = max(limit, 1e-6)
    figure, axes = plt.subplots(1, 2, figsize=(8.4, 3.8))
    for axis, image, title in zip(axes, (before, after), (title_before, title_after)):
        shown = axis.imshow(image, cmap="RdBu_r", vmin=-limit, vmax=limit)
        zoom_to_object(axis, np.isfinite(before) | np.isfinite(after))
        axis.set_title(title, fontsize=9)
        axis.axis("off")
    figure.colorbar(shown, ax=axes, fraction=0.046, label=label)
    return save_figure(figure, path)


def per_light_figure(path, before, after, title):
    plt = _plt()
    lights = np.arange(len(before))
    figure, axis = plt.subplots(figsize=(6.4, 3.2))
    b = np.array([np.nan if v is None else v for v in before], dtype=float)
    a = np.array([np.nan if v is None else v for v in after], dtype=float)
    axis.bar(lights - 0.2, b, 0.4, label="before")
    axis.bar(lights + 0.2, a, 0.4, label="after")
    axis.set_xlabel("light")
    axis.set_ylabel("gap")
    axis.set_title(title, fontsize=9)
    axis.legend(fontsize=8)
    figure.tight_layout()
    return save_figure(figure, path)


def posterior_figure(path, panels):
    """``panels``: list of (name, before draws or None, after draws)."""
    plt = _plt()
    n = max(len(panels), 1)
    cols = min(n, 4)
    rows = int(np.ceil(n / cols))
    figure, axes = plt.subplots(rows, cols, figsize=(3.0 * cols, 2.4 * rows), squeeze=False)
    for axis in axes.ravel()[n:]:
        axis.axis("off")
    for axis, (name, before, after) in zip(axes.ravel(), panels):
        if before is not None:
            axis.hist(before, bins=25, alpha=0.6, density=True, label="before")
        axis.hist(after, bins=25, alpha=0.6, density=True, label="after")
        axis.set_title(name, fontsize=8)
        axis.tick_params(labelsize=7)
    axes.ravel()[0].legend(fontsize=7)
    figure.tight_layout()
    return save_figure(figure, path)


def map_figure(path, image, title, cmap="viridis", vmin=None, vmax=None):
    return _map_figure(path, image, title, cmap=cmap, vmin=vmin, vmax=vmax).name


def signature_figure(path, residual, panels, title):
    """The mean standardised residual map next to candidate signature maps (same colours)."""
    plt = _plt()
    finite = residual[np.isfinite(residual)]
    limit = max(float(np.percentile(np.abs(finite), 99)) if finite.size else 1.0, 1e-6)
    figure, axes = plt.subplots(1, len(panels) + 1, figsize=(2.3 * (len(panels) + 1), 2.8), squeeze=False)
    for axis, (label, image) in zip(axes[0], [("residual", residual)] + list(panels)):
        axis.imshow(image, cmap="RdBu_r", vmin=-limit, vmax=limit)
        zoom_to_object(axis, np.isfinite(residual))
        axis.set_title(label, fontsize=7)
        axis.axis("off")
    figure.suptitle(title, fontsize=8)
    figure.tight_layout()
    return save_figure(figure, path)


def listed_figures(result: dict) -> list[str]:
    """The figures a diagnosis made, as ``diagnosis.json`` names them (file names in its folder):
    each step's, the signature panels, the Mitsuba simulation's; in that order, each once.

    The files of one diagnosis are those its ``diagnosis.json`` names: ``rjfit report`` embeds
    these and no others, and a new diagnosis removes them before it publishes its own.
    """
    names = []
    for step in result.get("steps") or []:
        names += list((step.get("figures") or {}).values())
    names += list(result.get("signature_figures") or [])
    names += list(((result.get("simulation") or {}).get("figures") or {}).values())
    return list(dict.fromkeys(name for name in names if isinstance(name, str) and name))


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


def gap_text(value) -> str:
    """How every gap is written (terminal, diagnosis.md): 4 significant digits."""
    return "-" if value is None else format(float(value), ".4g")


def named_text(result: dict) -> str:
    """The named effects, or why there are none (nothing decisive, or no search at all)."""
    named = result["named_effects"]
    if named:
        return ", ".join(named)
    stopped = result.get("search", {}).get("stopped", "")
    if stopped.startswith("search skipped"):
        return f"none ({stopped})"
    return f"none: no missing effect was found ({stopped})" if stopped else "none: no missing effect was found"


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
    return text + ("  decisive" if row.get("decisive") else "")


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
    lines = [f"# Diagnosis of `{result['dataset']}`", ""]
    lines.append(f"**Named effects:** {named_text(result)}")
    lines += ["", f"Gap: {result['gap_definition']}", "",
              f"Decision rule: {result['decision_rule']}", "",
              *([f"Likelihood power: {result['likelihood_power']:.4g} (the fit's coarsened likelihood; log Bayes "
                 f"factors weigh the data as the fit did)", ""] if result.get("likelihood_power", 1.0) != 1.0 else []),
              *([f"Noise model: {result['noise']['model']}, {result['noise']['formula']} (the fit's; the refits weigh "
                 f"each observation by its known scale)", ""]
                if (result.get("noise") or {}).get("model", "constant") != "constant" else []),
              f"Plain model gap: {gap_text(result['gap_plain'])}; final gap: {gap_text(result['gap_final'])} "
              f"(noise variance estimate {_fmt(result['noise_variance_estimate'], '.4g')}).", ""]
    if result.get("skipped"):
        lines += ["Candidates not tried on this data set:", ""]
        lines += [f"- `{name}`: skipped, {why}" for name, why in result["skipped"].items()]
        lines.append("")
    lines += ["## Steps", "", "| step | effect | log BF | dLOO (SE) | gap before | gap after |", "|---|---|---|---|---|---|"]
    for i, step in enumerate(result["steps"]):
        ev = step["evidence"]
        lines.append(f"| {i + 1} | {step['effect']} | {_fmt(ev['log_bayes_factor'], '.1f')} | "
                     f"{_fmt(ev.get('delta_elpd_loo'), '.1f')} ({_fmt(ev.get('delta_elpd_loo_se'), '.1f')}) | "
                     f"{gap_text(step['gap_before'])} | {gap_text(step['gap_after'])} |")
    if not result["steps"]:
        stopped = result.get("search", {}).get("stopped", "")
        lines.append(f"| - | {'no search' if stopped.startswith('search skipped') else 'none decisive'} | | | | |")
    for i, step in enumerate(result["steps"]):
        lines += ["", f"### Step {i + 1}: {step['effect']}", ""]
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
    lines += ["", "## Candidates per step", "",
              "| step | effect | log BF | dLOO | SE | max k-hat | k-hat > threshold | signature | gap with effect | decisive |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    for row in result["candidates"]:
        loo = (f"{_fmt(row.get('delta_elpd_loo'), '.1f')} | {_fmt(row.get('delta_elpd_loo_se'), '.1f')}"
               if "delta_elpd_loo" in row else (f"skipped ({row['loo_skipped']}) | -" if "loo_skipped" in row else "- | -"))
        lines.append(f"| {row['step'] + 1} | {row['effect']} | {_fmt(row.get('log_bayes_factor'), '.1f')} | {loo} | "
                     f"{_fmt(row.get('max_khat'), '.2f')} | {_percent(row.get('khat_unreliable_fraction'))} | "
                     f"{_fmt(row.get('signature_score'), '.2f')} | "
                     f"{gap_text(row.get('gap_with_effect'))} | "
                     f"{'yes' if row.get('decisive') else ('failed: ' + row['error'] if 'error' in row else 'no')} |")
    if not result["candidates"]:
        lines.append(f"| - | {result.get('search', {}).get('stopped', 'none tried')} | | | | | | | | |")
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
    if result.get("signature_figures"):
        lines += ["", "## Signatures", "",
                  "Each candidate's signature: the derivative of the predictions with respect to its parameters "
                  "(from geometry and Mitsuba features), fitted to the standardised residuals by least squares; "
                  "score = share of the residual sum of squares it explains.", ""]
        lines += [f"![signatures]({name})" for name in result["signature_figures"]]
    sim = result.get("simulation")
    if sim:
        lines += ["", "## Posterior predictive simulation with Mitsuba", ""]
        for label in ("plain", "final"):
            if label in sim:
                s = sim[label]
                lines.append(f"- {label} model: Mitsuba gap {_fmt(s['gap'])}, {s['n_draws']} draws, fraction of pixels "
                             f"with PPC p < 0.01: {_fmt(s['ppc_fraction_below_0.01'])}")
        for key, fig in sim.get("figures", {}).items():
            lines.append(f"\n![{key}]({fig})")
    lines += ["", "## Where the disagreement concentrates (closed form, before -> after)", ""]
    lines.append("| region | gap plain | gap final |")
    lines.append("|---|---|---|")
    for k, (a, b) in enumerate(zip(result["per_region_gap"]["plain"], result["per_region_gap"]["final"])):
        lines.append(f"| {k} | {gap_text(a)} | {gap_text(b)} |")
    return "\n".join(lines) + "\n"
