"""The naming rule's fifth part: nothing is named while the current model's gap is within UNEXPLAINED_GAP.

judge_candidates is called as the workflow calls it, without the Mitsuba simulation (rule 4 needs a mesh):
residuals whose mean square sets the gaps exactly (gap = mean(r^2) / sigma2 - 1, sigma2 = 1).
"""
import numpy as np

from rjfit.diagnose.misfit import UNEXPLAINED_GAP
from rjfit.diagnose.naming import judge_candidates


def residuals_with_gap(gap, n=1000):
    """n residuals of alternating sign with mean square exactly 1 + gap."""
    return np.sqrt(1.0 + gap) * np.where(np.arange(n) % 2 == 0, 1.0, -1.0)


def judge(gap_current, gap_with):
    row = {"effect": "light_calibration", "decisive": True}
    qualified = judge_candidates(None, [row], {}, {"light_calibration": residuals_with_gap(gap_with)},
                                 None, residuals_with_gap(gap_current), 1.0, simulate=False, n_sim_draws=0, seed=0)
    return row, qualified


def test_a_decisive_effect_on_a_gap_within_the_floor_is_not_named():
    # the coating stack's round 2: gap 0.001 -> -0.0103 ("closes 1133 %")
    row, qualified = judge(0.001, -0.0103)
    assert qualified == [] and not row["qualifies"]
    assert f"within {UNEXPLAINED_GAP:g}" in row["why_not"]


def test_just_above_the_floor_the_share_decides():
    row, qualified = judge(1.5 * UNEXPLAINED_GAP, 0.2 * UNEXPLAINED_GAP)
    assert qualified == [row] and row["gap_share"] > 0.5
    row, qualified = judge(1.5 * UNEXPLAINED_GAP, 1.2 * UNEXPLAINED_GAP)     # closes 20 %: the share rule says no
    assert qualified == [] and "closes" in row["why_not"]


def test_each_failed_rule_is_listed_in_short_of():
    row, _ = judge(0.001, -0.0103)
    assert row["short_of"] == ["misfit"]
    row, _ = judge(1.5 * UNEXPLAINED_GAP, 1.2 * UNEXPLAINED_GAP)
    assert row["short_of"] == ["gap_share"]
    row, _ = judge(1.5 * UNEXPLAINED_GAP, 0.2 * UNEXPLAINED_GAP)
    assert row["short_of"] == []


def test_a_supported_candidate_is_judged_for_a_trial_but_never_named():
    # Mitsuba's GGX dielectric under change points, 6 regions for 4: ggx's LOO gain 26.3 +- 15.9 over all
    # observations, 21.6 +- 7.7 where PSIS is reliable
    row = {"effect": "ggx", "decisive": False, "supported": True, "delta_elpd_loo": 26.3, "delta_elpd_loo_se": 15.9,
           "delta_elpd_loo_reliable": 21.6, "delta_elpd_loo_reliable_se": 7.7}
    qualified = judge_candidates(None, [row], {}, {"ggx": residuals_with_gap(0.2)}, None, residuals_with_gap(1.0),
                                 1.0, simulate=False, n_sim_draws=0, seed=0)
    assert qualified == [] and not row["qualifies"]
    assert row["short_of"] == ["decisive"]
    assert "26.3 = 1.7 SE; 21.6 = 2.8 SE where PSIS is reliable" in row["why_not"]
    unsupported = {"effect": "ambient", "decisive": False, "supported": False}
    assert judge_candidates(None, [unsupported], {}, {}, None, residuals_with_gap(1.0), 1.0, simulate=False,
                            n_sim_draws=0, seed=0) == []
    assert "short_of" not in unsupported        # neither decisive nor supported: not judged at all
