"""The fitted model in Mitsuba: a rendered data set's mesh cut along a fit's regions.

The criticism renders a fit (its posterior predictive simulation, interreflection's feature) on
the data set's mesh. A rendered data set's mesh parts are its true materials; a fit's regions
need not follow them. The cut (:func:`rjfit.render.effect_scenes.region_parts`) must render every
pixel with the parameters of the region the fit gives it, and a part that one region covers whole
exactly as the part itself. The reference is Mitsuba alone: the data
set's own scene rendered with every part given one region's parameters.
"""
from __future__ import annotations

import numpy as np
import pytest

from rjfit.render.datasets import load_dataset
from rjfit.render.effect_scenes import region_materials, region_parts, render_model
from rjfit.render.scene_change import MitsubaChange

# one (I0, kd, gamma) per region: distinct enough that a pixel rendered with a neighbour's shows
PARAMS = np.array([[100.0, 0.2 + 0.09 * r, 2.0 + 3.0 * r] for r in range(8)])


def _halved(truth):
    """Each true part's pixels split into its left and right halves: 8 regions on 4 parts."""
    labels = np.full(truth.shape, -1, dtype=np.int64)
    columns = np.arange(truth.shape[1])[None, :].repeat(truth.shape[0], axis=0)
    for part in range(int(truth.max()) + 1):
        on = truth == part
        middle = np.median(columns[on])
        labels[on & (columns < middle)] = 2 * part
        labels[on & (columns >= middle)] = 2 * part + 1
    return labels


def _reference(dataset, labels, params):
    """Per pixel, the data set's own scene with every part given the pixel's region's parameters."""
    n_parts = max(entry["material"] for entry in dataset.meta["meshes"]) + 1
    out = np.zeros((len(dataset.meta["lights"]), *labels.shape))
    for region in np.unique(labels[labels >= 0]):
        whole = render_model(dataset, region_materials(params[[region] * n_parts]), MitsubaChange())
        out[:, labels == region] = whole[:, labels == region]
    return out


def test_cut_renders_each_pixel_with_its_regions_parameters(paper_sphere_small):
    """8 regions on the 4 parts of paper_sphere (48 x 48): every object pixel as the reference, to float
    rounding (1e-5 relative: the same rays and triangles, the parts only regrouped); the true parts given
    their majority region's parameters (the old rendering) miss it on half the pixels."""
    dataset = load_dataset(paper_sphere_small)
    truth = dataset.truth_labels
    labels = _halved(truth)
    assert len(np.unique(labels[labels >= 0])) == 8
    cut, _folder = region_parts(dataset, labels)
    rendered = render_model(cut, region_materials(PARAMS), MitsubaChange())
    reference = _reference(dataset, labels, PARAMS)
    on = labels >= 0
    scale = np.abs(reference[:, on]).max()
    np.testing.assert_allclose(rendered[:, on], reference[:, on], rtol=1e-5, atol=1e-5 * scale)
    majority = region_materials(PARAMS[[2 * part for part in range(4)]])     # each part its left half's region
    whole_parts = render_model(dataset, majority, MitsubaChange())
    differs = np.abs(whole_parts[:, on] - reference[:, on]).max(axis=0) > 1e-3 * scale
    assert differs.mean() > 0.3


@pytest.mark.parametrize("fixture", ["paper_sphere_small", "dented_plaster_small"])
def test_a_part_one_region_covers_is_rendered_whole(fixture, request):
    """The truth's own segmentation: the cut renders as the data set's scene with its parts' parameters
    (to float rounding), pixel for pixel, though faces at a part's edge may lie nearer to the next part's pixels
    (dented_plaster's slab and dents)."""
    dataset = load_dataset(request.getfixturevalue(fixture))
    truth = dataset.truth_labels.astype(np.int64)
    params = PARAMS[1:2 * (int(truth.max()) + 1):2]
    cut, _folder = region_parts(dataset, truth)
    rendered = render_model(cut, region_materials(params), MitsubaChange())
    reference = render_model(dataset, region_materials(params), MitsubaChange())
    np.testing.assert_allclose(rendered, reference, rtol=1e-5, atol=1e-5 * np.abs(reference).max())


def test_every_face_keeps_its_parts_region_at_the_truth(dented_plaster_small):
    """dented_plaster (a slab with dents, 40 x 40): at the truth's segmentation each face of the cut carries the
    material of the part it came from, the faces no pixel sees (the slab's sides, the dents' hidden walls: 400 of
    80,400 when every face looked at every pixel) included; they light the rest by interreflection."""
    import trimesh
    from scipy.spatial import cKDTree

    dataset = load_dataset(dented_plaster_small)
    truth = dataset.truth_labels.astype(np.int64)
    cut, _folder = region_parts(dataset, truth)
    sources = [(cKDTree(trimesh.load(dataset.path / entry["file"], process=False).triangles_center), entry["material"])
               for entry in dataset.meta["meshes"]]
    for entry in cut.meta["meshes"]:
        centres = trimesh.load(entry["file"], process=False).triangles_center
        distances = np.stack([tree.query(centres)[0] for tree, _ in sources])
        source = np.array([material for _, material in sources])[distances.argmin(axis=0)]
        assert np.all(source == entry["material"]), (entry, np.count_nonzero(source != entry["material"]))
