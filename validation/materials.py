"""Free-form material layouts rendered with Mitsuba and fitted with ``--regions materials`` (issue 27 item 1).

Each layout is a material index image mapped onto the dented slab by its texture
coordinates (``geometry.material_map`` of :func:`rjfit.data.meshes.dented_slab`: every face
takes the texel under its centroid), rendered with the scene ``dented_plaster``'s camera
and 8 lights (its noise variance 0.1, 64 spp), direct light only (``max_depth`` 2: the
dents' interreflections are not in the fitted model; cast shadows are left out of the fit
by the data set's visibility):

- ``discs``: two discs of two paints on a third (3 materials);
- ``letter``: a block letter F on a background (2 materials);
- ``stripes``: stripes at 30 degrees, two paints alternating (2 materials);
- ``patches``: two disconnected patches of one paint on a background (2 materials: the
  patches must come out as one material).

Per layout: ``--chains`` (default 4) chains of ``--iterations`` (default 1000, half burn-in), the label accuracy of
the MAP materials against the rendered truth (optimal matching), the posterior probability
of the true K, and R-hat over 4 chains (relabelled draws at the MAP K). ``--sweep`` refits
each layout for beta in {0.5, 1, 2} x rho in {0.1, 1}. Prints a table and writes it as
JSON (``--out``/results.json). ``--regions changepoints`` fits each layout under the paper's
change-point model at its default settings instead (the comparison's rows; ``--out``/
results_changepoints_CxN.json): label accuracy (and the majority accuracy: each region
mapped to its most common paint), posterior over (n_u, n_v) and over the number of
cells, the probability that the object's pixels fall into exactly the true number of regions.

    PYTHONPATH=. python validation/materials.py --size 64 --out /tmp/materials [--sweep]
    PYTHONPATH=. python validation/materials.py --size 64 --regions changepoints --chains 2 --out /tmp/materials
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from rjfit.io import write_text_atomic
from rjfit.pipeline.options import PLAIN_POTTS_RHO, FitOptions

#: a fit's own default (--potts-beta); before 2026-11-27 this script defaulted to 1, where every layout reads K = 8
FIT_POTTS_BETA = FitOptions.default("potts_beta")

MATERIALS = [{"name": "white paint", "I0": 100.0, "kd": 0.85, "gamma": 8.0},
             {"name": "grey glaze", "I0": 70.0, "kd": 0.6, "gamma": 20.0},
             {"name": "dark paint", "I0": 45.0, "kd": 0.9, "gamma": 5.0}]


def layout(name: str, n: int = 64) -> np.ndarray:
    """The material index image (n x n) of a layout."""
    rows, cols = np.mgrid[0:n, 0:n] / n
    texels = np.zeros((n, n), np.int64)
    if name == "discs":
        texels[(rows - 0.35) ** 2 + (cols - 0.3) ** 2 < 0.18 ** 2] = 1
        texels[(rows - 0.65) ** 2 + (cols - 0.7) ** 2 < 0.2 ** 2] = 2
    elif name == "letter":
        texels[(rows > 0.15) & (rows < 0.85) & (cols > 0.25) & (cols < 0.42)] = 1      # stem
        texels[(rows > 0.15) & (rows < 0.3) & (cols > 0.25) & (cols < 0.8)] = 1        # top bar
        texels[(rows > 0.45) & (rows < 0.58) & (cols > 0.25) & (cols < 0.68)] = 1      # middle bar
    elif name == "stripes":
        along = cols * np.cos(np.radians(30)) + rows * np.sin(np.radians(30))
        texels[(np.floor(along / 0.2) % 2) == 1] = 1
    elif name == "patches":
        texels[(rows > 0.15) & (rows < 0.4) & (cols > 0.15) & (cols < 0.4)] = 1
        texels[(rows > 0.6) & (rows < 0.85) & (cols > 0.55) & (cols < 0.85)] = 1
    else:
        raise ValueError(f"unknown layout {name!r}")
    return texels


LAYOUTS = ("discs", "letter", "stripes", "patches")


def scene(name: str, size: int) -> dict:
    """The dented slab of ``dented_plaster`` with the layout's materials mapped on it."""
    from rjfit.render.render import load_scene_definition

    definition = load_scene_definition("dented_plaster")
    texels = layout(name)
    n_materials = int(texels.max()) + 1
    definition["name"] = f"materials_{name}"
    definition["resolution"] = [size, size]
    definition["materials"] = MATERIALS[:n_materials]
    definition["geometry"]["material_map"] = texels.tolist()
    definition["geometry"]["materials"] = list(range(n_materials))
    definition["geometry"]["resolution"] = max(200, 3 * size)
    # direct light only: the interreflections between the dents' walls are not in the fitted
    # model (issue 26's business), and here they would be misfit that buys materials
    definition["max_depth"] = 2
    return definition


