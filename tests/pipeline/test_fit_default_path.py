"""End to end: the DEFAULT fit path, as `rjfit fit` and `rjfit run` take it, recovers a small sphere.

Dispersed starts (a random model in {0, 1} x {0, 1}, straight change points at random
positions, parameters drawn around the prior's centre), the annealed warm-up over half the
burn-in, both birth/death pairs, max 3 x 3 change points: nothing is started near the truth.
The case (a 24 x 24 four-quadrant sphere, 8 lights, 2 chains x 1500 iterations) and its
criteria are those of ``validation/default_fit_seeds.py``, which runs it over seeds: on
2026-11-25, 19 of seeds 0-19 passed (seed 8 failed: one chain stayed in a twisted mode, R-hat
1.83, accuracy 0.68), so about 5 % of seeds would fail a run this short. The test uses seed 0,
the command line's default, not a seed picked because it passes. Criteria: MAP labels >= 97 %
right (the silhouette's grazing pixels, 2 % of the object, cannot all be decided at 24 px)
and posterior probability >= 0.9 that four regions hold the object's pixels.
"""
from __future__ import annotations

from builders import validation_script


def test_the_default_fit_path_recovers_the_four_regions_from_dispersed_starts():
    script = validation_script("default_fit_seeds")
    summary = script.fit_once(seed=0)
    assert summary["anneal_iterations"] > 0          # the tempered warm-up ran
    assert summary["label_accuracy"] >= script.ACCURACY, summary["label_accuracy"]
    assert summary["four_region_probability"] >= script.FOUR_REGIONS, summary["four_region_probability"]
    assert script.passes(summary)
