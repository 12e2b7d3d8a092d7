"""Chains of one fit: serial in one process beside a two-worker local Dask cluster.

Same specs, same seeds: prints both wall times and whether the samples are identical.

    .venv/bin/python validation/bench_distributed.py [--size 64] [--chains 4] [--iterations 2000]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from rjfit.data.synthetic import sphere_stack
from rjfit.pipeline.distributed import dask_client, dask_map
from rjfit.sampler.forward import Problem
from rjfit.sampler.priors import make_prior
from rjfit.sampler.runner import ChainSpec, run_chain
from rjfit.sampler.state import SamplerConfig


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=64, help="image size of the synthetic sphere")
    parser.add_argument("--chains", type=int, default=4, help="chains, run serially and on two Dask workers")
    parser.add_argument("--iterations", type=int, default=2000, help="iterations per chain")
    args = parser.parse_args()
    observations, labels, _ = sphere_stack(args.size, n_lights=10, seed=0)
    problem = Problem.from_observations(observations)
    prior = make_prior("default", y=problem.y, diffuse_scale=problem.A)
    config = SamplerConfig.from_flat(max_u=3, max_v=3, burn_in=args.iterations // 2)
    specs = [ChainSpec(problem=problem, prior=prior, config=config, seed=7, chain=c, n_chains=args.chains,
                       iterations=args.iterations, truth_labels=labels) for c in range(args.chains)]
    started = time.perf_counter()
    serial = [run_chain(spec) for spec in specs]
    serial_s = time.perf_counter() - started
    with dask_client(None, n_workers=2) as client:
        client.run(lambda: None)                         # workers up before timing
        started = time.perf_counter()
        distributed = dask_map(run_chain, specs, client=client)
        distributed_s = time.perf_counter() - started
    same = all(np.array_equal(a.theta, b.theta, equal_nan=True) and np.array_equal(a.n_u, b.n_u)
               for a, b in zip(serial, distributed))
    print(f"{args.chains} chains x {args.iterations} iterations, {args.size} x {args.size}, {problem.n_obs:,} observations")
    print(f"{'run':<28} {'wall s':>8}")
    print(f"{'serial (one process)':<28} {serial_s:>8.1f}")
    print(f"{'Dask, 2 local workers':<28} {distributed_s:>8.1f}")
    print(f"speed-up {serial_s / distributed_s:.2f}x; identical samples: {same}")


if __name__ == "__main__":
    main()
