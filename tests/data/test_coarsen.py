"""The suggested likelihood power of a coarsened fit: ~1 for white noise, small for a misfit shared by neighbours."""
import dataclasses

import numpy as np
import pytest

from rjfit.data.coarsen import misfit_warning, suggest_likelihood_power
from rjfit.data.pixelfit import per_pixel_residuals
from rjfit.data.synthetic import sphere_stack


@pytest.fixture(scope="module")
def stack():
    obs, _, _ = sphere_stack(64, n_lights=10, seed=2)
    return obs


def test_white_noise_keeps_the_plain_likelihood(stack):
    # per-pixel fits leave white noise uncorrelated: rho ~ N(0, 1/sqrt(pairs)) ~ 0.005 here,
    # so zeta = ((1 - rho) / (1 + rho))^2 > 0.9 unless rho > 0.026 (over 5 standard errors)
    suggestion = suggest_likelihood_power(stack)
    assert suggestion["pairs"] > 20000
    assert abs(suggestion["rho"]) < 0.026
    assert suggestion["likelihood_power"] > 0.9
    assert misfit_warning(suggestion, 1.0) is None


def test_a_misfit_shared_by_neighbours_lowers_the_power(stack):
    """A smooth multiplicative field per light (what a wrong lobe shape does) is not white.

    The field varies with position, so a per-pixel fit cannot absorb it fully when it also
    varies across lights; neighbours then share their residuals (rho well above 0).
    """
    height, width = stack.image_shape
    rows, cols = np.asarray(stack.pixel) // width, np.asarray(stack.pixel) % width
    light = np.asarray(stack.light)
    field = 1.0 + 0.2 * np.sin(rows / 6.0 + 1.3 * light) * np.cos(cols / 7.0 - 0.7 * light)
    shaded = dataclasses.replace(stack, y=np.asarray(stack.y) * field)
    suggestion = suggest_likelihood_power(shaded)
    assert suggestion["rho"] > 0.5
    assert suggestion["likelihood_power"] < 0.15
    warning = misfit_warning(suggestion, 1.0)
    assert f"rho {suggestion['rho']:.2f}" in warning and "rjfit diagnose" in warning


def test_a_fit_of_misfit_data_warns_that_regions_may_split_one_material(stack, tmp_path):
    """Through fit(): the warning reaches summary.json whatever likelihood power the fit uses."""
    from rjfit.pipeline.fit import fit

    height, width = stack.image_shape
    rows, cols = np.asarray(stack.pixel) // width, np.asarray(stack.pixel) % width
    light = np.asarray(stack.light)
    field = 1.0 + 0.2 * np.sin(rows / 6.0 + 1.3 * light) * np.cos(cols / 7.0 - 0.7 * light)
    options = dict(n_chains=1, iterations=20, max_u=1, max_v=1, processes=1, progress=False, figures=False)
    misfit = fit(dataclasses.replace(stack, y=np.asarray(stack.y) * field), tmp_path / "misfit", **options)
    assert any("may split one material" in warning for warning in misfit["warnings"])
    clean = fit(stack, tmp_path / "clean", **options)
    assert not any("may split one material" in warning for warning in clean["warnings"])


def test_per_pixel_residuals_vanish_for_an_exact_model(stack):
    """Noise-free data of the model itself: every pixel is fitted exactly (the grid holds its gamma)."""
    from rjfit.model.blinn import radiance

    exact = radiance(100.0, 0.5, np.geomspace(0.5, 500.0, 16)[5], stack.cos_ln, stack.cos_hn,
                     stack.irradiance)
    residuals = per_pixel_residuals(dataclasses.replace(stack, y=exact))
    finite = np.isfinite(residuals)
    assert finite.mean() > 0.9
    assert np.max(np.abs(residuals[finite])) < 1e-6 * np.max(exact)


def test_per_pixel_residuals_vanish_between_grid_exponents(stack):
    """Noise-free data of an exponent between two grid points (37: 31.7 and 50 on the grid) is
    fitted exactly too: the exponent is refined between its grid neighbours (the grid's own
    misfit would be shared by neighbouring pixels, a false alarm of the misfit warning)."""
    from rjfit.model.blinn import radiance

    exact = radiance(100.0, 0.3, 37.0, stack.cos_ln, stack.cos_hn, stack.irradiance)
    residuals = per_pixel_residuals(dataclasses.replace(stack, y=exact))
    finite = np.isfinite(residuals)
    assert finite.mean() > 0.9
    # golden-section bracket 0.618^24 of log(50 / 20): the exponent to ~1e-5 relative
    assert np.max(np.abs(residuals[finite])) < 1e-4 * np.max(exact)


@pytest.fixture(scope="module")
def glossy_clean_stack(tmp_path_factory):
    """paper_sphere re-materialed glossy (exponents 15 to 80) under 12 lights, rendered by Mitsuba
    at 32 x 32 with noise sd ~1.4 % of the mean signal (variance 0.005 on a mean of ~5)."""
    from rjfit.render.datasets import load_dataset
    from rjfit.render.render import load_scene_definition, render_dataset

    definition = load_scene_definition("paper_sphere")
    for material, gamma, kd in zip(definition["materials"], (40.0, 80.0, 25.0, 15.0), (0.3, 0.5, 0.6, 0.4)):
        material.update(gamma=gamma, kd=kd)
    definition["lights"] += [{"kind": "point", "position": [0.4, -1.6, 1.4], "intensity": 100.0},
                             {"kind": "point", "position": [-0.9, -0.8, 1.9], "intensity": 100.0}]
    folder = render_dataset(definition, tmp_path_factory.mktemp("glossy") / "dataset", resolution=32,
                            noise_variance=0.005)
    return load_dataset(folder).observations()


def test_a_clean_glossy_rendered_stack_does_not_warn_and_a_correlated_one_does(glossy_clean_stack):
    """White noise on a rendered clean stack: rho within 5 standard errors of 0 (1/sqrt(pairs) ~
    0.012 here), no warning (the gamma grid alone gave rho 0.34 and the warning, measured); the same
    stack times a smooth field per light: neighbours share the misfit and the warning is given."""
    obs = glossy_clean_stack
    assert obs.n_lights == 12
    clean = suggest_likelihood_power(obs)
    assert abs(clean["rho"]) < 5.0 / np.sqrt(clean["pairs"])
    assert misfit_warning(clean, 1.0) is None
    height, width = obs.image_shape
    rows, cols = np.asarray(obs.pixel) // width, np.asarray(obs.pixel) % width
    light = np.asarray(obs.light)
    field = 1.0 + 0.2 * np.sin(rows / 3.0 + 1.3 * light) * np.cos(cols / 3.5 - 0.7 * light)
    correlated = suggest_likelihood_power(dataclasses.replace(obs, y=np.asarray(obs.y) * field))
    assert misfit_warning(correlated, 1.0) is not None
