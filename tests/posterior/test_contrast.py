"""A piece's brightness against its surroundings, light by light (:mod:`rjfit.posterior.contrast`), on stacks built
in code whose ratios are known in closed form: a flat and a curved patch lit by lights of different strengths, with
a paint (its albedo times one factor) and a shadow (darkened by a different factor under each light)."""
import numpy as np
import pytest
from builders import PAINT_FACTOR as PAINT
from builders import SHADOW_FACTORS as SHADOW
from builders import paint_and_shadow_observations

from rjfit.posterior.contrast import (MEANING, border, contrast_entry, contrast_words, light_contrasts,
                                      material_contrasts, piece_around, piece_contrast, ring)

LIGHTS = SHADOW.size


def flat_stack():
    obs, labels = paint_and_shadow_observations()
    return obs.y, obs.light, obs.pixel, labels


def test_the_ring_is_the_object_pixels_two_to_four_steps_outside_the_piece():
    piece = np.zeros((15, 15), bool)
    piece[7, 7] = True
    everywhere = np.ones_like(piece)
    around = ring(piece, everywhere)
    rows, cols = np.nonzero(around)
    distance = np.maximum(abs(rows - 7), abs(cols - 7))         # 8-neighbour steps
    assert around.sum() == 9 ** 2 - 3 ** 2 and distance.min() == 2 and distance.max() == 4
    half = everywhere.copy()
    half[:, 8:] = False                                         # off the object: not in the ring
    assert ring(piece, half).sum() == np.count_nonzero(around[:, :8])
    assert ring(piece, everywhere, inner=1, outer=1).sum() == 8
    with pytest.raises(ValueError, match="give both on the image's pixel grid"):
        ring(piece, everywhere[:, :5])
    with pytest.raises(ValueError, match="1 <= inner <= outer"):
        ring(piece, everywhere, inner=3, outer=2)


def test_a_paint_keeps_one_factor_under_every_light_and_a_shadow_does_not():
    y, light, pixel, labels = flat_stack()
    body, paint, shadow = material_contrasts(y, light, pixel, labels, LIGHTS)
    # noise-free data, float64 sums: the ratios are the closed forms up to rounding
    assert paint["min"] == pytest.approx(PAINT, rel=1e-12) and paint["spread"] == pytest.approx(1.0, rel=1e-12)
    assert paint["lights"] == LIGHTS and paint["pixels"] == paint["border_pixels"] == 25 and paint["ring"] == [2, 4]
    assert shadow["min"] == pytest.approx(SHADOW.min(), rel=1e-12)
    assert shadow["max"] == pytest.approx(1.0, rel=1e-12)
    assert shadow["spread"] == pytest.approx(1 / SHADOW.min(), rel=1e-12)
    assert shadow["median"] == pytest.approx(np.median(SHADOW), rel=1e-12)
    # the body's ring lies inside the paint and the shadow: darker than the body, so the body is brighter
    # the body's ring: the cores of the paint's 5 x 5 and the shadow's 6 x 6
    assert body["min"] > 1.0 and body["ring_pixels"] == 3 * 3 + 4 * 4
    assert body["border_pixels"] < body["pixels"]                          # a band along its outline, not all of it
    per_light = light_contrasts(y, light, pixel, labels == 2, ring(labels == 2, labels >= 0), LIGHTS)
    np.testing.assert_allclose(per_light, SHADOW, rtol=1e-12)


def test_the_border_of_a_large_piece_is_a_band_along_its_outline_and_a_small_piece_all_of_it():
    big = np.zeros((31, 31), bool)
    big[8:23, 8:23] = True                                      # 15 x 15
    everywhere = np.ones_like(big)
    band = border(big, ring(big, everywhere))
    # a pixel d steps deep (1 at the outline) is d + 1 steps from the ring, which begins 2 px outside: d <= 3
    assert band.sum() == 15 ** 2 - 9 ** 2 and not band[12:19, 12:19].any()
    small = np.zeros((31, 31), bool)
    small[14:18, 14:18] = True                                  # 4 x 4: every pixel up to 3 px inside
    assert border(small, ring(small, everywhere)).sum() == 16
    # along the silhouette there is no ring, so no border: only the side that meets another material counts
    half = everywhere.copy()
    half[:, 23:] = False
    assert band[11:20, 20:23].all() and not border(big, ring(big, half))[11:20, 20:23].any()
    entry = contrast_entry(np.ones(3), 225, 144, 300)
    assert contrast_words(entry).startswith("its Lambertian albedo at its outline (its pixels up to 3 px inside it) "
                                            "is 1.00 times that of ")
    with pytest.raises(ValueError, match="a width of 1 or more"):
        border(big, everywhere, width=0)


