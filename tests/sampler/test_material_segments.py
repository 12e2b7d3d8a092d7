"""The segment moves' family of candidate sets, and the moves' bookkeeping.

The family (:func:`rjfit.sampler.regions.materials.segments.segment_family`) must be a
hierarchy of connected sets over the labelled pixels with positive weights summing to one;
and it must hold a set close to a compact region whose per-pixel features are too noisy to
single it out pixel by pixel, which is why it exists (psm-rock's pebble: 2.1 within-material
sd per pixel). The exactness of the moves is tested by enumeration in
``test_exact_materials.py``; their statistics against a full recompute in
``test_materials.py``.
"""
import numpy as np
import pytest
from scipy import ndimage

from rjfit.sampler.regions.materials.segment_move import SegmentSettings, edges_to_labels
from rjfit.sampler.regions.materials.layout import boundary_count
from rjfit.sampler.regions.materials.segments import segment_family

from builders import raises


def blob_features(seed, height=40, width=56):
    """An elliptical mask with a hole, holding an L-shaped blob whose first feature is 1.22 times the
    rest's under lognormal noise of sd 0.1 (2 noise sd apart per pixel); the second feature heavy-tailed
    and alike in both; 2 % of pixels without a fit (NaN)."""
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[0:height, 0:width]
    mask = (rows - height / 2) ** 2 / (0.47 * height) ** 2 + (cols - width / 2) ** 2 / (0.47 * width) ** 2 < 1
    mask &= (rows - 0.3 * height) ** 2 + (cols - 0.75 * width) ** 2 > 16          # a hole
    blob = (np.abs(rows - 0.6 * height) < 6) & (np.abs(cols - 0.35 * width) < 9)
    blob |= (np.abs(cols - 0.35 * width + 6) < 4) & (rows > 0.25 * height) & (rows < 0.6 * height)
    a = np.where(blob, 1.22, 1.0) * np.exp(rng.normal(0.0, 0.1, (height, width)))
    b = rng.lognormal(1.5, 1.5, (height, width))
    features = np.stack([a.ravel(), b.ravel()], axis=1)
    features[rng.random(height * width) < 0.02] = np.nan
    return features, mask, blob & mask


def sets_of(family, size):
    out = []
    for start, stop in zip(family.start, family.stop):
        member = np.zeros(size, bool)
        member[family.order[start:stop]] = True
        out.append(member)
    return out


def test_the_family_is_a_weighted_hierarchy_of_connected_sets_of_labelled_pixels():
    features, mask, _ = blob_features(0)
    family = segment_family(features, mask)
    assert np.array_equal(np.sort(family.order), np.flatnonzero(mask.ravel()))      # each labelled pixel once
    weights = np.diff(family.cdf, prepend=0.0)
    assert np.all(weights > 0)
    # each cut M = 2 .. 64 partitions the labelled pixels and carries P(M): the weights sum to 1
    assert family.cdf[-1] == pytest.approx(1.0, rel=1e-12)
    sets = sets_of(family, mask.size)
    for i, first in enumerate(sets):
        assert ndimage.label(first.reshape(mask.shape))[1] == 1, "a candidate set is not 4-connected"
        for second in sets[i + 1:]:
            overlap = np.count_nonzero(first & second)
            assert overlap in (0, min(first.sum(), second.sum())), "two sets overlap without nesting"
    rng = np.random.default_rng(3)
    drawn = family.draw(rng)
    assert np.all(np.diff(drawn) > 0) and any(np.array_equal(np.flatnonzero(s), drawn) for s in sets)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_the_family_holds_a_blob_that_pixel_by_pixel_features_cannot_single_out(seed):
    """The best set overlaps the blob (267 px) with IoU >= 0.75, where the best per-pixel threshold of the
    same feature stays below 0.65.

    Measured over seeds 0 .. 7: best set 0.77 to 0.88 (the blob's outline pixels are 2 noise
    sd from the rest, so superpixels straddle it by a pixel or so: a proposal the label sweeps
    then refine); per-pixel threshold 0.49 to 0.56.
    """
    features, mask, blob = blob_features(seed)
    family = segment_family(features, mask)
    truth = blob.ravel()

    def iou(member):
        return np.count_nonzero(member & truth) / np.count_nonzero(member | truth)

    best = max(iou(member) for member in sets_of(family, mask.size))
    log_a = np.log(features[:, 0])
    by_pixel = max(iou(mask.ravel() & (log_a > threshold)) for threshold in np.linspace(0.0, 0.2, 41))
    assert best >= 0.75 and by_pixel < 0.65, (best, by_pixel)


