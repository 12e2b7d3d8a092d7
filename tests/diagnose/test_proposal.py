"""A refit's posterior draws (rjfit.diagnose.proposal): the split normal's scales against closed
forms, its importance weights against quadrature, the Laplace draws unchanged where the posterior
is Gaussian, and the LOO it fixes on Mitsuba's roughplastic with one roughness."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.optimize import brentq

from rjfit.diagnose.evidence import laplace_draws
from rjfit.diagnose.proposal import (BISECTION_STEPS, MAX_SCALE_RATIO, POOR_DRAWS_KHAT, ONE_SD_RISE, axis_scales,
                                     importance_log_weights, posterior_draws, weight_pareto_k)


class _Objective:
    """f = -log p(y, z) of a toy posterior (only what posterior_draws calls)."""

    def __init__(self, f):
        self.f = f


def _log_weights(objective, result):
    return importance_log_weights([-objective.f(z) for z in result.draws], result.log_proposal)


def _quartic(curvature, quartic):
    # along z1 the log density falls as the fourth power: the rough coating's shape, measured
    return lambda z: 0.5 * z[0] ** 2 + 0.5 * curvature * z[1] ** 2 + quartic * z[1] ** 4


def _skewed(c):
    # (e^{cz} - cz) / c^2: curvature 1 at its minimum 0, steep on one side, shallow on the other
    return lambda z: (math.expm1(c * z[0]) - c * z[0]) / c ** 2 + 0.5 * z[1] ** 2


def test_a_gaussian_posterior_keeps_the_laplace_draws_and_weighs_them_equally():
    hessian = np.array([[2.0, 0.6], [0.6, 0.5]])
    objective = _Objective(lambda z: 0.5 * z @ hessian @ z + 3.0)
    result = posterior_draws(objective, np.zeros(2), hessian, 200, seed=4)
    np.testing.assert_array_equal(result.draws, laplace_draws(np.zeros(2), hessian, 200, 4))
    assert result.note is None
    # exact target = proposal: every log weight is 0 up to rounding (1e-9 of values of order 10)
    assert np.max(np.abs(_log_weights(objective, result))) < 1e-9


def test_split_normal_scales_are_where_the_log_density_has_risen_by_one_half():
    curvature, quartic = 0.01, 50.0
    z = np.zeros(2)
    hessian = np.diag([1.0, curvature])
    vectors, gaussian, plus, minus, kept = axis_scales(_quartic(curvature, quartic), z, hessian)
    exact = brentq(lambda t: 0.5 * curvature * t * t + quartic * t ** 4 - ONE_SD_RISE, 0.0, 10.0)
    bracket = gaussian[0] / 2 ** BISECTION_STEPS         # eigh orders the eigenvalues: the quartic axis first
    assert abs(vectors[1, 0]) == pytest.approx(1.0)
    assert plus[0] == pytest.approx(exact, abs=bracket) and minus[0] == pytest.approx(exact, abs=bracket)
    assert plus[1] == gaussian[1] == minus[1]            # the quadratic axis keeps the Gaussian's scale
    assert list(kept) == [False, True]


def test_a_skewed_axis_gets_a_scale_per_side():
    c = 3.0
    _, gaussian, plus, minus, kept = axis_scales(_skewed(c), np.zeros(2), np.eye(2))
    rise = lambda t: (math.expm1(c * t) - c * t) / c ** 2 - ONE_SD_RISE       # noqa: E731
    bracket = MAX_SCALE_RATIO / 2 ** BISECTION_STEPS
    assert plus[0] == pytest.approx(brentq(rise, 0.0, 5.0), abs=bracket)
    assert minus[0] == pytest.approx(-brentq(rise, -10.0, 0.0), abs=bracket)
    assert plus[0] < 1.0 < minus[0] and kept[1]


def test_the_weighted_draws_give_the_posterior_expectation_of_a_non_gaussian_posterior():
    """The self-normalised weighted mean of z1^2 under the split normal against quadrature of the
    quartic target. Tolerance: 4 Monte Carlo standard errors of the weighted mean (its delta-method
    variance), at one fixed seed; the Laplace draws' plain mean is off by far more."""
    curvature, quartic = 0.01, 50.0
    objective = _Objective(_quartic(curvature, quartic))
    density = lambda t: math.exp(-(0.5 * curvature * t * t + quartic * t ** 4))         # noqa: E731
    exact = quad(lambda t: t * t * density(t), -3, 3)[0] / quad(density, -3, 3)[0]
    hessian = np.diag([1.0, curvature])
    result = posterior_draws(objective, np.zeros(2), hessian, 4000, seed=11)
    assert result.note is not None and "1 of" in result.note
    log_weights = _log_weights(objective, result)
    w = np.exp(log_weights)
    w /= w.sum()
    values = result.draws[:, 1] ** 2
    estimate = float(np.sum(w * values))
    standard_error = math.sqrt(float(np.sum(w ** 2 * (values - estimate) ** 2)))
    assert abs(estimate - exact) < 4 * standard_error
    assert weight_pareto_k(log_weights) < POOR_DRAWS_KHAT
    laplace = laplace_draws(np.zeros(2), hessian, 4000, 11)[:, 1] ** 2
    assert laplace.mean() > 100 * exact