def test_the_shading_of_the_normals_is_divided_out_and_the_paint_keeps_its_one_factor_on_a_curved_patch():
    """On a cylinder whose shading changes across the columns, and differently under each light, the paint's raw
    intensity against its ring changes with the light (the ring lies at other columns); over the shading ``E <l.n>``
    it is the paint's factor under every light, and the shadow's its per-light factors."""
    obs, labels = paint_and_shadow_observations(curved=True)
    shading = obs.irradiance * obs.cos_ln
    _, paint, shadow = material_contrasts(obs.y, obs.light, obs.pixel, labels, LIGHTS, shading)
    assert paint["min"] == pytest.approx(PAINT, rel=1e-12) and paint["spread"] == pytest.approx(1.0, rel=1e-12)
    per_light = light_contrasts(obs.y, obs.light, obs.pixel, labels == 2, ring(labels == 2, labels >= 0), LIGHTS,
                                shading)
    np.testing.assert_allclose(per_light, SHADOW, rtol=1e-12)
    q1, q3 = np.percentile(SHADOW, [25, 75])
    assert shadow["middle_spread"] == pytest.approx(q3 / q1, rel=1e-12) and shadow["lower_quartile"] == \
        pytest.approx(q1, rel=1e-12)
    _, raw_paint, _ = material_contrasts(obs.y, obs.light, obs.pixel, labels, LIGHTS)
    assert raw_paint["spread"] > 1.05                                   # without the shading: the geometry leaks in


def test_a_colour_fit_gets_each_channels_factor_beside_the_channels_together():
    """Three channels of the flat patch, the paint's factor 0.3, 0.6 and 1.2 in them: each channel's ratio is its
    factor, the channels together their mean (the body is alike in every channel, so the sums weigh them alike)."""
    y, light, pixel, labels = flat_stack()
    factors = np.array([0.3, 0.6, 1.2]) / PAINT            # the builder's paint already holds PAINT
    painted = (labels.ravel()[pixel] == 1)
    ys = np.concatenate([np.where(painted, y * factor, y) for factor in factors])
    channel = np.repeat(np.arange(3), y.size)
    args = (np.tile(light, 3), np.tile(pixel, 3))
    _, paint, _ = material_contrasts(ys, *args, labels, LIGHTS, np.ones_like(ys), channel, ("R", "G", "B"))
    assert [paint["channels"][name]["median"] for name in "RGB"] == pytest.approx([0.3, 0.6, 1.2], rel=1e-12)
    assert paint["median"] == pytest.approx(0.7, rel=1e-12) and paint["middle_spread"] == pytest.approx(1.0)
    assert contrast_words(paint).endswith("; per channel, under the middle half: R 0.30 (1.00-fold), G 0.60 "
                                          "(1.00-fold), B 1.20 (1.00-fold)")


def test_a_light_without_observations_and_a_single_material_give_no_ratio():
    y, light, pixel, labels = flat_stack()
    seen = light != 4
    ratios = light_contrasts(y[seen], light[seen], pixel[seen], labels == 1, ring(labels == 1, labels >= 0), LIGHTS)
    assert np.isnan(ratios[4]) and np.all(np.isfinite(np.delete(ratios, 4)))
    assert contrast_entry(ratios, 25, 25, 100)["lights"] == LIGHTS - 1
    assert contrast_entry(np.full(3, np.nan), 1, 1, 1) is None
    one = np.where(labels >= 0, 0, -1)
    assert material_contrasts(y, light, pixel, one, LIGHTS) == [None]
    assert piece_contrast(y, light, pixel, labels == 1, labels == 1, LIGHTS) is None      # no ring on the object


def test_the_words_give_the_range_and_how_much_it_varies():
    y, light, pixel, labels = flat_stack()
    _, paint, shadow = material_contrasts(y, light, pixel, labels, LIGHTS)
    assert contrast_words(paint) == ("its Lambertian albedo is 0.30 times that of the pixels 2 to 4 px outside it "
                                     "under its 6 lights, 0.30 under the middle half of them (1.00-fold)")
    q1, q3 = np.percentile(SHADOW, [25, 75])
    assert contrast_words(shadow) == (f"its Lambertian albedo is 0.20 to 1.00 times that of the pixels 2 to 4 px "
                                      f"outside it under its 6 lights, {q1:.2f} to {q3:.2f} under the middle half of "
                                      f"them ({q3 / q1:.2f}-fold)")
    assert contrast_words(None) is None and "one factor under every light" in MEANING


def test_the_place_a_share_map_peaks_at_is_its_connected_pixels_above_half_the_peak():
    share = np.zeros((8, 8))
    share[2:4, 2:4] = [[0.4, 0.3], [0.25, 0.1]]     # 0.1 is below half the peak
    share[6, 6] = 0.4                               # as high, but not connected
    share[0, 0] = np.nan
    place = piece_around(share, 2, 2, np.ones((8, 8), bool))
    assert set(zip(*np.nonzero(place))) == {(2, 2), (2, 3), (3, 2)}
    with pytest.raises(ValueError, match="give the map's peak"):
        piece_around(share, 5, 5, np.ones((8, 8), bool))
    with pytest.raises(ValueError, match="give the map's peak"):
        piece_around(share, 9, 0, np.ones((8, 8), bool))
    off = np.ones((8, 8), bool)
    off[2, 2] = False
    with pytest.raises(ValueError, match="not a pixel of the object"):
        piece_around(share, 2, 2, off)
