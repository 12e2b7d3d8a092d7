"""How fast this machine runs rjfit's two kinds of work: a reference to quote beside wall times.

The project's figures (a fit's minutes, the test suite's) were measured on shared machines whose
speed changed by a factor of two to three from day to day. A wall time means little without the
machine's speed on the same day; this prints it, for two kinds of work that make up a fit:

- ``pass``: one compiled pass of the gamma sums (:func:`rjfit.sampler.passes.sums.b_sums`) over
  1,420,000 float32 observations, the DiLiGenT ball's size: what a large region's step is made of.
- ``scalar``: one region's log-likelihood from its statistics in Python floats
  (:func:`rjfit.sampler.moves.region_terms.region_log_lik`): what a small region's step and the
  test suite's tiny chains are made of.

Each is the best of ``--repeats`` rounds (one thread, BLAS limited to one). Run it before and
after the figures it goes with, and quote both lines:

    .venv/bin/python validation/machine_speed.py
"""
from __future__ import annotations

import argparse
import time

import numpy as np
from threadpoolctl import threadpool_limits

BALL_OBSERVATIONS = 1_420_000


def pass_seconds(repeats: int) -> float:
    """Best seconds of one compiled gamma-sums pass over :data:`BALL_OBSERVATIONS` observations."""
    from rjfit.sampler.passes.sums import b_sums

    rng = np.random.default_rng(0)      # fixed data: the pass's cost does not depend on the values
    y = rng.random(BALL_OBSERVATIONS, dtype=np.float32)
    diffuse = rng.random(BALL_OBSERVATIONS, dtype=np.float32)
    log_cos_hn = -rng.random(BALL_OBSERVATIONS, dtype=np.float32)
    starts = np.arange(0, BALL_OBSERVATIONS, 96, dtype=np.int64)      # a pixel's lights in one run, as the ball
    ends = np.minimum(starts + 96, BALL_OBSERVATIONS)
    b_sums(y, diffuse, log_cos_hn, starts, ends, 1.0)       # compiled (or loaded) before timing
    gammas = np.linspace(0.2, 20.0, 20)
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        for gamma in gammas:
            b_sums(y, diffuse, log_cos_hn, starts, ends, gamma)
        best = min(best, (time.perf_counter() - t0) / gammas.size)
    return best


def scalar_seconds(repeats: int, calls: int = 100_000) -> float:
    """Best seconds of one :func:`region_log_lik` call (Python floats)."""
    from rjfit.sampler.moves.region_terms import region_log_lik

    stats = (1000.0, 52.0, 30.0, 20.0, 11.0, 7.0, 4.0)
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        for k in range(calls):
            region_log_lik(stats, 1.0, 0.6, 5.0 + k * 1e-6, 0.01)
        best = min(best, (time.perf_counter() - t0) / calls)
    return best


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5, help="rounds of each measurement; the best is printed")
    args = parser.parse_args(argv)
    with threadpool_limits(1):
        from rjfit.sampler.runner import numba_threads

        with numba_threads(1):
            one_pass = pass_seconds(args.repeats)
        scalar = scalar_seconds(args.repeats)
    print(f"machine speed: pass {one_pass * 1e3:.2f} ms ({one_pass / BALL_OBSERVATIONS * 1e9:.2f} ns an observation); "
          f"scalar {scalar * 1e6:.2f} us a call (best of {args.repeats}; {time.strftime('%Y-%m-%d %H:%M')})")


if __name__ == "__main__":
    main()
