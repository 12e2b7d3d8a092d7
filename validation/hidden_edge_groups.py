"""Material fits of hidden-effect stacks: the posterior over K beside the edge-supported groups' posterior.

Every hidden effect that the forward model leaves out (ambient light, an sRGB camera response, a
light 15 % off its calibration, cast shadows, interreflection: :mod:`rjfit.render.hidden`) is a
misfit that can buy materials. This script renders each case (Mitsuba, ``--resolution`` px),
fits it with ``--regions materials`` at the defaults for rendered data (no preset; the gate is
skipped, since a hidden effect fails it by design) and prints, per case, the true number of
materials, the posterior over K, and ``edge_groups_posterior``: the same snapshots' materials
joined where they meet without a step in the data (:mod:`rjfit.posterior.boundaries`). Writes
one JSON line per fit to ``--table``.

    .venv/bin/python validation/hidden_edge_groups.py OUT_DIR [--cases ambient,clean] [--resolution 48]
                     [--chains 4] [--iterations 400] [--seed 1] [--table OUT_DIR/table.jsonl]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rjfit.pipeline.fit_dataset import fit_dataset  # noqa: E402
from rjfit.render.datasets import load_dataset  # noqa: E402
from rjfit.render.hidden import render_hidden  # noqa: E402

CASES = ("clean", "ambient", "camera_response", "camera_sensor", "light_calibration", "cast_shadows",
         "interreflection")


def run(case: str, out: Path, resolution: int, chains: int, iterations: int, seed: int) -> dict:
    data_dir = out / case / "data"
    if not (data_dir / "dataset.json").exists():
        render_hidden(case, data_dir, resolution=resolution, seed=seed)
    dataset = load_dataset(data_dir)
    truth = dataset.truth_labels
    true_k = None if truth is None else int(np.unique(truth[dataset.object_mask & (truth >= 0)]).size)
    started = time.perf_counter()
    summary = fit_dataset(data_dir, out / case / "fit", regions="materials", n_chains=chains, iterations=iterations,
                          seed=seed, allow_unvalidated=True, figures=False, progress=False)
    return {"case": case, "resolution": resolution, "chains": chains, "iterations": iterations, "seed": seed,
            "true_materials": true_k, "materials_posterior": summary["materials_posterior"],
            "edge_groups_posterior": summary.get("edge_groups_posterior"),
            "chain_edge_groups_posterior": summary.get("chain_edge_groups_posterior"),
            "label_accuracy": summary.get("label_accuracy"), "seconds": time.perf_counter() - started}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--cases", default=",".join(CASES))
    parser.add_argument("--resolution", type=int, default=48)
    parser.add_argument("--chains", type=int, default=4)
    parser.add_argument("--iterations", type=int, default=400)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--table", type=Path)
    args = parser.parse_args(argv)
    table = args.table or args.out / "table.jsonl"
    args.out.mkdir(parents=True, exist_ok=True)
    for case in args.cases.split(","):
        row = run(case, args.out, args.resolution, args.chains, args.iterations, args.seed)
        with open(table, "a") as handle:
            handle.write(json.dumps(row) + "\n")
        top = lambda p: ", ".join(f"{k}: {v:.2f}" for k, v in list((p or {}).items())[:3])  # noqa: E731
        print(f"{case:18s} true {row['true_materials']}  K {top(row['materials_posterior']):28s} edge groups "
              f"{top(row['edge_groups_posterior']):20s} {row['seconds']:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
