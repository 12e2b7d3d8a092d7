"""Revisiting earlier choices (issue 26, item 3; :mod:`rjfit.diagnose.revisit`).

Real refits on small hidden-effect stacks (24 x 24, 10 lights, Mitsuba renders): sRGB-encoded
images (``camera_response``; ``camera_sensor`` for the drop, its noise before the curve), and the
same with Mitsuba's constant emitter (ambient) as well.
Measured log Bayes factors over the plain model at this size (seed 0): on the sRGB stack
camera_srgb 5009, camera_gamma 4609, camera_gamma + ambient 4602, camera_srgb + ambient 5004;
on ambient + sRGB, camera_srgb + ambient 6366, camera_gamma + ambient 6357, ambient 4620,
camera_srgb 2141 (a diagnosis with the fit's ambient + camera_gamma swaps to camera_srgb by
8.9; measured when the criticism put the noise after the curve, before issue 44; the decisions
below pass unchanged with the noise before it). Every decision below is decided by a margin
of 8.9 nats or more against the threshold of ln 100 = 4.6 (a swap's against 0: the higher
evidence wins), except the drop of ambient on the sRGB stack (log BF -4.6 for keeping it: at or
below the threshold, whichever side of 0 it falls; -2.4 on the sensor stack it now runs on).
Cost: three renders and about 25 refits, 25 s.
"""
import pytest

from rjfit.diagnose.candidates import LOG_BF_THRESHOLD
from rjfit.diagnose.context import build_context
from rjfit.effects import get_effect
from rjfit.diagnose.refit import refit
from rjfit.diagnose.revisit import revisit
from rjfit.diagnose.workflow import diagnose
from rjfit.render.datasets import load_dataset

from builders import hidden_data_sets

CANDIDATES = tuple(get_effect(name) for name in ("ambient", "camera_gamma", "camera_srgb", "light_calibration"))


@pytest.fixture(scope="module")
def hidden(tmp_path_factory):
    return hidden_data_sets(tmp_path_factory, resolution=24)


@pytest.fixture(scope="module")
def contexts(hidden):
    def context(kind):
        dataset = load_dataset(hidden(kind))
        return build_context(dataset, dataset.truth_labels, seed=0)
    return context


def _revisit(ctx, names, newest, threshold=LOG_BF_THRESHOLD):
    current = refit(ctx, tuple(get_effect(name) for name in names), seed=0)
    newest = next(e for e in current.effects if e.name == newest)
    lines = []
    final, revisions = revisit(ctx, current, newest, CANDIDATES, step=1, seed=0, threshold=threshold,
                               say=lines.append)
    return current, final, revisions, lines


def test_a_power_law_named_before_ambient_is_swapped_for_srgb(contexts):
    """The greedy order of the issue: camera_gamma named first, ambient second, on sRGB data."""
    ctx = contexts("camera_response")
    current, final, revisions, lines = _revisit(ctx, ("camera_gamma", "ambient"), newest="ambient")
    assert revisions and revisions[0]["action"] == "swapped", revisions
    assert (revisions[0]["effect"], revisions[0]["replacement"]) == ("camera_gamma", "camera_srgb")
    assert revisions[0]["log_bayes_factor"] > LOG_BF_THRESHOLD
    assert sorted(final.effect_names) == ["ambient", "camera_srgb"]
    assert final.log_evidence - current.log_evidence == pytest.approx(revisions[0]["log_bayes_factor"])
    assert any("camera_gamma swapped for camera_srgb" in line for line in lines)


def test_an_effect_the_later_one_explains_is_dropped(contexts):
    """On sRGB data without ambient light, ambient named first (it mimics part of the curve) goes
    once camera_srgb is in the model. The data's noise is a sensor's, before the curve, as the
    camera effects model it (``camera_sensor``; measured log BF for keeping ambient -2.4 at this
    size, seed 0). With the noise after the curve (``camera_response``) the camera's noise model
    is the wrong one, and ambient gained 33 nats by absorbing part of that misfit (measured
    2026-11-28)."""
    ctx = contexts("camera_sensor")
    _, final, revisions, lines = _revisit(ctx, ("ambient", "camera_srgb"), newest="camera_srgb")
    assert [(r["action"], r["effect"]) for r in revisions] == [("dropped", "ambient")]
    assert revisions[0]["log_bayes_factor"] <= LOG_BF_THRESHOLD
    assert final.effect_names == ["camera_srgb"]
    assert any("ambient dropped" in line for line in lines)


@pytest.mark.parametrize("names, newest", [(("ambient", "camera_srgb"), "camera_srgb"),
                                           (("camera_srgb", "ambient"), "ambient")])
def test_both_true_effects_are_kept(contexts, names, newest):
    """Negative control: on ambient + sRGB data neither true effect is dropped or swapped."""
    ctx = contexts("ambient+camera_response")
    current, final, revisions, _ = _revisit(ctx, names, newest)
    assert revisions == []
    assert final is current


def test_a_swap_between_same_kind_curves_needs_higher_evidence_not_a_decisive_margin(contexts):
    """The incumbent has no priority over a same-kind alternative: the swap of the first test is
    taken whatever the decision rule's threshold (here one no Bayes factor of this stack reaches,
    under which the old rule kept the power law or dropped it)."""
    ctx = contexts("camera_response")
    _, final, revisions, _ = _revisit(ctx, ("camera_gamma", "ambient"), newest="ambient", threshold=1e9)
    assert [(r["action"], r["effect"], r.get("replacement")) for r in revisions] == \
           [("swapped", "camera_gamma", "camera_srgb")]
    assert revisions[0]["not_told_apart"] is True          # below the (huge) threshold: said so
    assert sorted(final.effect_names) == ["ambient", "camera_srgb"]


def test_a_diagnosis_revisits_the_effects_its_fit_sampled(hidden, tmp_path):
    """rjfit refine's second round on ambient + sRGB data: the fit sampled ambient and camera_gamma
    (named on a wrong first segmentation). Its diagnosis must swap camera_gamma for camera_srgb
    on the fit's segmentation (here the truth's) before searching further, so that the loop
    fits again with the revised set; it used to take the fit's effects as given. About 5 s."""
    dataset = load_dataset(hidden("ambient+camera_response"))
    result = diagnose(dataset, dataset.truth_labels, tmp_path / "diagnosis", candidates=CANDIDATES[:3],
                      base_effects=("ambient", "camera_gamma"), max_steps=1, simulate=False, make_figures=False,
                      jobs=1)
    assert [(r["action"], r["effect"], r.get("replacement"), r["after_step"]) for r in result["revisions"]] == \
           [("swapped", "camera_gamma", "camera_srgb", None)]
    assert result["final_model"]["effects"] == ["ambient", "camera_srgb"]
    assert result["named_effects"] == ["camera_srgb"]
    assert "before step 1" in (tmp_path / "diagnosis" / "diagnosis.md").read_text()
