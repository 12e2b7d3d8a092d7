"""Time of one label sweep of the material model over a 128 x 128 x 12 problem (issue 27's speed figure).

One sweep = the per-pixel log-likelihood pass under every material, both checkerboard
colours and the statistics update of the relabelled pixels (``sweep_labels``), K = 4
materials, labels from a start that leaves many pixels to change. Then the proposals of
the merge/split and cluster moves (made, not accepted), timed by kind. Prints medians of
``--repeats`` runs after a warm-up (compilation excluded).

    PYTHONPATH=. python validation/bench_label_sweep.py [--size 128 --lights 12 --threads 1 --channels 3]
"""
from __future__ import annotations

import argparse
import time

import numpy as np


def main(argv=None):
    from rjfit.data.observations import Observations, stack_channels
    from rjfit.model.blinn import radiance
    from rjfit.sampler.forward import Problem
    from rjfit.sampler.kernel import initial_state
    from rjfit.sampler.regions.materials.cluster_swc import CLUSTER_KINDS, propose_cluster_move
    from rjfit.sampler.regions.materials.label_gibbs import sweep_labels
    from rjfit.sampler.regions.materials.merge_split import propose_merge_split
    from rjfit.sampler.regions.materials.segment_move import SEGMENT_KINDS, propose_segment_move
    from rjfit.sampler.priors import make_prior
    from rjfit.sampler.runner import numba_threads
    from rjfit.sampler.state import SamplerConfig, StepInfo, Work

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--lights", type=int, default=12)
    parser.add_argument("--materials", type=int, default=4)
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--channels", type=int, default=1,
                        help="3: a joint colour fit (--channel rgb): every channel observed, per-channel amplitudes")
    args = parser.parse_args(argv)
    rng = np.random.default_rng(0)
    n, L = args.size, args.lights
    truth = (np.add.outer(np.arange(n), np.arange(n)) * args.materials // (2 * n)).ravel()
    params = np.array([[10.0, 0.8, 5.0, 0.02], [6.0, 0.4, 30.0, 0.02], [14.0, 0.6, 12.0, 0.02], [8.0, 0.9, 3.0, 0.02]])
    pixel = np.repeat(np.arange(n * n), L)
    cos_ln, cos_hn, irr = rng.uniform(0.2, 1, pixel.size), rng.uniform(0.5, 1, pixel.size), rng.uniform(0.5, 1.5, pixel.size)
    theta = params[truth[pixel] % len(params)]
    per_channel = []
    for c in range(args.channels):      # channel c's amplitudes scaled by 1, 0.8, 1.2, ...
        scale = 1.0 + 0.2 * ((c + 1) // 2) * (-1) ** c if c else 1.0
        y = (radiance(scale * theta[:, 0], theta[:, 1], theta[:, 2], cos_ln, cos_hn, irr)
             + rng.normal(0, 0.15, pixel.size))
        per_channel.append(Observations(image_shape=(n, n), n_lights=L, pixel=pixel,
                                        light=np.tile(np.arange(L), n * n).astype(np.int32), y=y, cos_ln=cos_ln,
                                        cos_hn=cos_hn, irradiance=irr, object_mask=np.ones((n, n), bool)))
    obs = per_channel[0] if args.channels == 1 else stack_channels(per_channel)
    problem = Problem.from_observations(obs)
    prior = make_prior("default", y=problem.y, diffuse_scale=problem.A)
    config = SamplerConfig.from_flat(region_model="materials")
    state = initial_state(problem, prior, config, rng, n_materials=args.materials, theta=params[:args.materials])
    times = []
    with numba_threads(args.threads):
        for repeat in range(args.repeats + 1):
            work = Work(layout=state.layout, theta=state.theta.copy(), stats=state.stats.copy(),
                        log_lik=state.log_lik.copy(), labels=state.labels)
            start = time.perf_counter()
            changed = sweep_labels(work, rng, problem, config.regions.potts, StepInfo())
            if repeat:
                times.append(time.perf_counter() - start)
        proposal_times = {kind: [] for kind in ("split", "merge", *CLUSTER_KINDS, *SEGMENT_KINDS)}
        regions = config.regions
        moves = ((propose_merge_split, regions.merge_split), (propose_cluster_move, regions.cluster),
                 (propose_segment_move, regions.cluster.new_prob))
        for repeat in range(args.repeats + 1):
            for propose, settings in moves:
                start = time.perf_counter()
                kind = propose(work, rng, problem, prior, settings, regions.proposals, regions.potts,
                               regions.max_materials).kind
                if repeat:
                    proposal_times[kind].append(time.perf_counter() - start)
    print(f"{n} x {n} x {L} x {args.channels} channel(s) ({problem.n_obs} observations), K = {args.materials}, "
          f"{args.threads} thread(s): "
          f"label sweep median {1e3 * np.median(times):.2f} ms (min {1e3 * min(times):.2f}), {changed} pixels changed")
    print("proposals (not accepted), median ms: " + ", ".join(
        f"{kind} {1e3 * np.median(t):.1f} ({len(t)})" for kind, t in proposal_times.items() if t))


if __name__ == "__main__":
    main()
