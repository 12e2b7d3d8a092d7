"""Bad input gets a clear error naming the file and the problem, never a silent wrong fit.

Each case starts from a tiny valid folder written here (a DiLiGenT-style photometric-stereo
folder of 16-bit PNGs, or rjfit's own layout), breaks one thing, and checks the message.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from rjfit.data.diligent import load_diligent
from rjfit.data.exr import write_exr
from rjfit.data.mesh import load_mesh
from rjfit.errors import DatasetError, DatasetFileNotFoundError
from rjfit.render.datasets import load_dataset

from builders import (
    DIRECTIONS,
    HEIGHT,
    INTENSITIES,
    MASK_PIXELS,
    WIDTH,
    edit_description,
    make_ps_folder,
    make_rjfit_folder,
    raises,
    shading,
    sphere_geometry,
    write_lines,
    write_png,
)

# -- the unbroken folders load: every failure below is due to the one thing broken -----------------

def test_valid_folders_load(tmp_path):
    dataset = load_dataset(make_ps_folder(tmp_path / "ps"))
    mask, normals = sphere_geometry()
    assert dataset.n_lights == 4 and dataset.image_shape == (HEIGHT, WIDTH)
    np.testing.assert_array_equal(dataset.object_mask, mask)
    assert dataset.saturated.sum() == 1 and dataset.saturated[0, 3, 4]
    assert not dataset.valid_mask()[0, 3, 4]
    raw = shading(mask, normals)
    np.testing.assert_allclose(dataset.images[1], raw[1] / INTENSITIES[1], rtol=1e-6)
    assert dataset.observations().n_obs == int(dataset.valid_mask().sum()) > 0
    generic = load_dataset(make_ps_folder(tmp_path / "generic", images="exr", normals_name="normals.npy"))
    np.testing.assert_allclose(generic.images[1:], dataset.images[1:], rtol=1e-6)
    assert generic.meta["saturation"]["raw_threshold"] is None  # float images: no default threshold
    assert load_dataset(make_rjfit_folder(tmp_path / "rjfit")).n_lights == 2
    full = load_dataset(make_rjfit_folder(tmp_path / "full", full=True))
    assert full.visibility.all() and set(np.unique(full.truth_labels)) == {-1, 0, 1}
    assert full.truth_params[1] == {"I0": 5.0, "kd": 0.9, "gamma": 20.0, "sigma2": 0.0}


def test_srgb_encoded_eight_bit_is_decoded(tmp_path):
    import colour

    folder = make_ps_folder(tmp_path)
    codes = np.random.default_rng(1).integers(0, 255, (4, HEIGHT, WIDTH, 3)).astype(np.uint8)
    codes[2, 0, 0] = 255
    for index, image in enumerate(codes):
        write_png(folder / f"{index + 1:03d}.png", image)
    dataset = load_diligent(folder, encoded="sRGB")
    expected = colour.cctf_decoding(codes / 255.0, "sRGB") / INTENSITIES[:, None, None, :]
    np.testing.assert_allclose(dataset.images, expected, rtol=1e-6, atol=1e-7)
    assert dataset.saturated[2, 0, 0] and dataset.meta["encoded"] == "sRGB"
    with raises(DatasetError, "encoded must be None (linear data) or one of ('sRGB', 'linear'), got 'gamma'"):
        load_diligent(folder, encoded="gamma")
    # the command line reads the folder's own declaration; an argument still wins over it
    (folder / "rjfit.json").write_text('{"encoded": "sRGB"}')
    np.testing.assert_array_equal(load_dataset(folder).images, dataset.images)
    with raises(DatasetError, folder / "001.png", "8-bit image"):
        load_diligent(folder, encoded=None)
    (folder / "rjfit.json").write_text('{"encoding": "sRGB"}')
    with raises(DatasetError, folder / "rjfit.json",
                "keys among saturation, dark, encoded, response, bits, mask, normals, crop, camera; unknown: encoding"):
        load_dataset(folder)
    for text, message in (('{"crop": -40}', "crop is -40; it must be true, false or a margin in pixels >= 0"),
                          ('{"crop": "yes"}', "crop is 'yes'"), ('{"saturation": "250"}', "saturation is '250'"),
                          ('{"normals": 5}', "normals is 5; it must be a file name"),
                          ('{"encoded": "gamma"}', "encoded is 'gamma'")):
        (folder / "rjfit.json").write_text(text)
        with raises(DatasetError, folder / "rjfit.json", message):
            load_dataset(folder)


# -- bad input ------------------------------------------------------------------------------------

def test_mismatched_image_size(tmp_path):
    folder = make_ps_folder(tmp_path)
    write_png(folder / "002.png", np.full((HEIGHT + 1, WIDTH, 3), 1000, np.uint16))
    with raises(DatasetError, folder / "002.png", "image is 10 x 9 (width x height), but mask.png is 10 x 8"):
        load_dataset(folder)


def test_nan_pixels(tmp_path):
    folder = make_ps_folder(tmp_path, images="exr")
    image = np.ones((HEIGHT, WIDTH), np.float32)
    image[2, 5] = np.nan
    write_exr(folder / "003.exr", {"R": image, "G": image, "B": np.where(image > 0, np.inf, 0).astype(np.float32)})
    with raises(DatasetError, folder / "003.exr", "80 pixels are NaN or Inf (first at row 0, column 0)"):
        load_dataset(folder)


def test_negative_radiance_is_refused_with_the_first_pixel_and_the_count(tmp_path):
    """A float image with a negative value (an over-subtracted sensor offset): refused, naming the
    file, the count of pixels, the first one and its value, before it reaches the likelihood. A
    16-bit stack cannot hold one; a float image of zeros (no light) is fine."""
    folder = make_ps_folder(tmp_path, images="exr")
    image = np.ones((HEIGHT, WIDTH), np.float32)
    image[3, 6] = image[5, 1] = -5.0
    write_exr(folder / "002.exr", {"R": image, "G": np.ones_like(image), "B": np.ones_like(image)})
    with raises(DatasetError, folder / "002.exr", "2 pixels are negative (first at row 3, column 6: -5); radiance cannot "
                                                  "be negative"):
        load_dataset(folder)
    write_exr(folder / "002.exr", {c: np.zeros((HEIGHT, WIDTH), np.float32) for c in "RGB"})
    assert load_dataset(folder).images[1].max() == 0.0


def test_the_rjfit_layout_s_declared_noise_may_dip_below_zero_by_eight_sd(tmp_path):
    """Rendered data carry the Gaussian noise their dataset.json declares (noise_variance), so dark
    pixels dip below zero: allowed down to -8 sd (a draw below that has probability under 7e-16),
    refused below it, and refused at any negative value where no noise is declared."""
    folder = make_rjfit_folder(tmp_path)
    edit_description(folder, lambda meta: meta.update(noise_variance=0.01))     # sd 0.1: the floor is -0.8
    image = np.full((HEIGHT, WIDTH), 0.5, np.float32)
    image[1, 2] = -0.79
    write_exr(folder / "images/light_001.exr", {c: image for c in "RGB"})
    assert load_dataset(folder).images[1, 1, 2, 0] == np.float32(-0.79)
    image[4, 4] = -0.81
    write_exr(folder / "images/light_001.exr", {c: image for c in "RGB"})
    with raises(DatasetError, folder / "images/light_001.exr", "1 pixels are below -0.8, the floor of the declared noise "
                                                               "(8 sd below 0) (first at row 4, column 4: -0.81)"):
        load_dataset(folder)
    edit_description(folder, lambda meta: meta.update(noise_variance=0.0))
    with raises(DatasetError, folder / "images/light_001.exr", "2 pixels are negative (first at row 1, column 2: -0.79)"):
        load_dataset(folder)


def test_a_truncated_png_is_one_line_without_libpng_s_noise(tmp_path, capfd):
    """libpng prints ``libpng error: Read Error`` on file descriptor 2 when a PNG ends early: the
    loader captures it into its one line, so nothing else reaches the terminal (checked at the
    descriptor level, where C libraries write)."""
    import cv2

    folder = make_ps_folder(tmp_path)
    noisy = np.random.default_rng(2).integers(0, 65535, (HEIGHT * 40, WIDTH * 40, 3)).astype(np.uint16)
    whole = tmp_path / "whole.png"
    write_png(whole, noisy)
    data = whole.read_bytes()
    (tmp_path / "cut.png").write_bytes(data[: len(data) // 2])
    capfd.readouterr()
    assert cv2.imread(str(tmp_path / "cut.png"), cv2.IMREAD_UNCHANGED) is None
    assert "libpng error" in capfd.readouterr().err          # the noise this test is about, read directly
    (folder / "002.png").write_bytes(data[: len(data) // 2])     # decoding stops before the size is checked
    with raises(DatasetError, folder / "002.png", "not a readable image (OpenCV could not decode it: libpng error"):
        load_dataset(folder)
    captured = capfd.readouterr()
    assert captured.err == "" and captured.out == ""


def test_nan_normals_and_directions(tmp_path):
    folder = make_ps_folder(tmp_path, normals_name="normals.npy")
    _, normals = sphere_geometry()
    normals[4, 5] = np.nan
    np.save(folder / "normals.npy", normals)
    with raises(DatasetError, folder / "normals.npy", "1 normals inside the object mask are NaN or Inf",
                "row 4, column 5"):
        load_dataset(folder)
    directions = (folder / "light_directions.txt").read_text().splitlines()
    directions[2] = "nan 0 1"
    (folder / "light_directions.txt").write_text("\n".join(directions) + "\n")
    with raises(DatasetError, folder / "light_directions.txt", "line 3: a light direction x y z is NaN or Inf"):
        load_dataset(folder)


def test_light_directions_that_are_not_unit_vectors(tmp_path):
    """A direction off unit length by more than 1 % (a typo, or a position) is refused; a few decimals' rounding is not."""
    folder = make_ps_folder(tmp_path)
    lines = (folder / "light_directions.txt").read_text().splitlines()
    rounded = list(lines)
    rounded[1] = " ".join(f"{c:.2f}" for c in DIRECTIONS[1])              # within 1 % of unit length
    (folder / "light_directions.txt").write_text("\n".join(rounded) + "\n")
    np.testing.assert_allclose(load_dataset(folder).lights[1].direction, DIRECTIONS[1], atol=0.01)
    lines[2] = "0.5 0.5 0.5"
    (folder / "light_directions.txt").write_text("\n".join(lines) + "\n")
    with raises(DatasetError, folder / "light_directions.txt", "line 3: light direction [0.5, 0.5, 0.5] has length 0.866",
                "1 of 4 lines are so"):
        load_dataset(folder)


