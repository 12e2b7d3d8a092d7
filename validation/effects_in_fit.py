"""Effects inside the fit (issue 26): a plain fit against a fit with the true effect named, on hidden-effect stacks.

For each case, renders the hidden-effect data set of :mod:`rjfit.render.hidden` (Mitsuba
built-ins where it has them), fits it twice with ``rjfit fit`` (the Python API:
:func:`rjfit.pipeline.fit_dataset.fit_dataset`, ``--allow-unvalidated`` since a hidden effect
fails the cross-check by design): plain, and with the true effect named (``--effects``;
interreflection through ``--effects-from`` a diagnosis folder this script writes, naming the
effect and the plain fit, whose region parameters the indirect-light feature is rendered
at). Prints and writes (``OUT/effects_in_fit.json``) per fit: the regions holding object
pixels in the MAP segmentation, the true count, the label accuracy, the effect parameter's
posterior against its true value, the gap and the seconds.

The gap here is the criticism's definition (:mod:`rjfit.diagnose.gap`) with a plug-in mean:
the posterior means of the region and effect parameters on the MAP segmentation, through the
extended closed form (:func:`rjfit.diagnose.model.fit_prediction`); the noise variance from
second differences of each fit's own residuals (``rjfit diagnose`` uses the final model's for
every gap of a data set, and the posterior mean of the prediction).

    .venv/bin/python validation/effects_in_fit.py OUT_DIR [--only CASE,...] [--resolution 64]
                     [--chains 2] [--iterations 1000]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rjfit.diagnose.context import build_context  # noqa: E402
from rjfit.effects import EFFECTS  # noqa: E402
from rjfit.diagnose.gap import gap, noise_variance  # noqa: E402
from rjfit.diagnose.model import fit_prediction, predict  # noqa: E402
from rjfit.io import write_json_atomic  # noqa: E402
from rjfit.effects.camera_srgb import srgb_encode  # noqa: E402
from rjfit.pipeline.fit_dataset import fit_dataset  # noqa: E402
from rjfit.pipeline.fit_folder import read_map_labels  # noqa: E402
from rjfit.render.datasets import load_dataset  # noqa: E402
from rjfit.render.hidden import AMBIENT_RELATIVE, CALIBRATED_LIGHT, CALIBRATION_ERROR, SRGB_WHITE, render_hidden  # noqa: E402

#: case -> (hidden kind, effect named)
CASES = {"clean": ("clean", "ambient"), "ambient": ("ambient", "ambient"),
         "light_calibration": ("light_calibration", "light_calibration"),
         "camera_srgb": ("camera_response", "camera_srgb"), "camera_srgb_sensor": ("camera_sensor", "camera_srgb"),
         "cast_shadows": ("cast_shadows", "cast_shadows"),
         "interreflection": ("interreflection", "interreflection")}


def truth(case, dataset) -> dict:
    """The effect's true parameter values, as the fit's summary names them (with how each was derived)."""
    if case in ("clean", "ambient"):
        return {"ambient": 0.0 if case == "clean" else AMBIENT_RELATIVE}
    if case == "light_calibration":
        n = dataset.n_lights
        scales = np.ones(n)
        scales[CALIBRATED_LIGHT] = CALIBRATION_ERROR
        return {"light_gains": (scales / np.exp(np.mean(np.log(scales)))).tolist()}
    if case in ("camera_srgb", "camera_srgb_sensor"):
        # W = 1.05 x the brightest linear value; the fit's white level is the brightest stored (encoded) value,
        # about W sRGB(1 / 1.05) before the read noise: white_rel ~ 1 / sRGB(1 / 1.05)
        return {"white_rel": float(1.0 / srgb_encode(1.0 / SRGB_WHITE)), "note": "approximate (read noise on the max)"}
    if case == "cast_shadows":
        return {"w_shadow": 1.0}
    return {"beta": 1.0}


def plug_in_gap(dataset, fit_dir, summary, effect_name):
    """The gap of a fit at its posterior means on its MAP segmentation (module docstring)."""
    labels = read_map_labels(fit_dir, dataset.object_mask)
    ctx = build_context(dataset, labels)
    regions = {int(r.get("region", i)): r for i, r in enumerate(summary["regions"])}
    first = [int(np.flatnonzero(ctx.labels.ravel() == k)[0]) for k in range(ctx.n_regions)]
    params = np.array([[regions[int(label)][name]["mean"] for name in ("I0", "kd", "gamma", "sigma2")]
                       for label in labels.ravel()[first]])
    if effect_name is None:
        mean = predict(ctx, (), params, (), ())
    else:
        effect = EFFECTS[effect_name]
        entry = next(e for e in summary["effects"] if e["name"] == effect_name)
        theta = [p["mean"] for p in entry["parameters"]]
        if effect_name == "interreflection":
            ctx.features["fit_region_params"] = params
        mean = fit_prediction(ctx, [effect], params, [theta])
    residuals = ctx.y - mean
    sigma2 = noise_variance(ctx, residuals)
    return gap(residuals, sigma2)


def row(case, kind, dataset, fit_dir, summary, effect_name, seconds):
    held = [r for r in summary["regions"] if r.get("pixels", 1) > 0]
    out = {"case": case, "hidden": kind, "effects": [] if effect_name is None else [effect_name],
           "regions": len(held), "true_regions": summary.get("true_region_count"),
           "label_accuracy": summary.get("label_accuracy"), "map_model": summary["map_model"],
           "gap": plug_in_gap(dataset, fit_dir, summary, effect_name), "seconds": seconds,
           "rhat_max": summary.get("rhat_max"), "warnings": len(summary.get("warnings", []))}
    if effect_name is not None:
        entry = next(e for e in summary["effects"] if e["name"] == effect_name)
        out["posterior"] = {p["name"]: {k: p[k] for k in ("mean", "sd", "q2.5", "q97.5", "rhat", "ess_bulk")}
                            for p in entry["parameters"]}
        if "light_gains" in entry:
            out["posterior"]["light_gains"] = [{k: g[k] for k in ("mean", "sd", "q2.5", "q97.5")}
                                               for g in entry["light_gains"]]
        out["truth"] = truth(case, dataset)
        out["acceptance"] = summary["acceptance"].get(f"effect_{effect_name}")
    return out


def run_case(case, out, resolution, chains, iterations, seed):
    kind, effect_name = CASES[case]
    folder = out / case
    data_dir = folder / "dataset"
    if not (data_dir / "dataset.json").is_file():
        render_hidden(kind, data_dir, resolution=resolution, seed=seed)
    dataset = load_dataset(data_dir)
    options = dict(n_chains=chains, iterations=iterations, seed=seed, allow_unvalidated=True, figures=False,
                   progress=False)
    rows = []
    started = time.perf_counter()
    plain = fit_dataset(data_dir, folder / "plain", **options)
    rows.append(row(case, kind, dataset, folder / "plain", plain, None, time.perf_counter() - started))
    extra = {"effects": (effect_name,)}
    if effect_name == "interreflection":
        diagnosis = folder / "diagnosis"
        diagnosis.mkdir(exist_ok=True)
        write_json_atomic(diagnosis / "diagnosis.json", {"named_effects": [effect_name],
                                                         "fit_dir": str((folder / "plain").resolve()),
                                                         "note": "written by validation/effects_in_fit.py"})
        extra = {"effects_from": diagnosis}
    started = time.perf_counter()
    with_effect = fit_dataset(data_dir, folder / "with_effect", **options, **extra)
    rows.append(row(case, kind, dataset, folder / "with_effect", with_effect, effect_name,
                    time.perf_counter() - started))
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--only", default=",".join(CASES))
    parser.add_argument("--resolution", type=int, default=64)
    parser.add_argument("--chains", type=int, default=2)
    parser.add_argument("--iterations", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    results = []
    for case in [c for c in args.only.split(",") if c]:
        for line in run_case(case, args.out, args.resolution, args.chains, args.iterations, args.seed):
            results.append(line)
            print(json.dumps(line, default=float), flush=True)
            write_json_atomic(args.out / "effects_in_fit.json", results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
