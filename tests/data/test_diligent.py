"""The measured DiLiGenT "ball" (../shared/data/diligent-ball), read by the photometric-stereo loader."""
from __future__ import annotations

import numpy as np
import pytest

from rjfit.data.dataset import Dataset
from rjfit.data.diligent import crop_to_mask, is_diligent_folder, load_diligent
from rjfit.render.datasets import load_dataset

from builders import SHARED_DATA

BALL = SHARED_DATA / "diligent-ball"
MASK_PIXELS = 15_791  # stated in the data's README

pytestmark = pytest.mark.skipif(not (BALL / "filenames.txt").is_file(),
                                reason=f"measured data set not present at {BALL.resolve()}")


@pytest.fixture(scope="module")
def ball() -> Dataset:
    return load_dataset(BALL)  # detected as a DiLiGenT folder: there is no dataset.json


@pytest.fixture(scope="module")
def ball_cropped(ball) -> Dataset:
    return crop_to_mask(ball)


@pytest.fixture(scope="module")
def intensities() -> np.ndarray:
    return np.loadtxt(BALL / "light_intensities.txt")


def test_layout_is_detected():
    assert is_diligent_folder(BALL)
    assert not (BALL / "dataset.json").exists()
    assert not is_diligent_folder(BALL / "001.png")


def test_shapes_meta_and_mask(ball):
    assert ball.images.shape == (96, 512, 612, 3)
    assert ball.n_lights == 96 and ball.image_shape == (512, 612)
    assert int(ball.object_mask.sum()) == MASK_PIXELS
    assert ball.meta["kind"] == "measured" and ball.meta["layout"] == "diligent"
    assert ball.meta["camera"]["kind"] == "orthographic"
    assert ball.meta["units"] == "raw sensor counts / light intensity (per channel)"
    assert ball.meta["pixel_type"] == "uint16"
    assert ball.meta["mask_pixels"] == MASK_PIXELS
    assert ball.positions is None and ball.visibility is None
    assert all(light.kind == "directional" and light.intensity == 1.0 for light in ball.lights)


def test_sixteen_bits_preserved(ball, intensities):
    import cv2

    scaled = ball.images[:, ball.object_mask] * intensities[:, None, :]  # back to raw counts
    inside = np.rint(scaled)
    np.testing.assert_allclose(scaled, inside, atol=0.02)
    assert (inside % 256 != 0).mean() > 0.9  # the low byte is there: not 8-bit data
    direct = cv2.imread(str(BALL / "001.png"), cv2.IMREAD_UNCHANGED)[..., ::-1]  # BGR -> RGB
    assert direct.dtype == np.uint16
    np.testing.assert_array_equal(np.rint(ball.images[0] * intensities[0]).astype(np.uint16), direct)


def test_saturated_observations_excluded(ball, ball_cropped, intensities):
    import cv2

    saturated_in_mask = ball.saturated[:, ball.object_mask]
    assert saturated_in_mask.sum() == ball.meta["saturation"]["saturated_observations_in_mask"] > 0
    # Flags agree with the raw files (65535 in any channel) for an image that has them.
    light = int(np.argmax(saturated_in_mask.sum(axis=1)))
    raw = cv2.imread(str(BALL / ball.meta["images"][light]), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(ball.saturated[light], (raw == 65535).any(axis=-1))
    valid = ball_cropped.valid_mask()
    assert ball_cropped.saturated[:, ball_cropped.object_mask].sum() == saturated_in_mask.sum()
    assert not (valid & ball_cropped.saturated).any()
    raw_y = ball_cropped.images * intensities[:, None, None, :]
    assert raw_y[valid].max() < 65535


def test_normals_unit_and_conventions(ball):
    mask = ball.object_mask
    np.testing.assert_allclose(np.linalg.norm(ball.normals[mask], axis=-1), 1.0, atol=1e-9)
    assert (ball.normals[~mask] == 0).all()
    assert (ball.view_dirs[mask] == [0.0, 0.0, 1.0]).all()
    rows, cols = np.nonzero(mask)
    assert ball.normals[rows.min(), cols[rows == rows.min()][0], 1] > 0.9  # y up: the top row faces up
    assert ball.normals[rows[cols == cols.max()][0], cols.max(), 0] > 0.9  # x right
    # Brightness follows <l.n> for a head-on light: light directions and normals share axes.
    # Measured correlations: 0.948 (light 0) and 0.847 (light 40); with y flipped 0.042 and 0.475,
    # with x flipped 0.924 and -0.18, so 0.75 fails either wrong convention on one of the two lights.
    n = ball.normals[mask]
    for index in (0, 40):
        y = ball.images[index].mean(axis=-1)[mask]
        cos_ln = np.clip(n @ np.asarray(ball.lights[index].direction), 0.0, None)
        assert np.corrcoef(y, cos_ln)[0, 1] > 0.75


def test_observations(ball, ball_cropped):
    observations = ball_cropped.observations()
    assert observations.n_lights == 96
    assert observations.n_obs > 0.9 * 96 * MASK_PIXELS
    assert np.isfinite(observations.y).all() and (observations.cos_ln > 0).all()
    assert observations.object_mask[observations.row, observations.col].all()
    counts = observations.valid_count
    assert counts[ball_cropped.object_mask].min() > 0 and counts[~ball_cropped.object_mask].max() == 0
    # Cropping moved pixels, not values.
    r0, c0 = ball_cropped.meta["crop"]["row0"], ball_cropped.meta["crop"]["col0"]
    np.testing.assert_array_equal(ball_cropped.images[:, 10, 20], ball.images[:, r0 + 10, c0 + 20])


def test_load_options_pass_through():
    cropped = load_dataset(BALL, crop=True)
    assert cropped.image_shape == (146, 146) and int(cropped.object_mask.sum()) == MASK_PIXELS
    strict = load_diligent(BALL, saturation=60000, crop=True)
    assert strict.meta["saturation"]["saturated_observations_in_mask"] > cropped.meta["saturation"][
        "saturated_observations_in_mask"]
