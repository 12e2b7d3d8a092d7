"""The figures of a diagnosis (PNG files in its folder), and which ones a ``diagnosis.json`` names.

The text of ``diagnosis.md`` and the terminal lines are :mod:`rjfit.diagnose.document`'s.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from rjfit.plotting import map_figure as _map_figure
from rjfit.plotting import pixel_axes, pyplot, zoom_to_object
from rjfit.plotting import save_figure as _save_figure

__all__ = ["save_figure", "residual_pair_figure", "per_light_figure", "posterior_figure", "map_figure",
           "signature_figure", "per_image_figure", "listed_figures", "step_figures", "signature_figures",
           "FIGURE_PATTERNS", "previous_results"]

#: names of the figures diagnose writes (``step{n}_{effect}_*.png``, ``signatures_step{n}.png``, the
#: Mitsuba simulation's): those of a previous diagnosis in the folder are removed by the next one
FIGURE_PATTERNS = ("step*_residuals.png", "step*_per_light.png", "step*_posteriors.png", "signatures_step*.png",
                   "mitsuba_residuals.png", "ppc_p_values.png", "mitsuba_per_image_*.png")


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
        pixel_axes(axis)
    figure.colorbar(shown, ax=axes, fraction=0.046, label=label + " (noise sd)")
    return save_figure(figure, path)


def per_light_figure(path, before, after, title):
    plt = _plt()
    lights = np.arange(len(before))
    figure, axis = plt.subplots(figsize=(6.4, 3.2))
    b = np.array([np.nan if v is None else v for v in before], dtype=float)
    a = np.array([np.nan if v is None else v for v in after], dtype=float)
    axis.bar(lights - 0.2, b, 0.4, label="before")
    axis.bar(lights + 0.2, a, 0.4, label="after")
    axis.set_xlabel("light (image index)")
    axis.set_ylabel("gap: misfit beyond the noise")
    axis.xaxis.get_major_locator().set_params(integer=True)     # lights are counted, not measured
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
        axis.set_xlabel("parameter value", fontsize=7)
        axis.set_ylabel("posterior density", fontsize=7)
        axis.tick_params(labelsize=7)
    axes.ravel()[0].legend(fontsize=7)
    figure.tight_layout()
    return save_figure(figure, path)


def map_figure(path, image, title, cmap="viridis", vmin=None, vmax=None, unit=""):
    return _map_figure(path, image, title, cmap=cmap, vmin=vmin, vmax=vmax, unit=unit).name


def signature_figure(path, residual, panels, title):
    """The mean standardised residual map next to candidate signature maps (same colours)."""
    plt = _plt()
    finite = residual[np.isfinite(residual)]
    limit = max(float(np.percentile(np.abs(finite), 99)) if finite.size else 1.0, 1e-6)
    # constrained layout: tight_layout cannot place a colorbar shared by a row (it warns and may clip it)
    figure, axes = plt.subplots(1, len(panels) + 1, figsize=(2.3 * (len(panels) + 1), 2.8), squeeze=False,
                                layout="constrained")
    for axis, (label, image) in zip(axes[0], [("residual", residual)] + list(panels)):
        shown = axis.imshow(image, cmap="RdBu_r", vmin=-limit, vmax=limit)
        zoom_to_object(axis, np.isfinite(residual))
        axis.set_title(label, fontsize=7)
        pixel_axes(axis)
    figure.colorbar(shown, ax=axes[0], fraction=0.046, label="standardised residual (noise sd)")
    figure.suptitle(title, fontsize=8)
    return save_figure(figure, path)


def per_image_figure(path, stack, title):
    """One panel per light of an (L, H, W) ``stack`` of standardised residuals (one colour range)."""
    plt = _plt()
    L = stack.shape[0]
    cols = min(L, 5)
    rows = int(math.ceil(L / cols))
    limit = max(float(np.nanpercentile(np.abs(stack), 99)), 1e-6)
    figure, axes = plt.subplots(rows, cols, figsize=(2.0 * cols, 2.0 * rows + 0.4), squeeze=False)
    for i, axis in enumerate(axes.ravel()):
        axis.axis("off")
        if i < L:
            shown = axis.imshow(stack[i], cmap="RdBu_r", vmin=-limit, vmax=limit)
            zoom_to_object(axis, np.isfinite(stack).any(axis=0))
            axis.set_title(f"light {i}", fontsize=7)
    if L:       # one colour range for every light: one bar, in units of the noise's sd
        figure.colorbar(shown, ax=axes, fraction=0.03, label="standardised residual (noise sd)")
    figure.suptitle(title + f" (colour range +-{limit:.2g}; panels: the object's pixels)", fontsize=9)
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


def step_figures(ctx, index, step_record, named, breakdowns, sigma2_hat, figure_dir):
    """A named step's figures (residuals before and after, gap per light, posteriors), their
    names entered in its record."""
    before, after, panels = named
    before_b, after_b = breakdowns
    tag = f"step{index + 1}_{step_record['effect']}"
    step_record["figures"]["residuals"] = residual_pair_figure(
        figure_dir / f"{tag}_residuals.png", ctx.per_pixel_mean(before) / math.sqrt(sigma2_hat),
        ctx.per_pixel_mean(after) / math.sqrt(sigma2_hat),
        f"before (gap {step_record['gap_before']:.3g})",
        f"after + {step_record['effect']} (gap {step_record['gap_after']:.3g})")
    step_record["figures"]["per_light"] = per_light_figure(
        figure_dir / f"{tag}_per_light.png", before_b["per_light"], after_b["per_light"],
        f"gap per light, step {index + 1}: + {step_record['effect']}")
    if panels:
        step_record["figures"]["posteriors"] = posterior_figure(figure_dir / f"{tag}_posteriors.png", panels)


def signature_figures(ctx, searched, signatures, sigma2_hat, figure_dir) -> list:
    """Per step searched (``searched``: the current model's residuals at each), the residual beside
    the five best-scoring candidates' signatures (``signatures``: (step, effect) -> (score, map))."""
    names = []
    for step, residuals in enumerate(searched):
        maps = sorted(((score, name, image) for (at_step, name), (score, image) in signatures.items()
                       if at_step == step), key=lambda t: -t[0])[:5]
        if maps:
            names.append(signature_figure(
                figure_dir / f"signatures_step{step + 1}.png", ctx.per_pixel_mean(residuals) / math.sqrt(sigma2_hat),
                [(f"{name}\nscore {score:.2f}", image) for score, name, image in maps],
                f"step {step + 1}: residual and what each missing effect would leave (fitted signature)"))
    return names


def previous_results(out_dir) -> list[str]:
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
        names |= {name for name in listed_figures(previous) if Path(name).name == name}
    return sorted(names)