def fit_layout(name, size, out, iterations, seed, beta=FIT_POTTS_BETA, rho=PLAIN_POTTS_RHO, workers=2, chains=4,
               noise="constant") -> dict:
    from rjfit.pipeline.fit_dataset import fit_dataset

    data = layout_dataset(name, size, out)
    started = time.perf_counter()
    suffix = "" if noise == "constant" else f"_{noise}"
    summary = fit_dataset(data, out / f"{name}_{size}" / f"fit_b{beta}_r{rho}{suffix}", allow_unvalidated=True,
                          regions="materials", potts_beta=beta, potts_rho=rho, iterations=iterations,
                          n_chains=chains, seed=seed, progress=False, figures=True, processes=workers, noise=noise)
    normal_error = summary["noise"].get("normal_error") or {}
    return {"layout": name, "size": size, "beta": beta, "rho": rho, "noise": noise, "footprint_c": normal_error.get("c"),
            "normal_error_deg": normal_error.get("sigma_n_deg"), "true_K": summary["true_region_count"],
            "label_accuracy": summary["label_accuracy"], "P(K=true)": summary["materials_right_probability"],
            "materials_posterior": summary["materials_posterior"], "rhat_max": summary["rhat_max"],
            "edge_groups_posterior": summary.get("edge_groups_posterior"),
            "map_probability_mean": summary["map_probability_mean"], "seconds": time.perf_counter() - started,
            "warnings": summary["warnings"]}


def layout_dataset(name: str, size: int, out: Path) -> Path:
    """The layout's rendered data set under ``out`` (rendered on first use)."""
    from rjfit.render.render import render_dataset

    data = out / f"{name}_{size}" / "dataset"
    if not (data / "dataset.json").is_file():
        render_dataset(scene(name, size), data)
    return data


def majority_accuracy(labels, truth_labels) -> float:
    """Fraction of object pixels whose region's most common true material is their own.

    Unlike the one-to-one matching of the label accuracy, several regions may map to one
    material: it says whether the regions' boundaries follow the paints, whatever the number
    of regions (a change-point model needs several cells for one free-form material).
    """
    truth = np.asarray(truth_labels)
    mask = truth >= 0
    est, tru = np.asarray(labels)[mask], truth[mask]
    right = sum(np.bincount(tru[est == region]).max() for region in np.unique(est))
    return float(right / est.size)


