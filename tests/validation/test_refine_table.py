"""validation/refine_table.py's row text, on a refine result built here (no fit)."""
from __future__ import annotations

from builders import validation_script


def test_a_revision_in_a_trial_that_was_not_kept_says_so():
    """Round 2 (kept) swapped an effect; round 3 was a trial that was not kept and dropped one; round 4, a trial
    that was kept, swapped one: only round 3's revision is marked, since the loop's result does not carry it."""
    swap = {"action": "swapped", "effect": "ggx", "replacement": "coating", "after_step": 0}
    drop = {"action": "dropped", "effect": "ambient", "after_step": 1}
    refined = {"rounds": [{"revisions": []}, {"revisions": [swap]}, {"revisions": [drop]}, {"revisions": [swap]}],
               "trials": [{"round": 3, "kept": False}, {"round": 4, "kept": True}]}
    assert validation_script("refine_table").revisions(refined) == [
        "ggx swapped for coating in round 2", "ambient dropped in round 3 (a trial not kept)",
        "ggx swapped for coating in round 4"]
