"""The one place figures are made and saved: headless pyplot, atomic PNG writes, map panels."""
from __future__ import annotations

from pathlib import Path

from rjfit.io import atomic_path

__all__ = ["pyplot", "save_figure", "pixel_axes", "map_figure", "exclusion_figure", "object_window", "zoom_to_object",
           "region_colours", "region_colormap", "label_image"]


def pyplot():
    """matplotlib.pyplot on the Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(figure, path, *, dpi=100, tight=False) -> Path:
    """Write ``figure`` to ``path`` as PNG atomically and close it.

    The PNG is written under a temporary name beside ``path``, flushed to disk and renamed
    (:func:`rjfit.io.atomic_path`): a failed or interrupted write leaves no temporary
    file and the previous ``path``, if any, as it was. The figure is closed either way.
    """
    path = Path(path)
    try:
        with atomic_path(path) as temporary:
            figure.savefig(temporary, format="png", dpi=dpi, bbox_inches="tight" if tight else None)
    finally:
        pyplot().close(figure)
    return path


def pixel_axes(axis) -> None:
    """Label an image panel's axes with the files' pixel coordinates (columns across, rows down)."""
    axis.set_xlabel("column (px)", fontsize=8)
    axis.set_ylabel("row (px)", fontsize=8)
    axis.tick_params(labelsize=7)


def object_window(mask, margin: int = 3):
    """The bounding box of ``mask``'s True pixels plus ``margin``, as (row slice, column slice) within the image.

    None when ``mask`` selects nothing. A map of a small object in a large frame (the
    DiLiGenT ball fills 2 % of its 612 x 512 images) is shown in this window, not lost in
    the frame.
    """
    import numpy as np

    rows, cols = np.nonzero(np.asarray(mask, bool))
    if rows.size == 0:
        return None
    height, width = np.shape(mask)
    return (slice(max(int(rows.min()) - margin, 0), min(int(rows.max()) + 1 + margin, height)),
            slice(max(int(cols.min()) - margin, 0), min(int(cols.max()) + 1 + margin, width)))


def zoom_to_object(axis, mask, margin: int = 3) -> None:
    """Limit an ``imshow`` axis to :func:`object_window` of ``mask`` (pixel coordinates stay those of the files)."""
    window = object_window(mask, margin)
    if window is None:
        return
    rows, cols = window
    axis.set_xlim(cols.start - 0.5, cols.stop - 0.5)
    axis.set_ylim(rows.stop - 0.5, rows.start - 0.5)       # image rows run downwards


def map_figure(path, image, title, cmap="viridis", vmin=None, vmax=None, *, dpi=100, unit="") -> Path:
    """One image with a colour bar and a title, saved with :func:`save_figure`; zoomed to its finite pixels.

    ``unit``: what the colour bar measures (its label); the axes are the files' pixel coordinates.
    """
    import numpy as np

    plt = pyplot()
    figure, axis = plt.subplots(figsize=(4.6, 4))
    shown = axis.imshow(image, cmap=cmap, vmin=vmin, vmax=vmax)
    zoom_to_object(axis, np.isfinite(image))                # maps are NaN off the object
    axis.set_title(title, fontsize=9)
    pixel_axes(axis)
    figure.colorbar(shown, ax=axis, fraction=0.046, label=unit)
    figure.tight_layout()
    return save_figure(figure, path, dpi=dpi)


EXCLUSION_TITLES = {"unlit": "light behind or grazing the surface", "grazing_view": "seen at a grazing angle (rim)",
                    "shadowed": "cast shadow (shadow rays)",
                    "saturated": "saturated (clipped)", "too_dark": "too dark (declared threshold)",
                    "not_finite": "NaN or Inf"}


def exclusion_figure(path, counts, object_mask, n_lights, *, dpi=100) -> Path:
    """The valid-images map (paper, Fig. 8) beside a map per rule that left observations out.

    Shows the object's bounding box. ``counts`` is
    :meth:`rjfit.data.dataset.Dataset.exclusion_counts`; a rule that left nothing out gets no
    panel, and each panel's title gives its total.
    """
    import numpy as np

    plt = pyplot()
    shown = [("valid", "valid images per pixel")] + [(name, title) for name, title in EXCLUSION_TITLES.items()
                                                    if counts[name][object_mask].any()]
    # the object's bounding box (plus a margin), so a small object is not lost in a large frame
    window = object_window(object_mask) or (slice(None), slice(None))
    figure, axes = plt.subplots(1, len(shown), figsize=(4.4 * len(shown), 4), squeeze=False)
    for axis, (name, title) in zip(axes[0], shown):
        image = np.where(object_mask, counts[name], np.nan)[window]
        # a rule's own scale (it may take one image in 96 from a few pixels), the valid count's 0..L
        top = n_lights if name == "valid" else max(int(np.nanmax(image)), 1)
        # the window drawn at the files' pixel coordinates (extent), so the axes' numbers are the files' rows, columns
        rows, cols = window
        extent = None if rows.start is None else (cols.start - 0.5, cols.stop - 0.5, rows.stop - 0.5, rows.start - 0.5)
        panel = axis.imshow(image, cmap="viridis" if name == "valid" else "magma", vmin=0, vmax=top,
                            interpolation="nearest", extent=extent)
        axis.set_title(f"{title}\n{int(counts[name][object_mask].sum()):,} of {n_lights * int(object_mask.sum()):,} "
                       f"observations", fontsize=9)
        pixel_axes(axis)
        figure.colorbar(panel, ax=axis, fraction=0.046, label="images (lights) per pixel")
    figure.tight_layout()
    return save_figure(figure, path, dpi=dpi)


def region_colours(n: int):
    """``n`` distinct RGB colours (n, 3) in [0, 1] for region labels 0 .. n - 1, the same in every label figure.

    The first ten are matplotlib's ``tab10``; each further one is the point of an RGB grid
    farthest from every colour chosen so far and from white (the background off the object),
    so no two regions share a colour however many there are (tested: at least 0.26 apart in
    RGB for up to 64 regions, where a ten-colour map repeats from the eleventh).
    """
    import math

    import numpy as np
    from matplotlib import colormaps

    chosen = [np.asarray(c, float) for c in colormaps["tab10"].colors[:n]]
    if n <= len(chosen):
        return np.array(chosen).reshape(n, 3)
    steps = max(16, math.ceil((n + 11) ** (1 / 3)) + 1)       # room for n colours besides white
    grid = np.linspace(0.0, 1.0, steps)
    candidates = np.stack(np.meshgrid(grid, grid, grid, indexing="ij"), axis=-1).reshape(-1, 3)
    nearest = np.linalg.norm(candidates - 1.0, axis=1)
    for colour in chosen:
        nearest = np.minimum(nearest, np.linalg.norm(candidates - colour, axis=1))
    while len(chosen) < n:
        pick = candidates[int(np.argmax(nearest))]
        chosen.append(pick)
        nearest = np.minimum(nearest, np.linalg.norm(candidates - pick, axis=1))
    return np.array(chosen)


def region_colormap(n: int):
    """A colormap and norm that draw labels 0 .. n - 1 in :func:`region_colours` (for ``imshow`` with a colour bar)."""
    import numpy as np
    from matplotlib.colors import BoundaryNorm, ListedColormap

    count = max(int(n), 1)
    return ListedColormap(region_colours(count)), BoundaryNorm(np.arange(count + 1) - 0.5, count)


def label_image(labels, n: int | None = None):
    """Labels (H, W) as an RGB image (H, W, 3) in :func:`region_colours`, white where a label is negative.

    ``n``: regions to colour for (default: the largest label + 1), so that figures of one fit
    agree on each region's colour.
    """
    import numpy as np

    labels = np.asarray(labels)
    count = int(labels.max()) + 1 if n is None and labels.size and labels.max() >= 0 else int(n or 0)
    rgb = np.ones(labels.shape + (3,))
    inside = labels >= 0
    if inside.any():
        rgb[inside] = region_colours(count)[labels[inside].astype(int)]
    return rgb
