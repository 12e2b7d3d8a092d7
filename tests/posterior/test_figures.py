"""Figures: region colours distinct for any number of regions; the trace figure's title clear of its panels' titles."""
from types import SimpleNamespace

import numpy as np
import pytest

from rjfit.plotting import label_image, region_colormap, region_colours
from rjfit.posterior.figures import trace_figure


def _min_distance(colours):
    distance = np.linalg.norm(colours[:, None] - colours[None], axis=-1)
    np.fill_diagonal(distance, np.inf)
    return distance.min()


def test_region_colours_are_distinct_for_up_to_64_regions():
    all_64 = region_colours(64)
    assert all_64.shape == (64, 3) and np.all((all_64 >= 0) & (all_64 <= 1))
    for n in range(1, 65):
        colours = region_colours(n)
        np.testing.assert_array_equal(colours, all_64[:n])     # a region keeps its colour whatever the count
        assert len({tuple(c) for c in colours}) == n
    # 0.26 in RGB: tab10's own closest pair (the first ten); every later colour is at least as far
    # from the others and from white, the background off the object
    assert _min_distance(all_64) >= 0.26
    assert np.linalg.norm(all_64 - 1.0, axis=1).min() >= 0.3
    assert len({tuple(c) for c in region_colours(200)}) == 200


def test_label_figures_draw_each_region_in_its_own_colour():
    cmap, norm = region_colormap(16)
    expected = region_colours(16)
    for label in range(16):
        np.testing.assert_allclose(cmap(norm(label))[:3], expected[label])
    labels = np.array([[0, 11, -1], [15, 10, 11]])
    image = label_image(labels, 16)
    np.testing.assert_array_equal(image[0, 2], [1.0, 1.0, 1.0])        # off the object: white
    np.testing.assert_array_equal(image[1, 0], expected[15])
    assert not np.array_equal(image[0, 1], image[1, 1])                  # regions 11 and 10 differ


def _overlap(a, b) -> bool:
    return a.x0 < b.x1 and b.x0 < a.x1 and a.y0 < b.y1 and b.y0 < a.y1


@pytest.mark.parametrize("model", [(0, 0), (1, 1)])
def test_the_trace_title_does_not_cover_the_panel_titles(model):
    from rjfit.plotting import pyplot

    regions = (model[0] + 1) * (model[1] + 1)
    rng = np.random.default_rng(0)
    record = SimpleNamespace(n_u=np.full(40, model[0]), n_v=np.full(40, model[1]),
                             theta=rng.uniform(0.5, 2.0, (40, regions, 4)))
    figure = trace_figure([record], 20, model)
    renderer = figure.canvas.get_renderer()
    figure.draw(renderer)
    title = figure._suptitle.get_window_extent(renderer)
    panel_titles = [axis.title.get_window_extent(renderer) for axis in figure.axes if axis.get_title()]
    assert len(panel_titles) == 4
    assert not any(_overlap(title, panel) for panel in panel_titles)
    assert all(title.y0 >= panel.y1 for panel in panel_titles)           # above them
    pyplot().close(figure)
