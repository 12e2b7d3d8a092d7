"""The edge term's measured noise (rjfit.sampler.regions.materials.edge_noise): the variance model's fit, its turn
feature, its floor and its refusals. That the term weighs each match by it as defined: tests/sampler/test_edge_term.py
(test_a_measured_noise_weighs_each_match_as_defined)."""
import numpy as np
import pytest

from rjfit.sampler.regions.materials.edge_noise import (MIN_WHITE, difference_noise, match_variance, pair_turn,
                                                        valid_noise)

TRUE = (0.6, 0.5, 40.0)


def simulated(seed, n=200_000, coefficients=TRUE, outliers=0.0):
    """Standardised misfits z ~ N(0, a + b g^2 + c t^2) with shading changes g and turns t spread as on the shared
    stacks (t of about 0.1, g of a few spreads); a share ``outliers`` of them replaced by steps of 20 sd (a paint's
    outline)."""
    rng = np.random.default_rng(seed)
    g, t = rng.normal(0.0, 2.0, n), rng.gamma(2.0, 0.05, n)
    z = rng.normal(0.0, np.sqrt(match_variance(coefficients, g, t)))
    hit = rng.random(n) < outliers
    z[hit] = 20.0 * np.sign(rng.normal(size=hit.sum())) * np.sqrt(match_variance(coefficients, g[hit], t[hit]))
    return z, g, t


# Tolerances: over seeds 20 to 31 (not the tests' seeds) at 200,000 matches the fitted coefficients' relative sd was
# 5.9 % (white), 1.8 % (shading) and 4.1 % (turn), the largest errors 9 %, 3 % and 9 %; over 20 seeds at 100,000 their
# means lay within 2 % of the truth. The bounds are 3.4 to 4.4 of those sd.
TOLERANCE = {"white": 0.2, "shading": 0.08, "turn": 0.15}


def test_the_coefficients_of_a_known_model_are_recovered():
    fitted = difference_noise(*simulated(seed=1))
    for name, truth in zip(("white", "shading", "turn"), TRUE):
        assert fitted[name] == pytest.approx(truth, rel=TOLERANCE[name]), name
    assert not fitted["floored"]


def test_a_paints_outline_does_not_widen_them():
    """1 % of the matches 20 sd off (a paint's outline crossing the cells) move no coefficient beyond its tolerance:
    the cells' variances are robust."""
    fitted = difference_noise(*simulated(seed=2, outliers=0.01))
    for name, truth in zip(("white", "shading", "turn"), TRUE):
        assert fitted[name] == pytest.approx(truth, rel=TOLERANCE[name]), name


def test_white_misfits_give_one_scale():
    """Misfits of one variance: white near 1 and no match's variance more than 5 % above it (the term of one scale
    in effect; the same tolerance reasoning as above, white's bound)."""
    z, g, t = simulated(seed=3, coefficients=(1.0, 0.0, 0.0))
    fitted = difference_noise(z, g, t)
    assert fitted["white"] == pytest.approx(1.0, rel=TOLERANCE["white"])
    coefficients = (fitted["white"], fitted["shading"], fitted["turn"])
    assert np.quantile(match_variance(coefficients, g, t), 0.99) < 1.05 * fitted["white"]


def test_a_model_without_a_white_part_is_floored_and_says_so():
    z, g, t = simulated(seed=4, coefficients=(0.0, 1.0, 0.0))
    fitted = difference_noise(z, g, t)
    assert fitted["floored"] and fitted["white"] == MIN_WHITE
    assert fitted["shading"] == pytest.approx(1.0, rel=TOLERANCE["shading"])


def test_too_few_matches_give_one_scale():
    z, g, t = simulated(seed=5, n=100)
    assert difference_noise(z, g, t) == {"white": 1.0, "shading": 0.0, "turn": 0.0, "floored": False}


def test_a_pairs_turn_is_the_rms_change_of_cos_hn():
    cos_first = np.array([0.9, 0.8, 0.5, 0.7])
    cos_second = np.array([0.8, 0.8, 0.9, 0.7])
    pair = np.array([0, 0, 1, 2])
    turn = pair_turn(np.log(cos_first), np.log(cos_second), pair, 4)
    assert turn == pytest.approx([np.sqrt((0.01 + 0.0) / 2), 0.4, 0.0, 0.0])


def test_refusals():
    with pytest.raises(ValueError, match="one shading change and one turn per match"):
        difference_noise(np.zeros(3), np.zeros(2), np.zeros(3))
    assert valid_noise("measured") and valid_noise("constant") and valid_noise((1.0, 0.0, 2.0))
    for bad in ("auto", (0.0, 1.0, 1.0), (1.0, -1.0, 0.0), (1.0, 2.0), (1.0, np.nan, 0.0), None):
        assert not valid_noise(bad), bad


def test_a_large_problem_measures_its_noise_on_evenly_spaced_matches(monkeypatch):
    """Above NOISE_FIT_MATCHES the model is fitted on that many evenly spaced matches (memory on a 2048 x 2048 stack)
    and every match gets its variance: the coefficients stay within the tolerances above."""
    from rjfit.sampler.regions.materials import edges

    z, g, t = simulated(seed=6, n=400_000)
    pair = np.arange(z.size)            # one match per pair: each pair's turn is its match's change of <h.n>
    cos_first = np.full(z.size, 0.5)
    monkeypatch.setattr(edges, "NOISE_FIT_MATCHES", 150_000)
    spread = 2.0
    coefficients, variance = edges._match_noise("measured", z * spread, g * spread, spread, np.log(cos_first + t),
                                                np.log(cos_first), pair, z.size)
    for value, truth, name in zip(coefficients, TRUE, ("white", "shading", "turn")):
        assert value == pytest.approx(truth, rel=TOLERANCE[name]), name
    assert variance.shape == z.shape
    assert variance == pytest.approx(match_variance(coefficients, g, t), rel=1e-6)
