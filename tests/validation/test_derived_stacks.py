"""validation/derived_stacks.py: a derived folder loads as the same object, turned or at half the resolution."""
from __future__ import annotations

import numpy as np
import pytest

from builders import make_ps_folder, validation_script
from rjfit.data.diligent import load_diligent


def _lambert(dataset):
    """n . l per light and pixel (L, H, W): what the geometry predicts, whatever the frame."""
    directions = np.array([light.direction for light in dataset.lights])
    return np.einsum("hwc,lc->lhw", dataset.normals, directions)


def test_a_turned_folder_is_the_same_object_upside_down(tmp_path):
    source = make_ps_folder(tmp_path / "ps")
    pixels = validation_script("derived_stacks").write_derived(source, tmp_path / "turned", "turn")
    original, turned = load_diligent(source), load_diligent(tmp_path / "turned")
    assert pixels == int(original.object_mask.sum())
    np.testing.assert_array_equal(turned.object_mask, original.object_mask[::-1, ::-1])
    np.testing.assert_array_equal(turned.images, original.images[:, ::-1, ::-1])
    # the geometry turns with the frame: each pixel's shading term is the one it had (float32 normals, 6-digit
    # light directions: 1e-5)
    np.testing.assert_allclose(_lambert(turned), _lambert(original)[:, ::-1, ::-1], atol=1e-5)
    np.testing.assert_allclose(turned.normals[..., 2], original.normals[::-1, ::-1, 2], atol=1e-6)


@pytest.mark.parametrize("offset", [0, 1])
def test_a_subsampled_folder_keeps_every_second_recorded_pixel(tmp_path, offset):
    source = make_ps_folder(tmp_path / "ps")
    validation_script("derived_stacks").write_derived(source, tmp_path / "half", "sub", offset)
    original, half = load_diligent(source), load_diligent(tmp_path / "half")
    np.testing.assert_array_equal(half.images, original.images[:, offset::2, offset::2])
    np.testing.assert_array_equal(half.object_mask, original.object_mask[offset::2, offset::2])
    np.testing.assert_allclose(half.normals, original.normals[offset::2, offset::2], atol=1e-6)
    assert [tuple(light.direction) for light in half.lights] == [tuple(light.direction) for light in original.lights]


def test_an_unknown_derivation_is_refused():
    with pytest.raises(ValueError, match="'sub' or 'turn'"):
        validation_script("derived_stacks").derive(np.zeros((4, 4)), "mirror")
