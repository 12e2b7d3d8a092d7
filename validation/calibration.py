"""How often a calibrated posterior meets the sampler issue's "all 16 parameters within 2 sd" check.

The issue asks that on ``paper_sphere`` all 16 parameters (4 regions x I0, kd, gamma,
sigma^2) lie within 2 posterior sd of the truth. For one noise realisation that is a
random event even for an exact sampler: each 2-sd interval misses the truth about 5 % of
the time. This script fits many noise realisations of the same sphere (the pure-numpy
stack of ``rjfit.data.synthetic.sphere_stack``: Table 2 truth, 10 lights, noise variance
0.1) with the default sampler on the true segmentation, and prints per parameter how
often its 1- and 2-sd intervals cover the truth, beside the nominal 68.3 % / 95.4 %, and
the fraction of realisations in which all 16 do.

With ``--segmentation sampled`` the fits run the full kernel instead (change-point
elements, block shifts, vector redraws, births and deaths; models up to (3, 3)), started
in the true model with straight change points through the image centre, and keep the
draws in the true model (1, 1): whether sampling the boundaries (pixels near them change
region from draw to draw) shifts or widens the parameter posteriors. The main job's
parameters come from such a fit.

    .venv/bin/python validation/calibration.py --size 256 --realisations 20
    .venv/bin/python validation/calibration.py --size 256 --realisations 30 --segmentation sampled --workers 2
"""
from __future__ import annotations

import argparse
import time

import numpy as np
from threadpoolctl import threadpool_limits

NAMES = ("I0", "kd", "gamma", "sigma2")


def fit_one(size, seed, iterations, sampled=False):
    from rjfit.data.synthetic import sphere_stack
    from rjfit.sampler.forward import Problem
    from rjfit.sampler.kernel import ChainContext, initial_state, step
    from rjfit.sampler.priors import make_prior
    from rjfit.sampler.state import SamplerConfig

    obs, _, truth = sphere_stack(size, n_lights=10, seed=seed)
    problem = Problem.from_observations(obs)
    prior = make_prior("default", y=problem.y, diffuse_scale=problem.A)
    burn = iterations // 2
    fixed = {} if sampled else dict(update_changepoints=False, jumps=False)
    config = SamplerConfig.from_flat(max_u=3 if sampled else 1, max_v=3 if sampled else 1, burn_in=burn, **fixed)
    rng = np.random.default_rng(10_000 + seed)
    height, width = problem.image_shape
    state = initial_state(problem, prior, config, rng,
                          changepoints=(np.full(height, width / 2.0), np.full(width, height / 2.0)))
    draws = np.full((iterations - burn, 4, 4), np.nan)
    context = ChainContext()
    with threadpool_limits(1):
        for t in range(iterations):
            state, _ = step(state, rng, problem, prior, config, context)
            if t >= burn and state.layout.model_key == (1, 1):     # in the true model
                draws[t - burn] = state.theta
    draws = draws[np.all(np.isfinite(draws), axis=(1, 2))]
    truth = np.array([[region[name] for name in NAMES] for region in truth])
    return draws.mean(axis=0), draws.std(axis=0, ddof=1), truth, len(draws)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--realisations", type=int, default=20, help="noise seeds 0, 1, ...")
    parser.add_argument("--iterations", type=int, default=2000, help="per fit, half of them burn-in")
    parser.add_argument("--segmentation", choices=("fixed", "sampled"), default="fixed",
                        help="fit on the true segmentation, or sample it as the main job does")
    parser.add_argument("--workers", type=int, default=1, help="fits run in this many processes")
    args = parser.parse_args(argv)
    from concurrent.futures import ProcessPoolExecutor
    from functools import partial

    z = []
    started = time.perf_counter()
    one = partial(fit_one, args.size, iterations=args.iterations, sampled=args.segmentation == "sampled")
    with ProcessPoolExecutor(args.workers) as pool:
        for seed, (mean, sd, truth, kept) in enumerate(pool.map(one, range(args.realisations))):
            z.append((mean - truth) / sd)
            worst = np.unravel_index(np.argmax(np.abs(z[-1])), z[-1].shape)
            print(f"noise seed {seed:3d}: max |z| {np.abs(z[-1]).max():.2f} (region {worst[0]}, {NAMES[worst[1]]}); "
                  f"{int((np.abs(z[-1]) <= 2).sum())}/16 within 2 sd; {kept} draws in the true model", flush=True)
    z = np.array(z)
    n = len(z)
    print(f"\n{n} realisations at {args.size} x {args.size}, segmentation {args.segmentation}, "
          f"{args.iterations} iterations each, {time.perf_counter() - started:.0f} s")
    print(f"{'parameter':14s} {'within 1 sd':>12s} {'within 2 sd':>12s}   (nominal 68.3 %, 95.4 %; "
          f"binomial sd of a rate near 95 % over {n}: {100 * np.sqrt(0.046 * 0.954 / n):.1f} points)")
    for r in range(4):
        for k, name in enumerate(NAMES):
            inside1 = np.mean(np.abs(z[:, r, k]) <= 1)
            inside2 = np.mean(np.abs(z[:, r, k]) <= 2)
            print(f"region {r} {name:6s} {100 * inside1:11.0f}% {100 * inside2:11.0f}%")
    all16 = np.mean(np.all(np.abs(z) <= 2, axis=(1, 2)))
    print(f"all 16 within 2 sd in {100 * all16:.0f} % of the realisations "
          f"(independent parameters would give 0.954^16 = {100 * 0.954 ** 16:.0f} %)")
    print(f"pooled coverage: 1 sd {100 * np.mean(np.abs(z) <= 1):.1f} %, 2 sd {100 * np.mean(np.abs(z) <= 2):.1f} %")


if __name__ == "__main__":
    main()
