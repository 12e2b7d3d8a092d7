"""Print the criticism table: hidden effect -> named effect, evidence, gap before and after.

Renders every hidden-effect data set of ``rjfit.render.hidden`` small (32 x 32, seeded),
runs the workflow on the truth segmentation with ALL candidates, and prints one row each;
then runs it on the measured DiLiGenT ball (one material: label 0 on the mask), subsampled to
keep the refits short (every 4th light, every 6th pixel of the mask's bounding box: adjacent
pixels of the subsampled image are 6 apart, where the ball's misfit is still smooth and the
noise still white, so the gap's noise estimate holds). The ball has no mesh: the candidates
that need Mitsuba features (interreflection, cast shadows) are skipped there, and the
posterior predictive rendering too.

    .venv/bin/python validation/criticism_table.py [OUT_DIR] [--only KIND,...] [--no-ball]
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rjfit.diagnose.workflow import diagnose  # noqa: E402
from rjfit.io import write_json_atomic  # noqa: E402
from rjfit.render.datasets import load_dataset
from rjfit.render.hidden import render_hidden  # noqa: E402

KINDS = ("clean", "ambient", "camera_response", "camera_sensor", "light_calibration", "interreflection",
         "cast_shadows", "fresnel", "fresnel_plugin", "masking", "ambient+light_calibration")
BALL = Path(__file__).resolve().parents[2] / "shared" / "data" / "diligent-ball"


def subsample(dataset, pixel_step=6, light_step=4):
    """A smaller view of a (directional-light) data set: every ``light_step``-th light, every
    ``pixel_step``-th pixel of the object's bounding box."""
    rows, cols = np.nonzero(dataset.object_mask)
    window = (slice(rows.min(), rows.max() + 1, pixel_step), slice(cols.min(), cols.max() + 1, pixel_step))
    lights = np.arange(0, dataset.n_lights, light_step)
    pick = lambda a: None if a is None else a[lights][:, window[0], window[1]]
    mask = dataset.object_mask[window]
    meta = dict(dataset.meta, resolution=list(mask.shape), subsampled={"pixel_step": pixel_step, "light_step": light_step})
    return dataclasses.replace(dataset, meta=meta, images=pick(dataset.images), normals=dataset.normals[window],
                               view_dirs=dataset.view_dirs[window],
                               positions=None if dataset.positions is None else dataset.positions[window],
                               visibility=pick(dataset.visibility), object_mask=mask,
                               lights=[dataset.lights[i] for i in lights], saturated=pick(dataset.saturated))


def row_of(name, result, seconds):
    steps = result["steps"]
    first = steps[0] if steps else None
    return {"hidden": name, "named": result["named_effects"],
            "log_bf": first["evidence"]["log_bayes_factor"] if first else None,
            "delta_loo": first["evidence"]["delta_elpd_loo"] if first else None,
            "delta_loo_se": first["evidence"]["delta_elpd_loo_se"] if first else None,
            "gap_before": first["gap_before"] if first else result["gap_plain"],
            "gap_after": first["gap_after"] if first else result["gap_final"],
            "gap_final": result["gap_final"], "best_rejected": _best_rejected(result), "seconds": round(seconds, 1)}


def _best_rejected(result):
    last_step = max((c["step"] for c in result["candidates"]), default=0)
    last = [c for c in result["candidates"] if c["step"] == last_step and "log_bayes_factor" in c]
    if not last:
        return None
    best = max(last, key=lambda c: c["log_bayes_factor"])
    return f"{best['effect']} ({best['log_bayes_factor']:.1f})"


def fmt(value, spec):
    return "-" if value is None else format(value, spec)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", nargs="?", default="runs/criticism", help="folder for the data sets and diagnoses")
    parser.add_argument("--only", default=None, help=f"comma-separated hidden effects, of: {', '.join(KINDS)}")
    parser.add_argument("--no-ball", action="store_true", help="leave out the measured DiLiGenT ball")
    parser.add_argument("--resolution", type=int, default=32, help="image size of the rendered data sets")
    args = parser.parse_args()
    out = Path(args.out)
    kinds = args.only.split(",") if args.only else KINDS
    rows = []
    for kind in kinds:
        started = time.perf_counter()
        path = render_hidden(kind, out / "data" / kind.replace("+", "_"), resolution=args.resolution)
        dataset = load_dataset(path)
        result = diagnose(dataset, dataset.truth_labels, out / "diagnosis" / kind.replace("+", "_"), seed=0,
                          simulate=(kind == "ambient+light_calibration"))
        rows.append(row_of(kind, result, time.perf_counter() - started))
        print(json.dumps(rows[-1]), flush=True)
    if not args.no_ball and BALL.is_dir():
        started = time.perf_counter()
        ball = subsample(load_dataset(BALL))
        labels = np.where(ball.object_mask, 0, -1)
        result = diagnose(ball, labels, out / "diagnosis" / "diligent_ball", seed=0, simulate=False)
        rows.append(row_of("diligent-ball (measured)", result, time.perf_counter() - started))
        rows[-1]["skipped"] = result["skipped"]
        rows[-1]["final_parameters"] = result["final_model"]["parameters"]
        print(json.dumps(rows[-1], default=str), flush=True)
    write_json_atomic(out / "criticism_table.json", rows)
    print()
    print("| hidden effect | named (in order) | log BF (step 1) | dLOO +- SE | gap before | gap after step 1 | final gap | "
          "best rejected at the end (log BF) | s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['hidden']} | {', '.join(r['named']) or 'none'} | {fmt(r['log_bf'], '.1f')} | "
              f"{fmt(r['delta_loo'], '.1f')} +- {fmt(r['delta_loo_se'], '.1f')} | {fmt(r['gap_before'], '.3g')} | "
              f"{fmt(r['gap_after'], '.3g')} | {fmt(r['gap_final'], '.3g')} | {r['best_rejected']} | {r['seconds']} |")


if __name__ == "__main__":
    main()