def test_a_tiny_mask_gets_one_superpixel_per_pixel():
    mask = np.ones((2, 3), bool)
    features = np.random.default_rng(1).random((6, 2))
    family = segment_family(features, mask)
    sizes = family.stop - family.start
    assert sizes.min() == 1 and sizes.max() <= 5 and family.cdf[-1] == pytest.approx(1.0)


def test_edges_to_labels_count_the_boundary_change():
    rng = np.random.default_rng(5)
    pixels = rng.integers(0, 3, (7, 9))
    pixels[0, :4] = -1
    members = np.flatnonzero((pixels.ravel() == 1) & (np.arange(63) % 9 < 5))
    n_to = edges_to_labels(pixels, members, 3)
    moved = pixels.copy().ravel()
    moved[members] = 2
    # moving the set from label 1 to 2 cuts its edges to the rest of 1 and joins those to 2
    assert boundary_count(moved.reshape(7, 9)) - boundary_count(pixels) == n_to[1] - n_to[2]


def test_bad_input_is_refused():
    features, mask, _ = blob_features(0)
    with raises(ValueError, "features must be"):
        segment_family(features[:10], mask)
    with raises(ValueError, "at least one labelled"):
        segment_family(features, np.zeros_like(mask))
    with raises(ValueError, "superpixel_size"):
        segment_family(features, mask, 0)
    with raises(ValueError, "segment moves per iteration"):
        SegmentSettings(moves=-1)


def test_a_large_mask_gets_grid_seeded_superpixels_that_partition_it_and_still_find_a_blob():
    """Above SLIC_WHOLE_MAX labelled pixels SLIC is seeded on a grid (the masked seeding's k-means costs pixels x
    superpixels). The superpixels must still partition the labelled pixels into 4-connected pieces, their mean
    size stay near the target (32 px: 16 to 64 allowed, SLIC's sizes follow the features and the mask cuts
    some), and the family hold a set overlapping a compact blob (2 noise sd per pixel, as above) with IoU >=
    0.7. Measured (seeds 0 .. 2, blob centres 256 and 300): 0.73 to 0.89 with the grid, 0.85 to 0.92 with the
    masked seeding; the bound is below the grid's lowest, not the masked bound of 0.75 above."""
    from rjfit.sampler.regions.materials.segments import SLIC_WHOLE_MAX, _standardised, _superpixels

    side = 530
    rng = np.random.default_rng(0)
    mask = np.ones((side, side), bool)
    mask[:20, :] = False
    mask[300:340, 100:140] = False          # a hole: superpixels around it must come out connected
    assert mask.sum() > SLIC_WHOLE_MAX
    rows, cols = np.mgrid[0:side, 0:side]
    blob = (np.abs(rows - 256) < 8) & (np.abs(cols - 256) < 10)
    a = np.where(blob, 1.22, 1.0) * np.exp(rng.normal(0.0, 0.1, (side, side)))
    b = rng.lognormal(1.5, 1.5, (side, side))
    features = np.stack([a.ravel(), b.ravel()], axis=1)
    superpixels = _superpixels(_standardised(features.reshape(side, side, 2), mask), mask, 32)
    assert np.all(superpixels[mask] >= 0) and np.all(superpixels[~mask] == -1)
    for s in np.unique(superpixels[mask])[::97]:
        assert ndimage.label(superpixels == s)[1] == 1, "a superpixel is not 4-connected"
    mean_size = mask.sum() / (superpixels.max() + 1)
    assert 16 <= mean_size <= 64, mean_size
    family = segment_family(features, mask)
    truth = (blob & mask).ravel()
    best = max(np.count_nonzero(m & truth) / np.count_nonzero(m | truth) for m in sets_of(family, mask.size))
    assert best >= 0.7, best


def test_edges_to_labels_count_every_label_s_edges_as_a_double_loop_does():
    """Each label's count against a plain loop over the set's pixels and their four neighbours (unlabelled
    pixels and the set's own pixels not counted), on random labellings with unlabelled pixels."""
    rng = np.random.default_rng(8)
    for _ in range(5):
        pixels = rng.integers(-1, 4, (6, 8))
        members = np.flatnonzero(rng.random(48) < 0.3)
        expected = np.zeros(4, int)
        inside = set(members.tolist())
        for p in members:
            r, c = divmod(int(p), 8)
            for rr, cc in ((r, c + 1), (r, c - 1), (r + 1, c), (r - 1, c)):
                if 0 <= rr < 6 and 0 <= cc < 8 and rr * 8 + cc not in inside and pixels[rr, cc] >= 0:
                    expected[pixels[rr, cc]] += 1
        np.testing.assert_array_equal(edges_to_labels(pixels, members, 4), expected)
