"""Does each chain hold a paint? The share of a fit's kept label snapshots that give a paint a material of its own.

The paint's pixels are read from a reference fit (one whose MAP labels hold it): the largest connected part
of its smallest MAP material (psm-cat: the nose and mouth, 1,488 px in the mean-channel fit at seed 1). For
every chain of each fit named after it, over its kept snapshots (after the burn-in share), the share in which
at least 90 % of the paint's labelled pixels carry one material and that material is not the body's (the most
frequent one outside the paint). How docs/results/2026-11-28-paints.md and 2026-11-28-colour.md measured the
cat's nose.

    python validation/paint_share.py REFERENCE_FIT FIT [FIT ...] [--burn-in 0.2]
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from chain_labels import chain_label_snapshots
from scipy import ndimage

from rjfit.data.exr import read_exr

#: the share of the paint's pixels that must carry one material
AGREEMENT = 0.9


def paint_mask(reference: Path) -> np.ndarray:
    """(H, W) the largest connected part of the smallest MAP material of the ``reference`` fit."""
    labels = np.asarray(read_exr(reference / "labels.exr")["labels"]).squeeze()
    materials, counts = np.unique(labels[labels >= 0], return_counts=True)
    parts, n_parts = ndimage.label(labels == materials[np.argmin(counts)])
    sizes = ndimage.sum(np.ones_like(parts), parts, range(1, n_parts + 1))
    return parts == 1 + int(np.argmax(sizes))


def chain_shares(fit: Path, paint: np.ndarray, burn_in: float) -> list:
    """Per chain of ``fit``: the share of its kept snapshots whose paint pixels are one material, not the body's."""
    shares = []
    for snapshots in chain_label_snapshots(fit):
        kept = snapshots[int(len(snapshots) * burn_in):]
        held = 0
        for snapshot in kept:
            labels = np.nan_to_num(np.asarray(snapshot, float), nan=-1.0).astype(int)
            body = np.bincount(labels[(labels >= 0) & ~paint]).argmax()
            inside = labels[paint & (labels >= 0)]
            top = np.bincount(inside).argmax()
            held += bool(top != body and np.mean(inside == top) >= AGREEMENT)
        shares.append(held / max(len(kept), 1))
    return shares


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("reference", type=Path, help="a fit whose MAP labels hold the paint")
    parser.add_argument("fits", type=Path, nargs="+", help="material fits of the same stack")
    parser.add_argument("--burn-in", type=float, default=0.2, help="share of each chain's snapshots left out")
    args = parser.parse_args(argv)
    paint = paint_mask(args.reference)
    print(f"paint: {int(paint.sum())} px")
    for fit in args.fits:
        shares = chain_shares(fit, paint, args.burn_in)
        print(f"{fit}: {' / '.join(f'{share:.2f}' for share in shares)}")


if __name__ == "__main__":
    main()
