"""``rjfit report``: one self-contained HTML page per fit (figures embedded, no network)."""
from __future__ import annotations

import base64
import html
from pathlib import Path

from rjfit.diagnose.document import revision_text
from rjfit.io import read_json, write_text_atomic
from rjfit.pipeline.fit_folder import read_summary
from rjfit.pipeline.regions import region_fit_of
from rjfit.pipeline.report_text import figure_caption, fit_settings, result_rows, truth_note
from rjfit.posterior.summary import RHAT_MAX

__all__ = ["build_report"]

_PARAMETERS = ("I0", "kd", "gamma", "sigma2")
_LABELS = {"I0": "I<sub>0</sub> (intensity &times; albedo, image units)", "kd": "k<sub>d</sub> (diffuse fraction)",
           "gamma": "&gamma; (Blinn-Phong exponent)", "sigma2": "&sigma;<sup>2</sup> (noise variance)"}
#: the cross-check's numbers in words (validation.json's keys)
_VALIDATION_LABELS = {"median_rel_err": "median relative error, closed form vs path tracer (good: <= 1e-4)",
                      "p99_rel_err": "99th percentile of the relative error (good: <= 1e-3)",
                      "max_rel_err": "largest relative error",
                      "observations_over_p99_tolerance": "observations over 1e-3 (the gate allows 1 % of them)",
                      "observations_compared": "observations compared (a lit pixel under one light)",
                      "pixels_compared": "pixels compared",
                      "unexplained_fraction": "share of the radiance the closed form does not explain"}

_STYLE = """
body{font-family:system-ui,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;color:#222}
h1{font-size:1.6em}h2{font-size:1.25em;border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:1.6em}
table{border-collapse:collapse;margin:.6em 0}td,th{border:1px solid #bbb;padding:.25em .6em;text-align:right}
th{background:#f0f0f0}td:first-child,th:first-child{text-align:left}
figure{display:inline-block;margin:.4em;vertical-align:top}figure img{max-width:520px;border:1px solid #ddd}
figure.wide{display:block}figure.wide img{max-width:100%}
figcaption{font-size:.85em;color:#555;max-width:520px}figure.wide figcaption{max-width:none}
td.note,th.note{text-align:left;font-size:.85em;color:#444;max-width:560px}.pass{color:#070;font-weight:bold}.fail{color:#b00;font-weight:bold}
code{background:#f4f4f4;padding:0 .2em}
"""


def _load_json(path: Path):
    return read_json(path) if path.is_file() else None


def _number(value, spec=".4g") -> str:
    """A number of the summary formatted by ``spec``; any other value (hand-edited) as text."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return format(value, spec)
    return _fmt(value)


def _embed(path: Path, caption: str) -> str:
    """The PNG at ``path`` embedded with ``caption``; its alt text names the figure (its file name in words)."""
    return _embed_bytes(path.read_bytes(), caption, path.stem.replace("_", " "))


def _embed_bytes(png: bytes, caption: str, alt: str) -> str:
    # a PNG's width and height are the big-endian words at bytes 16-24 (its IHDR chunk): a
    # figure of several panels side by side gets the page's full width instead of half
    width, height = int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")
    wide = ' class="wide"' if height and (width > 2 * height or width > 1000) else ""
    data = base64.b64encode(png).decode("ascii")
    return (f'<figure{wide}><img alt="{html.escape(alt)}" src="data:image/png;base64,{data}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def _fmt(value, digits=4):
    if value is None:
        return "&ndash;"
    if isinstance(value, float):
        return f"{value:.{digits}g}"
    return html.escape(str(value))


def _draws_note(region: dict) -> str:
    """Under a material's name: where its parameters are not summarised over the draws at the segmentation's K
    (``parameters_from``: the draws that hold it; none: unknown), else nothing."""
    if "parameters_from" not in region:
        return ""
    own = region["parameters_from"]
    if not own:
        return "<br><small>no draw holds it: parameters unknown</small>"
    chains = ", ".join(str(c) for c in own.get("chains", []))
    return f"<br><small>from the {_fmt(own.get('draws'))} draws that hold it (chain {chains})</small>"


def _region_table(summary: dict) -> str:
    """The paper's Table 2 / 4 layout: one row per region, mean &plusmn; sd and 95 % interval."""
    regions = summary.get("regions") or []
    # label_matching maps a fitted region to the true label it was matched to (Hungarian).
    truth_params = summary.get("truth_params") or []
    truth = {str(region): truth_params[label] for region, label in (summary.get("label_matching") or {}).items()
             if isinstance(label, int) and 0 <= label < len(truth_params) and isinstance(truth_params[label], dict)}
    head = "".join(f"<th>{_LABELS[p]}</th>" for p in _PARAMETERS)
    model = region_fit_of(summary)
    rows = []
    for index, region in enumerate(regions):
        name = region.get("name", model.region_title(region, index))
        cells = []
        for parameter in _PARAMETERS:
            stats = region.get(parameter, {})
            if not isinstance(stats, dict) or "mean" not in stats:
                cells.append("<td>&ndash;</td>")
                continue
            text = f"{_number(stats['mean'])} &plusmn; {_number(stats.get('sd', float('nan')), '.2g')}"
            low, high = stats.get("q2.5"), stats.get("q97.5")
            if low is not None and high is not None:
                text += f"<br><small>[{_number(low)}, {_number(high)}]</small>"
            true_value = (truth.get(str(index)) or {}).get(parameter) if truth else None
            if true_value is not None:
                text += f"<br><small>truth {_number(true_value)}</small>"
            cells.append(f"<td>{text}</td>")
        rows.append(f"<tr><td>{html.escape(str(name))}<br><small>{_fmt(region.get('pixels'))} px</small>"
                    f"{_draws_note(region)}</td>" + "".join(cells) + "</tr>")
    return f"<table><tr><th>{model.noun}</th>{head}</tr>{''.join(rows)}</table>"


