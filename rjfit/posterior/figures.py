"""The paper's figures as PNG (matplotlib, Agg backend).

- ``model_histogram.png``: posterior over model numbers (paper Fig. 2/5);
- ``traces.png``: parameter traces of the MAP model's regions, burn-in marked, each y axis spanning
  the kept draws (Fig. 3/6);
- ``changepoints.png``: change-point modes with 95 % bands and 2-D histograms (Fig. 7);
- ``reflectance.png``: posterior mean radiance, observed radiance and absolute error maps,
  averaged over lights (Fig. 1b, 4b/c);
- the material model's ``materials.png`` (the MAP material map, a distinct colour per
  material however many), ``materials_histogram.png`` (the posterior over K) and
  ``materials_extra.png`` (where the draws with more materials than the segmentation hold them).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from rjfit.plotting import (label_image, pixel_axes, pyplot, region_colormap, region_colours, save_figure,
                            zoom_to_object)
from rjfit.sampler.priors import PARAM_NAMES

#: a region parameter in words, with its unit
PARAMETER_TITLES = {"I0": "I0: intensity x albedo (image units)", "kd": "kd: diffuse fraction",
                    "gamma": "gamma: Blinn-Phong exponent", "sigma2": "sigma2: noise variance (image units^2)"}

__all__ = ["write_all", "model_histogram_figure", "reflectance_figure", "material_map_figure",
           "materials_histogram_figure", "PARAMETER_TITLES", "model_histogram", "traces", "trace_figure",
           "kept_draw_limits", "changepoints", "reflectance", "material_map", "materials_histogram",
           "extra_materials_map", "extra_materials_figure"]


def _plt():
    return pyplot()


def _save(fig, path):
    return str(save_figure(fig, path, dpi=110, tight=True))


def model_histogram(records, burn_in, max_v, path):
    return _save(model_histogram_figure(records, burn_in), path)


def model_histogram_figure(records, burn_in):
    """The posterior over the visited change-point models, each bar labelled by its (n_u, n_v)."""
    plt = _plt()
    models = np.concatenate([np.stack([r.n_u[burn_in:], r.n_v[burn_in:]], axis=1).astype(int) for r in records])
    visited, counts = np.unique(models, axis=0, return_counts=True)
    fig, ax = plt.subplots(figsize=(max(6, 0.7 * len(visited) + 2), 3.5))
    ax.bar(np.arange(len(visited)), counts / counts.sum(), color="tab:blue")
    ax.set_xticks(np.arange(len(visited)), [f"({u}, {v})" for u, v in visited])
    ax.set_xlim(-0.8, len(visited) - 0.2)          # one bar is a bar, not a plane
    ax.set_xlabel("change-point model (n_u, n_v): n_u vectors cut the rows, n_v the columns")
    ax.set_ylabel("posterior probability")
    ax.set_title("Posterior over change-point models")
    return fig


def kept_draw_limits(series, burn_in, margin=0.1):
    """y limits that show every kept draw of a trace: ``(low, high)``, or None without kept draws.

    ``series`` holds one 1-D trace per chain (NaN where the chain is in another model). The
    limits span the draws from ``burn_in`` on, widened by ``margin`` of their range on each
    side, so the kept draws fill a trace panel: scaled to the whole run, the burn-in's
    excursions (a dispersed start, the annealed warm-up) squeeze the kept draws into a flat
    line and hide how they mix.
    """
    kept = np.concatenate([np.asarray(s, float)[burn_in:] for s in series]) if len(series) else np.empty(0)
    kept = kept[np.isfinite(kept)]
    if kept.size == 0:
        return None
    low, high = float(kept.min()), float(kept.max())
    pad = margin * (high - low) or max(abs(high), 1.0) * 1e-6     # constant draws: a visible band around them
    return low - pad, high + pad


def traces(records, burn_in, model, path):
    return _save(trace_figure(records, burn_in, model), path)


def trace_figure(records, burn_in, model):
    """The figure of :func:`traces` (not saved): one row of panels per region of ``model``, one column per parameter."""
    plt = _plt()
    R = (model[0] + 1) * (model[1] + 1)
    # constrained layout keeps the overall title above the panel titles (a plain suptitle covers them)
    fig, axes = plt.subplots(R, 4, figsize=(14, 1.8 * R + 0.8), squeeze=False, sharex=True, layout="constrained")
    for r in range(R):
        for k, name in enumerate(PARAM_NAMES):
            ax = axes[r, k]
            series = []
            for c, rec in enumerate(records):
                in_model = (rec.n_u == model[0]) & (rec.n_v == model[1])
                series.append(np.where(in_model, rec.theta[:, r, k], np.nan))
                # a colour and a line style per chain: overplotted, the last chain would hide the others
                ax.plot(series[-1], lw=0.5, alpha=0.8, ls=("-", "--", ":", "-.")[c % 4], label=f"chain {c}")
            limits = kept_draw_limits(series, burn_in)
            if limits is not None:
                ax.set_ylim(*limits)
            ax.axvline(burn_in, color="k", ls="--", lw=0.8)
            ax.ticklabel_format(axis="y", useOffset=False)      # I0 near 100 reads 100.02, not 0.02 + 1e2
            ax.tick_params(labelsize=7)
            if r == 0:
                ax.set_title(PARAMETER_TITLES.get(name, name), fontsize=9)
            if k == 0:
                ax.set_ylabel(f"region {r}: value", fontsize=9)
    for ax in axes[-1]:
        ax.set_xlabel("iteration (black dashed: end of burn-in)")
    axes[0, -1].legend(fontsize=7, loc="upper right")
    fig.suptitle(f"Traces of the MAP model {model}; each y axis spans the kept draws "
                 "(burn-in excursions beyond them are cut off)")
    return fig


def changepoints(records, burn_in, model, image_shape, path):
    plt = _plt()
    n_u, n_v = model
    height, width = image_shape
    us, vs = [], []
    for rec in records:
        keep = [s for s in np.flatnonzero(rec.cp_iteration >= burn_in)
                if rec.n_u[rec.cp_iteration[s]] == n_u and rec.n_v[rec.cp_iteration[s]] == n_v]
        if keep:
            us.append(rec.cp_u[keep][:, :, :n_u])
            vs.append(rec.cp_v[keep][:, :, :n_v])
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5))
    ax = axes[0]
    ax.set_xlim(-1, width + 1)
    ax.set_ylim(height + 1, -1)
    ax.set_title("change-point modes and 95 % bands")
    if us:
        U, V = np.concatenate(us), np.concatenate(vs)
        rows, cols = np.arange(height), np.arange(width)
        for k in range(n_u):
            med, lo, hi = (np.quantile(U[:, :, k], q, axis=0) for q in (0.5, 0.025, 0.975))
            ax.plot(med, rows + 0.5, color="tab:red", lw=1)
            ax.fill_betweenx(rows + 0.5, lo, hi, color="tab:red", alpha=0.3)
        for k in range(n_v):
            med, lo, hi = (np.quantile(V[:, :, k], q, axis=0) for q in (0.5, 0.025, 0.975))
            ax.plot(cols + 0.5, med, color="tab:blue", lw=1)
            ax.fill_between(cols + 0.5, lo, hi, color="tab:blue", alpha=0.3)
        if n_u:
            *_, image = axes[1].hist2d(U.reshape(len(U), -1, n_u).transpose(0, 2, 1).ravel(),
                                       np.broadcast_to(rows + 0.5, U.transpose(0, 2, 1).shape).ravel(),
                                       bins=[min(width + 2, 200), min(height, 200)],
                                       range=[[-1, width + 1], [0, height]], cmap="magma")
            fig.colorbar(image, ax=axes[1], label="count over kept snapshots")
        if n_v:
            *_, image = axes[2].hist2d(np.broadcast_to(cols + 0.5, V.transpose(0, 2, 1).shape).ravel(),
                                       V.transpose(0, 2, 1).ravel(), bins=[min(width, 200), min(height + 2, 200)],
                                       range=[[0, width], [-1, height + 1]], cmap="magma")
            fig.colorbar(image, ax=axes[2], label="count over kept snapshots")
    axes[1].set_title("u change points: 2-D histogram (position, row)")
    axes[1].invert_yaxis()
    axes[2].set_title("v change points: 2-D histogram (column, position)")
    axes[2].invert_yaxis()
    for ax in axes:
        pixel_axes(ax)
    axes[1].set_xlabel("u change point: column where it cuts the row (px)", fontsize=8)
    axes[2].set_ylabel("v change point: row where it cuts the column (px)", fontsize=8)
    return _save(fig, path)


def reflectance(labels, prediction, path):
    """:func:`reflectance_figure`, saved to ``path``."""
    return _save(reflectance_figure(labels, prediction), path)


def reflectance_figure(labels, prediction):
    """Posterior mean radiance vs observed radiance, their absolute difference and the MAP labels, mean over lights.

    ``prediction`` is :func:`rjfit.posterior.summary.posterior_mean_prediction`: the
    radiance is averaged draw by draw, each draw with its own segmentation, not computed
    at pooled region means (which mix modes when chains disagree).
    """
    plt = _plt()
    fitted, observed, abs_err = prediction["radiance"], prediction["observed"], prediction["abs_error"]
    if "radiance_rgb" in prediction:        # a joint colour fit: the radiances in colour
        return _reflectance_colour(labels, prediction)
    fig, axes = plt.subplots(1, 4, figsize=(18, 4.4), layout="constrained")
    # fitted and observed share one colour scale, so equal colours mean equal radiance
    shared = dict(vmin=float(np.nanmin([np.nanmin(fitted), np.nanmin(observed)])),
                  vmax=float(np.nanmax([np.nanmax(fitted), np.nanmax(observed)])))
    for ax, img, title, scale in zip(axes[:3], (fitted, observed, abs_err),
                                     (f"posterior mean radiance\n(mean over lights; {prediction['draws']} draws)",
                                      "observed radiance\n(mean over lights)",
                                      "absolute error |y - E[mu]|\n(mean over lights)"),
                                     (shared, shared, {})):
        im = ax.imshow(img, cmap="viridis", **scale)
        ax.set_title(title, fontsize=9)
        fig.colorbar(im, ax=ax, shrink=0.85, label="radiance (image units)")
    _labels_panel(fig, axes[3], labels)
    for ax in axes:
        zoom_to_object(ax, np.isfinite(observed) | (np.asarray(labels) >= 0))
        pixel_axes(ax)
    return fig


def _labels_panel(fig, ax, labels):
    """The MAP labels with a colour bar of integer region ticks, one colour per region however many."""
    shown = np.where(np.asarray(labels) >= 0, labels, np.nan)
    cmap, norm = region_colormap(int(np.nanmax(shown)) + 1 if np.isfinite(shown).any() else 1)
    im = ax.imshow(shown, cmap=cmap, norm=norm, interpolation="nearest")
    ax.set_title("MAP labels", fontsize=9)
    regions = np.unique(np.asarray(labels)[np.asarray(labels) >= 0])
    fig.colorbar(im, ax=ax, shrink=0.85, ticks=regions, label="region (material)")


def _reflectance_colour(labels, prediction):
    """:func:`reflectance_figure` of a joint colour fit: fitted and observed radiance as RGB images (one scale: the
    observed 99th percentile maps to white), the absolute error (channel mean) and the MAP labels."""
    plt = _plt()
    fitted, observed = prediction["radiance_rgb"], prediction["observed_rgb"]
    top = float(np.nanpercentile(observed, 99)) or 1.0
    fig, axes = plt.subplots(1, 4, figsize=(18, 4.4), layout="constrained")
    for ax, img, title in zip(axes[:2], (fitted, observed),
                              (f"posterior mean radiance, RGB\n(mean over lights; {prediction['draws']} draws)",
                               f"observed radiance, RGB\n(white: {top:.3g} image units)")):
        ax.imshow(np.clip(np.nan_to_num(img / top, nan=1.0), 0.0, 1.0))
        ax.set_title(title, fontsize=9)
    im = axes[2].imshow(prediction["abs_error"], cmap="viridis")
    axes[2].set_title("absolute error |y - E[mu]| (mean over channels)", fontsize=9)
    fig.colorbar(im, ax=axes[2], shrink=0.85, label="radiance (image units)")
    _labels_panel(fig, axes[3], labels)
    for ax in axes:
        zoom_to_object(ax, np.isfinite(prediction["observed"]) | (np.asarray(labels) >= 0))
        pixel_axes(ax)
    return fig


def material_map(labels, path):
    """:func:`material_map_figure`, saved to ``path``."""
    return _save(material_map_figure(labels), path)


def material_map_figure(labels):
    """The MAP material of every pixel as an image, one colour per material (white: unlabelled)."""
    plt = _plt()
    labels = np.asarray(labels)
    n_materials = int(labels.max()) + 1 if np.any(labels >= 0) else 0
    colours = region_colours(max(n_materials, 1))
    image = label_image(labels, n_materials)
    fig, ax = plt.subplots(figsize=(6, 5.4))
    ax.imshow(image, interpolation="nearest")
    ax.set_title(f"MAP materials ({n_materials})", fontsize=10)
    zoom_to_object(ax, labels >= 0)
    pixel_axes(ax)
    from matplotlib.patches import Patch

    pixels = np.bincount(labels[labels >= 0].astype(int), minlength=n_materials)
    ax.legend(handles=[Patch(color=colours[m], label=f"material {m} ({pixels[m]:,} px)") for m in range(n_materials)],
              loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    return fig


def materials_histogram(posterior: dict, path):
    """:func:`materials_histogram_figure`, saved to ``path``."""
    return _save(materials_histogram_figure(posterior), path)


def materials_histogram_figure(posterior: dict):
    """The posterior over the number of materials K (``{"K": probability}``), one integer tick per K."""
    plt = _plt()
    ks = sorted(int(k) for k in posterior)
    fig, ax = plt.subplots(figsize=(5, 3.2))
    ax.bar(ks, [posterior[str(k)] for k in ks], color="tab:blue")
    ax.set_xlabel("number of materials K")
    ax.set_ylabel("posterior probability")
    ax.set_xticks(ks)
    ax.set_xlim(min(ks) - 0.8, max(ks) + 0.8)       # one bar is a bar, not a plane
    ax.set_ylim(0, 1.05)
    ax.set_title("Posterior over the number of materials")
    return fig


def extra_materials_map(share, labels, path):
    """:func:`extra_materials_figure`, saved to ``path``."""
    return _save(extra_materials_figure(share, labels), path)


def extra_materials_figure(share, labels):
    """Each pixel's share of the kept label snapshots that hold it in a material beyond the segmentation's number
    (``share``, H x W, NaN off the labelled pixels: :func:`rjfit.posterior.caveats.extra_materials`), over
    the segmentation's outlines (``labels``), zoomed to the object."""
    plt = _plt()
    share = np.asarray(share, float)
    labels = np.asarray(labels)
    fig, ax = plt.subplots(figsize=(6, 5.4))
    top = float(np.nanmax(share)) if np.any(np.isfinite(share)) else 0.0
    image = ax.imshow(np.ma.masked_invalid(share), cmap="magma_r", vmin=0.0, vmax=max(top, 1e-12),
                      interpolation="nearest")
    if labels.max(initial=-1) > 0:          # the segmentation's outlines, where it holds more than one material
        ax.contour(labels, levels=np.arange(labels.max()) + 0.5, colors="tab:cyan", linewidths=0.6)
    ax.set_title("Where other draws hold extra materials", fontsize=10)
    colour_bar = fig.colorbar(image, ax=ax, fraction=0.046, pad=0.04)
    colour_bar.set_label("share of the kept snapshots")
    zoom_to_object(ax, labels >= 0)
    pixel_axes(ax)
    return fig


def write_all(folder, *, records, burn_in, model, labels, problem, prediction, max_v=3) -> dict:
    """Write every figure into ``folder``; returns name -> path."""
    folder = Path(folder)
    return {
        "model_histogram": model_histogram(records, burn_in, max_v, folder / "model_histogram.png"),
        "traces": traces(records, burn_in, model, folder / "traces.png"),
        "changepoints": changepoints(records, burn_in, model, problem.image_shape, folder / "changepoints.png"),
        "reflectance": reflectance(labels, prediction, folder / "reflectance.png"),
    }


