"""Run every baseline on one data set, score it against the truth, and write the comparison.

:func:`compare_dataset` writes three files to ``out_dir``, together: they are written into a
staging folder inside it and published at once, ``comparison.json`` last (see
:func:`rjfit.io.publish`), so that the folder holds one comparison's files or none:

- ``comparison.json``: the settings, notes and one row per (method, k) with its metrics
  (see :func:`rjfit.baselines.metrics.segmentation_metrics`) and its runtime in seconds, and
  ``figures``, the names of the figures it comes with (what ``rjfit report`` embeds);
- ``comparison.md``: the same rows as a Markdown table, plus the notes;
- ``segmentations.png``: all segmentations side by side, truth first (like Figs. 9-11 of
  Lenoch et al. 2016), each coloured after the true region it is matched to.
"""
from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from rjfit.baselines import methods
from rjfit.baselines.metrics import BOUNDARY_TOLERANCE, relabel_to_truth, segmentation_metrics
from rjfit.io import atomic_path, publish, staging_dir, write_json_atomic
from rjfit.pipeline import fit_folder
from rjfit.render.datasets import load_dataset

__all__ = ["compare_dataset", "read_map_labels", "format_markdown", "METHODS", "MAP_LABEL_FILES", "RUNTIME_KEYS"]

#: method name -> (label in tables, values of k)
METHODS = {
    "kmeans": ("k-means (grey value per image)", range(4, 9)),
    "kmeans_multichannel": ("multichannel k-means (substitute, see notes)", range(4, 9)),
    "gmm_position": ("GMM (grey values + pixel position)", range(4, 9)),
    "normalized_cuts": ("normalized cuts (one image, + background)", range(5, 7)),
}
RJFIT = "rjfit_map"
#: file names of the MAP labels in a fit folder, tried in this order (rjfit/fit.py currently writes labels.exr)
MAP_LABEL_FILES = fit_folder.MAP_LABEL_FILES
#: keys of summary.json that may hold the fit's runtime in seconds, tried in this order
RUNTIME_KEYS = ("seconds", "runtime_seconds", "runtime_s", "wall_seconds", "elapsed_seconds", "fit_seconds")
#: the files of a comparison besides comparison.json (a new comparison replaces all of them)
RESULT_FILES = ("comparison.md", "segmentations.png")


def read_map_labels(fit_dir, mask) -> tuple[np.ndarray, dict]:
    """Read rjfit's MAP segmentation from a fit folder.

    Parameters
    ----------
    fit_dir : path
        Folder written by ``rjfit fit``: ``summary.json`` and ``map_labels.exr`` (or, failing
        that, ``labels.exr``; channel ``labels``: region index per pixel; off the object -1 or
        NaN, both accepted).
    mask : ndarray of bool, shape (H, W)
        The data set's object mask; pixels outside it become -1 whatever the file says.

    Returns
    -------
    labels : ndarray of int, shape (H, W)
        Region index on the object; -1 off it and wherever the file has -1.
    summary : dict
        The contents of ``summary.json`` ({} if it is missing).

    Raises
    ------
    FileNotFoundError
        If neither ``map_labels.exr`` nor ``labels.exr`` exists.
    ValueError
        As :func:`rjfit.pipeline.fit_folder.read_map_labels` and :func:`rjfit.pipeline.fit_folder.read_summary`
        (a damaged or hand-edited file; the message names it).
    """
    fit_dir = Path(fit_dir)
    labels = fit_folder.read_map_labels(fit_dir, mask)
    summary = fit_folder.read_summary(fit_dir) if (fit_dir / "summary.json").is_file() else {}
    return labels, summary


def _runtime_from(summary: dict):
    for key in RUNTIME_KEYS:
        value = summary.get(key)
        if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value):
            return float(value), key
    return None, None


def _import_libraries():
    import skimage.graph  # noqa: F401
    import skimage.segmentation  # noqa: F401
    import sklearn.cluster  # noqa: F401
    import sklearn.mixture  # noqa: F401