def _chain_region_tables(summary: dict) -> str:
    """Each chain's own region table, shown when the chains have not mixed (the pooled table mixes their modes)."""
    chains = [c for c in (summary.get("chain_regions") or []) if isinstance(c, dict) and c.get("regions")]
    rhat = summary.get("rhat_max")
    if len(chains) < 2 or (isinstance(rhat, (int, float)) and rhat <= RHAT_MAX):
        return ""
    parts = [f"<p>The chains have not mixed (R-hat {_fmt(rhat)}): region r is a cell of the change points, which "
             "lie elsewhere in each chain's mode, so the pooled table above mixes regions that are not the same "
             "pixels. Each chain on its own:</p>"]
    for chain in chains:
        parts.append(f"<h3>chain {_fmt(chain.get('chain'))} ({_fmt(chain.get('draws'))} draws in the MAP model)</h3>"
                     + _region_table({"regions": chain["regions"]}))
    return "".join(parts)


def _effects_table(summary: dict) -> str:
    """The effects sampled with the regions (``summary["effects"]``): each parameter's posterior, and per-light gains."""
    effects = [e for e in (summary.get("effects") or []) if isinstance(e, dict)]
    if not effects:
        return ""
    rows = []
    for effect in effects:
        for param in effect.get("parameters") or []:
            cells = [html.escape(str(effect.get("name"))), html.escape(str(param.get("name"))), _fmt(param.get("mean")),
                     _fmt(param.get("sd")), f"{_fmt(param.get('q2.5'))} &ndash; {_fmt(param.get('q97.5'))}",
                     _fmt(param.get("rhat")), _fmt(param.get("ess_bulk")), html.escape(str(param.get("prior")))]
            rows.append("<tr>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
        for light, gain in enumerate(effect.get("light_gains") or []):
            rows.append(f"<tr><td>{html.escape(str(effect.get('name')))}</td><td>gain of light {light}</td>"
                        f"<td>{_fmt(gain.get('mean'))}</td><td>{_fmt(gain.get('sd'))}</td>"
                        f"<td>{_fmt(gain.get('q2.5'))} &ndash; {_fmt(gain.get('q97.5'))}</td>"
                        f"<td>{_fmt(gain.get('rhat'))}</td><td>{_fmt(gain.get('ess_bulk'))}</td><td></td></tr>")
    notes = "".join(f"<li>{html.escape(e['name'])}: {html.escape(str(e['source']))}</li>"
                    for e in effects if e.get("source"))
    return ("<h2>Effects sampled with the regions</h2><p>Posterior of each effect parameter (constrained), sampled "
            "jointly with the segmentation and the region parameters (rjfit fit --effects). With a camera response "
            "the fit's noise is on the linearised scale (docs/sampler.md).</p>"
            "<table><tr><th>effect</th><th>parameter</th><th>mean</th><th>sd</th><th>95 % interval</th>"
            f"<th>R-hat</th><th>bulk ESS</th><th>prior</th></tr>{''.join(rows)}</table>"
            + (f"<ul>{notes}</ul>" if notes else ""))


def _key_values(payload: dict, keys, labels=None) -> str:
    """A two-column table of ``payload``'s ``keys``, each named by ``labels`` (the key itself where it has none)."""
    labels = labels or {}
    rows = "".join(f"<tr><td>{html.escape(labels.get(k, k))}</td><td>{_fmt(payload.get(k))}</td></tr>"
                   for k in keys if k in payload)
    return f"<table>{rows}</table>"


def _result_table(summary: dict) -> str:
    """The headline results, each with what it measures and when it is good (:func:`result_rows`)."""
    rows = "".join(f"<tr><td>{html.escape(name)}</td><td>{_fmt(value)}</td><td class='note'>{html.escape(meaning)}"
                   f"</td></tr>" for name, value, meaning in result_rows(summary))
    note = truth_note(summary)
    return ("<table><tr><th>quantity</th><th>value</th><th class='note'>what it means, when it is good</th></tr>"
            f"{rows}</table>"
            + (f"<p>{html.escape(note)}</p>" if note else ""))


def _markdown_to_html(text: str) -> str:
    """The little markdown the result writers produce: headings, pipe tables, lists, paragraphs,
    **bold** and `code`."""
    import re

    out, table, items = [], [], []

    def inline(text):
        text = re.sub(r"\*\*(.+?)\*\*", r"<b>\1</b>", html.escape(text))
        return re.sub(r"`([^`]+)`", r"<code>\1</code>", text)

    def flush():
        if table:
            cells = [[inline(c.strip()) for c in row.strip().strip("|").split("|")] for row in table]
            body = [row for row in cells[1:] if not all(set(c) <= set("-: ") for c in row)]
            out.append("<table><tr>" + "".join(f"<th>{c}</th>" for c in cells[0]) + "</tr>"
                       + "".join("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>" for row in body)
                       + "</table>")
            table.clear()
        if items:
            out.append("<ul>" + "".join(f"<li>{inline(i)}</li>" for i in items) + "</ul>")
            items.clear()

    for line in text.splitlines():
        stripped = line.strip()
        if stripped.startswith("|"):
            if items:
                flush()
            table.append(stripped)
            continue
        if stripped.startswith(("- ", "* ")):
            if table:
                flush()
            items.append(stripped[2:])
            continue
        flush()
        if stripped.startswith("#"):
            level = min(len(stripped) - len(stripped.lstrip("#")) + 2, 6)
            out.append(f"<h{level}>{html.escape(stripped.lstrip('#').strip())}</h{level}>")
        elif stripped:
            out.append(f"<p>{inline(stripped)}</p>")
    flush()
    return "".join(out)


def _listed_figures(sub: str, payload) -> list:
    """The figures of a diagnosis or comparison: those its json names, not every PNG of its folder.

    The json is published last, after its figures and after the previous run's files were
    removed, so the figures it names are its own; a folder may also hold PNGs that are not
    (the user's, a fit's when ``--out`` was the fit folder, those of an rjfit that did not
    stage its results). A comparison.json from before ``figures`` was recorded had always
    ``segmentations.png``.
    """
    if not isinstance(payload, dict):
        return []
    if sub == "diagnosis":
        from rjfit.diagnose.figures import listed_figures

        return listed_figures(payload)
    figures = payload.get("figures", ["segmentations.png"] if "rows" in payload else [])
    return [name for name in figures if isinstance(name, str)] if isinstance(figures, list) else []


def build_report(fit_dir, out_path=None, *, diagnosis_dir=None, comparison_dir=None, refine_dir=None) -> Path:
    """Write ``report.html`` for a fit folder and return its path.

    Reads ``summary.json`` and every PNG in the fit folder, and, where present, the data
    set's ``validation/validation.json`` (or the ``validation.json`` the fit was given) and the ``diagnosis`` and ``comparison`` results
    (``diagnosis_dir/diagnosis.json``, ``comparison_dir/comparison.json``; by default
    ``FIT_DIR/diagnosis`` and ``FIT_DIR/comparison``) with the figures their json names (no
    other PNG of those folders). A diagnosis or comparison made from another fit (its
    ``fit_id`` differs from the summary's) is not shown as this fit's: the report says it is
    stale. A refinement (``refine_dir/refine.json``, default ``FIT_DIR/refine``, as `rjfit run`
    leaves it; `rjfit refine --out` elsewhere) adds its rounds and each round's segmentation
    beside the last. The page is written atomically (:func:`rjfit.io.write_text_atomic`).

    Raises
    ------
    FileNotFoundError
        If ``fit_dir`` has no ``summary.json``.
    DatasetError
        If ``summary.json`` is damaged (see :func:`rjfit.pipeline.fit_folder.read_summary`).
    """
    fit_dir = Path(fit_dir)
    summary = read_summary(fit_dir)
    out_path = Path(out_path) if out_path else fit_dir / "report.html"
    dataset_dir = Path(summary["dataset"]) if summary.get("dataset") else None
    parts = _header(fit_dir, dataset_dir) + _validation_section(summary, dataset_dir)
    parts += _posterior_section(summary) + _settings_section(summary)
    parts.append("<h2>Figures</h2>")
    for png in sorted(fit_dir.glob("*.png")) + sorted((fit_dir / "figures").glob("*.png")):
        parts.append(_embed(png, figure_caption(png.stem)))
    parts += _chains_section(fit_dir, summary)
    folders = {"diagnosis": Path(diagnosis_dir) if diagnosis_dir else fit_dir / "diagnosis",
               "comparison": Path(comparison_dir) if comparison_dir else fit_dir / "comparison"}
    for sub, title, command in (("diagnosis", "Model criticism", "rjfit diagnose"), ("comparison", "Baselines",
                                                                                     "rjfit compare DATASET --fit")):
        parts += _derived_section(sub, title, command, folders[sub], fit_dir, summary)
    parts += _refine_section(Path(refine_dir) if refine_dir else fit_dir / "refine")

    document = (f"<!doctype html><html><head><meta charset='utf-8'><title>rjfit report</title>"
                f"<style>{_STYLE}</style></head><body>{''.join(parts)}</body></html>")
    return write_text_atomic(out_path, document)


def _header(fit_dir: Path, dataset_dir) -> list[str]:
    # a rendered data set's folder is often just "dataset": its description has the scene's name
    described = _load_json(dataset_dir / "dataset.json") if dataset_dir else None
    title = (described or {}).get("name") or (dataset_dir.name if dataset_dir else fit_dir.name)
    return [f"<h1>rjfit report: {html.escape(title)}</h1>",
            f"<p>Fit folder <code>{html.escape(str(fit_dir.resolve()))}</code>; data set "
            f"<code>{html.escape(str(dataset_dir))}</code>.</p>"]


def _validation_section(summary: dict, dataset_dir) -> list[str]:
    """The gate's result: the data set's own, or the file the fit was given (a read-only data set)."""
    validation_file = dataset_dir / "validation" / "validation.json" if dataset_dir else None
    recorded = (summary.get("validation") or {}).get("path")
    if isinstance(recorded, str) and recorded and not (validation_file and validation_file.is_file()):
        validation_file = Path(recorded)
    validation = _load_json(validation_file) if validation_file else None
    validation_dir = validation_file.parent if validation_file else None
    parts = ["<h2>Forward-model cross-check</h2>"]
    if not validation:
        return parts + ["<p>No validation found for this data set.</p>"]
    verdict = '<span class="pass">passed</span>' if validation.get("passed") else '<span class="fail">failed</span>'
    parts.append(f"<p>Closed form vs Mitsuba path tracer: {verdict}.</p>")
    parts.append(_key_values(validation, list(_VALIDATION_LABELS), _VALIDATION_LABELS))
    for name, caption in (("relative_error.png", "relative error"), ("unexplained_fraction.png",
                                                                    "unexplained fraction")):
        if (validation_dir / name).is_file():
            parts.append(_embed(validation_dir / name, caption))
    return parts


def _posterior_section(summary: dict) -> list[str]:
    """Warnings, the model posterior and the region tables."""
    parts = ["<h2>Segmentation and model posterior</h2>"]
    warnings = summary.get("warnings") or []
    if warnings:
        items = "".join(f"<li>{html.escape(w)}</li>" for w in warnings)
        parts.append(f'<div class="fail"><p>Warnings (convergence, model misfit and the numbers themselves): do not '
                     f"trust the summaries below until they are resolved.</p><ul>{items}</ul></div>")
    elif "warnings" in summary:
        parts.append('<p><span class="pass">Convergence checks passed</span> (split R-hat &le; 1.01, bulk and tail '
                     "ESS &ge; 100 per chain, the chains' model frequencies within 0.5 of each other in total "
                     "variation), and no number of the summary was flagged (region means inside their prior's central "
                     "99.9 % and their own 95 % intervals, no region without data, no binding model cap, no NaN "
                     "acceptance ratio).</p>")
    parts.append(_result_table(summary))
    model = region_fit_of(summary)
    parts += [f"<p>{html.escape(note)}</p>" for note in model.report_notes(summary)]
    model_posterior = summary.get("model_posterior") or {}
    if model_posterior:
        rows = "".join(f"<tr><td>{html.escape(str(k).replace(',', ', '))}</td><td>{_number(v, '.4f')}</td></tr>"
                       for k, v in sorted(model_posterior.items(), key=lambda kv: -kv[1])[:12])
        parts.append("<p>The change-point models the chains visited, most probable first: n<sub>u</sub> vectors cut "
                     "the rows, n<sub>v</sub> the columns.</p><table><tr><th>model (n<sub>u</sub>, n<sub>v</sub>)</th>"
                     f"<th>posterior probability</th></tr>{rows}</table>")
    materials = summary.get("materials_posterior") or {}
    if isinstance(materials, dict) and materials:
        rows = "".join(f"<tr><td>{html.escape(str(k))}</td><td>{_number(v, '.4f')}</td></tr>"
                       for k, v in sorted(materials.items(), key=lambda kv: -kv[1]) if isinstance(v, (int, float)))
        parts.append("<table><tr><th>number of materials K</th><th>posterior probability</th></tr>"
                     f"{rows}</table>")
    parts.append(f"<h2>Region parameters</h2><p>Posterior mean &plusmn; sd of each {model.noun}'s parameters, their central "
                 f"95 % interval below (the kept draws of all chains).</p>" + _region_table(summary))
    parts.append(_chain_region_tables(summary))
    parts.append(_effects_table(summary))
    return parts


def _settings_section(summary: dict) -> list[str]:
    """What the numbers above were computed with, in words: two fits of one data set can differ in these."""
    rows = "".join(f"<tr><td>{html.escape(name)}</td><td class='note'>{html.escape(str(value))}</td></tr>"
                   for name, value in fit_settings(summary))
    return ["<h3>Fit settings</h3><p>Every setting that shaped this fit (the command's options after the preset "
            f"filled those not given, and what was estimated before the chains ran).</p><table>{rows}</table>"]


def _chains_section(fit_dir: Path, summary: dict) -> list[str]:
    """Traces beside rank plots of the chains in ``chains.nc`` (:func:`rjfit.posterior.chain_figures.chain_figure`)."""
    import io

    import arviz        # ArviZ and matplotlib: only when a report is built

    from rjfit.plotting import pyplot
    from rjfit.posterior.chain_figures import chain_figure

    path = fit_dir / "chains.nc"
    if not path.is_file():
        return []
    try:
        figure = chain_figure(arviz.from_netcdf(str(path)), burn_in=summary.get("burn_in"))
    except (OSError, ValueError, KeyError) as error:       # a damaged or foreign file: say so, keep the report
        return [f'<p class="fail">chains.nc could not be drawn: {html.escape(str(error))}</p>']
    if figure is None:
        return []
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=90)
    pyplot().close(figure)
    return [_embed_bytes(buffer.getvalue(), "The chains in chains.nc: the log posterior and the parameters of the "
                         "first regions (materials), each chain in its own colour and line style; beside each trace, "
                         "the chains' rank histograms: chains that sample one distribution give flat histograms of "
                         "equal height, a chain stuck elsewhere one piled at an end.", "chains: traces and rank plots")]


