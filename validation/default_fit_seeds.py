"""How often the default fit path recovers a small synthetic sphere, over seeds.

The default path is what ``rjfit fit`` / ``rjfit run`` take: dispersed starts (a random model
in {0, 1} x {0, 1}, straight change points at random positions, parameters drawn around the
prior's centre), an annealed warm-up over half the burn-in, the adaptive kernel with both
birth/death pairs, max 3 x 3 change points. This script fits the four-quadrant sphere of
``rjfit.data.synthetic.sphere_stack`` (SIZE x SIZE, 8 lights) with CHAINS chains of
ITERATIONS iterations for each seed and reports how many seeds pass the end-to-end test's
criteria (tests/pipeline/test_fit_default_path.py): the MAP labels >= 97 % right and the
posterior probability of the four true regions >= 0.9.

    python validation/default_fit_seeds.py --seeds 0-19
"""
from __future__ import annotations

import argparse
import tempfile
import time

from rjfit.data.synthetic import sphere_stack
from rjfit.pipeline.fit import fit

SIZE, LIGHTS, DATA_SEED = 24, 8, 4
CHAINS, ITERATIONS = 2, 1500
ACCURACY, FOUR_REGIONS = 0.97, 0.9


def fit_once(seed: int, iterations: int = ITERATIONS, chains: int = CHAINS) -> dict:
    obs, labels, truth = sphere_stack(SIZE, n_lights=LIGHTS, seed=DATA_SEED)
    with tempfile.TemporaryDirectory() as out:
        return fit(obs, out, truth_labels=labels, truth_params=truth, seed=seed, n_chains=chains,
                   iterations=iterations, processes=chains, progress=False, figures=False)


def passes(summary: dict) -> bool:
    return summary["label_accuracy"] >= ACCURACY and summary["four_region_probability"] >= FOUR_REGIONS


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", default="0-19", help="first-last (inclusive)")
    parser.add_argument("--iterations", type=int, default=ITERATIONS)
    args = parser.parse_args()
    first, last = (int(x) for x in args.seeds.split("-"))
    passed = 0
    for seed in range(first, last + 1):
        started = time.perf_counter()
        summary = fit_once(seed, args.iterations)
        ok = passes(summary)
        passed += ok
        print(f"seed {seed:3d}: {'pass' if ok else 'FAIL'}  accuracy {summary['label_accuracy']:.4f}  "
              f"P(4 regions) {summary['four_region_probability']:.3f}  MAP {summary['map_model']}  "
              f"R-hat {summary['rhat_max']}  {time.perf_counter() - started:.1f} s", flush=True)
    print(f"{passed} of {last - first + 1} seeds pass")


if __name__ == "__main__":
    main()
