"""The rough interface's internal transmission ``1 - R_int(alpha, eta)`` as a Chebyshev series (rjfit/model/rough_interface.py).

``R_int = 2 mean_k(rho(mu_k; 1/eta) mu_k)`` over roughplastic's 64 cosines, ``rho`` the rough interface's reflectance
of light from inside. Its integrand has the kink of total internal reflection, so a product rule of fixed order is
jagged in (alpha, eta): at Mitsuba's 128 x 128 nodes, second differences over eta steps of 1e-3 change sign at 1e-5,
a hundred times the smooth function's, which a finite-difference Hessian reads as curvature. This script computes it
at ``ORDER`` x ``ORDER`` nodes (512: within about 2e-5 of 1024) at Chebyshev points of (log alpha, eta) over the
series' domain, fits a tensor Chebyshev series (least squares), checks it at random points, and prints the
coefficients for the module. About 5 minutes on 2 cores.

    .venv/bin/python validation/rough_interface_fit.py [--degree 15 9] [--check 24] [--seed 1]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rjfit.model.rough_interface import (SERIES_ALPHA, SERIES_ETA, TABLE_COSINES, chebyshev_coordinates,  # noqa: E402
                                         interface_reflectance)

ORDER = 512


def internal_transmission_quadrature(alpha, eta, order=ORDER):
    """``1 - R_int`` by the product rule of ``order`` x ``order`` nodes."""
    return 1.0 - 2.0 * float(np.mean(interface_reflectance(TABLE_COSINES, alpha, 1.0 / eta, order) * TABLE_COSINES))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--degree", type=int, nargs=2, default=(15, 9), help="series degree in log alpha and in eta")
    parser.add_argument("--check", type=int, default=24, help="random points the series is checked at")
    parser.add_argument("--seed", type=int, default=1, help="seed of the check points")
    args = parser.parse_args(argv)
    deg_a, deg_e = args.degree
    nodes_a = np.cos(np.pi * (np.arange(deg_a + 5) + 0.5) / (deg_a + 5))
    nodes_e = np.cos(np.pi * (np.arange(deg_e + 4) + 0.5) / (deg_e + 4))
    (a_low, a_high), (e_low, e_high) = SERIES_ALPHA, SERIES_ETA
    log_a = np.log(a_low) + 0.5 * (nodes_a + 1.0) * (np.log(a_high) - np.log(a_low))
    etas = e_low + 0.5 * (nodes_e + 1.0) * (e_high - e_low)
    started = time.perf_counter()
    rows, values = [], []
    for la in log_a:
        for eta in etas:
            x, y = chebyshev_coordinates(np.exp(la), eta)
            rows.append(np.polynomial.chebyshev.chebvander2d(np.atleast_1d(x), np.atleast_1d(y), [deg_a, deg_e])[0])
            values.append(internal_transmission_quadrature(np.exp(la), eta))
    coefficients, *_ = np.linalg.lstsq(np.array(rows), np.array(values), rcond=None)
    coefficients = coefficients.reshape(deg_a + 1, deg_e + 1)
    rng = np.random.default_rng(args.seed)
    worst = 0.0
    for _ in range(args.check):
        alpha = float(np.exp(rng.uniform(np.log(a_low), np.log(a_high))))
        eta = float(rng.uniform(e_low, e_high))
        x, y = chebyshev_coordinates(alpha, eta)
        fitted = float(np.polynomial.chebyshev.chebval2d(x, y, coefficients))
        worst = max(worst, abs(fitted / internal_transmission_quadrature(alpha, eta) - 1.0))
    print(f"# {len(values)} points, degree ({deg_a}, {deg_e}), {args.check} checks: max relative error {worst:.2e}, "
          f"{time.perf_counter() - started:.0f} s")
    print("INTERNAL_TRANSMISSION_SERIES = np.array([")
    for row in coefficients:
        print("    [" + ", ".join(f"{value:.10e}" for value in row) + "],")
    print("])")


if __name__ == "__main__":
    main()
