"""psm-rock pebble by pebble: does every chain put each bright pebble in the pebble material?

Issue 45's row "psm-rock: every bright pebble of >= 200 px in the pebble material, every chain". The pebbles are
read from the stack itself, not from a fit: each pixel's Lambertian albedo (the mean channel, least squares over
the lights that face it by n.l > 0.2, the given normals) and its saturation (max - min of its RGB albedo's
chromaticity); the pebbles are grey-green on a brown matrix, so a pebble pixel is both brighter and greyer than the
object's mean: ``z(albedo) - z(saturation) > threshold`` (z over the mask), opened by one pixel, connected parts of
at least 200 px. At the default threshold of 2 sd the parts are the compact pebbles one sees in the images; at
1.5 lighter patches of the matrix join them (the page reports both).

For every chain of each fit, over its kept label snapshots (``materials.npz``, after the burn-in share): the
pebble material is the material of most of the largest pebble's pixels, the matrix's the most frequent one off
every pebble; a pebble is held in a snapshot when the pebble material is not the matrix's and carries at least half
of the pebble's pixels. Printed: each pebble's share of held snapshots per chain.

    python validation/rock_pebbles.py FIT [FIT ...] [--data ../shared/data/psm-rock] [--figure PNG]
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from chain_labels import chain_label_snapshots
from scipy import ndimage

from rjfit.data.loading import read_dataset

#: the smallest pebble the issue's row counts (pixels)
MIN_PIXELS = 200
#: lights at a grazing angle carry little albedo and much normal error
MIN_SHADING = 0.2
#: the share of a pebble's pixels the pebble material must carry
HELD = 0.5


def pebble_score(data: Path) -> tuple:
    """(score, albedo, mask), each (H, W): ``z(albedo) - z(saturation)`` and the mean channel's albedo (see above)."""
    dataset = read_dataset(data)
    mask = dataset.object_mask
    directions = np.array([light.direction for light in dataset.lights])
    shading = np.einsum("hwc,lc->lhw", dataset.normals, directions)
    weight = np.where(shading > MIN_SHADING, shading, 0.0)
    images = np.nan_to_num(dataset.images.astype(float))
    albedo_rgb = (images * weight[..., None]).sum(0) / np.maximum((weight * shading).sum(0), 1e-9)[..., None]
    albedo = albedo_rgb.mean(-1)
    chromaticity = albedo_rgb / np.maximum(albedo_rgb.sum(-1, keepdims=True), 1e-9)
    saturation = chromaticity.max(-1) - chromaticity.min(-1)
    z = lambda values: (values - values[mask].mean()) / values[mask].std()
    return z(albedo) - z(saturation), albedo, mask


def pebble_parts(score: np.ndarray, mask: np.ndarray, threshold: float) -> np.ndarray:
    """(H, W) int: 0 off every pebble, 1.. the pebbles (parts of ``score > threshold``) by falling size."""
    pebble = ndimage.binary_opening(mask & (score > threshold))
    parts, n_parts = ndimage.label(pebble)
    sizes = ndimage.sum(pebble, parts, range(1, n_parts + 1))
    order = [index + 1 for index in np.argsort(-sizes) if sizes[index] >= MIN_PIXELS]
    numbered = np.zeros(mask.shape, int)
    for number, part in enumerate(order, start=1):
        numbered[parts == part] = number
    return numbered


def chain_shares(fit: Path, pebbles: np.ndarray, burn_in: float) -> list:
    """Per chain of ``fit``: per pebble, the share of kept snapshots that hold it in the pebble material."""
    shares = []
    for snapshots in chain_label_snapshots(fit):
        if snapshots.shape[1:] != pebbles.shape:
            raise ValueError(f"{fit}: label snapshots of {snapshots.shape[1:]} px, the stack's {pebbles.shape}: "
                             f"pass the data set the fit read (--data)")
        kept = snapshots[int(len(snapshots) * burn_in):]
        held = np.zeros(int(pebbles.max()))
        for snapshot in kept:
            labels = np.nan_to_num(np.asarray(snapshot, float), nan=-1.0).astype(int)
            matrix = np.bincount(labels[(labels >= 0) & (pebbles == 0)]).argmax()
            material = np.bincount(labels[(pebbles == 1) & (labels >= 0)]).argmax()
            for number in range(1, int(pebbles.max()) + 1):
                inside = labels[(pebbles == number) & (labels >= 0)]
                held[number - 1] += bool(material != matrix and np.mean(inside == material) >= HELD)
        shares.append(held / max(len(kept), 1))
    return shares


def draw(albedo: np.ndarray, mask: np.ndarray, pebbles: np.ndarray, out: Path) -> None:
    """The pebbles' outlines, numbered, over the albedo, cropped to the object."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows, cols = np.nonzero(mask)
    figure, ax = plt.subplots(figsize=(6, 4.2))
    ax.imshow(np.where(mask, albedo, np.nan), cmap="gray", interpolation="nearest")
    for number in range(1, int(pebbles.max()) + 1):
        ax.contour(pebbles == number, [0.5], colors="tab:red", linewidths=0.8)
        row, col = ndimage.center_of_mass(pebbles == number)
        ax.text(col, row, str(number), color="tab:red", fontsize=9, ha="center", va="center")
    ax.set_xlim(cols.min() - 0.5, cols.max() + 0.5)
    ax.set_ylim(rows.max() + 0.5, rows.min() - 0.5)
    ax.set_xticks([]), ax.set_yticks([])
    ax.set_title(f"psm-rock: pebbles of >= {MIN_PIXELS} px over the albedo", fontsize=9)
    figure.tight_layout()
    figure.savefig(out, dpi=100)
    plt.close(figure)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("fits", type=Path, nargs="+", help="material fits of psm-rock (with materials.npz)")
    parser.add_argument("--data", type=Path, default=Path("../shared/data/psm-rock"), help="the stack the fits read")
    parser.add_argument("--threshold", type=float, default=2.0, help="z(albedo) - z(saturation) of a pebble pixel")
    parser.add_argument("--burn-in", type=float, default=0.2, help="share of each chain's snapshots left out")
    parser.add_argument("--figure", type=Path, default=None, help="a PNG of the numbered pebbles")
    args = parser.parse_args(argv)
    score, albedo, mask = pebble_score(args.data)
    pebbles = pebble_parts(score, mask, args.threshold)
    sizes = [int(np.sum(pebbles == number)) for number in range(1, int(pebbles.max()) + 1)]
    print(f"pebbles at {args.threshold} sd: " + ", ".join(f"{n}: {size} px" for n, size in enumerate(sizes, 1)))
    if args.figure:
        draw(albedo, mask, pebbles, args.figure)
    for fit in args.fits:
        for chain, shares in enumerate(chain_shares(fit, pebbles, args.burn_in)):
            print(f"{fit} chain {chain}: " + " / ".join(f"{share:.2f}" for share in shares))


if __name__ == "__main__":
    main()
