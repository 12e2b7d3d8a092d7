"""``rjfit render`` on a scene JSON with a bad value: one line naming the file, the entry and
its allowed values, exit status 1, nothing written (it used to be a traceback: the plugin's
ValueError inside Mitsuba's parser error, or KeyError: 'camera')."""
from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from rjfit.cli import main
from rjfit.render.render import SCENES_DIR, load_scene_definition


def _scene(**changes):
    scene = json.loads((SCENES_DIR / "paper_sphere.json").read_text())
    for key, value in changes.items():
        if value is None:
            del scene[key]
        else:
            scene[key] = value
    return scene


def _materials(index, **values):
    materials = _scene()["materials"]
    materials[index] = dict(materials[index], **values)
    return materials


@pytest.mark.parametrize("scene, message", [
    (_scene(materials=_materials(0, kd=1.5)), "materials[0].kd is 1.5; it must be a number in [0, 1]"),
    (_scene(materials=_materials(1, gamma=-2)), "materials[1].gamma is -2; it must be a number > 0"),
    (_scene(camera=None), "'camera' is missing; a scene needs a camera"),
])
def test_render_refuses_a_bad_scene_file_in_one_line(tmp_path, scene, message):
    path = tmp_path / "bad_scene.json"
    path.write_text(json.dumps(scene))
    outcome = CliRunner().invoke(main, ["render", str(path), "--resolution", "8", "--out", str(tmp_path / "out")])
    assert outcome.exit_code == 1, outcome.output
    lines = outcome.output.strip().splitlines()
    assert lines == [lines[0]] and lines[0].startswith(f"Error: {path}: {message}"), outcome.output
    assert not (tmp_path / "out").exists()


def test_a_scene_passed_as_a_dict_is_checked_too():
    from rjfit.errors import SceneError

    with pytest.raises(SceneError, match=r"the scene definition: materials\[0\]\.kd is 1.5"):
        load_scene_definition(_scene(materials=_materials(0, kd=1.5)))
