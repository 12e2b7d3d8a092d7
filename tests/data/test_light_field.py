"""Each light's gain as a field over the image (``--light-field``): the basis, and the estimate on renders whose
lights were made uneven by a known field."""
import dataclasses

import numpy as np
import pytest

from rjfit.data.calibrate import calibrate_measured, estimate_common_field, estimate_light_gains, replay_calibration
from rjfit.data.light_field import field_basis, field_extent, field_image, monomials, robust_polynomial
from rjfit.render.datasets import load_dataset


def test_the_basis_is_the_monomials_of_centred_coordinates():
    assert monomials(0) == [(0, 0)]
    assert monomials(2) == [(0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2)]
    shape = (5, 9)
    basis = field_basis(np.arange(45), shape, 2)
    rows, cols = np.divmod(np.arange(45), 9)
    u, v = (cols - 4) / 4, (rows - 2) / 2
    np.testing.assert_allclose(basis, np.stack([np.ones(45), u, v, u * u, u * v, v * v], axis=1), atol=1e-15)
    with pytest.raises(ValueError, match="degree is 0 or more"):
        monomials(-1)


def test_a_field_image_is_the_exponential_of_its_polynomial():
    coefficients = np.array([[0.1, 0.2, -0.3], [-0.1, -0.2, 0.3]])
    field = field_image(coefficients, (3, 5), 1)
    v, u = np.mgrid[-1:1:3j, -1:1:5j]
    np.testing.assert_allclose(field[0], np.exp(0.1 + 0.2 * u - 0.3 * v), rtol=1e-12)
    np.testing.assert_allclose(field[0] * field[1], 1.0, rtol=1e-12)


def _quadratic_field(dataset):
    """Per light, exp of a random quadratic in the image coordinates (up to about +-30 % over the image), normalised
    to geometric mean 1 over the lights at each pixel, as the estimate is."""
    n, height, width = dataset.n_lights, *dataset.images.shape[1:3]
    coefficients = np.random.default_rng(3).uniform(-0.1, 0.1, (n, len(monomials(2))))
    coefficients -= coefficients.mean(axis=0)
    return field_image(coefficients, (height, width), 2)


def test_a_known_field_on_the_images_comes_back_on_top_of_the_datas_own(dented_plaster_small):
    """The estimate is equivariant: on the images times a field of the family, it is the estimate on the images
    times that field. A field that the fit's model cannot carry (interreflection and cast shadows in the dents) is
    in both and cancels. The rounds stop once a round changes a log gain by under 1e-4, at a different round in
    each case, so they agree to 10 times that (1e-3); an estimate that ignored the data's field, or divided by the
    wrong light's, misses by the field itself (up to 0.3)."""
    dataset = load_dataset(dented_plaster_small)
    field = _quadratic_field(dataset)
    plain = estimate_light_gains(dataset, n_bootstrap=2, field_degree=2)["field"]
    uneven = estimate_light_gains(dataclasses.replace(dataset, images=dataset.images * field[..., None]),
                                  n_bootstrap=2, field_degree=2)["field"]
    shape = dataset.images.shape[1:3]
    inside = dataset.object_mask
    recovered = (field_image(uneven["coefficients"], shape, 2) / field_image(plain["coefficients"], shape, 2))[:, inside]
    assert np.max(np.abs(np.log(recovered / field[:, inside]))) < 1e-3
    assert np.max(np.abs(np.log(field[:, inside]))) > 0.05


def test_degree_zero_is_one_gain_per_light(paper_sphere_small):
    """Known gains 0.8 to 1.25 come back within 2 % (as tests/data/test_normal_error.py's), and a record without a
    field."""
    dataset = load_dataset(paper_sphere_small)
    gains = np.geomspace(0.8, 1.25, dataset.n_lights)[np.random.default_rng(1).permutation(dataset.n_lights)]
    gains /= np.exp(np.mean(np.log(gains)))
    estimate = estimate_light_gains(dataclasses.replace(dataset, images=dataset.images * gains[:, None, None, None]),
                                    n_bootstrap=3, field_degree=0)
    np.testing.assert_allclose(estimate["gains"], gains, rtol=0.02)
    assert "field" not in estimate


def test_a_field_calibration_replays_and_refuses_another_image_size(dented_plaster_small):
    dataset = load_dataset(dented_plaster_small)
    calibrated, record = calibrate_measured(dataset, seed=1, gains=True, field_degree=1)
    field = record["light_gains"]["field"]
    assert field["degree"] == 1 and len(field["coefficients"]) == dataset.n_lights
    assert all(low <= 1.0 <= high for low, high in field["range"])
    assert field_extent(field) == (min(low for low, _ in field["range"]), max(high for _, high in field["range"]))
    assert field_extent(record["common_field"]) == tuple(record["common_field"]["range"])
    assert record["common_field"]["degree"] == 1 and 0.5 < record["common_field"]["inlier_share"] <= 1.0
    replayed = replay_calibration(dataset, record)
    np.testing.assert_allclose(replayed.images, calibrated.images, rtol=1e-12)
    cropped = dataclasses.replace(dataset, images=dataset.images[:, :30], object_mask=dataset.object_mask[:30],
                                  normals=dataset.normals[:30])
    with pytest.raises(ValueError, match="light field was estimated on"):
        replay_calibration(cropped, record)


def test_the_robust_polynomial_ignores_a_minority():
    """A quadratic under noise sd 0.01, a fifth of the values raised by 1 (a second paint): the biweight fit
    recovers the quadratic to 0.01 (a least-squares fit misses by about 0.2) and gives the raised values weight 0."""
    rng = np.random.default_rng(5)
    basis = field_basis(np.arange(40 * 50), (40, 50), 2)
    truth = np.array([0.1, -0.2, 0.3, 0.05, -0.1, 0.15])
    values = basis @ truth + rng.normal(0.0, 0.01, len(basis))
    other = rng.random(len(basis)) < 0.2
    values[other] += 1.0
    coefficients, weights, scale = robust_polynomial(values, basis)
    assert np.max(np.abs(basis @ (coefficients - truth))) < 0.01
    assert np.all(weights[other] == 0) and np.mean(weights[~other] > 0) > 0.99
    assert 0.009 < scale < 0.016      # the MAD of all residuals: a fifth of outliers raises it to about 1.3 sd
    plain = np.linalg.lstsq(basis, values, rcond=None)[0]
    assert np.max(np.abs(basis @ (plain - truth))) > 0.1


def test_a_common_field_on_the_images_comes_back(dented_plaster_small):
    """Every image times one quadratic field: the common field's estimate on them is the estimate on the plain images
    plus the field's log (each centred over the object), to 1e-3 (the biweight's weights move a little with the
    values; the field is up to 0.2)."""
    dataset = load_dataset(dented_plaster_small)
    height, width = dataset.images.shape[1:3]
    log_field = np.log(field_image([[0.0, 0.1, -0.15, 0.05, 0.0, -0.05]], (height, width), 2)[0])
    plain = estimate_common_field(dataset, degree=2)
    lit = estimate_common_field(dataclasses.replace(dataset, images=dataset.images * np.exp(log_field)[None, :, :, None]),
                                degree=2)
    inside = dataset.object_mask
    difference = (np.log(field_image([lit["coefficients"]], (height, width), 2)[0])
                  - np.log(field_image([plain["coefficients"]], (height, width), 2)[0]))[inside]
    expected = log_field[inside] - log_field[inside].mean()
    assert np.max(np.abs(difference - expected)) < 1e-3
    assert np.ptp(expected) > 0.1
