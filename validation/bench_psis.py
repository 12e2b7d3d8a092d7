"""Benchmark of PSIS-LOO: rjfit's vectorised estimator beside ArviZ's ``az.loo``, on one input.

The input is what ``rjfit diagnose`` gives PSIS-LOO: the pointwise log-likelihood (S draws x N
observations) of a Gaussian model under Laplace draws. Here S independent draws of a
location and a log scale, shared by all observations, against N Student-t observations (so
the k-hats span the good and the bad range). Prints, side by side, the seconds each takes,
the observations per second, and how far apart their results are (total elpd, its SE, the
largest per-observation difference of elpd and of k-hat).

    .venv/bin/python validation/bench_psis.py --observations 200000
"""
from __future__ import annotations

import argparse
import math
import time
import warnings

import numpy as np


def log_lik_matrix(n_draws, n_obs, seed):
    rng = np.random.default_rng(seed)
    location = 0.05 * rng.standard_normal((n_draws, 1))
    log_scale = 0.02 * rng.standard_normal((n_draws, 1))
    y = rng.standard_t(4, n_obs)
    return -0.5 * math.log(2 * math.pi) - log_scale - 0.5 * (y[None] - location) ** 2 * np.exp(-2 * log_scale)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int, default=100, help="posterior draws (rjfit diagnose uses 100)")
    parser.add_argument("--observations", type=int, default=200_000, help="observations")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    import arviz as az

    from rjfit.diagnose.psis import psis_loo

    log_lik = log_lik_matrix(args.draws, args.observations, args.seed)
    t0 = time.perf_counter()
    ours = psis_loo(log_lik)
    t_ours = time.perf_counter() - t0
    idata = az.from_dict(posterior={"z": np.zeros((1, args.draws))}, log_likelihood={"y": log_lik[None]})
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        theirs = az.loo(idata, pointwise=True)
    t_theirs = time.perf_counter() - t0

    print(f"PSIS-LOO of {args.observations:,} observations x {args.draws} draws (one core)")
    print(f"{'':26s} {'seconds':>9s} {'obs/s':>12s} {'elpd':>16s} {'SE':>10s}")
    for name, seconds, result in (("rjfit.diagnose.psis", t_ours, (ours.elpd, ours.se)),
                                  ("arviz az.loo", t_theirs, (float(theirs.elpd_loo), float(theirs.se)))):
        print(f"{name:26s} {seconds:9.2f} {args.observations / seconds:12,.0f} {result[0]:16.6f} {result[1]:10.4f}")
    print(f"speed-up {t_theirs / t_ours:.1f}x; largest per-observation difference: elpd "
          f"{np.max(np.abs(ours.pointwise - np.asarray(theirs.loo_i))):.2e}, k-hat "
          f"{np.max(np.abs(ours.pareto_k - np.asarray(theirs.pareto_k))):.2e}; "
          f"k-hat range {ours.pareto_k.min():.2f} to {ours.pareto_k.max():.2f}")


if __name__ == "__main__":
    main()
