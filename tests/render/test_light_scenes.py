"""One scene moved from light to light (:func:`rjfit.render.mitsuba_scene.light_scenes`) renders what a scene
built for each light renders.

On the concave two-material object (cast shadows and interreflection both depend on where the light is), with
indirect light (path depth 4), point lights of different positions and intensities, then directional lights of
different directions and irradiances (the change of kind builds a new scene), then point lights again. Each image
is compared with the one of a scene built for that light alone, drawn from the same random streams.
"""
import numpy as np

from rjfit.data.lights import Light
from rjfit.render.datasets import load_dataset


def _lights(meta):
    points = [Light.from_json(entry) for entry in meta["lights"][:2]]
    points[1] = Light(kind="point", intensity=points[1].intensity * 2.5, position=points[1].position)
    directional = [Light(kind="directional", intensity=0.7, direction=(0.3, -0.2, 1.0)),
                   Light(kind="directional", intensity=1.9, direction=(-0.6, 0.1, 0.8)),
                   Light(kind="directional", intensity=1.0, direction=(0.0, 0.0, 1.0))]    # along an axis
    return points + directional + points[::-1]


def test_one_scene_moved_from_light_to_light_renders_what_a_scene_per_light_renders(dented_plaster_small):
    from rjfit.render.effect_scenes import trace_centre_rays
    from rjfit.render.mitsuba_scene import activate, light_scenes
    from rjfit.render.render import scene_from_dataset_meta

    activate()
    meta = load_dataset(dented_plaster_small).meta
    lights = _lights(meta)

    def make_scene(one):
        return scene_from_dataset_meta(meta, dented_plaster_small, lights=one, max_depth=4)

    images = []
    for index, (light, moved) in enumerate(zip(lights, light_scenes(make_scene, lights))):
        expected = trace_centre_rays(make_scene([light]), spp=4, seed=(1, index))
        assert expected.max() > 0
        # the same rays, samples and emitter values through the same kernels; 1e-6 of the brightest value allows
        # for float32 rounding that may differ between two kernel compilations
        np.testing.assert_allclose(trace_centre_rays(moved, spp=4, seed=(1, index)), expected, rtol=0,
                                   atol=1e-6 * expected.max())
        images.append(expected)
    # the lights differ: a scene left at an earlier light would fail above by far more than the tolerance
    for earlier, later in zip(images[:4], images[1:5]):
        assert np.abs(earlier - later).max() > 0.05 * max(earlier.max(), later.max())
