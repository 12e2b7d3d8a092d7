"""Benchmark of the samplers in effective samples per second (the sampler issue's speed goals).

One chain per sampler, run one after the other in this process (BLAS limited to one
thread; ``--threads N`` gives each chain N Numba threads for its large passes, default 1:
one core; the ``--parallel-chains`` share the cores among them unless ``--threads`` is
given). Prints, side by side: rjfit's default sampler with the segmentation fixed at the
true four quadrant regions; the same kernel with the segmentation sampled as well (change
points moved, whole vectors redrawn, births and deaths tried; started in the true model,
ESS over its iterations in that model); and the paper-style component-wise random-walk MH
(segmentation fixed, with the incremental likelihood, and with a full likelihood pass per
proposal as the paper did): iterations per second, minimum and median ArviZ bulk ESS per
second of the 16 parameters, per second of sampling (after burn-in) and per second of the
whole run (burn-in counted). With ``--parallel-chains K``, K chains of the full kernel also
run side by side in processes (as ``rjfit fit`` runs its chains), ``--parallel-iterations``
(20,000) in all, and their sampling and wall times are printed beside the 60 s goal.

Data: the pure-numpy synthetic sphere (``rjfit.data.synthetic.sphere_stack``: Table 2 truth,
10 asymmetric point lights, noise variance 0.1), or a rendered data set (``--dataset DIR``,
read with ``rjfit.render.datasets.load_dataset``; the fixed change points are then the image's
centre lines, which is where ``paper_sphere`` puts its quadrant boundaries).

    .venv/bin/python validation/bench_sampler.py --size 128 --iterations 4000
"""
from __future__ import annotations

import argparse
import time

import numpy as np
from threadpoolctl import threadpool_limits


def _observations(args):
    if args.dataset:
        from rjfit.render.datasets import load_dataset

        dataset = load_dataset(args.dataset)
        return dataset.observations(), dataset.truth_params
    from rjfit.data.synthetic import sphere_stack

    obs, _, truth = sphere_stack(args.size, n_lights=args.lights, seed=args.seed)
    return obs, truth


def run_one(problem, prior, config, iterations, seed, start_theta):
    from rjfit.sampler.kernel import ChainContext, initial_state, step

    rng = np.random.default_rng(seed)
    height, width = problem.image_shape
    state = initial_state(problem, prior, config, rng,
                          changepoints=(np.full(height, width / 2.0), np.full(width, height / 2.0)), theta=start_theta)
    draws = np.empty((iterations, state.n_regions, 4))
    burn = config.kernel.burn_in
    context = ChainContext()         # what the chain's steps reuse, as run_chain keeps it
    t0 = time.perf_counter()
    t_burn = t0
    for t in range(iterations):
        state, _ = step(state, rng, problem, prior, config, context)
        # segmentation sampled: parameters are kept in the start's model only (NaN elsewhere)
        draws[t] = state.theta if state.n_regions == draws.shape[1] else np.nan
        if t + 1 == burn:
            t_burn = time.perf_counter()
    t1 = time.perf_counter()
    return draws, t1 - t0, t1 - t_burn


