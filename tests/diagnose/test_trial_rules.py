"""The trial a diagnosis offers and how rjfit refine judges it (rjfit.diagnose.pairs, rjfit.pipeline.refine_trial):
the rules on rows and round records as the workflow and the loop write them, without fits (the loop itself is
run on a rendered stack in tests/pipeline/test_refine_trial.py)."""
import pytest

from rjfit.diagnose.misfit import UNEXPLAINED_GAP
from rjfit.diagnose.pairs import trial_candidates
from rjfit.diagnose.document import _pair_lines
from rjfit.pipeline.refine import _next_round_lines
from rjfit.pipeline.refine_trial import (TRIAL_GAP_SHARE, drop_trial, judge_trial, next_trial, trial_after, trial_line,
                                         trial_to_fit)


def row(effect, log_bf, short_of, decisive=True, effects=None):
    out = {"step": 0, "effect": effect, "log_bayes_factor": log_bf, "decisive": decisive, "short_of": short_of,
           "gap_share": 0.2}
    if effects:
        out["effects"] = effects
    return out


def test_the_trial_is_the_decisive_candidate_short_of_the_gap_share_only_with_the_largest_log_bf():
    rows = [row("ggx", 1265.0, ["gap_share"]),
            row("coating", 1221.0, ["gap_share", "physical"]),            # a conflict: never tried
            row("ggx+coating", 2330.0, ["gap_share"], effects=["ggx", "coating"]),
            row("ambient", 5000.0, ["gap_share"], decisive=False)]        # not decisive: never tried
    assert [t["effects"] for t in trial_candidates(rows)] == [["ggx", "coating"], ["ggx"]]   # by log BF
    assert [t["effects"] for t in trial_candidates(rows[:2])] == [["ggx"]]
    assert trial_candidates(rows[1:2]) == []
    assert trial_candidates([row("ggx", 10.0, ["simulation"])]) == []    # the physics did not agree
    assert [t["within_floor"] for t in trial_candidates(rows)] == [False, False]


def test_a_decisive_candidate_on_a_gap_within_the_floor_is_a_trial_marked_so():
    # ggx_plastic under the material model: 7 regions for 4 left a gap of 0.099, fresnel decisive (log BF 80)
    rows = [row("fresnel", 80.4, ["misfit"]), row("masking", 37.9, ["misfit", "physical"]),
            row("second_lobe", 15.6, ["misfit"], decisive=False)]
    assert [(t["effects"], t["within_floor"]) for t in trial_candidates(rows)] == [(["fresnel"], True)]


def test_after_a_trial_not_kept_the_next_is_the_best_one_not_tried():
    diagnosis = {"trials": [{"effects": ["rough_coating"]}, {"effects": ["ambient", "fresnel"]},
                            {"effects": ["fresnel"]}]}
    tried = [["rough_coating"], ["fresnel"]]
    # the fit's own effects are left out of a trial; a set tried before is not fitted again
    assert next_trial(diagnosis, record(1.0, effects=["ambient"]), tried) is None
    assert next_trial(diagnosis, record(1.0), tried) == ["ambient", "fresnel"]
    assert tried[-1] == ["ambient", "fresnel"]
    assert next_trial(diagnosis, record(1.0), tried) is None
    assert next_trial({"trial": {"effects": ["fresnel"]}}, record(1.0), []) is None  # an older diagnosis


def record(gap, effects=(), named=(), dropped=(), follows=True, n_regions=4):
    return {"gap": gap, "effects": list(effects), "named": list(named), "dropped": list(dropped),
            "feature_change": [{"follows": follows}], "n_regions": n_regions}


def test_a_trial_is_fitted_only_where_the_round_changed_nothing():
    diagnosis = {"trial": {"effects": ["ggx", "coating"]}}
    assert trial_to_fit(diagnosis, record(3.6), [], True) == ["ggx", "coating"]
    assert trial_to_fit(diagnosis, record(3.6), [], False) is None                   # a joint colour fit
    assert trial_to_fit(diagnosis, record(3.6, named=["ambient"]), [], True) is None  # the loop refits anyway
    assert trial_to_fit(diagnosis, record(3.6, dropped=["ambient"]), [], True) is None
    assert trial_to_fit(diagnosis, record(3.6, follows=False), [], True) is None
    assert trial_to_fit(diagnosis, record(3.6), [["coating", "ggx"]], True) is None   # tried before
    assert trial_to_fit(diagnosis, record(3.6, effects=["ggx"]), [], True) == ["coating"]
    assert trial_to_fit({"trial": None}, record(3.6), [], True) is None


@pytest.mark.parametrize("gap_after, dropped, kept", [
    (TRIAL_GAP_SHARE * 3.58 * 0.99, False, True),       # at most half: kept
    (TRIAL_GAP_SHARE * 3.58 * 1.01, False, False),      # just above half: not kept
    (0.5, True, False),                                 # the diagnosis of the trial fit dropped one of its effects
])
def test_a_trial_is_kept_when_the_gap_on_its_own_segmentation_halves_and_its_effects_stay(gap_after, dropped, kept):
    final = ["ggx"] if dropped else ["ggx", "coating"]
    verdict = judge_trial(["ggx", "coating"], record(3.58), record(gap_after), final)
    assert verdict["kept"] is kept
    assert verdict["gap_before"] == 3.58 and verdict["gap_after"] == gap_after
    assert ("dropped coating" in verdict["why"]) is dropped


