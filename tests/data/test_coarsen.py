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