def _parallel_chain(problem, prior, iterations, seed, start, threads):
    from rjfit.sampler.runner import numba_threads
    from rjfit.sampler.state import SamplerConfig

    with threadpool_limits(1), numba_threads(threads):
        config = SamplerConfig.from_flat(burn_in=iterations // 2, sampler="adaptive", max_u=3, max_v=3)
        _, total_s, _ = run_one(problem, prior, config, iterations, seed, start)
    return total_s


def parallel_figures(problem, prior, args, start):
    """The full kernel as fits run it: chains side by side in processes, ``--parallel-iterations`` in total."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from rjfit.sampler.runner import default_threads

    k = args.parallel_chains
    share = args.parallel_iterations // k
    threads = args.threads or default_threads(k)     # as rjfit fit shares the cores among its chains
    seeds = np.random.SeedSequence(args.seed).spawn(k)       # one independent stream per chain
    t0 = time.perf_counter()
    with ProcessPoolExecutor(k, mp_context=multiprocessing.get_context("spawn")) as pool:
        seconds = list(pool.map(_parallel_chain, [problem] * k, [prior] * k, [share] * k, seeds, [start] * k,
                                 [threads] * k))
    wall = time.perf_counter() - t0
    print(f"full kernel, {k} chains x {share} iterations side by side ({k * share} in all, {threads} thread(s) "
          f"each): the chains sample for "
          f"{', '.join(f'{s:.1f}' for s in seconds)} s; wall {wall:.1f} s with process start and loading "
          f"(goal at 256 x 256: 20,000 iterations in <= 60 s)")


def ess_figures(draws, burn):
    import arviz as az

    post = draws[burn:]
    post = post[np.all(np.isfinite(post), axis=(1, 2))]      # iterations in the start's model
    ess = np.array([[float(az.ess(post[:, r, k][None], method="bulk")) for k in range(4)] for r in range(post.shape[1])])
    return ess


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=128, help="image size of the pure-NumPy paper sphere")
    parser.add_argument("--lights", type=int, default=10, help="number of lights")
    parser.add_argument("--iterations", type=int, default=4000, help="iterations of the default sampler")
    parser.add_argument("--paper-iterations", type=int, default=4000,
                        help="iterations of the paper-style sampler on the incremental likelihood")
    parser.add_argument("--segmentation-iterations", type=int, default=2000,
                        help="iterations of the default kernel with change points, births and deaths sampled "
                             "(started in the true model; ESS over its iterations in that model)")
    parser.add_argument("--full-iterations", type=int, default=400,
                        help="iterations of the paper-style sampler with a full likelihood pass per proposal")
    parser.add_argument("--burn-in", type=float, default=0.5, help="discarded fraction of each run")
    parser.add_argument("--dataset", default=None, help="a data set folder instead of the pure-NumPy sphere")
    parser.add_argument("--seed", type=int, default=0, help="seed of the data and the chains")
    parser.add_argument("--threads", type=int, default=None,
                        help="Numba threads of each chain (its large passes run in pieces on them; the samples are "
                             "the same for any number); default: 1 for the chains run in this process, the cores "
                             "each of the --parallel-chains leaves free for those")
    parser.add_argument("--parallel-chains", type=int, default=0,
                        help="also run this many chains of the full kernel side by side, in processes (as fits run "
                             "their chains), --parallel-iterations in total, and print their wall time (0: skip)")
    parser.add_argument("--parallel-iterations", type=int, default=20000,
                        help="iterations of the --parallel-chains chains together (each runs its share)")
    args = parser.parse_args(argv)

    from rjfit.sampler.forward import Problem
    from rjfit.sampler.priors import make_prior
    from rjfit.sampler.state import SamplerConfig

    obs, truth = _observations(args)
    problem = Problem.from_observations(obs)
    prior = make_prior("default", y=problem.y, diffuse_scale=problem.A)
    # a dispersed common start: the prior's I0 centre, kd 0.5, gamma 10, sigma^2 = var(y) / 10
    start = np.tile([np.exp(prior.params[0].a), 0.5, 10.0, 0.1 * np.var(problem.y)], (4, 1))
    print(f"{problem.n_obs} valid observations, image {problem.image_shape}, 4 fixed regions")
    rows = []
    fixed = dict(max_u=1, max_v=1, update_changepoints=False, jumps=False)
    runs = [("default (adaptive)", dict(sampler="adaptive", **fixed), args.iterations),
            ("default, segmentation sampled", dict(sampler="adaptive", max_u=3, max_v=3), args.segmentation_iterations),
            ("paper-style MH, incremental", dict(sampler="paper", **fixed), args.paper_iterations),
            ("paper-style MH, full pass", dict(sampler="paper", full_recompute=True, **fixed), args.full_iterations)]
    from rjfit.sampler.runner import numba_threads

    threads = args.threads or 1
    print(f"each chain on {threads} Numba thread(s)")
    with threadpool_limits(1), numba_threads(threads):
        for name, options, iterations in runs:
            if iterations <= 0:
                continue
            burn = int(args.burn_in * iterations)
            config = SamplerConfig.from_flat(burn_in=burn, **options)
            draws, total_s, sampling_s = run_one(problem, prior, config, iterations, args.seed, start)
            ess = ess_figures(draws, burn)
            means = draws[burn:].mean(axis=0)
            rows.append((name, iterations, iterations / total_s, ess.min(), np.median(ess), sampling_s, total_s, means))
    header = (f"{'sampler':30s} {'iters':>6s} {'it/s':>8s} {'minESS/s':>9s} {'medESS/s':>9s} "
              f"{'minESS/s(+burn)':>15s} {'medESS/s(+burn)':>15s} {'min ESS':>8s}")
    print(header)
    for name, iterations, rate, ess_min, ess_med, sampling_s, total_s, _ in rows:
        print(f"{name:30s} {iterations:6d} {rate:8.1f} {ess_min / sampling_s:9.2f} {ess_med / sampling_s:9.2f} "
              f"{ess_min / total_s:15.2f} {ess_med / total_s:15.2f} {ess_min:8.1f}")
    rate = {name: ess_min / sampling_s for name, _, _, ess_min, _, sampling_s, _, _ in rows}
    for mine in ("default (adaptive)", "default, segmentation sampled"):
        for other in ("paper-style MH, incremental", "paper-style MH, full pass"):
            if mine in rate and other in rate:
                print(f"min ESS/s ratio {mine} / {other}: {rate[mine] / max(rate[other], 1e-12):.1f}x")
    for name, _, its_per_s, ess_min, _, sampling_s, _, _ in rows:
        if name == "default, segmentation sampled":      # the sampler issue's goals, beside the figures
            print(f"goals: min ESS/s {ess_min / sampling_s:.0f} with the segmentation sampled (goal at 128 x 128: "
                  f">= 137, NumPyro NUTS with the segmentation fixed; >= 100x the paper-style sampler); 20,000 "
                  f"iterations of the full kernel at this size take {20000 / its_per_s:.0f} s (goal at 256 x 256: "
                  f"<= 60 s)")
    if args.parallel_chains > 0:
        parallel_figures(problem, prior, args, start)
    if truth and rows:
        print("posterior means of the default sampler vs truth (I0, kd, gamma, sigma2):")
        for r, t in enumerate(truth):
            print(f"  region {r}: {np.round(rows[0][7][r], 4)}  truth {[t['I0'], t['kd'], t['gamma'], t['sigma2']]}")


if __name__ == "__main__":
    main()