def test_every_draw_at_zero_density_is_refused():
    with pytest.raises(ValueError, match="zero or non-finite density"):
        importance_log_weights(np.full(20, -np.inf), np.zeros(20))


def test_the_rough_coating_loo_agrees_with_its_evidence_on_mitsuba_roughplastic(tmp_path):
    """Mitsuba's roughplastic with one roughness is exactly ggx + rough_coating; on its true
    regions the rough coating's Laplace evidence is far above ggx alone (log BF ~800). Its
    Laplace draws gave a dLOO of -2,593 (k-hat 23): the posterior falls as the fourth power along
    one axis. With the split normal the dLOO must agree in sign, by at least 2 of its SEs."""
    from rjfit.diagnose.context import build_context
    from rjfit.diagnose.loo import draws_pareto_k, loo_difference
    from rjfit.diagnose.refit import refit
    from rjfit.effects import EFFECTS
    from rjfit.render.datasets import load_dataset
    from rjfit.render.hidden import render_hidden

    dataset = load_dataset(render_hidden("rough_plastic", tmp_path / "d", resolution=32))
    ctx = build_context(dataset, dataset.truth_labels)
    ggx = refit(ctx, [EFFECTS["ggx"]], seed=0)
    coated = refit(ctx, [EFFECTS["ggx"], EFFECTS["rough_coating"]], seed=0)
    assert coated.log_evidence - ggx.log_evidence > 100
    assert ggx.draws_proposal == "Laplace" and coated.draws_proposal.startswith("the log posterior is not Gaussian")
    delta, se = loo_difference(coated, ggx)[:2]
    assert delta > 2 * se
    # the importance weights' check: finite, and the ggx fit's Laplace draws cover its posterior
    assert draws_pareto_k(ggx) < POOR_DRAWS_KHAT and math.isfinite(draws_pareto_k(coated))


def test_the_diagnosis_text_names_the_split_normal_rows_and_the_poorly_covered_ones():
    from rjfit.diagnose.document import _draws_lines

    def row(step, effect, proposal, khat=None):
        draws = {"proposal": proposal} if khat is None else {"proposal": proposal, "weights_khat": khat}
        return {"step": step, "effect": effect, "posterior_draws": draws}
    rows = [row(0, "ambient", "Laplace", 0.3), row(0, "ggx", "split", 0.9), row(1, "coating", "split", 0.5),
            row(1, "masking", "split")]                    # no LOO taken: not listed
    text = "\n".join(_draws_lines({"candidates": rows}))
    assert "step 1: ggx; step 2: coating." in text and "masking" not in text
    assert "The draws of 1 refit(s)" in text and "up to 0.90, step 1, ggx" in text
    assert _draws_lines({"candidates": [row(0, "ambient", "Laplace", 0.3)]}) == []