def format_markdown(rows, notes=()) -> str:
    """A Markdown table of comparison rows (and the notes as a list below it)."""
    def number(value, digits=3):
        return "n/a" if value is None else f"{value:.{digits}f}"

    lines = ["| method | k | pixel accuracy | ARI | boundary F1 (2 px) | boundary P / R | seconds |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for row in rows:
        lines.append(f"| {row['label']} | {row['k']} | {number(row['pixel_accuracy'])} | {number(row['ari'])} | "
                     f"{number(row['boundary_f1'])} | {number(row['boundary_precision'], 2)} / "
                     f"{number(row['boundary_recall'], 2)} | {number(row['seconds'], 2)} |")
    text = "\n".join(lines) + "\n"
    if notes:
        text += "\nNotes:\n\n" + "".join(f"- {note}\n" for note in notes)
    return text


def _panel_image(labels):
    from matplotlib import colormaps

    palette = colormaps["tab10"].colors + colormaps["Set3"].colors
    rgb = np.ones(labels.shape + (3,))
    for label in np.unique(labels[labels >= 0]):
        rgb[labels == label] = palette[int(label) % len(palette)]
    return rgb


def _write_figure(path: Path, truth, mask, panels, title):
    """panels: list of rows, each a list of (title, labels or None for a text-only panel, text)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    n_rows = len(panels)
    n_cols = max(len(row) for row in panels)
    figure = Figure(figsize=(2.3 * n_cols, 2.55 * n_rows))
    FigureCanvasAgg(figure)
    axes = figure.subplots(n_rows, n_cols, squeeze=False)
    for r, row in enumerate(panels):
        for c in range(n_cols):
            axis = axes[r][c]
            axis.set_xticks([])
            axis.set_yticks([])
            if c >= len(row):
                axis.set_axis_off()
                continue
            name, labels, text = row[c]
            if labels is None:
                axis.text(0.5, 0.5, text, ha="center", va="center", wrap=True, fontsize=8, transform=axis.transAxes)
            else:
                shown = labels if labels is truth else relabel_to_truth(truth, labels, mask)
                shown = np.where(mask, shown, -1)
                axis.imshow(_panel_image(shown), interpolation="nearest")
            axis.set_title(name, fontsize=8)
    figure.suptitle(title, fontsize=10)
    figure.tight_layout()
    with atomic_path(path) as temporary:
        figure.savefig(temporary, format="png", dpi=110)


def compare_dataset(dataset_dir, out_dir, *, fit_dir=None, seed: int = 0, channel: str = "mean",
                    progress=None) -> list[dict]:
    """Run k-means, multichannel k-means, GMM with positions and normalized cuts on a data set.

    Parameters
    ----------
    dataset_dir : path
        A data set with ground truth (``truth_labels``), e.g. from ``rjfit render``.
    out_dir : path
        Where ``comparison.json``, ``comparison.md`` and ``segmentations.png`` go (created).
    fit_dir : path, optional
        A folder written by ``rjfit fit`` (``summary.json``, ``map_labels.exr``); its MAP
        segmentation is scored too. Without it rjfit's row is left out, with a note.
    seed : int
        Every (method, k) run gets ``numpy.random.default_rng([seed, method index, k])``, so a
        run's labels do not depend on which other runs are made.
    channel : str
        Colour channel of the grey values (see ``Dataset.channel_values``); the multichannel
        k-means uses all three colour channels regardless.
    progress : callable, optional
        Called with a short message before each run (the CLI passes ``click.echo``).

    Returns
    -------
    list of dict
        One row per (method, k): ``method``, ``label``, ``k``, the metrics of
        :func:`~rjfit.baselines.metrics.segmentation_metrics`, ``seconds`` (wall-clock time of
        the method call; for rjfit, the fit's own runtime from ``summary.json`` if given) and
        ``note``.

    Raises
    ------
    ValueError
        If the data set has no ground truth, or ``fit_dir`` holds a fit of another data set.
    """
    dataset = load_dataset(dataset_dir)
    if dataset.truth_labels is None:
        raise ValueError(f"{dataset_dir}: has no truth_labels; the comparison needs a data set with ground "
                         f"truth (render one with `rjfit render SCENE --out DIR`)")
    truth, mask = dataset.truth_labels, dataset.object_mask & (dataset.truth_labels >= 0)
    # the fit is read and checked before any baseline runs, so a wrong --fit fails at once
    fit_labels, fit_summary = _fit_of(dataset, fit_dir, mask)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)      # an --out that cannot be written fails before the baselines run
    rows, segmentations, ncut = _run_baselines(dataset, channel, mask, truth, seed, progress)
    notes = _notes(dataset, mask, truth, channel, seed, ncut)
    if fit_dir is not None:
        seconds, key = _runtime_from(fit_summary)
        note = (f"runtime from summary.json['{key}']" if key else
                f"no runtime in summary.json (looked for {', '.join(RUNTIME_KEYS)})")
        metrics = segmentation_metrics(truth, fit_labels, mask)
        rows.append({"method": RJFIT, "label": "rjfit MAP (RJMCMC)", "k": metrics["n_clusters"], **metrics,
                     "seconds": seconds, "note": note})
        segmentations[(RJFIT, metrics["n_clusters"])] = fit_labels
        notes.append(f"rjfit MAP segmentation from {fit_dir}; {note}.")
    else:
        notes.append("rjfit MAP: no fit folder given (--fit FIT_DIR), so rjfit's row is left out.")
    payload = {"dataset": str(dataset.path), "resolution": list(mask.shape), "n_object_pixels": int(mask.sum()),
               "channel": channel, "seed": seed, "boundary_tolerance_px": BOUNDARY_TOLERANCE,
               "ncut_image": ncut[0], "notes": notes, "rows": rows, "fit_id": fit_summary.get("fit_id"),
               "figures": ["segmentations.png"]}
    with staging_dir(out_dir) as staging:
        _write_figure(staging / "segmentations.png", truth, mask, _panels(rows, segmentations, truth),
                      f"{dataset.path.name}: segmentations matched to the truth (colour = matched region)")
        (staging / "comparison.md").write_text("# Segmentation baselines\n\n" + format_markdown(rows, notes),
                                               encoding="utf-8")
        write_json_atomic(staging / "comparison.json", payload)
        publish(staging, out_dir, manifest="comparison.json", names=RESULT_FILES, remove=RESULT_FILES)
    return rows


def _fit_of(dataset, fit_dir, mask):
    """``(MAP labels, summary)`` of ``fit_dir`` checked to be a fit of ``dataset`` (None, {} without a fit)."""
    if fit_dir is None:
        return None, {}
    fit_labels, fit_summary = read_map_labels(fit_dir, mask)
    fitted = fit_summary.get("dataset")
    if not fitted or Path(fitted).resolve() != Path(dataset.path).resolve():
        unknown = ("an unknown data set (summary.json has no 'dataset' entry)" if fit_summary
                   else "an unknown data set (no summary.json)")
        raise ValueError(f"{fit_dir}: is a fit of {fitted or unknown}, not of "
                         f"{Path(dataset.path).resolve()}; compare a data set with its own fit")
    return fit_labels, fit_summary


def _run_baselines(dataset, channel, mask, truth, seed, progress):
    """Every (method, k) of :data:`METHODS`: rows, segmentations, and (image, valid pixels) normalized cuts used."""
    grey = dataset.channel_values(channel)
    ncut_index = methods.pick_ncut_image(dataset.valid_mask(channel))
    n_valid = int(dataset.valid_mask(channel)[ncut_index].sum())
    runners = {
        "kmeans": lambda k, rng: methods.kmeans_segmentation(grey, mask, k, rng=rng),
        "kmeans_multichannel": lambda k, rng: methods.multichannel_kmeans(dataset.images, mask, k, rng=rng),
        "gmm_position": lambda k, rng: methods.gmm_position_segmentation(grey, mask, k, rng=rng),
        "normalized_cuts": lambda k, rng: methods.normalized_cuts(grey[ncut_index], k, rng=rng),
    }
    _import_libraries()          # so that no method's runtime includes importing its library
    rows, segmentations = [], {}
    for index, (name, (label, ks)) in enumerate(METHODS.items()):
        for k in ks:
            if progress:
                progress(f"  {name} k={k}")
            start = time.perf_counter()
            labels = runners[name](k, np.random.default_rng([seed, index, k]))
            seconds = time.perf_counter() - start
            segmentations[(name, k)] = labels
            rows.append({"method": name, "label": label, "k": k, **segmentation_metrics(truth, labels, mask),
                         "seconds": seconds, "note": ""})
    return rows, segmentations, (ncut_index, n_valid)


def _notes(dataset, mask, truth, channel, seed, ncut) -> list[str]:
    ncut_index, n_valid = ncut
    return [
        f"Data set {dataset.path} ({mask.shape[1]} x {mask.shape[0]}, {int(mask.sum())} object pixels, "
        f"{int(np.unique(truth[mask]).size)} true regions, {dataset.n_lights} images), channel '{channel}', "
        f"seed {seed}. Metrics on object pixels only; clusters matched to regions by the Hungarian method, "
        f"surplus clusters count as errors. Boundary F1 at a {BOUNDARY_TOLERANCE:g}-pixel tolerance.",
        "multichannel k-means: Pichler and Hosticka (1995) could not be found or reconstructed; this row is a "
        "substitute (k-means on all 3 L colour channels, each standardised over the object), not their algorithm.",
        "GMM: full covariances over the L grey values plus row and column, each position coordinate standardised "
        "and scaled to the median standard deviation of the grey values.",
        f"normalized cuts: image {ncut_index} (the one with the most valid object pixels, {n_valid}), SLIC "
        f"superpixels, RAG of mean grey values (affinity exp(-d^2 sigma^-1), sigma = 1/255 on the image scaled "
        f"to [0, 1] by its 99th percentile: scikit-image's default for 8-bit images), recursive N-cut, then "
        f"adjacent segments merged by Ward's criterion until k remain; k includes the background segment.",
    ]


def _panels(rows, segmentations, truth):
    """The figure's rows of panels: truth, rjfit and normalized cuts first, then one row per other method."""
    def panel(row):
        return (f"{row['method']} k={row['k']}\nacc {row['pixel_accuracy']:.2f}  bF1 {row['boundary_f1']:.2f}",
                segmentations[(row["method"], row["k"])], "")

    first = [("truth", truth, "")]
    rjfit_rows = [row for row in rows if row["method"] == RJFIT]
    first += [panel(row) for row in rjfit_rows] or [("rjfit MAP", None, "no fit given\n(--fit FIT_DIR)")]
    first += [panel(row) for row in rows if row["method"] == "normalized_cuts"]
    return [first] + [[panel(row) for row in rows if row["method"] == name]
                      for name in METHODS if name != "normalized_cuts"]
