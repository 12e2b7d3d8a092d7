"""What the edge term pays each boundary of a fit's label snapshots, pair by pair.

A material fit under ``--preset measured`` holds a few-pixel material where the edge term pays its outline more than
the Potts prior charges for it. This rebuilds the fit's own problem and edge term (its first chain's, without running
it), takes a chain's label snapshots with two materials or more, fits each material's parameters to its pixels by
least squares (clipped into the prior's support: a 1-px material's fit may leave it), and prints per boundary its
pairs, its 4-neighbour pairs (what the Potts prior charges: beta each), the term's value, the pairs' own earnings
against no step (``scale (no_step - step)``, nats) and the value if no pair could earn more than a cap (an
outlier allowance in the no-step baseline: ``min(no_step, step + cap / scale)`` per pair).

Example::

    python validation/edge_pairs.py ../shared/data/diligent-ball runs/ball --chains 3 --caps 1 3 5
"""
from __future__ import annotations

import argparse
from pathlib import Path
from unittest import mock

import numpy as np
from chain_labels import chain_label_snapshots


def boundary_rows(edges, labels, theta) -> dict:
    """``{(k, m): (P, 4) array}`` per boundary of ``labels`` (flat or (H, W); -1 unlabelled) under ``theta`` (K, 4):
    each of its pairs' SS of the step, of both ends in k, in m, and of no step (the edge term's sums before they are
    added up: :func:`rjfit.sampler.regions.materials.passes.edges.pair_sums`); one channel."""
    from rjfit.sampler.passes.densities import coefficients
    from rjfit.sampler.regions.materials.passes.edges import pair_sums

    flat = np.asarray(labels).ravel()
    coef = coefficients(np.asarray(theta, float))
    rows = {}
    for j in range(edges.first.size):
        k, m = flat[edges.first[j]], flat[edges.second[j]]
        if k < 0 or m < 0 or k == m:
            continue
        two, one_k, one_m = pair_sums(j, k, m, coef, edges.start, edges.d, edges.c_first, edges.c_second,
                                      edges.l_first, edges.l_second, edges.gain)
        key, alone = ((k, m), (one_k, one_m)) if k < m else ((m, k), (one_m, one_k))
        rows.setdefault((int(key[0]), int(key[1])), []).append((two, *alone, edges.no_step[j]))
    return {key: np.array(value) for key, value in rows.items()}


def boundary_value(rows, scale: float, cap: float = np.inf) -> float:
    """One boundary's share of the edge term from its :func:`boundary_rows` (nats), with no pair earning more than
    ``cap`` nats against no step (inf: the term as it is)."""
    two, alone_k, alone_m, no_step = rows.T
    capped = np.minimum(no_step, two + cap / scale)
    return float(scale * (min(alone_k.sum(), alone_m.sum(), capped.sum()) - two.sum()))


def least_squares_theta(problem, labels, n_materials: int, prior) -> np.ndarray:
    """(K, 4) each material's least-squares parameters on its pixels, each clipped just inside the prior's support."""
    from rjfit.data.pixelfit import group_params

    group = np.asarray(labels).ravel()[np.asarray(problem.pixel, np.int64)]
    keep = group >= 0
    theta = group_params(*(np.asarray(a, np.float64)[keep] for a in (problem.y, problem.C, problem.log_cos_hn)),
                         group[keep], n_materials)
    for column, param in enumerate(prior.params):
        low, high = param.support()
        margin = 1e-6 * ((high - low) if np.isfinite(high - low) else 1.0)
        middle = low + 0.5 * (high - low) if np.isfinite(high - low) else low + 1.0
        theta[:, column] = np.clip(np.nan_to_num(theta[:, column], nan=middle), low + margin, high - margin)
    return theta


def fit_problem(dataset: Path, seed: int):
    """The problem, prior and edge term a ``--preset measured`` material fit of ``dataset`` samples (its first chain's
    spec, taken before any chain runs)."""
    import tempfile

    import rjfit.pipeline.fit as fit_module
    from rjfit.pipeline.fit_dataset import fit_dataset
    from rjfit.pipeline.options import FitOptions

    taken = {}

    class Taken(Exception):
        pass

    def take(specs, processes=None, threads=None):
        taken["spec"] = next(iter(specs))
        raise Taken

    options = FitOptions(n_chains=1, iterations=10, seed=seed, progress=False, regions="materials",
                         preset="measured")
    with tempfile.TemporaryDirectory() as out, mock.patch.object(fit_module, "run_chains", take):
        try:
            fit_dataset(dataset, Path(out) / "fit", options, allow_unvalidated=True)
        except Taken:
            pass
    spec = taken["spec"]
    return spec.problem, spec.prior, spec.shared["bonds"].edges


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("fit", type=Path, help="a material fit of it (with materials.npz)")
    parser.add_argument("--chains", type=int, nargs="*", help="the chains to read (default: all)")
    parser.add_argument("--snapshots", type=int, default=4, help="the last this many snapshots with K >= 2, per chain")
    parser.add_argument("--caps", type=float, nargs="*", default=[1.0, 3.0, 5.0], help="caps per pair, nats")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    problem, prior, edges = fit_problem(args.dataset, args.seed)
    print(f"edge term: power {edges.power:.4g}, scale {edges.scale:.4g}, {edges.first.size} pairs")
    for chain, snapshots in enumerate(chain_label_snapshots(args.fit)):
        if args.chains and chain not in args.chains:
            continue
        labelled = [np.nan_to_num(np.asarray(s, float), nan=-1.0).astype(np.int64) for s in snapshots]
        several = [i for i, labels in enumerate(labelled) if np.unique(labels[labels >= 0]).size >= 2]
        for i in several[-args.snapshots:]:
            ids, labels = np.unique(labelled[i], return_inverse=True)
            labels = labels.reshape(labelled[i].shape) - int(ids[0] < 0)      # 0 .. K - 1, -1 unlabelled
            theta = least_squares_theta(problem, labels, int(labels.max()) + 1, prior)
            counts = np.bincount(labels[labels >= 0])
            print(f"chain {chain}, snapshot {i}: materials of {counts.tolist()} px")
            for (k, m), rows in sorted(boundary_rows(edges, labels, theta).items()):
                potts = int(np.sum((labels[:, :-1] == k) & (labels[:, 1:] == m) | (labels[:, :-1] == m)
                                   & (labels[:, 1:] == k)) + np.sum((labels[:-1] == k) & (labels[1:] == m)
                                                                    | (labels[:-1] == m) & (labels[1:] == k)))
                earn = edges.scale * (rows[:, 3] - rows[:, 0])
                print(f"  {k}-{m}: {len(rows)} pairs, {potts} 4-neighbour pairs, term "
                      f"{boundary_value(rows, edges.scale):.1f}; per pair against no step: median "
                      f"{np.median(earn):.2f}, max {earn.max():.2f}; "
                      + ", ".join(f"cap {cap:g}: {boundary_value(rows, edges.scale, cap):.1f}" for cap in args.caps))


if __name__ == "__main__":
    main()
