"""Rendering data sets with the real Mitsuba (LLVM variant, small images)."""
import json

import numpy as np
import pytest
from scipy import stats

from rjfit.data.exr import read_exr
from rjfit.model.blinn import radiance
from rjfit.render.datasets import load_dataset
from rjfit.render.render import render_dataset


def _truth_mu(dataset):
    observations = dataset.observations()
    labels = dataset.truth_labels.ravel()[observations.pixel]
    params = np.array([[p["I0"], p["kd"], p["gamma"]] for p in dataset.truth_params])
    mu = radiance(params[labels, 0], params[labels, 1], params[labels, 2], observations.cos_ln, observations.cos_hn,
                  observations.irradiance)
    return observations, mu


def test_dataset_layout_and_description(paper_sphere_small):
    meta = json.loads((paper_sphere_small / "dataset.json").read_text())
    assert meta["format"] == "rjfit-dataset/1" and meta["kind"] == "synthetic"
    assert len(meta["images"]) == len(meta["lights"]) == 10
    assert {"mitsuba", "drjit", "rjfit"} <= set(meta["versions"])
    assert meta["versions"]["mitsuba"].startswith("3.")
    image = read_exr(paper_sphere_small / meta["images"][0])
    assert set(image) == {"R", "G", "B"} and image["R"].dtype == np.float32 and image["R"].shape == (48, 48)
    geometry = read_exr(paper_sphere_small / "geometry.exr")
    normals = np.stack([geometry[f"N.{a}"] for a in "XYZ"], -1)[geometry["mask"] > 0.5]
    np.testing.assert_allclose(np.linalg.norm(normals, axis=-1), 1.0, atol=1e-5)