def test_nan_pixels_in_rjfit_layout(tmp_path):
    folder = make_rjfit_folder(tmp_path)
    write_exr(folder / "images/light_001.exr", {c: np.full((HEIGHT, WIDTH), np.nan, np.float32) for c in "RGB"})
    with raises(DatasetError, folder / "images/light_001.exr", "80 pixels are NaN or Inf"):
        load_dataset(folder)


def test_light_without_image(tmp_path):
    folder = make_ps_folder(tmp_path)
    (folder / "003.png").unlink()
    with raises(DatasetFileNotFoundError, folder / "003.png", "no such file",
                "filenames.txt line 3 names it as the image of light 3 (a light without an image)"):
        load_dataset(folder)
    folder = make_ps_folder(tmp_path / "extra_light")
    with open(folder / "light_directions.txt", "a") as file:
        file.write("0.1 0.1 0.99\n")
    with raises(DatasetError, folder / "light_directions.txt", "has 5 lights but",
                folder / "filenames.txt", "lists 4 images: the light on line 5 and any after it have no image"):
        load_dataset(folder)


def test_image_without_light(tmp_path):
    folder = make_ps_folder(tmp_path)
    write_png(folder / "005.png", np.full((HEIGHT, WIDTH, 3), 1000, np.uint16))
    with open(folder / "filenames.txt", "a") as file:
        file.write("005.png\n")
    with raises(DatasetError, folder / "filenames.txt", "lists 5 images but", folder / "light_directions.txt",
                "has 4 lights: image 005.png (line 5) and any after it have no light"):
        load_dataset(folder)


