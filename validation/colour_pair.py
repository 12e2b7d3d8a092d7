"""Two paints equal in grey level, different in hue: a joint colour fit against a grey one (issue 27 item 3).

The layout ``letter`` of ``validation/materials.py`` (a block letter F on a background, the
dented slab of ``dented_plaster``, 8 lights, direct light only) with two paints of one kd
and gamma whose per-channel I0 are ``I0 x (1.5, 0.8, 0.7)`` (reddish) and
``I0 x (0.75, 0.75, 1.5)`` (bluish): their channel means are equal, so the ``mean``
channel's data of the two paints follow one BRDF. The Blinn plugin takes one amplitude
per material, so each colour channel is its own Mitsuba render of the scene (the paints'
I0 that channel's, noise drawn per render: seeds ``seed + c``); the data set keeps
channel c of render c.

Fits: ``--regions materials`` with ``--channel rgb`` and ``--channel mean``, the same
chains, seed and iterations. Prints and writes (``--out``/results.json) the label
accuracy against the rendered truth, the K posterior, R-hat and the time.

    PYTHONPATH=. python validation/colour_pair.py --size 48 --chains 2 --iterations 600 --out /tmp/colour_pair
"""
from __future__ import annotations

import argparse
import json
import shutil
import time
from pathlib import Path

import numpy as np

from rjfit.io import write_text_atomic

HUES = ((1.5, 0.8, 0.7), (0.75, 0.75, 1.5))      # reddish, bluish: channel means equal (1.0); no channel
# equal in both (Mitsuba merges mesh parts of identical BSDFs, and a hit's material could not be told)
PAINT = {"I0": 80.0, "kd": 0.7, "gamma": 12.0}


def render_pair(size: int, out: Path, seed: int) -> Path:
    """The colour data set of the pair: channel c of every image from the render with the paints' channel-c I0."""
    import materials as layouts  # validation/materials.py: the layouts and the slab scene

    from rjfit.data.exr import read_exr, write_exr
    from rjfit.render.render import render_dataset

    target = out / "dataset"
    if (target / "dataset.json").is_file():
        return target
    renders = []
    for c in range(3):
        definition = layouts.scene("letter", size)
        definition["name"] = "colour_pair"
        definition["materials"] = [dict(PAINT, name=f"paint {m}", I0=PAINT["I0"] * HUES[m][c]) for m in range(2)]
        folder = out / f"render_{'RGB'[c]}"
        if not (folder / "dataset.json").is_file():
            render_dataset(definition, folder, seed=seed + c)
        renders.append(folder)
    staging = out / "dataset.partial"
    shutil.rmtree(staging, ignore_errors=True)
    shutil.copytree(renders[0], staging)
    meta = json.loads((staging / "dataset.json").read_text())
    for name in meta["images"]:
        channels = {key: np.asarray(value) for key, value in read_exr(renders[0] / name).items()}
        for c, key in enumerate("RGB"):
            channels[key] = np.asarray(read_exr(renders[c] / name)[key])
        write_exr(staging / name, channels)
    meta["note"] = ("channel c of each image is Mitsuba's render of the scene with the paints' channel-c I0 "
                    f"(validation/colour_pair.py: hues {HUES}, paint {PAINT})")
    (staging / "dataset.json").write_text(json.dumps(meta, indent=1))
    staging.rename(target)
    return target


def fit_pair(data: Path, out: Path, channel: str, chains: int, iterations: int, seed: int, workers: int) -> dict:
    from rjfit.pipeline.fit_dataset import fit_dataset

    started = time.perf_counter()
    summary = fit_dataset(data, out / f"fit_{channel}", allow_unvalidated=True, regions="materials", channel=channel,
                          iterations=iterations, n_chains=chains, seed=seed, progress=False, figures=True,
                          processes=workers)
    return {"channel": channel, "label_accuracy": summary["label_accuracy"],
            "P(K=2)": summary["materials_right_probability"], "materials_posterior": summary["materials_posterior"],
            "rhat_max": summary["rhat_max"], "chain_seconds": summary["chain_seconds"],
            "seconds": time.perf_counter() - started, "regions": summary["regions"], "warnings": summary["warnings"],
            "figures": summary.get("figures")}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--size", type=int, default=48)
    parser.add_argument("--chains", type=int, default=2)
    parser.add_argument("--iterations", type=int, default=600)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--channels", nargs="*", default=["rgb", "mean"])
    parser.add_argument("--out", type=Path, default=Path("validation_colour"))
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    data = render_pair(args.size, args.out, args.seed)
    print(f"rendered in {time.perf_counter() - t0:.0f} s", flush=True)
    rows = []
    for channel in args.channels:
        row = fit_pair(data, args.out, channel, args.chains, args.iterations, args.seed, args.workers)
        rows.append(row)
        print(f"{channel:5s}: accuracy {row['label_accuracy']:.4f}, P(K=2) {row['P(K=2)']:.3f}, K posterior "
              f"{row['materials_posterior']}, R-hat {row['rhat_max']:.3f}, {row['seconds']:.0f} s", flush=True)
        write_text_atomic(args.out / "results.json", json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
