"""``rjfit.posterior.boundaries``: a boundary where the data step is supported, one that a smooth change of
brightness bought is not, and a step spread over a pixel or two is still an edge."""
import numpy as np
import pytest

from rjfit.model.blinn import radiance
from rjfit.posterior.boundaries import (
    EDGE_LOG_ODDS,
    boundary_support,
    edge_group_count,
    edge_groups,
    edge_verdict,
    least_squares_params,
    unsupported_boundary_warnings,
)
from tests.builders import raises

KD, GAMMA, NOISE_SD = 0.8, 5.0, 0.05


def stack(brightness, lights=8, seed=0):
    """Observations of one lobe shape whose I0 per pixel is ``brightness`` (H, W), with Gaussian noise."""
    rng = np.random.default_rng(seed)
    height, width = brightness.shape
    pixel = np.repeat(np.arange(height * width), lights)
    light = np.tile(np.arange(lights), height * width)
    cos_ln, cos_hn = rng.uniform(0.2, 1, pixel.size), rng.uniform(0.5, 1, pixel.size)
    C = rng.uniform(0.5, 1.5, pixel.size) * cos_ln
    y = radiance(brightness.ravel()[pixel], KD, GAMMA, cos_ln, cos_hn, C / cos_ln) + rng.normal(0, NOISE_SD, pixel.size)
    return y, C, np.log(cos_hn), pixel, light


def fitted_params(labels, y, C, log_cos_hn, pixel):
    """Each material's (I0, kd, gamma): kd and gamma as simulated, I0 by least squares over its pixels."""
    shape = C * (KD / np.pi + (1 - KD) * (GAMMA + 2) * (GAMMA + 4) / (8 * np.pi * (2 ** (-GAMMA / 2) + GAMMA))
                 * np.exp(GAMMA * log_cos_hn))
    rows = []
    for m in range(labels.max() + 1):
        mine = labels.ravel()[pixel] == m
        rows.append((float(y[mine] @ shape[mine] / (shape[mine] @ shape[mine])), KD, GAMMA))
    return np.array(rows)


def support(brightness, labels):
    y, C, log_cos_hn, pixel, light = stack(brightness)
    rows = boundary_support(labels, fitted_params(labels, y, C, log_cos_hn, pixel), y, C, log_cos_hn, pixel, light, 8)
    assert len(rows) == 1 and rows[0]["materials"] == [0, 1]
    return rows[0]