def test_image_listed_twice(tmp_path):
    folder = make_ps_folder(tmp_path)
    (folder / "filenames.txt").write_text("001.png\n002.png\n001.png\n004.png\n")
    with raises(DatasetError, folder / "filenames.txt", "line 3: 001.png is listed twice (also on line 1)"):
        load_dataset(folder)


def test_eight_bit_where_sixteen_promised(tmp_path):
    folder = make_ps_folder(tmp_path)
    write_png(folder / "002.png", np.full((HEIGHT, WIDTH, 3), 100, np.uint8))
    with raises(DatasetError, folder / "002.png", "8-bit image, but linear data must have 16 bits per channel"):
        load_dataset(folder)
    with raises(DatasetError, "write {\"encoded\": \"linear\"} to rjfit.json in its folder", "{\"encoded\": \"sRGB\"}"):
        load_dataset(folder)
    # 8-bit data widened to 16 bits (low byte always 0) is refused too.
    write_png(folder / "002.png", (np.full((HEIGHT, WIDTH, 3), 100, np.uint16) << 8))
    with raises(DatasetError, folder / "002.png", "16-bit file holding 8-bit data (every value is a multiple of 256"):
        load_dataset(folder)


def test_normals_not_unit_length(tmp_path):
    import scipy.io

    folder = make_ps_folder(tmp_path)
    _, normals = sphere_geometry()
    normals[3, 5] *= 0.5
    scipy.io.savemat(folder / "Normal_gt.mat", {"Normal_gt": normals})
    with raises(DatasetError, folder / "Normal_gt.mat",
                f"1 of {MASK_PIXELS} normals inside the object mask are not unit length",
                "first at row 3, column 5"):
        load_dataset(folder)


