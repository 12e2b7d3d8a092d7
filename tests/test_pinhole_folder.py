"""Photometric-stereo folders seen by a pinhole (perspective) camera.

With distant lights the radiance depends on the point only through its normal and the
direction towards the camera, which for a pinhole is minus the pixel-centre ray's direction
whatever the depth; the folder declares the focal length and principal point in pixels
(``rjfit.json``: ``{"camera": {"kind": "perspective", "focal_px": f, "principal_point":
[cx, cy]}}``). The gate path-traces the folder's facets through the same pinhole with
Mitsuba, so it checks the view directions the loader computed.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from test_bad_input import HEIGHT, WIDTH, make_ps_folder

from rjfit.data.diligent import crop_to_mask, load_diligent
from rjfit.data.errors import DatasetError
from rjfit.validate import closed_form_radiance, validate_dataset

# A wide, off-centre pinhole: the view directions across the 10 x 8 frame differ by up to
# about 45 deg, so a closed form that assumed v = (0, 0, 1) would be far off.
PINHOLE = {"kind": "perspective", "focal_px": 6.0, "principal_point": [4.0, 3.5]}


def pinhole_folder(folder, camera=PINHOLE):
    folder = make_ps_folder(folder)
    (folder / "rjfit.json").write_text(json.dumps({"camera": camera}))
    return folder


def test_view_directions_of_a_pinhole(tmp_path):
    dataset = load_diligent(pinhole_folder(tmp_path / "ps"))
    assert dataset.meta["camera"]["type"] == "perspective"
    assert dataset.meta["camera"]["focal_px"] == 6.0 and dataset.meta["camera"]["principal_point"] == [4.0, 3.5]
    for row, col in ((0, 0), (HEIGHT - 1, WIDTH - 1), (3, 4), (5, 2)):
        # minus the ray through the pixel centre (col + 0.5, row + 0.5); x right, y up
        towards = np.array([-(col + 0.5 - 4.0) / 6.0, (row + 0.5 - 3.5) / 6.0, 1.0])
        np.testing.assert_allclose(dataset.view_dirs[row, col], towards / np.linalg.norm(towards), atol=1e-12)
    # the pixel whose centre is nearest the principal point looks almost straight on
    assert dataset.view_dirs[3, 3, 2] > 0.99
    # the default principal point is the frame's centre
    centred = load_diligent(tmp_path / "ps", camera={"kind": "perspective", "focal_px": 6.0})
    assert centred.meta["camera"]["principal_point"] == [WIDTH / 2.0, HEIGHT / 2.0]
    np.testing.assert_allclose(centred.view_dirs[::-1, ::-1, :2], -centred.view_dirs[..., :2], atol=1e-12)
    # an orthographic declaration (DiLiGenT's convention, the default) looks along z everywhere
    orthographic = load_diligent(tmp_path / "ps", camera={"kind": "orthographic"})
    assert orthographic.meta["camera"]["type"] == "orthographic"
    assert np.array_equal(orthographic.view_dirs, np.broadcast_to([0.0, 0.0, 1.0], orthographic.view_dirs.shape))


def test_crop_moves_the_principal_point(tmp_path):
    dataset = load_diligent(pinhole_folder(tmp_path / "ps"))
    cropped = crop_to_mask(dataset, margin=0)
    row0, col0 = cropped.meta["crop"]["row0"], cropped.meta["crop"]["col0"]
    assert (row0, col0) != (0, 0)            # the test means something only if the crop moves the corner
    assert cropped.meta["camera"]["principal_point"] == [4.0 - col0, 3.5 - row0]
    height, width = cropped.object_mask.shape
    np.testing.assert_array_equal(cropped.view_dirs, dataset.view_dirs[row0:row0 + height, col0:col0 + width])


@pytest.mark.parametrize("camera, message", [
    ({"kind": "fisheye"}, "kind is 'fisheye'; it must be one of orthographic, perspective"),
    ({"kind": "perspective"}, "focal_px is None; a perspective camera needs its focal length in pixels"),
    ({"kind": "perspective", "focal_px": -3}, "focal_px is -3"),
    ({"kind": "perspective", "focal_px": 6, "principal_point": [1]}, "principal_point is [1]; it must be [cx, cy]"),
    ({"kind": "perspective", "focal_px": 6, "fov": 40}, "unknown key(s) fov for a perspective camera"),
    ("perspective", "camera is 'perspective'; it must be an object"),
])
def test_bad_camera_declarations_name_the_file(tmp_path, camera, message):
    folder = pinhole_folder(tmp_path / "ps", camera)
    with pytest.raises(DatasetError) as error:
        load_diligent(folder)
    assert str(folder / "rjfit.json") in str(error.value) and message in str(error.value), str(error.value)


def test_gate_traces_the_pinhole(tmp_path):
    """Mitsuba's pinhole (fov and principal-point offsets from the declaration) sees each facet
    from the direction the loader computed: the view directions agree to float rounding and
    the closed form matches the path tracer. Negative control: the same folder judged by a
    closed form that assumes an orthographic view, v = (0, 0, 1), fails the gate."""
    folder = pinhole_folder(tmp_path / "ps")
    result = validate_dataset(folder, tmp_path / "v", spp=1)
    assert result["passed"], result
    # float32 ray directions: about 1e-7 rad, i.e. 1e-5 deg
    assert result["max_view_angle_deg"] < 1e-3, result["max_view_angle_deg"]
    assert result["max_normal_angle_deg"] < 0.05

    def orthographic_view(positions, normals, view_dirs, light, material, reference):
        straight = np.broadcast_to(np.array([0.0, 0.0, 1.0]), view_dirs.shape)
        return closed_form_radiance(positions, normals, straight, light, material, reference)

    wrong = validate_dataset(folder, tmp_path / "w", spp=1, forward_model=orthographic_view)
    assert not wrong["passed"] and wrong["median_rel_err"] > 100 * wrong["thresholds"]["median_rel_err"], wrong
