"""Every chain's last label snapshot of a material fit, side by side: does each chain hold the paint?

The fit's figures show the MAP labels of the pooled draws; a claim about "every chain" needs each
chain's own state. This reads ``materials.npz`` (every chain's label snapshots) and draws the last
snapshot of each chain, cropped to the object, its materials' pixel counts in the title.

With ``--over IMAGE`` it draws instead, over that image of the stack, where each chain's materials other than its
largest lie in its last snapshot (a colour per chain, each marked pixel ringed so that one pixel shows): a
one-material object's extra materials of a few pixels are invisible in the side-by-side panels.

With ``--pieces FOLDER`` (the stack's folder of numbered PNGs) it prints each such connected piece of 2 px or more,
its place, and under every light the mean of its pixels over the mean of a ring around it (2 to 4 px out, on the
object): near one under every light, the piece looks like its surroundings; the same factor under every light, a
change of albedo; a factor under some lights only, shading (a cast shadow, a highlight). Then, as a control, the
median over every kept snapshot's pieces of their largest contrast against the same pieces moved at random on the
object: do they sit where the images differ more than anywhere?

Example::

    python validation/chain_labels.py runs/cat docs/figures/psm-cat-chains.png
    python validation/chain_labels.py runs/horse docs/figures/psm-horse-extras.png --over ../shared/data/psm-horse/001.png
    python validation/chain_labels.py runs/horse docs/figures/psm-horse-extras.png --over ../shared/data/psm-horse/001.png \
        --pieces ../shared/data/psm-horse
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def chain_label_snapshots(fit: Path) -> list:
    """Each chain's label snapshots (S, H, W; NaN off the object) from ``materials.npz``, in chain order."""
    with np.load(fit / "materials.npz") as files:
        names = sorted((name for name in files.files if name.endswith("_material_labels")),
                       key=lambda name: int(name[len("chain"):].split("_")[0]))
        return [files[name] for name in names]


def chain_snapshots(fit: Path) -> list:
    """Each chain's last label snapshot (H, W; -1 off the object), in chain order."""
    return [np.nan_to_num(np.asarray(snapshots[-1], float), nan=-1.0) for snapshots in chain_label_snapshots(fit)]


def draw(fit: Path, out: Path) -> Path:
    """Draw :func:`chain_snapshots` of ``fit`` into ``out`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    snapshots = chain_snapshots(fit)
    figure, axes = plt.subplots(1, len(snapshots), figsize=(3.2 * len(snapshots), 3.4), squeeze=False)
    for chain, (labels, ax) in enumerate(zip(snapshots, axes[0])):
        rows, cols = np.nonzero(labels >= 0)
        sizes = [int(np.sum(labels == k)) for k in range(int(labels.max()) + 1)]
        ax.imshow(np.where(labels >= 0, labels, np.nan), cmap="tab10", vmin=0, vmax=9, interpolation="nearest")
        ax.set_xlim(cols.min() - 0.5, cols.max() + 0.5)
        ax.set_ylim(rows.max() + 0.5, rows.min() - 0.5)
        ax.set_title(f"chain {chain}: {len(sizes)} materials\n{sorted(sizes, reverse=True)} px", fontsize=8)
        ax.set_xticks([]), ax.set_yticks([])
    figure.suptitle(f"{fit.name}: each chain's last label snapshot", fontsize=9)
    figure.tight_layout()
    figure.savefig(out, dpi=90)
    plt.close(figure)
    return out


def extra_pixels(labels) -> np.ndarray:
    """(H, W) bool: the pixels of ``labels`` (-1 off the object) in any material but the largest."""
    labelled = labels >= 0
    if not labelled.any():
        return labelled
    largest = np.argmax(np.bincount(labels[labelled].astype(np.int64)))
    return labelled & (labels != largest)


def draw_extras(fit: Path, image: Path, out: Path) -> Path:
    """Draw over ``image`` (a PNG of the stack) each chain's :func:`extra_pixels` of its last snapshot into ``out``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from PIL import Image

    picture = np.asarray(Image.open(image).convert("L"), float)
    snapshots = chain_snapshots(fit)
    if picture.shape != snapshots[0].shape:
        raise ValueError(f"{image}: {picture.shape[1]} x {picture.shape[0]} px, but the fit's labels are "
                         f"{snapshots[0].shape[1]} x {snapshots[0].shape[0]}; give an image of the fitted stack")
    rows, cols = np.nonzero(snapshots[0] >= 0)
    figure, ax = plt.subplots(figsize=(8, 8 * (np.ptp(rows) + 1) / max(np.ptp(cols) + 1, 1) + 0.6))
    ax.imshow(picture, cmap="gray", interpolation="nearest")
    colours = plt.get_cmap("tab10")
    for chain, labels in enumerate(snapshots):
        extra_rows, extra_cols = np.nonzero(extra_pixels(labels))
        ax.scatter(extra_cols, extra_rows, s=30, facecolors="none", edgecolors=[colours(chain)], linewidths=0.8,
                   label=f"chain {chain}: {extra_rows.size} px")
    ax.set_xlim(cols.min() - 5.5, cols.max() + 5.5)
    ax.set_ylim(rows.max() + 5.5, rows.min() - 5.5)
    ax.set_xticks([]), ax.set_yticks([])
    ax.legend(fontsize=8, loc="lower right")
    ax.set_title(f"{fit.name}: each chain's materials other than its largest, last snapshot", fontsize=9)
    figure.tight_layout()
    figure.savefig(out, dpi=90)
    plt.close(figure)
    return out