def test_a_gap_falling_into_the_floor_without_halving_does_not_keep_a_trial():
    # the GGX roughplastic stack under the material model: coating + light_calibration took 0.105 to 0.069
    both = ["coating", "light_calibration"]
    verdict = judge_trial(both, record(0.105), record(0.069), both)
    assert not verdict["kept"] and 0.069 < UNEXPLAINED_GAP


def test_a_trial_fit_with_more_regions_is_not_kept_however_far_its_gap_falls():
    # Mitsuba's Beckmann roughplastic under change points: fresnel took 1.51 to 0.0117 with 9 regions for 6
    verdict = judge_trial(["fresnel"], record(1.51, n_regions=6), record(0.0117, n_regions=9), ["fresnel"])
    assert not verdict["kept"] and "more regions (9 against 6)" in verdict["why"]
    assert judge_trial(["fresnel"], record(1.51, n_regions=6), record(0.0117, n_regions=6), ["fresnel"])["kept"]


@pytest.mark.parametrize("gap_after, regions_after, dropped, kept", [
    (0.02, 4, False, True),                     # fewer regions, the gap still within the floor: kept
    (0.02, 7, False, False),                    # as many regions: a tiny gap's share says nothing
    (-0.05, 8, False, False),                   # more regions
    (UNEXPLAINED_GAP * 1.01, 4, False, False),  # fewer regions, but a misfit the floor calls one
    (0.02, 4, True, False),                     # its diagnosis dropped an effect of the trial
])
def test_a_trial_offered_within_the_floor_is_kept_only_where_its_fit_needs_fewer_regions(gap_after, regions_after,
                                                                                        dropped, kept):
    final = [] if dropped else ["fresnel"]
    verdict = judge_trial(["fresnel"], record(0.099, n_regions=7), record(gap_after, n_regions=regions_after), final)
    assert verdict["kept"] is kept
    assert (f"{regions_after} regions for 7" in verdict["why"]) is kept


def test_a_flexible_effect_decisive_on_a_tiny_gap_at_the_true_regions_is_not_kept():
    # the GGX roughplastic stack after the coating: light_calibration was decisive on a gap of 0.001 at 4 regions
    verdict = judge_trial(["light_calibration"], record(0.001), record(-0.03), ["light_calibration"])
    assert not verdict["kept"] and "no fewer regions" in verdict["why"]


def test_the_loop_and_the_diagnosis_state_the_rule_a_trial_within_the_floor_is_judged_by():
    trial = {"effects": ["fresnel"], "log_bayes_factor": 80.4, "gap_share": 0.23, "step": 0}
    within = _pair_lines({"trial": {**trial, "within_floor": True}})[-1]
    above = _pair_lines({"trial": {**trial, "within_floor": False}})[-1]
    assert "fewer regions" in within and "at most half" in above
    floor, halving = ({"trial": ["fresnel"], "gap": gap, "n_regions": 7} for gap in (0.099, 0.4))
    assert "fewer than 7 regions" in _next_round_lines(0, floor, ("fresnel",))[0]
    assert "at most 50% of 0.4" in _next_round_lines(0, halving, ("fresnel",))[0]


def final_model(effects, counts):
    return {"effects": effects,
            "parameters": {f"{name}.p{k}": {} for name, n in zip(effects, counts) for k in range(n)} | {"I0[0]": {}}}


def test_a_passenger_of_a_kept_pair_is_dropped_as_a_trial_the_effect_of_most_parameters_first():
    # the GGX lobe under a coating (materials, seed 1): ggx kept alone, then coating + light_calibration kept on
    # 8 regions for 4; round 3's gap -0.021 within the floor, nothing offered
    diagnosis = {"final_model": final_model(["ggx", "coating", "light_calibration"], [1, 2, 9])}
    verdicts = [{"effects": ["ggx"], "kept": True}, {"effects": ["coating", "light_calibration"], "kept": True}]
    tried = [["ggx"], ["coating", "light_calibration"]]
    assert drop_trial(diagnosis, record(-0.021, n_regions=8), verdicts, tried) == (["ggx", "coating"],
                                                                                     "light_calibration")
    assert tried[-1] == ["coating", "ggx"]
    assert drop_trial(diagnosis, record(-0.021), verdicts, tried) == (["ggx", "light_calibration"], "coating")
    assert drop_trial(diagnosis, record(-0.021), verdicts, tried) is None          # both tried
    for blocked in (record(0.2), record(-0.02, named=["ambient"]), record(-0.02, dropped=["ggx"]),
                    record(-0.02, follows=False)):
        assert drop_trial(diagnosis, blocked, verdicts, []) is None
    single = [{"effects": ["ggx"], "kept": True}, {"effects": ["coating", "light_calibration"], "kept": False}]
    assert drop_trial(diagnosis, record(-0.02), single, []) is None                 # no pair was kept
    dropped_before = verdicts + [{"effects": ["ggx", "coating"], "kept": True, "drops": ["light_calibration"]}]
    lone = {"final_model": final_model(["ggx", "coating"], [1, 2])}
    assert drop_trial(lone, record(-0.02), dropped_before, []) == (["ggx"], "coating")    # the pair's coating
    assert drop_trial({"final_model": final_model(["coating"], [2])}, record(-0.02), verdicts, []) is None


