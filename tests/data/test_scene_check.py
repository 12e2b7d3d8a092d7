"""Scene JSON files with bad values are refused up front, with one message that names the
scene file, the entry and what it allows (no raw KeyError / plugin ValueError from Mitsuba)."""
from __future__ import annotations

import json

import pytest

from rjfit.data.descriptions import check_scene_definition
from rjfit.errors import DatasetError, SceneError
from rjfit.io import read_json
from rjfit.render.render import SCENES_DIR


def _paper_sphere():
    return json.loads((SCENES_DIR / "paper_sphere.json").read_text())


def _dented():
    return json.loads((SCENES_DIR / "dented_plaster.json").read_text())


def _set(path, value):
    def edit(scene):
        target = scene
        for key in path[:-1]:
            target = target[key]
        if value is _DELETE:
            del target[path[-1]]
        else:
            target[path[-1]] = value
        return scene
    return edit


_DELETE = object()

# (what to change, the entry the message must name, the allowed values it must state)
CASES = {
    "kd 1.5": (_set(["materials", 0, "kd"], 1.5), "materials[0].kd is 1.5", "in [0, 1]"),
    "gamma -2": (_set(["materials", 1, "gamma"], -2), "materials[1].gamma is -2", "> 0"),
    "gamma NaN": (_set(["materials", 1, "gamma"], float("nan")), "materials[1].gamma is nan", "> 0"),
    "kd as text": (_set(["materials", 2, "kd"], "0.5"), "materials[2].kd is '0.5'", "in [0, 1]"),
    "I0 0": (_set(["materials", 3, "I0"], 0), "materials[3].I0 is 0", "> 0"),
    "no kd": (_set(["materials", 0, "kd"], _DELETE), "materials[0].kd is missing", "kd in [0, 1]"),
    "no camera": (_set(["camera"], _DELETE), "'camera' is missing", "fov or half_width"),
    "camera kind": (_set(["camera", "kind"], "fisheye"), "camera.kind is 'fisheye'", "'perspective' or 'orthographic'"),
    "fov 200": (_set(["camera", "fov"], 200), "camera.fov is 200", "in (0, 180)"),
    "no fov": (_set(["camera", "fov"], _DELETE), "camera.fov is missing", "field of view"),
    "fov and focal_px": (_set(["camera", "focal_px"], 900.0), "camera gives both fov and focal_px", "give one"),
    "focal_px 0": (lambda s: _set(["camera", "focal_px"], 0)(_set(["camera", "fov"], _DELETE)(s)),
                   "camera.focal_px is 0", "focal length in pixels, > 0"),
    "principal point of 3": (_set(["camera", "principal_point"], [1, 2, 3]), "camera.principal_point is [1, 2, 3]",
                             "[cx, cy] in pixels"),
    "principal point NaN": (_set(["camera", "principal_point"], [1, float("nan")]),
                            "camera.principal_point (y) is nan", "finite number of pixels"),
    "up along view": (_set(["camera", "up"], [0, 0, 1]), "camera.up is [0.0, 0.0, 1.0]", "across"),
    "origin 2d": (_set(["camera", "origin"], [0, 8]), "camera.origin is [0, 8]", "3 finite numbers"),
    "light -1": (_set(["lights", 2, "intensity"], -1), "lights[2].intensity is -1", "> 0"),
    "light kind": (_set(["lights", 0, "kind"], "spot"), "lights[0].kind is 'spot'", "'point' or 'directional'"),
    "no position": (_set(["lights", 0, "position"], _DELETE), "lights[0].position is missing", "[x, y, z]"),
    "no lights": (_set(["lights"], []), "lights is []", "non-empty list"),
    "resolution 0": (_set(["resolution"], [0, 32]), "resolution[0] is 0", ">= 1"),
    "spp 0": (_set(["spp"], 0), "spp is 0", ">= 1"),
    "noise -1": (_set(["noise_variance"], -1.0), "noise_variance is -1.0", ">= 0"),
    "reference 0": (_set(["reference_intensity"], 0), "reference_intensity is 0", "> 0"),
    "misspelt entry": (_set(["camra"], {}), "entry 'camra' is not part of a scene", "known entries"),
    "generator": (_set(["geometry", "generator"], "cube"), "geometry.generator is 'cube'", "dented_slab, sphere_quadrants"),
    "n_longitude 6": (_set(["geometry", "n_longitude"], 6), "geometry.n_longitude is 6", "multiple of 4"),
    "material index": (_set(["geometry", "materials"], [0, 1, 2, 7]), "geometry.materials[3] is 7", "[0, 3]"),
    "too few materials": (lambda s: dict(s, materials=s["materials"][:2]), "geometry.materials[2] is 2", "[0, 1]"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_scene_file_names_file_entry_and_allowed_values(tmp_path, case):
    edit, entry, allowed = CASES[case]
    path = tmp_path / "my_scene.json"
    path.write_text(json.dumps(edit(_paper_sphere())))
    with pytest.raises(SceneError) as caught:
        check_scene_definition(read_json(path), path)
    message = str(caught.value)
    assert message.startswith(f"{path}: {entry}"), message
    assert allowed in message and "fix it in the scene file" in message, message
    assert isinstance(caught.value, DatasetError) and isinstance(caught.value, ValueError)
    assert "\n" not in message


@pytest.mark.parametrize("edit, entry", [
    (_set(["geometry", "dents", 1], [0.45, -0.4, 0.3]), "geometry.dents[1] is [0.45, -0.4, 0.3]"),
    (_set(["geometry", "grooves", 0, 2], 0), "geometry.grooves[0] width is 0"),
    (_set(["geometry", "boundary_x"], 5.0), "geometry.boundary_x is 5.0"),
    (_set(["geometry", "radius"], 1.0), "geometry has entries ['radius']"),
    (_set(["lights", 0], {"kind": "directional", "intensity": 1.0, "direction": [0, 0, 0]}),
     "lights[0].direction is [0, 0, 0]"),
])
def test_bad_dented_plaster_geometry_and_lights(tmp_path, edit, entry):
    path = tmp_path / "dented.json"
    path.write_text(json.dumps(edit(_dented())))
    with pytest.raises(SceneError, match=rf"^{path}: ") as caught:
        check_scene_definition(read_json(path), path)
    assert str(caught.value).startswith(f"{path}: {entry}"), str(caught.value)


def test_a_scene_must_be_a_json_object(tmp_path):
    path = tmp_path / "list.json"
    path.write_text("[1, 2]")
    with pytest.raises(SceneError, match="a scene definition is a JSON object"):
        check_scene_definition(read_json(path), path)


def test_built_in_and_derived_scenes_pass():
    from rjfit.render.hidden import backlit_sphere_definition

    for path in sorted(SCENES_DIR.glob("*.json")):
        check_scene_definition(read_json(path), path)
    check_scene_definition(backlit_sphere_definition())
    directional = _paper_sphere()
    directional["lights"] = [{"kind": "directional", "direction": [0.2, 0.3, 1.0], "intensity": 2.0}]
    directional["camera"] = {"kind": "orthographic", "origin": [0, 0, 8], "target": [0, 0, 0], "up": [0, 1, 0],
                             "half_width": 1.2}
    check_scene_definition(directional, "directional.json")


def test_out_of_range_material_reaching_mitsuba_is_a_value_error_naming_it(tmp_path):
    """Past the scene check (a hand-edited dataset.json), the plugin's range check used to
    reach the caller as Mitsuba's RuntimeError with a Python traceback in its text."""
    from rjfit.render.mitsuba_scene import activate, material_dict

    activate("llvm_ad_rgb")
    with pytest.raises(ValueError, match=r"material 'upper left': rjfit_blinn: kd must lie in \[0, 1\], got 1.5"):
        material_dict({"name": "upper left", "I0": 100.0, "kd": 1.5, "gamma": 5.0}, 100.0)


_STACK = {"format": "rjfit-mesh-stack/1", "images": ["img_000.exr", "img_001.exr"], "mesh": "object.ply",
          "camera": {"kind": "perspective", "origin": [0, 0, 5], "target": [0, 0, 0], "up": [0, 1, 0], "fov": 30},
          "resolution": [16, 16], "lights": [{"kind": "point", "position": [1, 1, 3], "intensity": 1.0},
                                             {"kind": "point", "position": [-1, 1, 3], "intensity": 1.0}]}


@pytest.mark.parametrize("change, entry", [
    ({"images": [5, 6]}, "images[0] is 5; it must be an image file name relative to the folder, a non-empty string"),
    ({"images": "img_000.exr"}, "images is 'img_000.exr'; it must be a non-empty list of image file names"),
    ({"images": []}, "images is []; it must be a non-empty list"),
    ({"images": ["img_000.exr", ""]}, "images[1] is ''; it must be an image file name"),
    ({"mesh": 3}, "mesh is 3; it must be the mesh's file name relative to the folder, a non-empty string"),
    ({"mesh": ["object.ply"]}, "mesh is ['object.ply']; it must be the mesh's file name"),
])
def test_mesh_stack_images_and_mesh_must_be_file_names(tmp_path, change, entry):
    """Used to reach the loader as ``PosixPath / int`` (TypeError) or, for a string, count its
    characters as images."""
    from rjfit.render.datasets import load_dataset

    (tmp_path / "stack.json").write_text(json.dumps({**_STACK, **change}))
    with pytest.raises(SceneError) as caught:
        load_dataset(tmp_path)
    message = str(caught.value)
    assert message.startswith(f"{tmp_path / 'stack.json'}: {entry}"), message
    assert "Measured mesh stacks" in message and "\n" not in message


def test_dataset_description_must_be_an_object_with_its_format():
    from rjfit.data.descriptions import check_dataset_description

    with pytest.raises(SceneError, match=r"^ds/dataset.json: a data set description is a JSON object"):
        check_dataset_description("text", "ds/dataset.json")
    with pytest.raises(SceneError, match=r"^ds/dataset.json: format is 'rjfit-dataset/0'; it must be 'rjfit-dat"):
        check_dataset_description({"format": "rjfit-dataset/0", "resolution": [2, 2], "images": ["a.exr"],
                                   "geometry": "g.exr", "lights": [{"kind": "directional", "direction": [0, 0, 1],
                                                                    "intensity": 1.0}]}, "ds/dataset.json")
