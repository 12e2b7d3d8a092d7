"""Bit-identity check of the sampler across a restructuring: same seeds, same draws, array by array.

Mode ``run`` runs short chains of several sampler settings on the pure-NumPy synthetic
sphere (:func:`rjfit.data.synthetic.sphere_stack`) with fixed seeds and writes every
recorded array of each :class:`~rjfit.sampler.runner.ChainRecord` (draws, log densities,
truth flags, change-point snapshots, acceptance counts) to one ``.npz``; mode ``compare``
reads two such files and checks every array common to both with ``np.array_equal`` (NaN
equal to NaN), listing arrays only one of them has.

Run it once with the code before a change and once after (``PYTHONPATH`` chooses the
tree), then compare::

    PYTHONPATH=/path/to/old .venv/bin/python validation/sampler_identity.py run old.npz
    PYTHONPATH=$PWD .venv/bin/python validation/sampler_identity.py run new.npz
    .venv/bin/python validation/sampler_identity.py compare old.npz new.npz

Mode ``compare-fit`` compares two ``rjfit fit`` output folders of the same data, seed and
options: ``summary.json`` without its timing fields (:data:`TIMING_KEYS`), every variable
of every group of ``chains.nc`` and every array of ``changepoints.npz``.

It only uses names that both the start commit of issue 25's sampler restructuring and
later code have (``rjfit.sampler``'s package exports), and builds the configuration with
``SamplerConfig.from_flat`` where it exists (the flat keyword names), else with the flat
constructor the older code had.
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

#: name -> (flat sampler settings, problem options, start) of each case; every case's
#: chains run ITERATIONS iterations with burn-in BURN (the gamma step adapts during it).
ITERATIONS, BURN, ANNEAL = 1000, 300, 150
CASES = {
    # the default path of `rjfit fit`: dispersed starts (a random model in {0, 1}^2), annealed warm-up
    "default": ({}, {}, None),
    "paper_sampler": ({"sampler": "paper"}, {}, None),
    "split_mean": ({"split_map": "mean"}, {}, None),
    "split_mean_drop_jacobian": ({"split_map": "mean", "drop_jacobian": True, "free_jump_prob": 0.0}, {}, None),
    "split_paper_drop_jacobian": ({"split_map": "paper", "drop_jacobian": True, "free_jump_prob": 0.0}, {}, None),
    "cp_prior_paper": ({"cp_prior": "paper"}, {}, None),
    "likelihood_power": ({}, {"likelihood_power": 0.3}, None),
    "shot_noise": ({}, {"noise": "shot"}, None),
    "fixed_segmentation": ({"update_changepoints": False, "jumps": False}, {}, "quadrants"),
    # every structure move often: births/deaths (both kinds), block shifts, vector redraws
    "busy_moves": ({"jump_prob": 0.7, "block_prob": 0.4, "vector_prob": 0.7, "cp_uniform_prob": 0.3, "gamma_move": "rw",
                    "refresh_every": 50}, {}, None),
    "paper_full_recompute": ({"sampler": "paper", "full_recompute": True, "max_u": 1, "max_v": 1}, {}, None),
    # a weak likelihood: births and deaths of both kinds are accepted often
    "weak_likelihood": ({"jump_prob": 0.5}, {"likelihood_power": 0.002}, None),
    # over the compiled passes' PARALLEL_MIN_OBS: the large passes run in pieces on two threads
    "large_two_threads": ({}, {"size": 96, "threads": 2}, None),
}


def _config(flat):
    from rjfit.sampler import SamplerConfig

    build = getattr(SamplerConfig, "from_flat", SamplerConfig)     # the flat constructor before issue 25
    return build(**flat)


def run_case(name, size, n_chains, iterations, seed):
    from rjfit.data.noise import noise_scale
    from rjfit.data.synthetic import sphere_stack
    from rjfit.sampler import Problem, make_prior
    from rjfit.sampler.runner import ChainSpec, run_chain

    flat, problem_options, start = CASES[name]
    obs, truth_labels, _ = sphere_stack(problem_options.get("size", size), n_lights=10, seed=3)
    scale = noise_scale(obs, problem_options["noise"]) if "noise" in problem_options else None
    problem = Problem.from_observations(obs, likelihood_power=problem_options.get("likelihood_power", 1.0),
                                        noise_scale=scale)
    prior = make_prior("default", y=problem.y, diffuse_scale=problem.A)
    flat = {"max_u": 3, "max_v": 3, "burn_in": BURN, "anneal": ANNEAL, **flat}
    if flat.get("update_changepoints") is False:
        flat["anneal"] = 0
    config = _config(flat)
    height, width = problem.image_shape
    chain_start = None
    if start == "quadrants":
        chain_start = {"changepoints": (np.full(height, width / 2.0), np.full(width, height / 2.0))}
    arrays = {}
    for chain in range(n_chains):
        spec = ChainSpec(problem=problem, prior=prior, config=config, seed=seed, chain=chain, n_chains=n_chains,
                         iterations=iterations, cp_thin=5, truth_labels=truth_labels, start=chain_start)
        record = run_chain(spec, threads=problem_options.get("threads", 1))
        for field in ("n_u", "n_v", "theta", "log_lik", "log_post", "exact_truth", "true_regions", "object_regions",
                      "cp_iteration", "cp_u", "cp_v"):
            arrays[f"{name}/chain{chain}/{field}"] = np.asarray(getattr(record, field))
        arrays[f"{name}/chain{chain}/iterations_done"] = np.asarray(record.iterations_done)
        for kind in sorted(record.proposed):
            arrays[f"{name}/chain{chain}/accepted/{kind}"] = np.asarray(record.accepted.get(kind, 0))
            arrays[f"{name}/chain{chain}/proposed/{kind}"] = np.asarray(record.proposed[kind])
        # NaN log ratios counted as rejections (recorded by the code after issue 25 only)
        for kind, count in sorted(getattr(record, "nan_rejected", {}).items()):
            arrays[f"{name}/chain{chain}/nan_rejected/{kind}"] = np.asarray(count)
    return arrays


def run(out, cases, size, n_chains, iterations, seed):
    arrays = {}
    for name in cases:
        t0 = time.perf_counter()
        arrays.update(run_case(name, size, n_chains, iterations, seed))
        print(f"{name}: {n_chains} chains x {iterations} iterations in {time.perf_counter() - t0:.1f} s", flush=True)
    np.savez_compressed(out, **arrays)
    print(f"wrote {len(arrays)} arrays to {out}")


def compare(first, second) -> int:
    a, b = np.load(first), np.load(second)
    common = sorted(set(a.files) & set(b.files))
    differ = [key for key in common if not (a[key].shape == b[key].shape and a[key].dtype == b[key].dtype
                                            and np.array_equal(a[key], b[key], equal_nan=a[key].dtype.kind == "f"))]
    for key in differ:
        print(f"DIFFERENT {key}")
    for key in sorted(set(a.files) - set(b.files)):
        print(f"only in {first}: {key}")
    for key in sorted(set(b.files) - set(a.files)):
        print(f"only in {second}: {key}")
    print(f"{len(common) - len(differ)} of {len(common)} common arrays identical")
    # arrays in one file only (a counter the other code does not record) are listed, not failed
    return 1 if differ else 0


#: summary.json fields that hold wall-clock measurements, left out of ``compare-fit``
TIMING_KEYS = ("seconds", "chain_seconds")


def compare_fit(first, second) -> int:
    import json
    from pathlib import Path

    import arviz as az

    first, second = Path(first), Path(second)
    differ = []
    summaries = [json.loads((d / "summary.json").read_text()) for d in (first, second)]
    for summary in summaries:
        for key in TIMING_KEYS:
            summary.pop(key, None)
    keys = sorted(set(summaries[0]) | set(summaries[1]))
    differ += [f"summary.json:{key}" for key in keys if summaries[0].get(key) != summaries[1].get(key)]
    data = [az.from_netcdf(str(d / "chains.nc")) for d in (first, second)]
    n_variables = 0
    for group in sorted(set(data[0].groups()) | set(data[1].groups())):
        sets = [getattr(d, group, None) for d in data]
        if any(s is None for s in sets):
            differ.append(f"chains.nc:{group} (in one file only)")
            continue
        for name in sorted(set(sets[0].data_vars) | set(sets[1].data_vars)):
            n_variables += 1
            if name not in sets[0] or name not in sets[1] or not np.array_equal(
                    sets[0][name].values, sets[1][name].values, equal_nan=sets[0][name].dtype.kind == "f"):
                differ.append(f"chains.nc:{group}/{name}")
    npz = [np.load(d / "changepoints.npz") for d in (first, second)]
    names = sorted(set(npz[0].files) | set(npz[1].files))
    differ += [f"changepoints.npz:{name}" for name in names
               if name not in npz[0].files or name not in npz[1].files
               or not np.array_equal(npz[0][name], npz[1][name], equal_nan=True)]
    for item in differ:
        print(f"DIFFERENT {item}")
    print(f"summary.json: {len(keys)} fields (timing {', '.join(TIMING_KEYS)} left out); chains.nc: {n_variables} "
          f"variables; changepoints.npz: {len(names)} arrays; {len(differ)} different")
    return 1 if differ else 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="mode", required=True)
    run_parser = sub.add_parser("run", help="run the cases and write their records to an .npz")
    run_parser.add_argument("out")
    run_parser.add_argument("--cases", default=",".join(CASES), help="comma-separated case names")
    run_parser.add_argument("--size", type=int, default=64, help="image size of the synthetic sphere")
    run_parser.add_argument("--chains", type=int, default=2)
    run_parser.add_argument("--iterations", type=int, default=ITERATIONS)
    run_parser.add_argument("--seed", type=int, default=7)
    compare_parser = sub.add_parser("compare", help="compare two .npz files array by array")
    compare_parser.add_argument("first")
    compare_parser.add_argument("second")
    fit_parser = sub.add_parser("compare-fit", help="compare two `rjfit fit` output folders")
    fit_parser.add_argument("first")
    fit_parser.add_argument("second")
    args = parser.parse_args(argv)
    if args.mode == "compare":
        return compare(args.first, args.second)
    if args.mode == "compare-fit":
        return compare_fit(args.first, args.second)
    cases = [c for c in args.cases.split(",") if c]
    unknown = [c for c in cases if c not in CASES]
    if unknown:
        parser.error(f"unknown case(s) {', '.join(unknown)}: choose from {', '.join(CASES)}")
    run(args.out, cases, args.size, args.chains, args.iterations, args.seed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
