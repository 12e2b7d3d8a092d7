"""Which parts of the measured-data default matter: fits of the real stacks under variants of it.

Each run fits one data set under one variant and appends one JSON line to ``--table``
(data set, variant, region model, posterior over K (materials) or over (n_u, n_v)
(change points), the MAP, per-chain posteriors, zeta, the normal-error estimate, the
calibration, seconds). ``--summarise`` prints the table in Markdown from those lines.

The data sets are read through folders of symbolic links with an ``rjfit.json`` that crops
them to the mask (docs/dataset-format.md), e.g. for the ball::

    mkdir -p /tmp/rd/ball && ln -s /work/shared/data/diligent-ball/* /tmp/rd/ball/ && \\
        rm /tmp/rd/ball/rjfit.json 2>/dev/null; echo '{"crop": true}' > /tmp/rd/ball/rjfit.json

(psm folders: ``{"crop": true, "response": "unknown"}``). Fits run unvalidated
(``allow_unvalidated``): the gate checks the forward model's rendering, not what is
measured here.

Example::

    python validation/real_stacks.py /tmp/rd/ball --variant measured --chains 2 --iterations 300 \\
        --out /tmp/rd/runs --table /tmp/rd/table.jsonl
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from rjfit.data.calibrate import drop_small_components
from rjfit.pipeline.fit_dataset import fit_dataset, ghost_material_prior
from rjfit.pipeline.options import FitOptions
from rjfit.render.datasets import load_dataset

# option changes per variant; "rho" -> potts_rho = 1 / (labelled pixels); "ghost" -> (potts_beta, potts_rho) of
# rjfit.pipeline.fit_dataset.ghost_material_prior (what --preset measured uses)
VARIANTS = {
    "auto": {"likelihood_power": "auto"},
    "area": {"likelihood_power": "area"},
    "normals-auto": {"noise": "normals", "likelihood_power": "auto"},
    "normals-area": {"noise": "normals", "likelihood_power": "area"},
    "auto-rho": {"likelihood_power": "auto", "potts_rho": "rho"},
    "area-rho": {"likelihood_power": "area", "potts_rho": "rho"},
    "normals-area-rho": {"noise": "normals", "likelihood_power": "area", "potts_rho": "rho"},
    "calibrated-area-rho": {"likelihood_power": "area", "potts_rho": "rho", "calibrate": True},
    "ghost": {"potts_rho": "ghost"},
    "auto-ghost": {"likelihood_power": "auto", "potts_rho": "ghost"},
    "area-ghost": {"likelihood_power": "area", "potts_rho": "ghost"},
    "normals-area-ghost": {"noise": "normals", "likelihood_power": "area", "potts_rho": "ghost"},
    "calibrated-auto-ghost": {"likelihood_power": "auto", "potts_rho": "ghost", "calibrate": True},
    "calibrated-normals-auto-ghost": {"noise": "normals", "likelihood_power": "auto", "potts_rho": "ghost",
                                      "calibrate": True},
    "measured": {"preset": "measured"},
    "measured-auto": {"preset": "measured", "likelihood_power": "auto"},
    "measured-auto-noanneal": {"preset": "measured", "likelihood_power": "auto", "anneal": 0.0},
    "measured-noanneal": {"preset": "measured", "anneal": 0.0},
    "cp-auto": {"regions": "changepoints", "likelihood_power": "auto"},
    "cp-measured": {"regions": "changepoints", "noise": "normals", "likelihood_power": "area", "calibrate": True},
    "cp-preset": {"regions": "changepoints", "preset": "measured"},
    # the preset's parts with the change-point model's annealed warm-up kept (the preset turns it off)
    "cp-preset-anneal": {"regions": "changepoints", "noise": "normals", "likelihood_power": "auto", "calibrate": True},
    # the preset with the footprint term added to the normals' noise (docs/results/measured-data.md, "The footprint term")
    "measured-footprint": {"preset": "measured", "noise": "footprint"},
    # the preset without the material model's segment moves (docs/results/measured-data.md, "Segment moves")
    "measured-nosegments": {"preset": "measured", "segment_moves": 0},
    # the preset with effects sampled inside the material fit (since 2026-11-27): the light gains (the preset
    # estimates them once before the fit), and those with the lobe's masking (the ball's diagnosis' runners-up)
    "measured-lights": {"preset": "measured", "effects": ("light_calibration",)},
    "measured-lights-masking": {"preset": "measured", "effects": ("light_calibration", "masking")},
    # the preset at a larger likelihood power than its lag-1 rule gives (0.011 to 0.027 on the three stacks): what
    # resolving smaller painted details costs (docs/results/materials.md, "Resolution")
    "measured-power0.03": {"preset": "measured", "likelihood_power": 0.03},
    # the preset on R, G and B jointly, with its edge term (docs/results/2026-11-28-colour.md)
    "measured-rgb": {"preset": "measured", "channel": "rgb"},
    "measured-mean": {"preset": "measured", "channel": "mean"},
    # the preset with the edge term's local gain (the preset's since 2026-11-29), with the component moves, and with
    # both (the component moves are not the preset's: docs/results/2026-11-28-local-gain.md)
    "measured-gain": {"preset": "measured", "edge_gain_sd": "auto"},
    # the preset without the local gain (before 2026-11-29), and with the edge term's differences on one scale
    # (before its measured noise: docs/results/2026-11-29-edge-noise.md)
    "measured-nogain": {"preset": "measured", "edge_gain_sd": 0.0},
    "measured-constant-noise": {"preset": "measured", "edge_noise": "constant"},
    "measured-components": {"preset": "measured", "component_moves": 2},
    "measured-scatter": {"preset": "measured", "scatter_moves": 1},
    "measured-gain-components": {"preset": "measured", "edge_gain_sd": "auto", "component_moves": 2},
}


def run(dataset: Path, variant: str, chains: int, iterations: int, out: Path, table: Path, seed: int) -> dict:
    changes = dict(VARIANTS[variant])
    if changes.get("potts_rho") == "rho":
        changes["potts_rho"] = 1.0 / int(load_dataset(dataset).object_mask.sum())
    if changes.get("potts_rho") == "ghost":
        mask = drop_small_components(load_dataset(dataset))[0].object_mask if changes.get("calibrate") else \
            load_dataset(dataset).object_mask
        changes["potts_beta"], changes["potts_rho"] = ghost_material_prior(mask, FitOptions.default("potts_beta"))
    changes.setdefault("regions", "materials")
    changes.setdefault("preset", "none")        # a variant names what it sets (the stacks' own default is the preset)
    options = FitOptions(n_chains=chains, iterations=iterations, seed=seed, progress=False, **changes)
    folder = out / f"{dataset.name}_{variant}_{chains}x{iterations}"
    started = time.perf_counter()
    summary = fit_dataset(dataset, folder, options, allow_unvalidated=True)
    row = {"dataset": dataset.name, "variant": variant, "chains": chains, "iterations": iterations, "seed": seed,
           "seconds": round(time.perf_counter() - started, 1), "folder": str(folder),
           "likelihood_power": summary["likelihood_power"],
           "normal_error_deg": (summary["noise"].get("normal_error") or {}).get("sigma_n_deg"),
           "potts_rho": summary["fit_options"]["potts_rho"], "potts_beta": summary["fit_options"]["potts_beta"],
           "rhat_max": summary.get("rhat_max"),
           "calibration": summary.get("calibration")}
    if options.regions == "materials":
        row.update(posterior=summary["materials_posterior"], map=summary["map_materials"],
                   chains_posterior=summary["chain_materials_posterior"],
                   edge_groups=summary.get("edge_groups_posterior"),
                   pixels=[region["pixels"] for region in summary["regions"]])
    else:
        row.update(posterior=summary["model_posterior"], map=summary["map_model"],
                   chains_posterior=summary["chain_model_posterior"],
                   pixels=[region.get("pixels") for region in summary["regions"]])
    with open(table, "a") as handle:
        handle.write(json.dumps(row) + "\n")
    return row


def _cells(key: str) -> int:
    """The number of cells (regions) of a change-point model key "(n_u,n_v)": (n_u + 1)(n_v + 1)."""
    n_u, n_v = (int(k) for k in key.strip("()").split(","))
    return (n_u + 1) * (n_v + 1)


def _top(posterior: dict, count: int = 4) -> str:
    return ", ".join(f"{k}: {v:.2f}" for k, v in sorted(posterior.items(), key=lambda kv: -kv[1])[:count])


def summarise(table: Path) -> str:
    """The table's rows in Markdown: one table for the material model's fits, one for the change points'."""
    rows = [json.loads(text) for text in table.read_text().splitlines()]
    materials = [r for r in rows if not isinstance(r["map"], dict)]
    changepoints = [r for r in rows if isinstance(r["map"], dict)]
    lines = []
    if materials:
        lines += ["| data set | variant | chains x iter. | zeta | normal error (deg) | K posterior | per chain | "
                  "edge groups | MAP | MAP pixels | R-hat | s |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in materials:
        error = "-" if row["normal_error_deg"] is None else f"{row['normal_error_deg']:.2f}"
        rhat = "-" if row["rhat_max"] is None else f"{row['rhat_max']:.2f}"
        chains = ", ".join("/".join(k for k, v in sorted(c.items(), key=lambda kv: -kv[1]) if v >= 0.1)
                           for c in row["chains_posterior"])
        lines.append(f"| {row['dataset']} | {row['variant']} | {row['chains']} x {row['iterations']} | "
                     f"{row['likelihood_power']:.3g} | {error} | {_top(row['posterior'])} | {chains} | "
                     f"{_top(row['edge_groups']) if row.get('edge_groups') else '-'} | {row['map']} | "
                     f"{row['pixels']} | {rhat} | {row['seconds']:.0f} |")
    if changepoints:
        lines += ["" if lines else None, "| data set | variant | chains x iter. | zeta | normal error (deg) | "
                  "(n_u, n_v) posterior | regions posterior | per chain | MAP | MAP pixels | R-hat | s |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in changepoints:
        error = "-" if row["normal_error_deg"] is None else f"{row['normal_error_deg']:.2f}"
        rhat = "-" if row["rhat_max"] is None else f"{row['rhat_max']:.2f}"
        cells = {}
        for key, p in row["posterior"].items():
            cells[_cells(key)] = cells.get(_cells(key), 0.0) + p
        chains = ", ".join("/".join(k for k, v in sorted(c.items(), key=lambda kv: -kv[1]) if v >= 0.1)
                           for c in row["chains_posterior"])
        n_u, n_v = row["map"]["n_u"], row["map"]["n_v"]
        lines.append(f"| {row['dataset']} | {row['variant']} | {row['chains']} x {row['iterations']} | "
                     f"{row['likelihood_power']:.3g} | {error} | {_top(row['posterior'])} | {_top(cells)} | {chains} | "
                     f"({n_u},{n_v}) | {row['pixels']} | {rhat} | {row['seconds']:.0f} |")
    return "\n".join(line for line in lines if line is not None)


def overlay(folder: Path, dataset: Path, out: Path) -> Path:
    """The MAP materials' (or change-point regions') boundaries (red) over the stack's mean image, beside the map."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from rjfit.data.exr import read_exr

    labels = np.asarray(read_exr(folder / "labels.exr")["labels"]).squeeze()
    image = load_dataset(dataset).channel_values("mean").mean(axis=0)
    edge = np.zeros(labels.shape, bool)
    for axis in (0, 1):
        change = np.diff(labels, axis=axis) != 0
        both = (np.delete(labels, -1, axis=axis) >= 0) & (np.delete(labels, 0, axis=axis) >= 0)
        if axis == 0:
            edge[:-1] |= change & both
        else:
            edge[:, :-1] |= change & both
    figure, (left, right) = plt.subplots(1, 2, figsize=(12, 5))
    left.imshow(image / np.percentile(image, 99.5), cmap="gray", vmin=0, vmax=1)
    left.imshow(np.ma.masked_where(~edge, edge), cmap="autumn", alpha=1.0, interpolation="nearest")
    left.set_title(f"{dataset.name}: material boundaries over the mean image")
    summary = json.loads((folder / "summary.json").read_text())
    right.imshow(np.where(labels >= 0, labels, np.nan), cmap="tab10" if labels.max() < 10 else "tab20",
                 interpolation="nearest")
    if "map_materials" in summary:
        shares = ", ".join(f"{k}: {v:.2f}" for k, v in list(summary["materials_posterior"].items())[:4])
        right.set_title(f"segmentation: {summary.get('segmentation_materials', summary['map_materials'])} materials\n"
                        f"(posterior over K {shares})")
    else:       # a change-point fit: its MAP model's cells
        model = summary["map_model"]
        right.set_title(f"MAP change points (n_u, n_v) = ({model['n_u']},{model['n_v']}): {len(summary['regions'])} "
                        f"regions\nposterior {_top(summary['model_posterior'], 3)}")
        left.set_title(f"{dataset.name}: MAP change-point region boundaries\nover the mean image")
    for axes in (left, right):
        axes.set_xticks([]), axes.set_yticks([])
    figure.tight_layout()
    figure.savefig(out, dpi=110)
    plt.close(figure)
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path, nargs="?")
    parser.add_argument("--variant", choices=sorted(VARIANTS), default="measured")
    parser.add_argument("--chains", type=int, default=2)
    parser.add_argument("--iterations", type=int, default=300)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("runs/real_stacks"))
    parser.add_argument("--table", type=Path, default=Path("runs/real_stacks/table.jsonl"))
    parser.add_argument("--summarise", action="store_true")
    parser.add_argument("--overlay", type=Path, help="a fit folder of DATASET: draw its overlay figure to --out")
    args = parser.parse_args()
    if args.overlay:
        print(overlay(args.overlay, args.dataset, args.out))
        return
    if args.summarise:
        print(summarise(args.table))
        return
    args.out.mkdir(parents=True, exist_ok=True)
    print(json.dumps(run(args.dataset, args.variant, args.chains, args.iterations, args.out, args.table, args.seed)))


if __name__ == "__main__":
    main()