def test_normals_not_unit_length_in_rjfit_layout(tmp_path):
    folder = make_rjfit_folder(tmp_path)
    mask, normals = sphere_geometry()
    channels = {f"{p}.{a}": normals[..., i] * 2 for p in "PN" for i, a in enumerate("XYZ")}
    channels.update({"V.X": np.zeros((HEIGHT, WIDTH)), "V.Y": np.zeros((HEIGHT, WIDTH)),
                     "V.Z": np.ones((HEIGHT, WIDTH)), "mask": mask.astype(np.float32)})
    write_exr(folder / "geometry.exr", channels)
    with raises(DatasetError, folder / "geometry.exr",
                f"(channels N.X N.Y N.Z): {MASK_PIXELS} of {MASK_PIXELS} normals inside the object mask are not "
                "unit length"):
        load_dataset(folder)


def test_mask_selects_nothing(tmp_path):
    folder = make_ps_folder(tmp_path)
    write_png(folder / "mask.png", np.zeros((HEIGHT, WIDTH, 3), np.uint8))
    with raises(DatasetError, folder / "mask.png", "the object mask selects no pixel"):
        load_dataset(folder)
    folder = make_rjfit_folder(tmp_path / "rjfit")
    channels = {name: np.zeros((HEIGHT, WIDTH)) for name in
                ("P.X", "P.Y", "P.Z", "N.X", "N.Y", "N.Z", "V.X", "V.Y", "V.Z", "mask")}
    write_exr(folder / "geometry.exr", channels)
    with raises(DatasetError, folder / "geometry.exr", "(channel mask): the object mask selects no pixel"):
        load_dataset(folder)