def _derived_section(sub: str, title: str, command: str, folder: Path, fit_dir: Path, summary: dict) -> list[str]:
    """A diagnosis or comparison of this fit, with the figures its json names; a stale one is flagged, not shown."""
    payload = _load_json(folder / f"{sub}.json")
    if payload is None:
        if sub != "diagnosis":
            return []
        return [f"<h2>{title}</h2><p>Not run for this fit: <code>rjfit diagnose "
                f"{html.escape(str(fit_dir))}</code> finds where the model and the data disagree and "
                f"names the physical effect the model misses.</p>"]
    parts = [f"<h2>{title}</h2>"]
    made_from = payload.get("fit_id") if isinstance(payload, dict) else None
    if made_from and summary.get("fit_id") and made_from != summary["fit_id"]:
        return parts + [f'<p class="fail">The {sub} in <code>{html.escape(str(folder.resolve()))}</code> was made '
                        f"from another fit (fit id {html.escape(made_from)}, this one is "
                        f"{html.escape(summary['fit_id'])}), so it is not shown; run <code>{command} "
                        f"{html.escape(str(fit_dir))}</code> again.</p>"]
    parts += _derived_text(sub, payload, folder / f"{sub}.md")
    for name in _listed_figures(sub, payload):
        png = folder / name
        if Path(name).name != name or png.suffix.lower() != ".png":
            continue                # a figure of the folder is named by a plain PNG file name
        if png.is_file():
            parts.append(_embed(png, f"{sub}: {png.stem.replace('_', ' ')}"))
        else:
            parts.append(f'<p class="fail">Figure <code>{html.escape(name)}</code>, which {sub}.json names, is '
                         f"missing from <code>{html.escape(str(folder.resolve()))}</code>.</p>")
    return parts


