"""The measured default at scale: peak memory and time per iteration up to 2048 x 2048 x 12 lights.

For each size S, a synthetic photometric-stereo folder (what a scanner writes; rjfit did not
render it, so ``rjfit fit`` gives it the measured default: materials, the measured preset, the
edge term): a sphere filling an S x S frame (about 0.7 S^2 object pixels), one Lambert +
Blinn-Phong material with a painted disc at a quarter of its albedo, psm-horse's 12 light
directions, normals given with a 2 degree error, 8-bit PNG images. Then, in a fresh
subprocess each (so peak resident memory is that size's own), the command a user runs::

    rjfit fit FOLDER --allow-unvalidated --chains 1 --iterations N --seed 1

Printed side by side per size: object pixels, observations, wall time, the time before the
chain (loading, calibration, noise model, powers, the edge term), seconds per iteration (the
chain's own; the chain uses the machine's cores as ``--threads`` does by default), peak resident memory, and per-observation ratios to the smallest size (linear
scaling gives 1). Written to ``OUT/bench_measured_scale.json``.

    .venv/bin/python validation/bench_measured_scale.py OUT [--sizes 256 512 1024 2048] [--iterations 10]
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HORSE = Path(__file__).resolve().parents[2] / "shared" / "data" / "psm-horse"
NORMAL_ERROR_DEG = 2.0
ALBEDO, PAINT, SHININESS, SPECULAR = 0.7, 0.25, 30.0, 0.15


def write_stack(size: int, folder: Path, seed: int = 1) -> int:
    """The synthetic scanner folder of ``size`` (module docstring); returns its object pixels."""
    import cv2

    rng = np.random.default_rng(seed)
    directions = np.loadtxt(HORSE / "light_directions.txt")
    rows, cols = np.mgrid[0:size, 0:size].astype(np.float32)
    x, y = (cols - size / 2 + 0.5) / (0.47 * size), -(rows - size / 2 + 0.5) / (0.47 * size)
    mask = x * x + y * y < 0.97
    normals = np.zeros((size, size, 3), np.float32)
    normals[..., 0], normals[..., 1] = x, y
    normals[..., 2] = np.sqrt(np.clip(1 - x * x - y * y, 0, None))
    normals[~mask] = 0
    albedo = np.where((x - 0.3) ** 2 + (y - 0.2) ** 2 < 0.02, ALBEDO * PAINT, ALBEDO).astype(np.float32)
    folder.mkdir(parents=True, exist_ok=True)
    names = [f"{i + 1:03d}.png" for i in range(len(directions))]
    half = (directions + np.array([0, 0, 1.0])) / np.linalg.norm(directions + np.array([0, 0, 1.0]), axis=1,
                                                                  keepdims=True)
    for name, light, h in zip(names, directions, half):
        cos_ln = np.clip(normals @ light.astype(np.float32), 0, None)
        cos_hn = np.clip(normals @ h.astype(np.float32), 0, None)
        value = 220 * cos_ln * (albedo + SPECULAR * (SHININESS + 8) / 8 * cos_hn ** SHININESS)
        value = np.clip(value + rng.normal(0, 1.0, value.shape), 0, 255) * mask
        cv2.imwrite(str(folder / name), np.repeat(value.astype(np.uint8)[..., None], 3, axis=-1))
    # the given normals: the true ones off by about NORMAL_ERROR_DEG (sd of each tangent component, in radians)
    given = normals + rng.normal(0, np.radians(NORMAL_ERROR_DEG), normals.shape).astype(np.float32)
    given /= np.maximum(np.linalg.norm(given, axis=-1, keepdims=True), 1e-12)
    given[~mask] = 0
    np.save(folder / "normals.npy", given)
    cv2.imwrite(str(folder / "mask.png"), np.repeat((mask * 255).astype(np.uint8)[..., None], 3, axis=-1))
    (folder / "filenames.txt").write_text("".join(n + "\n" for n in names))
    np.savetxt(folder / "light_directions.txt", directions, fmt="%.6f")
    np.savetxt(folder / "light_intensities.txt", np.ones((len(names), 3)), fmt="%.4f")
    (folder / "rjfit.json").write_text(json.dumps({"response": "unknown"}))
    return int(mask.sum())


def one_size(folder: Path, out: Path, iterations: int) -> dict:
    """Run the user's command in this (fresh) process; its wall time, peak memory and the summary's figures."""
    from rjfit.cli import main

    started = time.perf_counter()
    code = main(["fit", str(folder), "--allow-unvalidated", "--chains", "1", "--iterations", str(iterations),
                 "--seed", "1", "--out", str(out)], standalone_mode=False)
    wall = time.perf_counter() - started
    summary = json.loads((out / "summary.json").read_text())
    chain = float(summary["chain_seconds"][0])
    return {"exit_code": code, "wall_s": wall, "chain_s": chain, "before_chain_s": wall - chain,
            "s_per_iteration": chain / iterations, "observations": int(summary["n_observations"]),
            "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 ** 2,
            "edge_power": summary.get("edge_power"), "likelihood_power": summary.get("likelihood_power"),
            "map_materials": summary.get("map_materials")}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out", type=Path)
    parser.add_argument("--sizes", type=int, nargs="+", default=[256, 512, 1024, 2048])
    parser.add_argument("--iterations", type=int, default=10)
    parser.add_argument("--one", nargs=3, metavar=("FOLDER", "OUT", "ITERATIONS"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.one:       # the child: one size in this process
        print(json.dumps(one_size(Path(args.one[0]), Path(args.one[1]), int(args.one[2]))))
        return 0
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for size in args.sizes:
        folder = args.out / f"stack_{size}"
        pixels = write_stack(size, folder)
        child = subprocess.run([sys.executable, __file__, str(args.out), "--one", str(folder),
                                str(args.out / f"fit_{size}"), str(args.iterations)],
                               capture_output=True, text=True, check=False)
        if child.returncode != 0:
            print(f"size {size}: the fit failed:\n{child.stderr[-2000:]}", file=sys.stderr)
            return 1
        rows.append({"size": size, "object_pixels": pixels, **json.loads(child.stdout.strip().splitlines()[-1])})
        write_table(args.out, rows, args.iterations)
    return 0


def write_table(out: Path, rows: list, iterations: int) -> None:
    base = rows[0]
    print(f"{'size':>6} {'object px':>10} {'obs':>11} {'wall s':>8} {'before s':>9} {'s/iter':>8} "
          f"{'peak GB':>8} {'s/iter per obs vs first':>24} {'GB per obs vs first':>20}")
    for row in rows:
        per_obs_time = row["s_per_iteration"] / row["observations"] / (base["s_per_iteration"] / base["observations"])
        per_obs_memory = row["peak_rss_gb"] / row["observations"] / (base["peak_rss_gb"] / base["observations"])
        print(f"{row['size']:>6} {row['object_pixels']:>10,} {row['observations']:>11,} {row['wall_s']:>8.1f} "
              f"{row['before_chain_s']:>9.1f} {row['s_per_iteration']:>8.3f} {row['peak_rss_gb']:>8.2f} "
              f"{per_obs_time:>24.2f} {per_obs_memory:>20.2f}")
    (out / "bench_measured_scale.json").write_text(json.dumps({"iterations": iterations, "rows": rows}, indent=1))


if __name__ == "__main__":
    sys.exit(main())
