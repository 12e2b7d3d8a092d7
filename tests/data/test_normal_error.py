"""The normals' error as noise, the area likelihood power and the measured-data transforms, on rendered stacks.

Cost: about 10 s with the session's paper_sphere_small render (48 x 48, Mitsuba) already made.
"""
import dataclasses

import numpy as np
import pytest

from rjfit.data.calibrate import drop_small_components, estimate_light_gains
from rjfit.data.coarsen import area_likelihood_power
from rjfit.data.normal_error import normal_error_noise, tangential_gradient_squared
from rjfit.data.synthetic import sphere_stack
from rjfit.model.blinn import blinn_normalisation
from rjfit.render.datasets import load_dataset

from builders import perturbed_normals


def test_the_tangential_gradient_is_the_derivative_of_the_prediction():
    rng = np.random.default_rng(3)
    view = np.array([0.0, 0.0, 1.0])
    for _ in range(5):
        normal, light = (np.abs(rng.normal(size=3)) + [0, 0, 1.0] for _ in range(2))
        normal, light = normal / np.linalg.norm(normal), light / np.linalg.norm(light)
        half = (light + view) / np.linalg.norm(light + view)
        a, b, gamma, irradiance = 0.7, 0.3, 20.0, 1.3

        def mu(n):
            return irradiance * (a * (light @ n) / np.pi + b * blinn_normalisation(gamma) * (light @ n) * (half @ n) ** gamma)

        obs = dataclasses.make_dataclass("O", ["cos_ln", "cos_hn", "cos_lh", "irradiance"])(
            np.array([light @ normal]), np.array([half @ normal]), np.array([light @ half]), np.array([irradiance]))
        first = np.cross(normal, [1.0, 0.0, 0.0])
        first /= np.linalg.norm(first)
        second = np.cross(normal, first)
        step = 1e-6
        numeric = sum(((mu(normal + step * t) - mu(normal - step * t)) / (2 * step)) ** 2 for t in (first, second))
        assert tangential_gradient_squared(obs, a, b, gamma)[0] == pytest.approx(numeric, rel=1e-6)


def test_exact_normals_give_no_normal_error():
    """The closed-form sphere (normals exact at the pixel centres, white noise): k = 0."""
    obs, _, _ = sphere_stack(64, n_lights=10, seed=2)
    scale, record = normal_error_noise(obs)
    assert record["sigma_n_deg"] < 0.05
    assert np.all(scale < 1.01)


def test_a_known_normal_error_is_recovered(paper_sphere_small):
    """Mitsuba's paper_sphere at 48 px with its normals turned by 1 and 2 degrees (sd per direction).

    The clean render already reads as 0.6 degrees: not a pixel footprint (the render traces the
    pixel-centre rays; one material reads 0, tests/data/test_footprint.py) but the tile fits that
    straddle the four quadrants' boundaries. Independent errors add in quadrature, so sqrt(sd^2 - sd_clean^2) must recover the
    turn within 10 % (first-order model; 18,000 observations).
    """
    dataset = load_dataset(paper_sphere_small)
    clean = normal_error_noise(dataset.observations())[1]["sigma_n_deg"]
    assert clean < 1.0
    for degrees in (1.0, 2.0):
        turned = dataclasses.replace(dataset, normals=perturbed_normals(dataset.normals, dataset.object_mask, degrees, 1))
        estimate = normal_error_noise(turned.observations())[1]["sigma_n_deg"]
        assert np.sqrt(estimate ** 2 - clean ** 2) == pytest.approx(degrees, rel=0.10)


def test_the_tiles_across_a_paints_outline_are_counted_and_warned_of():
    """One material (the closed-form sphere, exact normals, white noise) and the same with a disc painted at a
    fifth of its albedo: the plain sphere has no tile over 10 times the median tile's misfit and no warning; the
    painted one has the disc outline's tiles there, holding most of the squared residual (sigma_r^2 measured over
    every tile: several times the plain sphere's), and the fit's warning says so."""
    from rjfit.pipeline.fit_power import misfit_tile_warnings

    uniform = ({"I0": 100.0, "kd": 0.7, "gamma": 10.0, "sigma2": 0.1},) * 4
    plain, _, _ = sphere_stack(64, n_lights=10, truth=uniform, seed=2)
    rows, cols = plain.pixel // 64, plain.pixel % 64
    disc = (rows - 24) ** 2 + (cols - 40) ** 2 <= 6 ** 2
    painted = dataclasses.replace(plain, y=np.where(disc, 0.2 * plain.y, plain.y))
    surface = normal_error_noise(plain)[1]
    assert surface["misfit_tiles"]["tiles"] == 0 and surface["misfit_tiles"]["share"] == 0.0
    assert misfit_tile_warnings({"normal_error": surface}) == []
    record = normal_error_noise(painted)[1]
    assert record["sigma_r2"] > 2.0 * surface["sigma_r2"]
    assert 0 < record["misfit_tiles"]["tiles"] <= 12 and record["misfit_tiles"]["share"] > 0.5
    warning, = misfit_tile_warnings({"normal_error": record})
    assert f"{record['misfit_tiles']['tiles']} of its 5 x 5 px tiles" in warning
    # a colour fit's record: the worst channel's
    assert misfit_tile_warnings({"normal_error": {**surface, "channels": [surface, record]}}) == [warning]