def test_lights_behind_the_object(tmp_path):
    folder = make_ps_folder(tmp_path)
    write_lines(folder / "light_directions.txt", DIRECTIONS * [1, 1, -1])
    with raises(DatasetError, folder / "light_directions.txt", "all 4 lights are behind the object "
                f"(<l.n> <= 0 at every one of the {MASK_PIXELS} mask pixels)",
                "z points towards the camera: is the z axis (or the direction sign) flipped?"):
        load_dataset(folder)
    write_lines(folder / "light_directions.txt", np.vstack([DIRECTIONS[:1], [[0.1, 0.2, -0.97]], DIRECTIONS[2:]]))
    with raises(DatasetError, "1 of 4 lights are behind the object", folder / "light_directions.txt",
                "line 2 (light 2, image 002.png, direction"):
        load_dataset(folder)
    folder = make_rjfit_folder(tmp_path / "rjfit", lights=[
        {"kind": "point", "intensity": 1.0, "position": [0.0, 0.0, -5.0]},
        {"kind": "directional", "intensity": 1.0, "direction": [0.0, 0.0, -1.0]}])
    with raises(DatasetError, folder / "dataset.json", "all 2 lights are behind the object"):
        load_dataset(folder)


def test_missing_layout_files(tmp_path):
    folder = make_ps_folder(tmp_path)
    (folder / "mask.png").unlink()
    with raises(DatasetFileNotFoundError, folder / "mask.png", "no such file (the object mask"):
        load_dataset(folder)
    folder = make_ps_folder(tmp_path / "no_normals")
    (folder / "Normal_gt.mat").unlink()
    with raises(DatasetFileNotFoundError, folder, "no normal map (looked for Normal_gt.mat"):
        load_dataset(folder)
    with raises(FileNotFoundError, tmp_path / "nothing", "not a data set"):
        load_dataset(tmp_path / "nothing")


def test_bad_light_file_lines(tmp_path):
    folder = make_ps_folder(tmp_path)
    (folder / "light_intensities.txt").write_text("1 1 1\n1 1\n1 1 1\n1 1 1\n")
    with raises(DatasetError, folder / "light_intensities.txt", "line 2: expected 1 or 3 numbers"):
        load_dataset(folder)
    (folder / "light_intensities.txt").write_text("1 1 1\n1 1 1\n1 0 1\n1 1 1\n")
    with raises(DatasetError, folder / "light_intensities.txt", "line 3: light intensities must be positive"):
        load_dataset(folder)


def test_mesh_without_faces(tmp_path):
    import trimesh

    path = tmp_path / "points.ply"
    trimesh.PointCloud(np.random.default_rng(0).random((20, 3))).export(path)
    with raises(DatasetError, path, "the mesh has no faces (20 vertices, 0 triangles)"):
        load_mesh(path)
    with raises(DatasetFileNotFoundError, tmp_path / "missing.obj", "no such mesh file"):
        load_mesh(tmp_path / "missing.obj")
    good = tmp_path / "box.ply"
    trimesh.creation.box().export(good)
    assert len(load_mesh(good).faces) == 12


# -- dataset.json: every entry the loaders read is checked up front ---------------------------------

def _drop(*keys):
    """An edit that deletes meta[keys[0]][keys[1]]..."""
    def edit(meta):
        target = meta
        for key in keys[:-1]:
            target = target[key]
        del target[keys[-1]]
    return edit


def _put(value, *keys):
    def edit(meta):
        target = meta
        for key in keys[:-1]:
            target = target[key]
        target[keys[-1]] = value
    return edit


