"""The closed form of eq. 2 against values derived by hand and against Giesen's claim."""
import numpy as np
import pytest

from rjfit.model.blinn import blinn_normalisation, brdf, log_cos_power, radiance


def test_normalisation_matches_formula_at_hand_computed_points():
    # gamma = 0: (2)(4) / (8 pi (1 + 0)) = 1/pi, the Lambertian value.
    assert blinn_normalisation(0.0) == pytest.approx(1.0 / np.pi, rel=1e-15)
    # gamma = 2: (4)(6) / (8 pi (0.5 + 2)) = 24 / (20 pi)
    assert blinn_normalisation(2.0) == pytest.approx(24.0 / (20.0 * np.pi), rel=1e-15)


def test_radiance_is_eq2_term_by_term():
    rng = np.random.default_rng(1)
    cos_ln, cos_hn, irradiance = rng.uniform(0.05, 1, 100), rng.uniform(0.05, 1, 100), rng.uniform(0.1, 2, 100)
    I0, kd, gamma = 80.0, 0.3, 7.5
    norm = (gamma + 2) * (gamma + 4) / (8 * np.pi * (2 ** (-gamma / 2) + gamma))
    expected = I0 * irradiance * (kd / np.pi + (1 - kd) * norm * cos_hn ** gamma) * cos_ln
    np.testing.assert_allclose(radiance(I0, kd, gamma, cos_ln, cos_hn, irradiance), expected, rtol=1e-12)


def test_back_facing_and_grazing_half_vector_give_zero():
    assert radiance(100.0, 0.5, 5.0, -0.2, 0.9, 1.0) == 0.0
    assert log_cos_power(np.array([-0.1, 0.0]), 3.0).tolist() == [0.0, 0.0]
    assert brdf(1.0, 5.0, 0.5) == pytest.approx(1 / np.pi)


def test_region_parameters_broadcast_per_observation():
    kd = np.array([0.2, 0.8])
    values = radiance(100.0, kd, 5.0, np.array([0.5, 0.5]), np.array([0.9, 0.9]), 1.0)
    assert values.shape == (2,) and values[0] != values[1]


def test_radiance_of_rows_is_the_term_by_term_radiance_of_each_row():
    """The per-row form (factors per row, one exponential per observation) against eq. 2 term by term, over
    an angle sweep of <h.n> and three rows from a broad to a sharp lobe. 1e-12 relative: the two differ only
    in the order of float64 operations; a wrong row, factor or exponent is off by far more."""
    from rjfit.model.blinn import radiance, radiance_of_rows

    theta = np.array([[100.0, 0.9, 0.3, 1.0], [50.0, 0.2, 8.0, 1.0], [2.0, 0.0, 300.0, 1.0]])
    cos_hn = np.cos(np.deg2rad(np.linspace(0.0, 89.0, 90)))
    rows = np.repeat(np.arange(3), cos_hn.size)
    cos_hn = np.tile(cos_hn, 3)
    C = np.linspace(0.1, 2.0, cos_hn.size)        # E <l.n>: the irradiance folded in, as the Problem holds it
    expected = radiance(theta[rows, 0], theta[rows, 1], theta[rows, 2], C, cos_hn, 1.0)
    np.testing.assert_allclose(radiance_of_rows(theta, rows, C, np.log(cos_hn)), expected, rtol=1e-12, atol=0)
