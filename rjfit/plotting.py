"""The one place figures are made and saved: headless pyplot, atomic PNG writes, map panels."""
from __future__ import annotations

from pathlib import Path

from rjfit.atomic import atomic_path

__all__ = ["pyplot", "save_figure", "map_figure"]


def pyplot():
    """matplotlib.pyplot on the Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(figure, path, *, dpi=100, tight=False) -> Path:
    """Write ``figure`` to ``path`` as PNG atomically and close it.

    The PNG is written under a temporary name beside ``path``, flushed to disk and renamed
    (:func:`rjfit.atomic.atomic_path`): a failed or interrupted write leaves no temporary
    file and the previous ``path``, if any, as it was. The figure is closed either way.
    """
    path = Path(path)
    try:
        with atomic_path(path) as temporary:
            figure.savefig(temporary, format="png", dpi=dpi, bbox_inches="tight" if tight else None)
    finally:
        pyplot().close(figure)
    return path


def map_figure(path, image, title, cmap="viridis", vmin=None, vmax=None, *, dpi=100) -> Path:
    """One image with a colour bar and a title, saved with :func:`save_figure`."""
    plt = pyplot()
    figure, axis = plt.subplots(figsize=(4.6, 4))
    shown = axis.imshow(image, cmap=cmap, vmin=vmin, vmax=vmax)
    axis.set_title(title, fontsize=9)
    axis.axis("off")
    figure.colorbar(shown, ax=axis, fraction=0.046)
    figure.tight_layout()
    return save_figure(figure, path, dpi=dpi)
