"""The paper's figures as PNG (matplotlib, Agg backend).

- ``model_histogram.png``: posterior over model numbers (paper Fig. 2/5);
- ``traces.png``: parameter traces of the MAP model's regions, burn-in marked, each y axis spanning
  the kept draws (Fig. 3/6);
- ``changepoints.png``: change-point modes with 95 % bands and 2-D histograms (Fig. 7);
- ``reflectance.png``: posterior mean radiance, observed radiance and absolute error maps,
  averaged over lights (Fig. 1b, 4b/c);
- the material model's ``materials.png`` (the MAP material map, a distinct colour per
  material however many) and ``materials_histogram.png`` (the posterior over K).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from rjfit.plotting import label_image, pyplot, region_colormap, region_colours, save_figure, zoom_to_object
from rjfit.sampler.priors import PARAM_NAMES

__all__ = ["write_all", "model_histogram", "traces", "trace_figure", "kept_draw_limits", "changepoints", "reflectance",
           "material_map", "materials_histogram"]


def _plt():
    return pyplot()


def _save(fig, path):
    return str(save_figure(fig, path, dpi=110, tight=True))


def model_histogram(records, burn_in, max_v, path):
    plt = _plt()
    m = np.concatenate([r.n_u[burn_in:].astype(int) * (max_v + 1) + r.n_v[burn_in:] + 1 for r in records])
    values, counts = np.unique(m, return_counts=True)
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.bar(values, counts / counts.sum(), color="tab:blue")
    ax.set_xlabel("model number m = n_u (max_v + 1) + n_v + 1")
    ax.set_ylabel("posterior probability")
    ax.set_xticks(values)
    ax.set_title("Posterior over models")
    return _save(fig, path)


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
                ax.plot(series[-1], lw=0.4, alpha=0.8, label=f"chain {c}")
            limits = kept_draw_limits(series, burn_in)
            if limits is not None:
                ax.set_ylim(*limits)
            ax.axvline(burn_in, color="k", ls="--", lw=0.8)
            ax.ticklabel_format(axis="y", useOffset=False)      # I0 near 100 reads 100.02, not 0.02 + 1e2
            ax.tick_params(labelsize=7)
            if r == 0:
                ax.set_title(name, fontsize=9)
            if k == 0:
                ax.set_ylabel(f"region {r}", fontsize=9)
    axes[-1, 0].set_xlabel("iteration (dashed: end of burn-in)")
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
            axes[1].hist2d(U.reshape(len(U), -1, n_u).transpose(0, 2, 1).ravel(),
                           np.broadcast_to(rows + 0.5, U.transpose(0, 2, 1).shape).ravel(),
                           bins=[min(width + 2, 200), min(height, 200)], range=[[-1, width + 1], [0, height]], cmap="magma")
        if n_v:
            axes[2].hist2d(np.broadcast_to(cols + 0.5, V.transpose(0, 2, 1).shape).ravel(),
                           V.transpose(0, 2, 1).ravel(),
                           bins=[min(width, 200), min(height + 2, 200)], range=[[0, width], [-1, height + 1]], cmap="magma")
    axes[1].set_title("u change points: 2-D histogram (position, row)")
    axes[1].invert_yaxis()
    axes[2].set_title("v change points: 2-D histogram (column, position)")
    axes[2].invert_yaxis()
    return _save(fig, path)


def reflectance(labels, prediction, path):
    """Posterior mean radiance vs observed radiance, their absolute difference and the MAP labels, mean over lights.

    ``prediction`` is :func:`rjfit.posterior.summary.posterior_mean_prediction`: the
    radiance is averaged draw by draw, each draw with its own segmentation, not computed
    at pooled region means (which mix modes when chains disagree).
    """
    plt = _plt()
    fitted, observed, abs_err = prediction["radiance"], prediction["observed"], prediction["abs_error"]
    if "radiance_rgb" in prediction:        # a joint colour fit: the radiances in colour
        return _reflectance_colour(labels, prediction, path)
    fig, axes = plt.subplots(1, 4, figsize=(18, 4.2), layout="constrained")
    # fitted and observed share one colour scale, so equal colours mean equal radiance
    shared = dict(vmin=float(np.nanmin([np.nanmin(fitted), np.nanmin(observed)])),
                  vmax=float(np.nanmax([np.nanmax(fitted), np.nanmax(observed)])))
    for ax, img, title, scale in zip(axes[:3], (fitted, observed, abs_err),
                                     (f"posterior mean radiance (mean over lights; {prediction['draws']} draws)",
                                      "observed radiance", "absolute error |y - E[mu]|"), (shared, shared, {})):
        im = ax.imshow(img, cmap="viridis", **scale)
        ax.set_title(title, fontsize=9)
        fig.colorbar(im, ax=ax, shrink=0.85)
    shown = np.where(np.asarray(labels) >= 0, labels, np.nan)
    # one colour per region however many there are (a ten-colour map repeats from the eleventh)
    cmap, norm = region_colormap(int(np.nanmax(shown)) + 1 if np.isfinite(shown).any() else 1)
    im = axes[3].imshow(shown, cmap=cmap, norm=norm, interpolation="nearest")
    for ax in axes:
        zoom_to_object(ax, np.isfinite(observed) | np.isfinite(shown))
    axes[3].set_title("MAP labels", fontsize=9)
    regions = np.unique(np.asarray(labels)[np.asarray(labels) >= 0])
    colorbar = fig.colorbar(im, ax=axes[3], shrink=0.85, ticks=regions)
    colorbar.set_label("region")
    return _save(fig, path)


def _reflectance_colour(labels, prediction, path):
    """:func:`reflectance` of a joint colour fit: fitted and observed radiance as RGB images (one scale: the
    observed 99th percentile maps to white), the absolute error (channel mean) and the MAP labels."""
    plt = _plt()
    fitted, observed = prediction["radiance_rgb"], prediction["observed_rgb"]
    top = float(np.nanpercentile(observed, 99)) or 1.0
    fig, axes = plt.subplots(1, 4, figsize=(18, 4.2), layout="constrained")
    for ax, img, title in zip(axes[:2], (fitted, observed),
                              (f"posterior mean radiance, RGB (mean over lights; {prediction['draws']} draws)",
                               "observed radiance, RGB")):
        ax.imshow(np.clip(np.nan_to_num(img / top, nan=1.0), 0.0, 1.0))
        ax.set_title(title, fontsize=9)
    im = axes[2].imshow(prediction["abs_error"], cmap="viridis")
    axes[2].set_title("absolute error |y - E[mu]| (mean over channels)", fontsize=9)
    fig.colorbar(im, ax=axes[2], shrink=0.85)
    shown = np.where(np.asarray(labels) >= 0, labels, np.nan)
    cmap, norm = region_colormap(int(np.nanmax(shown)) + 1 if np.isfinite(shown).any() else 1)
    im = axes[3].imshow(shown, cmap=cmap, norm=norm, interpolation="nearest")
    for ax in axes:
        zoom_to_object(ax, np.isfinite(prediction["observed"]) | np.isfinite(shown))
    axes[3].set_title("MAP labels", fontsize=9)
    fig.colorbar(im, ax=axes[3], shrink=0.85, ticks=np.unique(np.asarray(labels)[np.asarray(labels) >= 0]))
    return _save(fig, path)


def material_map(labels, path):
    """The MAP material of every pixel as an image, one colour per material (white: unlabelled)."""
    plt = _plt()
    labels = np.asarray(labels)
    n_materials = int(labels.max()) + 1 if np.any(labels >= 0) else 0
    colours = region_colours(max(n_materials, 1))
    image = label_image(labels, n_materials)
    fig, ax = plt.subplots(figsize=(6, 5.4))
    ax.imshow(image, interpolation="nearest")
    ax.set_title(f"MAP materials ({n_materials})", fontsize=10)
    ax.set_xticks([])
    ax.set_yticks([])
    from matplotlib.patches import Patch

    ax.legend(handles=[Patch(color=colours[m], label=f"material {m}") for m in range(n_materials)],
              loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    return _save(fig, path)


def materials_histogram(posterior: dict, path):
    """The posterior over the number of materials K (``{"K": probability}``)."""
    plt = _plt()
    ks = sorted(int(k) for k in posterior)
    fig, ax = plt.subplots(figsize=(5, 3.2))
    ax.bar(ks, [posterior[str(k)] for k in ks], color="tab:blue")
    ax.set_xlabel("number of materials K")
    ax.set_ylabel("posterior probability")
    ax.set_xticks(ks)
    ax.set_title("Posterior over the number of materials")
    return _save(fig, path)


def write_all(folder, *, records, burn_in, model, labels, problem, prediction, max_v=3) -> dict:
    """Write every figure into ``folder``; returns name -> path."""
    folder = Path(folder)
    return {
        "model_histogram": model_histogram(records, burn_in, max_v, folder / "model_histogram.png"),
        "traces": traces(records, burn_in, model, folder / "traces.png"),
        "changepoints": changepoints(records, burn_in, model, problem.image_shape, folder / "changepoints.png"),
        "reflectance": reflectance(labels, prediction, folder / "reflectance.png"),
    }