def test_truth_labels_are_the_papers_quadrants(paper_sphere_small):
    dataset = load_dataset(paper_sphere_small)
    labels = dataset.truth_labels
    h, w = labels.shape
    # Table 2 order: upper left, lower left, upper right, lower right.
    assert [labels[h // 4, w // 4], labels[3 * h // 4, w // 4], labels[h // 4, 3 * w // 4],
            labels[3 * h // 4, 3 * w // 4]] == [0, 1, 2, 3]
    assert labels[0, 0] == -1 and (labels >= 0).sum() == dataset.object_mask.sum()
    assert [p["kd"] for p in dataset.truth_params] == [0.5, 0.9, 0.6, 0.4]


def test_rendered_noise_is_gaussian_with_the_stated_variance(paper_sphere_small):
    """Residuals of the data around the true closed form are N(0, 0.1): the rendered mean is
    eq. 2 (checked to ~1e-7 by the cross-check) and the noise is the scene's."""
    observations, mu = _truth_mu(load_dataset(paper_sphere_small))
    residuals = observations.y - mu
    n = residuals.size
    # Variance: (n-1) s^2 / sigma^2 ~ chi2(n-1); two-sided test at the 0.1 % level.
    statistic = (n - 1) * residuals.var(ddof=1) / 0.1
    assert stats.chi2.ppf(0.0005, n - 1) < statistic < stats.chi2.ppf(0.9995, n - 1)
    # Mean: z-test at the 0.1 % level; shape: KS against N(0, 0.1) at the 0.1 % level.
    assert abs(residuals.mean()) < stats.norm.ppf(0.9995) * np.sqrt(0.1 / n)
    assert stats.kstest(residuals / np.sqrt(0.1), "norm").pvalue > 1e-3


def test_rendering_is_seeded_and_bitwise_reproducible(tmp_path, paper_sphere_small):
    again = render_dataset("paper_sphere", tmp_path / "again", resolution=48)
    other_seed = render_dataset("paper_sphere", tmp_path / "other", resolution=48, seed=99)
    first, second, third = (read_exr(p / "images" / "light_003.exr")["G"]
                            for p in (paper_sphere_small, again, other_seed))
    assert np.array_equal(first, second)
    assert not np.array_equal(first, third)


def test_noise_free_render_matches_closed_form(tmp_path):
    path = render_dataset("paper_sphere", tmp_path / "clean", resolution=32, noise_variance=0.0)
    dataset = load_dataset(path)
    observations, mu = _truth_mu(dataset)
    relative = np.abs(observations.y - mu) / mu
    # per true region, at the gate's own thresholds (median 1e-4, p99 1e-3): a quadrant
    # rendered with another material cannot hide behind a good median over all four
    region = dataset.truth_labels.ravel()[observations.pixel]
    for r in range(4):
        assert np.median(relative[region == r]) < 1e-5 and np.quantile(relative[region == r], 0.99) < 1e-3, r


def test_concave_object_has_cast_shadows_and_two_materials(dented_plaster_small):
    dataset = load_dataset(dented_plaster_small)
    assert set(np.unique(dataset.truth_labels)) == {0, 1}
    shadowed = ~dataset.visibility & dataset.object_mask[None]
    assert shadowed.any(), "the dents and the groove must shadow some pixels from some lights"
    valid = dataset.valid_mask()
    assert not (valid & ~dataset.visibility).any()


def test_unknown_scene_is_a_clear_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="no built-in scene"):
        render_dataset("no_such_scene", tmp_path / "x")


def test_render_never_replaces_a_folder_that_is_not_a_data_set(tmp_path, monkeypatch):
    """``--out`` pointed at the wrong folder (a fit, the working folder) must not delete it."""
    from rjfit.errors import DatasetError

    precious = tmp_path / "work" / "notes.txt"
    precious.parent.mkdir()
    precious.write_text("keep me")
    with pytest.raises(DatasetError, match="not a data set .no dataset.json.*not replaced"):
        render_dataset("paper_sphere", precious.parent, resolution=8)
    monkeypatch.chdir(precious.parent)
    for out in (".", ".."):
        with pytest.raises(DatasetError, match="working folder"):
            render_dataset("paper_sphere", out, resolution=8)
    assert precious.read_text() == "keep me" and sorted(p.name for p in precious.parent.iterdir()) == ["notes.txt"]
    with pytest.raises(ValueError, match="spp .* >= 1"):
        render_dataset("paper_sphere", tmp_path / "d", resolution=8, spp=0)
    with pytest.raises(ValueError, match="resolution must be >= 1"):
        render_dataset("paper_sphere", tmp_path / "d", resolution=0)


def test_auto_variant_falls_back_to_llvm_without_a_gpu_and_records_what_ran(paper_sphere_small):
    """CI has no GPU: "auto" must pick llvm_ad_rgb there (cuda_ad_rgb where a GPU answers)
    and the data set must say which variant rendered it."""
    import subprocess
    import sys

    from rjfit.render.mitsuba_scene import resolve_variant

    probe = subprocess.run([sys.executable, "-c", "import drjit as dr; print(bool(dr.has_backend(dr.JitBackend.CUDA)))"],
                           capture_output=True, text=True)
    expected = "cuda_ad_rgb" if probe.stdout.strip() == "True" else "llvm_ad_rgb"
    assert resolve_variant("auto") == expected
    assert resolve_variant("llvm_ad_mono") == "llvm_ad_mono"
    assert json.loads((paper_sphere_small / "dataset.json").read_text())["variant"] == expected


def test_calibrated_pinhole_camera_focal_length_and_principal_point(tmp_path):
    """A perspective camera may be given as a calibrated pinhole: focal length and principal
    point in pixels (off-centre here, on a frame that is not square, so a swapped or mirrored
    axis shows). The traced view directions are minus the rays through the pixel centres that
    those intrinsics define, to float32 rounding, and the rendered data set passes the gate."""
    from rjfit.render.gate import validate_dataset
    from rjfit.render.render import load_scene_definition

    definition = load_scene_definition("paper_sphere")
    height, width, focal, cx, cy = 32, 40, 142.0, 17.0, 13.5
    camera = {key: value for key, value in definition["camera"].items() if key != "fov"}
    definition = {**definition, "resolution": [height, width],
                  "camera": {**camera, "focal_px": focal, "principal_point": [cx, cy]}}
    folder = render_dataset(definition, tmp_path / "pinhole")
    dataset = load_dataset(folder)
    rows, cols = np.mgrid[0:height, 0:width]
    # the camera sits on +z looking at the origin with y up: x right, y up in the image
    towards = np.stack([-(cols + 0.5 - cx) / focal, (rows + 0.5 - cy) / focal, np.ones((height, width))], axis=-1)
    towards /= np.linalg.norm(towards, axis=-1, keepdims=True)
    np.testing.assert_allclose(dataset.view_dirs, towards, atol=2e-6)
    assert dataset.object_mask.sum() > 100
    assert validate_dataset(folder, tmp_path / "v", spp=1)["passed"]