def stack_images(folder: Path) -> np.ndarray:
    """(L, H, W) the ``folder``'s numbered PNGs (001.png, ...), grey.

    Raises
    ------
    ValueError
        If the folder holds no numbered PNG.
    """
    from PIL import Image

    files = sorted(folder.glob("[0-9][0-9][0-9].png"))
    if not files:
        raise ValueError(f"{folder}: no numbered PNG images (001.png, ...); give the stack's folder")
    return np.stack([np.asarray(Image.open(file).convert("L"), float) for file in files])


def contrast(images, piece, labels) -> np.ndarray:
    """(L,) the mean of ``images`` over ``piece`` (H, W bool) over their mean on its ring: the pixels 2 to 4 px
    (8-neighbour steps) outside it on the object (``labels`` >= 0, :func:`rjfit.posterior.contrast.ring`); NaN where
    the ring is empty."""
    from rjfit.posterior.contrast import ring as piece_ring

    ring = piece_ring(piece, labels >= 0)
    if not ring.any():
        return np.full(images.shape[0], np.nan)
    return images[:, piece].mean(axis=1) / np.maximum(images[:, ring].mean(axis=1), 1e-12)


def pieces(labels) -> list:
    """The connected pieces (8-neighbours) of 2 px or more of ``labels``' :func:`extra_pixels`, each (H, W) bool."""
    from scipy import ndimage

    parts, n = ndimage.label(extra_pixels(labels), structure=np.ones((3, 3)))
    sizes = np.bincount(parts.ravel(), minlength=n + 1)
    return [parts == part for part in range(1, n + 1) if sizes[part] >= 2]


def piece_contrasts(fit: Path, folder: Path) -> list:
    """Per chain, per piece of its last snapshot (:func:`pieces`): ``(chain, pixels, (row, column) centre,
    ratios)``, ``ratios`` the piece's :func:`contrast` in the ``folder``'s images (module docstring)."""
    images = stack_images(folder)
    rows = []
    for chain, labels in enumerate(chain_snapshots(fit)):
        for piece in pieces(labels):
            centre = tuple(round(c) for c in np.argwhere(piece).mean(axis=0))
            rows.append((chain, int(piece.sum()), centre, contrast(images, piece, labels)))
    return rows


def placement_control(fit: Path, folder: Path, seed: int = 0, placements: int = 20, every: int = 5) -> list:
    """Per chain with pieces: ``(chain, n_pieces, held, moved)``, the median over its pieces of the largest
    ``|log contrast|`` over the lights, in every ``every``-th snapshot after the first fifth (``held``), and the same
    of each piece moved ``placements`` times by a random shift (up to 150 px, ``seed``) to where every pixel of it
    lies on the object (``moved``): do the pieces sit where the images differ from their surroundings more than
    anywhere?"""
    images = stack_images(folder)
    rng = np.random.default_rng(seed)
    out = []
    for chain, snapshots in enumerate(chain_label_snapshots(fit)):
        held, moved = [], []
        for snapshot in snapshots[len(snapshots) // 5::every]:
            labels = np.nan_to_num(np.asarray(snapshot, float), nan=-1.0)
            for piece in pieces(labels):
                held.append(_largest_log_contrast(images, piece, labels))
                moved += [_largest_log_contrast(images, shifted, labels)
                          for shifted in _shifted(piece, labels >= 0, rng, placements)]
        if held:
            out.append((chain, len(held), float(np.nanmedian(held)), float(np.nanmedian(moved))))
    return out


def _largest_log_contrast(images, piece, labels) -> float:
    ratios = contrast(images, piece, labels)
    with np.errstate(divide="ignore"):      # a piece black under a light: an infinite contrast, the largest
        return float(np.max(np.abs(np.log(ratios)))) if np.all(np.isfinite(ratios)) else np.nan


def _shifted(piece, inside, rng, count: int):
    rows, cols = np.nonzero(piece)
    for _ in range(count):
        for _ in range(1000):
            dr, dc = rng.integers(-150, 151, 2)
            r, c = rows + dr, cols + dc
            if (r.min() >= 0 and c.min() >= 0 and r.max() < inside.shape[0] and c.max() < inside.shape[1]
                    and inside[r, c].all()):
                shifted = np.zeros_like(piece)
                shifted[r, c] = True
                yield shifted
                break


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("fit", type=Path, help="a material fit's folder (with materials.npz)")
    parser.add_argument("out", type=Path, help="the PNG to write")
    parser.add_argument("--over", type=Path, help="an image of the stack (PNG): draw each chain's materials other "
                                                  "than its largest over it instead")
    parser.add_argument("--pieces", type=Path, help="the stack's folder: print each chain's pieces other than its "
                                                    "largest material and their contrast to their surroundings")
    args = parser.parse_args()
    print(draw(args.fit, args.out) if args.over is None else draw_extras(args.fit, args.over, args.out))
    if args.pieces is None:
        return
    for chain, pixels, centre, ratios in piece_contrasts(args.fit, args.pieces):
        print(f"chain {chain}: {pixels} px at {centre}; over its ring, per light: "
              + " ".join(f"{r:.2f}" for r in ratios))
    for chain, count, held, moved in placement_control(args.fit, args.pieces):
        print(f"chain {chain}: {count} pieces over its kept snapshots, median largest |log contrast| {held:.2f}; "
              f"the same pieces moved at random on the object {moved:.2f}")


if __name__ == "__main__":
    main()