# (the edit of a valid full dataset.json, the entry and the problem the message must state)
DESCRIPTION_CASES = {
    "no lights": (_drop("lights"), "'lights' is missing; a data set needs a list of lights"),
    "no resolution": (_drop("resolution"), "'resolution' is missing; a data set needs a resolution [height, width]"),
    "no geometry": (_drop("geometry"), "'geometry' is missing"),
    "resolution scalar": (_put(16, "resolution"), "resolution is 16; it must be [height, width]"),
    "light without kind": (_drop("lights", 0, "kind"), "lights[0].kind is missing"),
    "lights not a list": (_put({"kind": "point"}, "lights"),
                          "lights is {'kind': 'point'}; it must be a non-empty list"),
    "position of 2": (_put([1, 2], "lights", 0, "position"),
                      "lights[0].position is [1, 2]; it must be a list of 3 finite numbers"),
    "intensity text": (_put("bright", "lights", 1, "intensity"),
                       "lights[1].intensity is 'bright'; it must be a number > 0"),
    "no materials": (_drop("materials"),
                     "'materials' is missing; a data set needs its materials {I0, kd, gamma, sigma2} when it has "
                     "truth_labels"),
    "material without kd": (_drop("materials", 0, "kd"), "materials[0].kd is missing"),
    "material without sigma2": (_drop("materials", 1, "sigma2"), "materials[1].sigma2 is missing"),
    "kd 1.5": (_put(1.5, "materials", 1, "kd"), "materials[1].kd is 1.5; it must be a number in [0, 1]"),
    "description is a list": (lambda meta: [1, 2, 3], "a data set description is a JSON object"),
    "reference intensity 0": (_put(0, "reference_intensity"), "reference_intensity is 0; it must be a number > 0"),
    "no reference intensity with meshes": (_drop("reference_intensity"), "'reference_intensity' is missing"),
    "camera without fov": (lambda meta: meta.update(camera={"kind": "perspective", "origin": [0, 0, 8],
                                                              "target": [0, 0, 0], "up": [0, 1, 0]}),
                           "camera.fov is missing"),
    "no camera with meshes": (_drop("camera"), "'camera' is missing"),
    "mesh without file": (_drop("meshes", 0, "file"), "meshes[0].file is missing"),
    "mesh material 9": (_put(9, "meshes", 1, "material"), "meshes[1].material is 9; it must index the 2 entries of "
                                                         "'materials', i.e. lie in [0, 1]"),
    "meshes not a list": (_put("meshes/part_000.ply", "meshes"), "meshes is 'meshes/part_000.ply'; it must be a list"),
    "image not a name": (_put([5, "images/light_001.exr"], "images"), "images[0] is 5; it must be an image file name"),
    "one image for two lights": (_put(["images/light_000.exr"], "images"),
                                 "images lists 1 files but 'lights' has 2; every light needs exactly one image"),
    "visibility not a name": (_put(3, "visibility"), "visibility is 3; it must be a file name"),
    "saturation negative": (_put(-1, "saturation"), "saturation is -1; it must be a value > 0 at which a pixel clips, "
                                                    "or null"),
    "max_depth 1": (_put(1, "max_depth"), "max_depth is 1; it must be an integer >= 2"),
}


@pytest.mark.parametrize("case", sorted(DESCRIPTION_CASES))
def test_bad_dataset_description_names_the_file_and_entry(tmp_path, case):
    from rjfit.errors import SceneError

    edit, message = DESCRIPTION_CASES[case]
    folder = make_rjfit_folder(tmp_path, full=True)
    path = edit_description(folder, edit)
    with pytest.raises(SceneError) as caught:
        load_dataset(folder)
    text = str(caught.value)
    assert text.startswith(f"{path}: "), text
    assert message in text and "docs/dataset-format.md" in text and "\n" not in text, text
    assert isinstance(caught.value, DatasetError)