def test_the_trial_after_a_round_is_the_diagnosis_trial_beside_the_model_else_a_drop_which_the_loop_announces():
    diagnosis = {"trial": {"effects": ["ggx"]}, "final_model": final_model(["coating", "light_calibration"], [2, 9])}
    verdicts = [{"effects": ["coating", "light_calibration"], "kept": True}]
    assert trial_after(diagnosis, record(-0.02), ["coating", "light_calibration"], (verdicts, []), True) == (
        ["ggx"], ["coating", "light_calibration"], [])
    chosen = trial_after(diagnosis, record(-0.02), ["coating", "light_calibration"], (verdicts, [["ggx"]]), True)
    assert chosen == (["coating"], [], ["light_calibration"])
    assert trial_after(diagnosis, record(-0.02), ["coating"], (verdicts, [["ggx"]]), False) is None   # colour
    line = trial_line(2, {**record(-0.02, n_regions=8), "trial": chosen[0], "trial_drops": chosen[2]}, ("coating",))
    assert "without light_calibration" in line and "fewer than 8 regions" in line


def test_a_supported_candidate_is_a_trial_after_every_decisive_one_and_says_so():
    supported = {**row("ggx", 30.9, ["decisive", "gap_share"], decisive=False), "supported": True, **LOO}
    rows = [supported, row("fresnel", 12.0, ["gap_share"]),
            {**row("masking", 50.0, ["decisive", "physical"], decisive=False), "supported": True, **LOO}]  # a conflict
    trials = trial_candidates(rows)
    assert [(t["effects"], t["decisive"]) for t in trials] == [(["fresnel"], True), (["ggx"], False)]
    assert {key: trials[1][key] for key in LOO} == LOO
    # the diagnosis, the loop's choice and its announcement all say it is supported, not decisive
    assert f"is supported (its LOO gain {SUPPORT}, short of" in _pair_lines({"trial": trials[1]})[-1]
    assert "is decisive" in _pair_lines({"trial": trials[0]})[-1]
    line = trial_line(0, {"trial": ["ggx"], "gap": 0.4, "n_regions": 6, "trial_offer": trials[1]}, ("ggx",))
    assert f"supported (its LOO gain {SUPPORT}" in line and "decisive" not in line.replace("decision", "")
    assert "decisive" in trial_line(0, {"trial": ["fresnel"], "gap": 0.4, "n_regions": 6, "trial_offer": trials[0]},
                                     ("fresnel",))


#: ggx on the GGX dielectric's 6 regions for 4 under change points (docs/results/2026-12-01-supported-trials.md)
LOO = {"delta_elpd_loo": 26.3, "delta_elpd_loo_se": 15.9, "delta_elpd_loo_reliable": 21.6,
       "delta_elpd_loo_reliable_se": 7.7}
SUPPORT = "26.3 = 1.7 SE; 21.6 = 2.8 SE where PSIS is reliable"


def test_a_step_where_nothing_is_decisive_offers_its_supported_candidates_as_trials():
    import numpy as np
    from types import SimpleNamespace

    from rjfit.diagnose.document import trial_offer_line
    from rjfit.diagnose.pairs import step_trials
    from rjfit.diagnose.workflow import SearchSettings

    def residuals_with_gap(gap, n=1000):      # mean square exactly 1 + gap: the gap at sigma2 = 1
        return np.sqrt(1.0 + gap) * np.where(np.arange(n) % 2 == 0, 1.0, -1.0)

    ggx = {"step": 1, "effect": "ggx", "kind": "lobe", "log_bayes_factor": 30.9, "decisive": False, "supported": True,
           **LOO}
    ambient = {"step": 1, "effect": "ambient", "kind": "light", "log_bayes_factor": 2.0, "decisive": False,
               "supported": False}
    pairs, trials = step_trials(SimpleNamespace(has_mesh=False), (1, None, [ggx, ambient]),
                                ({}, {"ggx": residuals_with_gap(0.2)}), residuals_with_gap(1.0), 1.0,
                                SearchSettings(candidates=()))
    assert pairs == [] and ggx["short_of"] == ["decisive"] and "short_of" not in ambient
    assert [(t["effects"], t["decisive"], t["step"]) for t in trials] == [(["ggx"], False, 1)]
    assert trial_offer_line(trials[0]).endswith(f"ggx (supported: its LOO gain {SUPPORT})")
