"""Painted details on a real one-material stack: which ones a material fit finds, against the size it states.

Builds copies of ``../shared/data/psm-horse`` (8-bit, 12 lights, one material) with two discs of one
darker paint painted into every image (codes times ``--factor`` inside the discs: after the stack's
estimated response, kappa about 1.3, a quarter of the albedo at 0.35), far apart on the flank and
the head, fits each with ``validation/real_stacks.py``'s variant, and prints per fit: the K posterior,
how many pixels of each disc the MAP labels give a material other than the body's, and the size the
fit states (``summary.json["material_resolution"]``) rescaled to the discs' contrast.

    python validation/painted_details.py --radii 6 9 12 16 --out /tmp/painted      # about 2 min per fit

``--hue H`` paints discs that change hue, not the mean of R, G and B: inside them each image's red codes
gain ``H`` times the green codes and the green codes lose as much (less where red would pass 255), so the
channel mean a one-channel fit reads is unchanged (to the codes' rounding); fit them with
``--variant measured-rgb`` and ``--variant measured-mean`` to compare.

docs/results/materials.md ("Resolution") has the measured table.
"""
from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import imageio.v3 as iio
import numpy as np
from real_stacks import run

from rjfit.data.exr import read_exr
from rjfit.posterior.resolution import disc_radius
from rjfit.sampler.regions.materials.edges import EDGE_GAP

HORSE = Path(__file__).resolve().parents[2] / "shared" / "data" / "psm-horse"
#: the discs' centres (row, column in the full 340 x 512 images): on the flank and on the head, at least 18 px
#: inside the mask
CENTRES = ((180, 204), (119, 375))


def painted_stack(source: Path, folder: Path, radius: int, factor: float, hue: float | None = None) -> np.ndarray:
    """``folder``: ``source`` with the two discs' codes times ``factor`` in every image (or, with ``hue``, their
    hue changed, the mean of R, G and B kept: :func:`hue_shift`); returns the discs' map."""
    folder.mkdir(parents=True, exist_ok=True)
    mask = iio.imread(source / "mask.png")
    rows, cols = np.mgrid[0:mask.shape[0], 0:mask.shape[1]]
    discs = np.zeros(mask.shape[:2], np.uint8)
    for index, (r, c) in enumerate(CENTRES, start=1):
        discs[(rows - r) ** 2 + (cols - c) ** 2 <= radius ** 2] = index
    inside = (mask[..., 0] if mask.ndim == 3 else mask) > 0
    if np.any((discs > 0) & ~inside):
        raise ValueError(f"a disc of radius {radius} leaves the mask: use a radius of 16 or less")
    for path in sorted(source.iterdir()):
        if path.suffix == ".png" and path.name != "mask.png":
            image = iio.imread(path).astype(float)
            if hue is None:
                image[discs > 0] *= factor
                image = np.round(image)
            else:
                image[discs > 0] = hue_shift(image[discs > 0], hue)
            iio.imwrite(folder / path.name, np.clip(image, 0, 255).astype(np.uint8))
        elif path.is_file():
            shutil.copy(path, folder / path.name)
    (folder / "rjfit.json").write_text(json.dumps({"crop": True, "response": "unknown"}))
    return discs


def hue_shift(rgb: np.ndarray, hue: float) -> np.ndarray:
    """(N, 3) 8-bit codes with the red raised by ``hue`` times the green (at most to 255) and the green lowered by
    as much, rounded so that each pixel's R + G + B is kept exactly: a paint of another hue, of the same mean."""
    out = rgb.astype(float).copy()
    shift = np.round(np.minimum(hue * out[:, 1], 255.0 - out[:, 0]))
    out[:, 0] += shift
    out[:, 1] -= shift
    return out


def found_pixels(fit_folder: Path, discs: np.ndarray, crop: dict) -> list:
    """Per disc: its pixels that the MAP labels give a material other than the most common one (the body's)."""
    labels = read_exr(fit_folder / "labels.exr")
    labels = np.asarray(labels[next(iter(labels))] if isinstance(labels, dict) else labels)
    full = np.full(discs.shape, -1.0)
    full[crop["row0"]:crop["row0"] + labels.shape[0], crop["col0"]:crop["col0"] + labels.shape[1]] = labels
    values, counts = np.unique(full[full >= 0], return_counts=True)
    body = values[np.argmax(counts)]
    return [int(np.sum((discs == index) & (full >= 0) & (full != body))) for index in range(1, len(CENTRES) + 1)]


def at_contrast(resolution: dict, contrast: float, n_materials: int) -> float:
    """The stated radius for a paint of ``contrast`` times the albedo (the summary states it at its own), the edge
    term's earning per outline pair rescaled alike (``rjfit.posterior.resolution``)."""
    rescale = (1.0 - contrast) ** 2 / (1.0 - resolution["contrast"]) ** 2
    earning = resolution.get("edge_evidence_per_pair", 0.0) * rescale * EDGE_GAP
    return disc_radius(resolution["evidence_per_pixel"] * rescale, resolution["potts_beta"] - earning,
                       resolution["potts_rho"], n_materials)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--radii", type=int, nargs="+", default=[6, 9, 12, 16])
    parser.add_argument("--factor", type=float, default=0.35)
    parser.add_argument("--hue", type=float, default=None, help="paint discs of another hue, the mean kept")
    parser.add_argument("--variant", default="measured")
    parser.add_argument("--chains", type=int, default=4)
    parser.add_argument("--iterations", type=int, default=300)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--source", type=Path, default=HORSE)
    parser.add_argument("--out", type=Path, default=Path("runs/painted_details"))
    args = parser.parse_args(argv)
    for radius in args.radii:
        data = args.out / (f"horse_discs{radius}" if args.hue is None else f"horse_hue{args.hue:g}_discs{radius}")
        discs = painted_stack(args.source, data, radius, args.factor, args.hue)
        row = run(data, args.variant, args.chains, args.iterations, args.out, args.out / "table.jsonl", args.seed)
        summary = json.loads((Path(row["folder"]) / "summary.json").read_text())
        resolution = summary["material_resolution"]
        out = {"radius": radius, "disc_pixels": int(np.sum(discs == 1)), "variant": args.variant, "hue": args.hue,
               "likelihood_power": row["likelihood_power"], "posterior": row["posterior"],
               "chains_posterior": row["chains_posterior"], "seconds": row["seconds"],
               "found_pixels": found_pixels(Path(row["folder"]), discs, summary["crop"]),
               "stated_radius_half_albedo": resolution["radius_px"]}
        if args.hue is None:
            contrast = args.factor ** summary["calibration"]["response"]["kappa"]
            out.update(contrast=round(contrast, 3),
                       stated_radius_at_contrast=at_contrast(resolution, contrast, summary["map_materials"]))
        print(json.dumps(out))


if __name__ == "__main__":
    main()