def test_lean_description_without_meshes_or_truth_loads(tmp_path):
    """Camera, meshes, materials and truth are optional together: a measured data set in the
    rjfit layout has only lights, images and geometry."""
    folder = make_rjfit_folder(tmp_path, full=True)
    edit_description(folder, lambda meta: {key: value for key, value in meta.items()
                                           if key not in ("camera", "meshes", "materials", "truth_labels",
                                                          "reference_intensity")})
    dataset = load_dataset(folder)
    assert dataset.truth_labels is None and dataset.reference_intensity == 1.0
    # meshes without materials: the cross-check renders them with its one probe material
    folder = make_rjfit_folder(tmp_path / "no_materials", full=True)
    edit_description(folder, lambda meta: {**{key: value for key, value in meta.items()
                                              if key not in ("materials", "truth_labels")},
                                           "meshes": [{"file": "meshes/part_000.ply", "material": 0}]})
    assert load_dataset(folder).truth_params is None
    edit_description(folder, _put(1, "meshes", 0, "material"))
    with raises(DatasetError, folder / "dataset.json", "meshes[0].material is 1; without 'materials' every part "
                "must use material 0"):
        load_dataset(folder)


def test_missing_mesh_file_is_named(tmp_path):
    folder = make_rjfit_folder(tmp_path, full=True)
    (folder / "meshes/part_001.ply").unlink()
    with raises(DatasetFileNotFoundError, folder / "meshes/part_001.ply", "no such file",
                folder / "dataset.json", "names it as meshes[1].file"):
        load_dataset(folder)


def test_unreadable_json_names_the_file(tmp_path):
    from rjfit.io import read_json

    folder = make_rjfit_folder(tmp_path)
    (folder / "dataset.json").write_bytes(b"{\n \"x\xfb\xfe\": 1}")
    with raises(DatasetError, folder / "dataset.json", "not a readable JSON text file", "can't decode byte 0xfb"):
        load_dataset(folder)
    (tmp_path / "folder.json").mkdir()
    with raises(DatasetError, tmp_path / "folder.json", "not a readable JSON text file"):
        read_json(tmp_path / "folder.json")
    with pytest.raises(FileNotFoundError):
        read_json(tmp_path / "absent.json")


# -- the EXR files of the rjfit layout: channels, sizes, labels ----------------------------------------

def _rewrite_exr(path, edit):
    from rjfit.data.exr import read_exr

    write_exr(path, edit(read_exr(path)))


def _without(name):
    return lambda channels: {key: value for key, value in channels.items() if key != name}


def _shrunk(channels):
    return {key: value[:4, :5] for key, value in channels.items()}


@pytest.mark.parametrize("file, edit, message", [
    ("geometry.exr", _without("mask"), "needs channels P.X P.Y P.Z N.X N.Y N.Z V.X V.Y V.Z mask (the geometry); "
                                       "missing mask"),
    ("geometry.exr", _without("N.X"), "needs channels P.X P.Y P.Z N.X N.Y N.Z V.X V.Y V.Z mask (the geometry); "
                                      "missing N.X (the file has N.Y N.Z P.X"),
    ("visibility.exr", _without("light_001"), "needs channels light_000 light_001 (the shadow-ray visibility"),
    ("visibility.exr", _shrunk, "channel light_000 is 5 x 4 (width x height), but"),
    ("truth_labels.exr", lambda channels: {"labels": channels["label"]}, "needs channel label (the truth labels); "
                                                                         "missing label (the file has labels)"),
    ("truth_labels.exr", _shrunk, "channel label is 5 x 4 (width x height), but"),
    ("images/light_001.exr", _without("G"), "needs channels R G B (the image of light 1 (images[1])); missing G"),
    ("images/light_000.exr", _shrunk, "channel R is 5 x 4 (width x height), but"),
])
def test_exr_channels_and_sizes_are_checked(tmp_path, file, edit, message):
    folder = make_rjfit_folder(tmp_path, full=True)
    _rewrite_exr(folder / file, edit)
    with raises(DatasetError, f"{folder / file}: {message}"):
        load_dataset(folder)
    if "x 4" in message:   # the size message says what size the data set has, and where that is stated
        with raises(DatasetError, f"{folder / 'dataset.json'} says the images are {WIDTH} x {HEIGHT} (resolution)"):
            load_dataset(folder)


