"""The misfit the fitted model leaves: the lag-1 correlation of its standardised residuals
(:func:`rjfit.posterior.misfit.residual_correlation`), against fields of known correlation."""
from __future__ import annotations

import numpy as np

from rjfit.data.observations import Observations
from rjfit.posterior.misfit import residual_correlation
from rjfit.sampler.forward import Problem

SHAPE, LIGHTS = (40, 40), 4
# about 12,000 neighbour pairs, correlated within a 2 x 2 box: the estimate's sd is near 0.015,
# so 0.05 is over 3 sd
TOLERANCE = 0.05


def problem_and_field(field_of_light, drop=0.0, seed=2):
    rng = np.random.default_rng(seed)
    height, width = SHAPE
    pixel = np.repeat(np.arange(height * width), LIGHTS)
    light = np.tile(np.arange(LIGHTS), height * width)
    keep = rng.random(pixel.size) >= drop
    pixel, light = pixel[keep], light[keep]
    ones = np.ones(pixel.size)
    obs = Observations(image_shape=SHAPE, n_lights=LIGHTS, pixel=pixel.astype(np.int64),
                       light=light.astype(np.int32), y=ones, cos_ln=0.5 * ones, cos_hn=0.9 * ones,
                       irradiance=ones, object_mask=np.ones(SHAPE, bool))
    problem = Problem.from_observations(obs)
    fields = np.stack([field_of_light(rng) for _ in range(LIGHTS)])      # (L, H, W)
    return problem, fields[problem.light.astype(int), problem.pixel // width, problem.pixel % width]


def box_average(rng):
    """White noise summed over 2 x 2 boxes: neighbours share 2 of 4 cells, correlation 0.5 in both directions."""
    white = rng.normal(size=(SHAPE[0] + 1, SHAPE[1] + 1))
    return white[:-1, :-1] + white[1:, :-1] + white[:-1, 1:] + white[1:, 1:]


def test_white_residuals_are_uncorrelated_and_imply_power_one():
    problem, standardised = problem_and_field(lambda rng: rng.normal(size=SHAPE))
    misfit = residual_correlation(problem, standardised)
    assert abs(misfit["rho_rows"]) < TOLERANCE and abs(misfit["rho_cols"]) < TOLERANCE
    assert misfit["implied_power"] > ((1 - TOLERANCE) / (1 + TOLERANCE)) ** 2


def test_a_shared_field_gives_its_correlation_also_with_observations_missing():
    problem, standardised = problem_and_field(box_average, drop=0.3)
    misfit = residual_correlation(problem, standardised)
    assert abs(misfit["rho_rows"] - 0.5) < TOLERANCE and abs(misfit["rho_cols"] - 0.5) < TOLERANCE
    assert abs(misfit["implied_power"] - 1 / 9) < 0.03     # ((1 - 0.5) / 1.5)^2; d zeta / d rho = -0.3 at 0.5


def test_no_adjacent_observations_state_nothing():
    # a checkerboard of observed pixels: no two neighbours share a light, so no correlation is measured
    problem, standardised = problem_and_field(lambda rng: rng.normal(size=SHAPE))
    row, col = np.divmod(problem.pixel.astype(int), SHAPE[1])
    standardised = np.where((row + col) % 2 == 0, standardised, np.nan)
    assert residual_correlation(problem, standardised) is None
