"""The measured calibration's cast-shadow rule (rjfit.data.shadows) on Mitsuba renders whose shadows are known.

About 6 s: two 32 x 32 renders (LLVM).
"""
import dataclasses

import numpy as np

from rjfit.data.shadows import WELL_LIT_COS, flag_cast_shadows, flag_silhouette
from rjfit.render.datasets import load_dataset
from rjfit.render.hidden import CAST_SHADOWS_SPP
from rjfit.render.render import load_scene_definition, render_dataset


def observed(dataset, values):
    """(L, H, W) of one value per valid observation of ``dataset`` (zero elsewhere) and the mask of them."""
    obs = dataset.observations("mean")
    where = (np.asarray(obs.light),) + np.unravel_index(np.asarray(obs.pixel), dataset.image_shape)
    out, seen = np.zeros((dataset.n_lights,) + dataset.image_shape), np.zeros((dataset.n_lights,) + dataset.image_shape,
                                                                             bool)
    out[where], seen[where] = getattr(obs, values), True
    return out, seen


def test_cast_shadows_of_a_direct_light_render_are_found(tmp_path):
    """dented_plaster under direct light only, its shadow rays' visibility known: of the truly shadowed observations
    facing their light well (<l.n> > 0.3, where the rule judges) at least 85 % are flagged (the rest: pixels that a
    shadow's outline crosses, lit over part of their footprint, 8 % at this seed); every flagged observation that
    the shadow rays call lit is dark all the same (under 1.5, where the materials' Lambertian share there is at
    least 5.7 and the noise sd 0.32: occluded by the dents' own geometry, not a noise draw)."""
    scene = load_scene_definition("dented_plaster")
    scene["max_depth"] = 2
    dataset = load_dataset(render_dataset(scene, tmp_path / "plaster", resolution=32, seed=3, noise_variance=0.1,
                                          spp=CAST_SHADOWS_SPP))
    shadowed = ~dataset.visibility
    blind = dataclasses.replace(dataset, visibility=None)
    cos_ln, seen = observed(blind, "cos_ln")
    y, _ = observed(blind, "y")
    flagged, record = flag_cast_shadows(blind)
    found = ~flagged.visibility
    judged_shadows = shadowed & seen & (cos_ln > WELL_LIT_COS)
    assert judged_shadows.sum() > 50, "the render should hold cast shadows where the rule judges"
    assert (found & judged_shadows).sum() / judged_shadows.sum() >= 0.85
    assert np.all(y[found & ~shadowed] < 1.5)
    assert record["observations_flagged"] == int((found & seen).sum())
    assert not np.any(found & ~seen), "only observations that enter the fit are judged"


def test_a_shadowless_render_loses_nothing(tmp_path):
    """paper_sphere (convex, four materials of different albedo): no observation is a cast shadow, and the rule,
    which judges each pixel against its own albedo, flags none, whatever its paint."""
    dataset = load_dataset(render_dataset("paper_sphere", tmp_path / "sphere", resolution=32, seed=3))
    flagged, record = flag_cast_shadows(dataclasses.replace(dataset, visibility=None))
    assert record["observations_flagged"] == 0
    assert flagged.visibility.all()
    # all but the rim's pixels, which face fewer than three of its lights well (91 % judged at this seed)
    assert record["pixels_judged"] >= 0.85 * dataset.object_mask.sum()


def test_the_silhouette_loses_its_observations(tmp_path):
    """The mask's outline (pixels with a 4-neighbour off the mask) loses every observation and nothing else does; on
    paper_sphere at 32 px that is the disc's one-pixel ring."""
    dataset = load_dataset(render_dataset("paper_sphere", tmp_path / "sphere", resolution=32, seed=3))
    flagged, record = flag_silhouette(dataclasses.replace(dataset, visibility=None))
    mask = dataset.object_mask
    inner = mask.copy()
    inner[1:-1, 1:-1] = mask[1:-1, 1:-1] & mask[:-2, 1:-1] & mask[2:, 1:-1] & mask[1:-1, :-2] & mask[1:-1, 2:]
    inner[[0, -1], :], inner[:, [0, -1]] = False, False
    outline = mask & ~inner
    assert record["pixels_flagged"] == outline.sum() > 0
    assert not flagged.visibility[:, outline].any() and flagged.visibility[:, ~outline].all()
    seen = {int(p) for p in flagged.observations("mean").pixel}
    assert not seen & set(np.flatnonzero(outline.ravel()))
