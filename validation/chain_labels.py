"""Every chain's last label snapshot of a material fit, side by side: does each chain hold the paint?

The fit's figures show the MAP labels of the pooled draws; a claim about "every chain" needs each
chain's own state. This reads ``materials.npz`` (every chain's label snapshots) and draws the last
snapshot of each chain, cropped to the object, its materials' pixel counts in the title.

Example::

    python validation/chain_labels.py runs/cat docs/figures/psm-cat-chains.png
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


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("fit", type=Path, help="a material fit's folder (with materials.npz)")
    parser.add_argument("out", type=Path, help="the PNG to write")
    args = parser.parse_args()
    print(draw(args.fit, args.out))


if __name__ == "__main__":
    main()
