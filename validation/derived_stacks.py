"""Derived photometric-stereo folders from a shared one: a check that a default is not tuned to one stack.

Two derivations that keep the data real (no resampling of values: every pixel is one the camera recorded):

- ``sub OFFSET``: every second pixel in each direction, starting at row and column OFFSET (0 or 1): the same
  object at half the resolution, a quarter of the pixels, the same noise and codes;
- ``turn``: the images, mask and normal map turned by 180 degrees, with the x and y components of the normals
  and of the light directions negated: the same object upside down, which permutes the pixels and moves
  everything that depends on the position in the frame (the light field, tiles, starts).

The normal map (any name the loader reads) is written as ``normals.npy``; files other than the images, mask,
normal map and light directions are copied (``README.md`` is left out: the derived folder is not the source).

    python validation/derived_stacks.py ../shared/data/psm-cat /tmp/cat-turn turn
    python validation/derived_stacks.py ../shared/data/psm-cat /tmp/cat-sub1 sub 1
"""
from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import cv2
import numpy as np

from rjfit.data.diligent import DIRECTIONS
from rjfit.data.diligent_files import NORMAL_MAP_NAMES, find_normal_map, read_normal_map


def derive(array: np.ndarray, how: str, offset: int = 0) -> np.ndarray:
    """``array`` (H, W, ...) subsampled (``how="sub"``, from ``offset``) or turned by 180 degrees (``"turn"``)."""
    if how == "sub":
        return np.ascontiguousarray(array[offset::2, offset::2])
    if how == "turn":
        return np.ascontiguousarray(array[::-1, ::-1])
    raise ValueError(f"how must be 'sub' or 'turn', got {how!r}")


def turned_vectors(vectors: np.ndarray) -> np.ndarray:
    """Directions (..., 3) as the turned image sees them: x and y negated (a half turn about the view axis)."""
    turned = np.array(vectors, dtype=float, copy=True)
    turned[..., :2] *= -1.0
    return turned


def write_derived(source: Path, target: Path, how: str, offset: int = 0) -> int:
    """Write the derived folder; returns its mask's pixel count."""
    if not source.is_dir():
        raise SystemExit(f"{source}: no such folder")
    if offset not in (0, 1):
        raise SystemExit(f"offset must be 0 or 1, got {offset}")
    normals = derive(read_normal_map(find_normal_map(source, None)), how, offset)
    target.mkdir(parents=True, exist_ok=True)
    np.save(target / "normals.npy", (turned_vectors(normals) if how == "turn" else normals).astype(np.float32))
    for path in sorted(source.iterdir()):
        if path.suffix.lower() == ".png":
            # unchanged: 16-bit codes stay 16-bit (Pillow and imageio's default plugin keep 8 bits)
            cv2.imwrite(str(target / path.name), derive(cv2.imread(str(path), cv2.IMREAD_UNCHANGED), how, offset))
        elif path.name in NORMAL_MAP_NAMES:
            continue
        elif path.name == DIRECTIONS and how == "turn":
            np.savetxt(target / path.name, turned_vectors(np.loadtxt(path, ndmin=2)), fmt="%.6f")
        elif path.is_file() and path.name != "README.md":
            shutil.copy(path, target / path.name)
    mask = cv2.imread(str(target / "mask.png"), cv2.IMREAD_UNCHANGED)
    return int(np.count_nonzero((mask if mask.ndim == 2 else mask[..., 0]) > 127))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("source", type=Path)
    parser.add_argument("target", type=Path)
    parser.add_argument("how", choices=("sub", "turn"))
    parser.add_argument("offset", type=int, nargs="?", default=0, help="sub: the first row and column (0 or 1)")
    args = parser.parse_args()
    print(f"{args.target}: {write_derived(args.source, args.target, args.how, args.offset)} mask pixels")


if __name__ == "__main__":
    main()