def _derived_text(sub: str, payload, markdown: Path) -> list[str]:
    if sub == "diagnosis":
        named = payload.get("named_effects") or []
        if not markdown.is_file():
            return [f"<p>Named effects: {html.escape(', '.join(named) if named else 'none')}.</p>"]
        # diagnosis.md holds the gaps, the steps, every candidate's evidence and the skipped
        # ones; its title and image links are left out (the figures follow, embedded)
        lines = [line for line in markdown.read_text(encoding="utf-8").splitlines()
                 if not line.startswith("# ") and not line.startswith("![")]
        return [_markdown_to_html("\n".join(lines))]
    if isinstance(payload, list) or "methods" in payload:
        entries = payload if isinstance(payload, list) else payload["methods"]
        header = sorted({k for e in entries for k in e if not isinstance(e[k], (dict, list))})
        rows = "".join("<tr>" + "".join(f"<td>{_fmt(e.get(k))}</td>" for k in header) + "</tr>" for e in entries)
        return ["<table><tr>" + "".join(f"<th>{html.escape(k)}</th>" for k in header) + f"</tr>{rows}</table>"]
    if markdown.is_file():
        return [_markdown_to_html(markdown.read_text(encoding="utf-8"))]
    return []


_ROUND_COLUMNS = ("effects", "n_regions", "label_accuracy", "gap", "gap_simulated", "named", "revisions", "seconds")
#: each round's column in words (refine.json's keys)
_ROUND_HEADERS = {"effects": "effects sampled", "n_regions": "regions", "label_accuracy": "label accuracy",
                  "gap": "gap (misfit beyond noise)", "gap_simulated": "gap, Mitsuba simulation",
                  "named": "effects named", "revisions": "revisions", "seconds": "seconds"}