def test_white_noise_keeps_the_area_power_at_one(paper_sphere_small):
    """Rendered white noise: the summed autocorrelation of tile-fit residuals is about 1, so zeta = 1.

    Its sampling sd over (2 x 8 + 1)^2 lags with 18,000 observations is about 0.13; 1.5 is
    about 4 sd above 1.
    """
    obs, _, _ = sphere_stack(64, n_lights=10, seed=2)
    for observations in (obs, load_dataset(paper_sphere_small).observations()):
        power = area_likelihood_power(observations, window=8)
        assert power["area"] < 1.5
        assert power["likelihood_power"] > 0.66


def test_a_smooth_misfit_lowers_the_area_power():
    obs, _, _ = sphere_stack(64, n_lights=10, seed=2)
    rows, cols = obs.pixel // 64, obs.pixel % 64
    field = 1.0 + 0.2 * np.sin(rows / 6.0 + 1.3 * obs.light) * np.cos(cols / 7.0 - 0.7 * obs.light)
    power = area_likelihood_power(dataclasses.replace(obs, y=obs.y * field), window=8)
    assert power["area"] > 10 and power["likelihood_power"] < 0.1


def test_isolated_pixels_are_left_out(paper_sphere_small):
    dataset = load_dataset(paper_sphere_small)
    mask = dataset.object_mask.copy()
    mask[0, 0] = mask[0, 2] = True             # two lone pixels in the corner, off the sphere
    kept, record = drop_small_components(dataclasses.replace(dataset, object_mask=mask))
    assert record["pixels_dropped"] == 2 and record["components_dropped"] == 2
    np.testing.assert_array_equal(kept.object_mask, dataset.object_mask)


def test_light_gains_are_recovered(paper_sphere_small):
    """Known gains 0.8 to 1.25 applied to a render's images come back within 2 % (noise sd 0.3 on values ~30)."""
    dataset = load_dataset(paper_sphere_small)
    gains = np.geomspace(0.8, 1.25, dataset.n_lights)[np.random.default_rng(0).permutation(dataset.n_lights)]
    gains /= np.exp(np.mean(np.log(gains)))
    scaled = dataclasses.replace(dataset, images=dataset.images * gains[:, None, None, None])
    estimate = estimate_light_gains(scaled, n_bootstrap=5)
    np.testing.assert_allclose(estimate["gains"], gains, rtol=0.02)
    assert all(sd < 0.02 for sd in estimate["gains_std"])


def test_a_colour_stack_measures_the_normal_error_per_channel(paper_sphere_small):
    """``--channel rgb`` under the preset: each channel gets its own tile fits and k. The turned
    sphere with its channels tinted (1, 0.5, 0.25): each channel's scales are those of the channel
    fitted alone (the same numbers: the colour stack only routes them), and each recovers the
    2-degree turn within the single-channel test's 10 % (a tint scales the signal and its noise
    alike, so it leaves sigma_n unchanged)."""
    from rjfit.pipeline.fit_power import channel_normal_error_noise

    dataset = load_dataset(paper_sphere_small)
    clean = normal_error_noise(dataset.observations())[1]["sigma_n_deg"]
    tint = np.array([1.0, 0.5, 0.25])
    turned = dataclasses.replace(dataset, images=dataset.images * tint,
                                 normals=perturbed_normals(dataset.normals, dataset.object_mask, 2.0, 1))
    colour = turned.observations("rgb")
    scale, record = channel_normal_error_noise(colour)
    assert len(record["channels"]) == 3
    for c, name in enumerate("RGB"):
        alone_scale, alone = normal_error_noise(turned.observations(name))
        np.testing.assert_array_equal(scale[colour.channel == c], alone_scale)
        assert record["channels"][c]["sigma_n_deg"] == alone["sigma_n_deg"]
        assert np.sqrt(alone["sigma_n_deg"] ** 2 - clean ** 2) == pytest.approx(2.0, rel=0.10)
    assert record["sigma_n_deg"] == max(channel["sigma_n_deg"] for channel in record["channels"])