def halves(size=24):
    labels = np.zeros((size, size), int)
    labels[:, size // 2:] = 1
    return labels


def test_a_step_of_paint_is_supported():
    """I0 4 against 8 across the middle (far beyond the noise): the materials' step is the data's."""
    labels = halves()
    row = support(np.where(labels == 1, 8.0, 4.0), labels)
    assert row["log_likelihood_ratio"] > 1000 and row["step_explained"] > 0.9
    assert row["pairs"] == 3 * 24 and not unsupported_boundary_warnings([row])


def test_a_smooth_brightness_ramp_split_in_two_is_not():
    """I0 rising smoothly from 4 to 8 across the image, split at the middle: each half's least-squares I0 is its
    mean, so the two materials jump by about 2 where the data rise by 3 / 24 * 4 per 3 px."""
    labels = halves()
    ramp = np.tile(np.linspace(4.0, 8.0, 24), (24, 1))
    row = support(ramp, labels)
    assert row["log_likelihood_ratio"] < 0
    (warning,) = unsupported_boundary_warnings([row])
    assert "materials 0 and 1 meet where the data show no edge" in warning


def test_a_step_spread_over_two_pixels_is_still_an_edge():
    """A paint edge blurred over the two columns next to the boundary (I0 5.33 and 6.67 there): pairs 3 px apart
    straddle the whole step."""
    labels = halves()
    column = np.array([4.0] * 11 + [4 + 4 / 3, 4 + 8 / 3] + [8.0] * 11)
    row = support(np.tile(column, (24, 1)), labels)
    assert row["log_likelihood_ratio"] > 0 and row["step_explained"] > 0.5
    # why the pairs lie 3 px apart: next-door neighbours straddle a third of the step, and read no edge
    y, C, log_cos_hn, pixel, light = stack(np.tile(column, (24, 1)))
    (next_door,) = boundary_support(labels, fitted_params(labels, y, C, log_cos_hn, pixel), y, C, log_cos_hn, pixel,
                                    light, 8, gap=1)
    assert next_door["log_likelihood_ratio"] < 0


def test_bad_arguments_say_which():
    labels = halves(4)
    y, C, log_cos_hn, pixel, light = stack(np.ones((4, 4)))
    with raises(ValueError, "params has 1 rows"):
        boundary_support(labels, np.ones((1, 3)), y, C, log_cos_hn, pixel, light, 8)
    with raises(ValueError, "one entry per observation"):
        boundary_support(labels, np.ones((2, 3)), y[:-1], C, log_cos_hn, pixel, light, 8)
    assert boundary_support(np.zeros((4, 4), int), np.ones((1, 3)), y, C, log_cos_hn, pixel, light, 8) == []


@pytest.mark.parametrize("gap", [1, 3])
def test_pairs_lie_gap_apart(gap):
    labels = halves(12)
    y, C, log_cos_hn, pixel, light = stack(np.where(labels == 1, 8.0, 4.0))
    (row,) = boundary_support(labels, fitted_params(labels, y, C, log_cos_hn, pixel), y, C, log_cos_hn, pixel, light,
                              8, gap=gap)
    assert row["pairs"] == gap * 12 and row["observations"] == gap * 12 * 8


def test_without_params_each_material_is_fitted_by_least_squares():
    """The fit passes no parameters: pooled posterior means of chains that disagree belong to no chain. Least
    squares over each labelled material recover I0 within 5 % (gamma on a grid 1.32 apart) and give the step and
    the ramp the same verdicts as the simulated parameters."""
    labels = halves()
    y, C, log_cos_hn, pixel, light = stack(np.where(labels == 1, 8.0, 4.0))
    params = least_squares_params(labels, y, C, log_cos_hn, pixel)
    assert params[:, 0] == pytest.approx([4.0, 8.0], rel=0.05)
    assert boundary_support(labels, None, y, C, log_cos_hn, pixel, light, 8)[0]["log_likelihood_ratio"] > 1000
    y, C, log_cos_hn, pixel, light = stack(np.tile(np.linspace(4.0, 8.0, 24), (24, 1)))
    assert boundary_support(labels, None, y, C, log_cos_hn, pixel, light, 8)[0]["log_likelihood_ratio"] < 0


def test_edge_groups_join_only_the_materials_that_meet_where_the_data_show_no_edge():
    """Decisive either way at odds of 100:1 (log ratio beyond +-4.61); an undecided or NaN boundary joins nothing."""
    ratios = [-5.0, 40.0, float("nan"), -4.0, -400.0]
    rows = [{"materials": [m, m + 1], "pairs": 10, "log_likelihood_ratio": ratio} for m, ratio in enumerate(ratios)]
    assert [edge_verdict(row) for row in rows] == ["no edge", "edge", "undecided", "undecided", "no edge"]
    assert edge_groups(rows, 7) == [[0, 1], [2], [3], [4, 5], [6]]
    assert edge_groups([], 2) == [[0], [1]]
    (warning,) = unsupported_boundary_warnings(rows[:4])
    assert warning.startswith("materials 0 and 1 meet where the data show no edge")


def test_a_label_maps_edge_groups_count_paint_steps_and_not_a_ramps_bands():
    """Three bands of a ramp (I0 4 to 8) are one group; a disc of I0 8 inside I0 4 beside them is a second, in a
    label map numbered with gaps (a state's own numbering) whose unlabelled pixels are NaN."""
    size = 24
    rows, cols = np.mgrid[0:size, 0:size]
    brightness = np.tile(np.linspace(4.0, 8.0, size), (size, 1))
    bands = np.minimum(cols // 8, 2).astype(float) * 3           # labels 0, 3, 6
    assert edge_group_count(bands, *stack(brightness), 8) == 1
    disc = (rows - 12) ** 2 + (cols - 12) ** 2 < 25
    painted = np.where(disc, 8.0, 4.0)
    labels = np.where(disc, 5.0, 2.0)
    labels[0, 0] = np.nan
    assert edge_group_count(labels, *stack(painted), 8) == 2
    assert edge_group_count(np.full((size, size), 7.0), *stack(painted), 8) == 1


def test_a_material_without_observations_is_not_counted():
    """Pixels labelled by their neighbours alone (the rim under --max-view-angle: no observation) may hold a
    material of their own; with no data it is no group of the data's."""
    size = 24
    y, C, log_cos_hn, pixel, light = stack(np.full((size, size), 5.0))
    labels = np.zeros((size, size))
    labels[:, -2:] = 1
    seen = labels.ravel()[pixel] == 0
    assert edge_group_count(labels, y[seen], C[seen], log_cos_hn[seen], pixel[seen], light[seen], 8) == 1
    # the same band seen, and of a paint twice as bright: a group of its own
    y, C, log_cos_hn, pixel, light = stack(np.where(labels == 1, 10.0, 5.0))
    assert edge_group_count(labels, y, C, log_cos_hn, pixel, light, 8) == 2


@pytest.mark.parametrize("seed", range(5))
def test_two_materials_fitted_to_one_paint_are_no_edge(seed):
    """One uniform paint split into two materials, each fitted by least squares to its own pixels: the fits' own
    noise makes their step fit the differences slightly better or worse (log ratios -0.92 to +0.59 on these five
    seeds; +1.4 to +1.9 for a band 2 px wide): undecided at odds of 100:1 either way, where a threshold of 0 would
    call three of the five an edge and two no edge."""
    y, C, log_cos_hn, pixel, light = stack(np.full((24, 24), 5.0), seed=seed)
    labels = np.zeros((24, 24), int)
    labels[:, -4:] = 1
    (row,) = boundary_support(labels, None, y, C, log_cos_hn, pixel, light, 8)
    assert abs(row["log_likelihood_ratio"]) < EDGE_LOG_ODDS and edge_verdict(row) == "undecided"