def _refine_section(folder: Path) -> list[str]:
    """The rounds of `rjfit refine` (its ``refine.json``) and their segmentations, if it ran."""
    refined = _load_json(folder / "refine.json")
    if not isinstance(refined, dict) or not isinstance(refined.get("rounds"), list):
        return []
    parts = ["<h2>Refinement (rjfit refine: fit again with the named effects)</h2>",
             f"<p>Named effects: {html.escape(', '.join(refined.get('named_effects') or []) or 'none')}; "
             f"{html.escape(str(refined.get('stopped', '')))}. Final fit <code>"
             f"{html.escape(str(refined.get('final_fit')))}</code>. The gaps are each round's fitted model on its own "
             f"MAP segmentation (diagnosis gap_plain, with the effects that fit sampled); label accuracy only with "
             f"ground truth.</p>"]
    for warning in refined.get("warnings") or []:
        parts.append(f'<p class="fail">{html.escape(str(warning))}</p>')
    parts += [f"<p>Round {t['round']} tried {html.escape(' + '.join(t['effects']))} with the regions: "
              f"{'kept' if t['kept'] else 'not kept'}, {html.escape(t['why'])}.</p>"
              for t in refined.get("trials") or []]
    header = "".join(f"<th>{_ROUND_HEADERS.get(name, name)}</th>" for name in ("round",) + _ROUND_COLUMNS)
    rows = []
    for index, record in enumerate(refined["rounds"]):
        cells = [str(index + 1)]
        for name in _ROUND_COLUMNS:
            value = record.get(name)
            if name == "revisions":             # the diagnosis' swaps and drops, in words
                value = [revision_text(revision) for revision in value or []]
            cells.append(html.escape(", ".join(value) or "none") if isinstance(value, list) else _fmt(value))
        rows.append("<tr>" + "".join(f"<td>{cell}</td>" for cell in cells) + "</tr>")
    parts.append(f"<table><tr>{header}</tr>{''.join(rows)}</table>")
    figure = folder / str(refined.get("segmentations") or "segmentations.png")
    if figure.is_file():
        parts.append(_embed(figure, "each round's MAP segmentation, the last on the right"))
    return parts