def test_truth_labels_must_be_finite_material_indices(tmp_path):
    folder = make_rjfit_folder(tmp_path, full=True)
    path = folder / "truth_labels.exr"
    _rewrite_exr(path, lambda c: {"label": np.where(c["label"] >= 0, np.nan, c["label"]).astype(np.float32)})
    with raises(DatasetError, path, f"{MASK_PIXELS} labels are NaN or Inf (first at row"):
        load_dataset(folder)
    _rewrite_exr(path, lambda c: {"label": np.where(np.isnan(c["label"]), 2.0, c["label"]).astype(np.float32)})
    with raises(DatasetError, path, f"{MASK_PIXELS} labels are outside [-1, 1] (first 2 at row",
                "an index into the 2 entries of 'materials'", folder / "dataset.json"):
        load_dataset(folder)


# -- --validation FILE that is not a validation result ----------------------------------------------

@pytest.mark.parametrize("content, problem", [
    ({"passed": False}, "no 'dataset_sha256' entry"),
    ({"regions": [], "warnings": [], "dataset_sha256": "ab"}, "no 'passed' entry"),   # a fit's summary.json
    ({"passed": "yes", "dataset_sha256": "ab"}, "'passed' is 'yes', not true or false"),
    ([1, 2], "a JSON list, not an object"),
])
def test_validation_file_that_is_not_a_validation_result(tmp_path, content, problem):
    from rjfit.pipeline.fit_dataset import fit_datasets

    folder = make_rjfit_folder(tmp_path / "data")
    path = tmp_path / "summary.json"
    path.write_text(json.dumps(content))
    with raises(DatasetError, path, "not a validation result written by `rjfit validate`", problem,
                "pass the validation.json that `rjfit validate DATASET --out DIR` wrote"):
        fit_datasets([folder], tmp_path / "fit", validation_path=path, allow_unvalidated=True)
    assert not (tmp_path / "fit").exists()


def test_validation_result_without_measures_is_described(tmp_path):
    """A failed result whose measures are null (NaN written by write_json_atomic) or absent."""
    from rjfit.data.dataset import read_validation_result
    from rjfit.pipeline.fit_dataset import validation_record

    path = tmp_path / "validation.json"
    path.write_text(json.dumps({"passed": False, "dataset_sha256": "ab", "median_rel_err": None}))
    result = read_validation_result(path)
    assert np.isnan(result["median_rel_err"]) and np.isnan(result["p99_rel_err"])
    record = validation_record({"passed": False, "median_rel_err": None}, path)
    assert record["note"] == "FAILED the cross-check (median rel. err. n/a, p99 n/a)"


# -- photometric-stereo masks with an alpha channel ------------------------------------------------------

def test_mask_alpha_channel_is_not_a_colour(tmp_path):
    import cv2
    from PIL import Image

    folder = make_ps_folder(tmp_path)
    mask, _ = sphere_geometry()
    colour = (mask * 255).astype(np.uint8)
    opaque = np.full_like(colour, 255)
    # RGBA (OpenCV writes BGRA) with an opaque alpha everywhere: the alpha must not select the whole frame
    assert cv2.imwrite(str(folder / "mask.png"), np.stack([colour, colour, colour, opaque], axis=-1))
    np.testing.assert_array_equal(load_dataset(folder).object_mask, mask)
    # grey + alpha (OpenCV reads it as 4 channels) whose alpha agrees with the grey
    Image.fromarray(np.stack([colour, colour], axis=-1), "LA").save(folder / "mask.png")
    np.testing.assert_array_equal(load_dataset(folder).object_mask, mask)
    # the object drawn in the alpha only (white everywhere): ambiguous, refused
    Image.fromarray(np.stack([opaque, colour], axis=-1), "LA").save(folder / "mask.png")
    with raises(DatasetError, folder / "mask.png", f"alpha channel marks {MASK_PIXELS} pixels but its colour channels "
                f"mark {HEIGHT * WIDTH}", "save the mask without an alpha channel"):
        load_dataset(folder)
