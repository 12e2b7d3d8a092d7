"""Scale: memory and time from 256 to 2048 pixels square (paper_sphere-like, 18 lights).

For each size, in a fresh subprocess (so peak resident memory is that size's own):
render the ``scanner_sphere`` scene, validate it (the cross-check gate), load it, build the
observations and run the sampler (one chain, change points sampled) for ``--iterations``
iterations; time per 1,000 iterations is scaled from those. Printed side by side, with the
cost per valid observation and its ratio to the smallest size (linear scaling gives 1).

    .venv/bin/python validation/bench_scale.py [--sizes 256 512 1024 2048] [--iterations 200]
    .venv/bin/python validation/bench_scale.py --render-only --variant cuda_ad_rgb   # GPU rendering figures
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def render_and_validate(size: int, folder: Path, variant: str):
    """Render scanner_sphere at ``size`` and run the gate; (dataset folder, validation, timings)."""
    import json as json_module

    from rjfit.render.gate import validate_dataset
    from rjfit.render.render import render_dataset

    timings = {}
    started = time.perf_counter()
    dataset_dir = render_dataset("scanner_sphere", folder / f"scanner_{size}", resolution=size, variant=variant)
    timings["render_s"] = time.perf_counter() - started
    started = time.perf_counter()
    validation = validate_dataset(dataset_dir, spp=1, variant=variant)
    timings["validate_s"] = time.perf_counter() - started
    timings["variant"] = json_module.loads((dataset_dir / "dataset.json").read_text())["variant"]
    return dataset_dir, validation, timings


def render_only(size: int, folder: Path, variant: str) -> dict:
    _, validation, timings = render_and_validate(size, folder, variant)
    return {"size": size, "validation_passed": bool(validation["passed"]),
            "median_rel_err": validation["median_rel_err"],
            "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 ** 2, **timings}


def one_size(size: int, iterations: int, folder: Path, variant: str = "auto") -> dict:
    from rjfit.render.datasets import load_dataset
    from rjfit.sampler.forward import Problem
    from rjfit.sampler.priors import make_prior
    from rjfit.sampler.runner import ChainSpec, run_chain
    from rjfit.sampler.state import SamplerConfig

    dataset_dir, validation, timings = render_and_validate(size, folder, variant)
    started = time.perf_counter()
    dataset = load_dataset(dataset_dir)
    observations = dataset.observations()
    problem = Problem.from_observations(observations)
    timings["load_s"] = time.perf_counter() - started
    n_obs, n_lights = int(observations.n_obs), int(observations.n_lights)
    del dataset, observations       # the sampler needs only the Problem's compact arrays
    prior = make_prior("default", y=problem.y, diffuse_scale=problem.A)
    config = SamplerConfig.from_flat(max_u=3, max_v=3, burn_in=iterations // 2)
    spec = ChainSpec(problem=problem, prior=prior, config=config, seed=0, chain=0, n_chains=1, iterations=iterations,
                     cp_thin=10)
    started = time.perf_counter()
    record = run_chain(spec)
    seconds = time.perf_counter() - started
    return {"size": size, "valid_observations": n_obs, "lights": n_lights,
            "validation_passed": bool(validation["passed"]), "median_rel_err": validation["median_rel_err"],
            "iterations": iterations, "chain_s": seconds, "per_1000_iterations_s": seconds / iterations * 1000,
            "final_model": [int(record.n_u[-1]), int(record.n_v[-1])],
            "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 ** 2, **timings}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[256, 512, 1024, 2048])
    parser.add_argument("--iterations", type=int, default=200)
    parser.add_argument("--variant", default="auto",
                        help="Mitsuba variant of rendering and validation (auto: cuda_ad_rgb where a GPU answers)")
    parser.add_argument("--render-only", action="store_true",
                        help="only render and validate (e.g. to compare a GPU variant with the CPU one)")
    parser.add_argument("--one", type=int, default=None, help=argparse.SUPPRESS)
    parser.add_argument("--folder", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one is not None:
        row = (render_only(args.one, Path(args.folder), args.variant) if args.render_only
               else one_size(args.one, args.iterations, Path(args.folder), args.variant))
        print(json.dumps(row))
        return
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for size in args.sizes:
            command = [sys.executable, __file__, "--one", str(size), "--iterations", str(args.iterations),
                       "--folder", folder, "--variant", args.variant] + (["--render-only"] if args.render_only else [])
            output = subprocess.run(command, check=True, capture_output=True, text=True).stdout
            rows.append(json.loads(output.strip().splitlines()[-1]))
            print(f"  {size}: done", file=sys.stderr, flush=True)
    if args.render_only:
        print("scanner_sphere, render and validate (gate at 1 spp) per size")
        print(f"{'size':>6} {'variant':>12} {'render s':>9} {'validate s':>11} {'peak RSS GB':>12} {'gate':>5}")
        for row in rows:
            print(f"{row['size']:>6} {row['variant']:>12} {row['render_s']:>9.1f} {row['validate_s']:>11.1f} "
                  f"{row['peak_rss_gb']:>12.2f} {'pass' if row['validation_passed'] else 'FAIL':>5}")
        return
    base = rows[0]["per_1000_iterations_s"] / rows[0]["valid_observations"]
    print(f"scanner_sphere, {rows[0]['lights']} lights; sampler: 1 chain, change points sampled, "
          f"{args.iterations} iterations timed")
    print(f"{'size':>6} {'valid obs':>11} {'peak RSS GB':>12} {'s/1000 it':>10} {'render s':>9} {'validate s':>11} "
          f"{'load s':>7} {'gate':>5} {'cost/obs vs smallest':>21}")
    for row in rows:
        ratio = row["per_1000_iterations_s"] / row["valid_observations"] / base
        print(f"{row['size']:>6} {row['valid_observations']:>11,} {row['peak_rss_gb']:>12.2f} "
              f"{row['per_1000_iterations_s']:>10.1f} {row['render_s']:>9.1f} {row['validate_s']:>11.1f} "
              f"{row['load_s']:>7.1f} {'pass' if row['validation_passed'] else 'FAIL':>5} {ratio:>21.2f}")
    print("goal: 2048 x 2048 with 18 lights within 24 GB; cost per valid observation not growing with size (ratio <= ~1)")


if __name__ == "__main__":
    main()