def fit_layout_changepoints(name, size, out, iterations, seed, workers=2, chains=4) -> dict:
    """The layout under the paper's change-point model at its default settings (the comparison's rows)."""
    from rjfit.data.exr import read_exr
    from rjfit.pipeline.fit_dataset import fit_dataset
    from rjfit.render.datasets import load_dataset

    data = layout_dataset(name, size, out)
    folder = out / f"{name}_{size}" / f"fit_changepoints_{chains}x{iterations}"
    started = time.perf_counter()
    summary = fit_dataset(data, folder, allow_unvalidated=True, regions="changepoints", iterations=iterations,
                          n_chains=chains, seed=seed, progress=False, figures=True, processes=workers)
    seconds = time.perf_counter() - started
    majority = majority_accuracy(np.asarray(read_exr(folder / "labels.exr")["labels"]).squeeze(),
                                 load_dataset(data).truth_labels)
    # a change-point model of (n_u, n_v) has (n_u + 1)(n_v + 1) cells, some of them possibly off the object
    cells = {}
    for key, p in summary["model_posterior"].items():
        n_u, n_v = (int(k) for k in key.strip("()").split(","))
        cells[(n_u + 1) * (n_v + 1)] = cells.get((n_u + 1) * (n_v + 1), 0.0) + p
    return {"layout": name, "size": size, "regions": "changepoints", "true_K": summary["true_region_count"],
            "label_accuracy": summary["label_accuracy"], "majority_accuracy": majority,
            "map_model": summary["map_model"],
            "model_posterior": summary["model_posterior"], "chain_model_posterior": summary["chain_model_posterior"],
            "cells_posterior": {str(k): v for k, v in sorted(cells.items())},
            "P(object regions = true K)": summary["four_region_probability"],
            "P(true regions)": summary["true_regions_probability"], "rhat_max": summary["rhat_max"],
            "seconds": seconds, "warnings": summary["warnings"]}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--iterations", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--layouts", nargs="*", default=list(LAYOUTS))
    parser.add_argument("--sweep", action="store_true", help="beta in {0.5, 1, 2} x rho in {0.1, 1}")
    parser.add_argument("--betas", type=float, nargs="*", default=[FIT_POTTS_BETA],
                        help="Potts beta values (default: a fit's)")
    parser.add_argument("--rho", type=float, default=PLAIN_POTTS_RHO,
                        help="Potts rho (prior factor per material) with --betas; default: a fit's")
    parser.add_argument("--workers", type=int, default=2, help="chains run at once (worker processes; 1: in this one)")
    parser.add_argument("--chains", type=int, default=4)
    parser.add_argument("--regions", choices=("materials", "changepoints"), default="materials",
                        help="changepoints: the paper's model at its default settings (--betas, --sweep unused)")
    parser.add_argument("--noise", default="constant", help="noise model (--noise of rjfit fit), e.g. footprint")
    parser.add_argument("--out", type=Path, default=Path("validation_materials"))
    args = parser.parse_args(argv)
    settings = [(b, r) for b in (0.5, 1.0, 2.0) for r in (0.1, 1.0)] if args.sweep else [(b, args.rho) for b in args.betas]
    rows = []
    if args.regions == "changepoints":
        for name in args.layouts:
            row = fit_layout_changepoints(name, args.size, args.out, args.iterations, args.seed, args.workers,
                                          args.chains)
            rows.append(row)
            print(f"{name:8s} change points: accuracy {row['label_accuracy']:.4f} (majority "
                  f"{row['majority_accuracy']:.4f}), MAP {row['map_model']}, "
                  f"cells {row['cells_posterior']}, P(object regions = {row['true_K']}) "
                  f"{row['P(object regions = true K)']:.3f}, R-hat {row['rhat_max']}, {row['seconds']:.0f} s",
                  flush=True)
            write_text_atomic(args.out / f"results_changepoints_{args.chains}x{args.iterations}.json",
                              json.dumps(rows, indent=1))
        return
    for name in args.layouts:
        for beta, rho in settings:
            row = fit_layout(name, args.size, args.out, args.iterations, args.seed, beta, rho, args.workers,
                             args.chains, args.noise)
            rows.append(row)
            print(f"{name:8s} beta {beta:3.1f} rho {rho:g} noise {args.noise}: accuracy {row['label_accuracy']:.4f}, "
                  f"P(K={row['true_K']}) {row['P(K=true)']:.3f}, K posterior {row['materials_posterior']}, "
                  f"R-hat {row['rhat_max']:.3f}, {row['seconds']:.0f} s", flush=True)
            # after every fit, so that a run stopped part way keeps the fits it made
            results = "results" + ("" if args.noise == "constant" else f"_{args.noise}") + (
                "" if args.rho == PLAIN_POTTS_RHO else f"_rho{args.rho:g}") + ".json"
            write_text_atomic(args.out / results, json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
