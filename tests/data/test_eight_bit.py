"""8-bit stacks, an unknown camera response, 8-bit codes in 16-bit files and a named mask (issue 27, item 4).

Each case writes a tiny photometric-stereo folder (``test_bad_input.make_ps_folder``: 8 x 10
pixels, four lights) and changes one thing. The response estimator is checked on paper_sphere
rendered by Mitsuba (32 x 32, orthographic, 12 directional lights), encoded with a known
power law and quantised to 8 bits. Cost: about 10 s in all, most of it the one render and
the gate on psm-horse.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from rjfit.data.codes import QUANTISATION_VARIANCE_CODES, channel_quantisation_variance, widening_factor
from rjfit.data.diligent import load_diligent
from rjfit.data.pixelfit import tile_lattice
from rjfit.data.response import estimate_power_response
from rjfit.errors import DatasetError, DatasetFileNotFoundError
from rjfit.render.datasets import load_dataset

from builders import HEIGHT, INTENSITIES, SHARED_DATA, WIDTH, make_ps_folder, raises, write_lines, write_png


def eight_bit_folder(folder, options=None, *, equal_intensities=False, seed=0):
    """make_ps_folder's folder with 8-bit codes as its images (one code 255 at light 3, pixel (0, 0))."""
    folder = make_ps_folder(folder)
    codes = np.random.default_rng(seed).integers(1, 250, (4, HEIGHT, WIDTH, 3)).astype(np.uint8)
    codes[2, 0, 0] = 255
    for index, image in enumerate(codes):
        write_png(folder / f"{index + 1:03d}.png", image)
    if equal_intensities:
        write_lines(folder / "light_intensities.txt", [INTENSITIES[0]] * len(INTENSITIES))
    if options is not None:
        (folder / "rjfit.json").write_text(json.dumps(options))
    return folder, codes


# -- "encoded": "linear" --------------------------------------------------------------------------

def test_linear_eight_bit_codes_with_quantisation_floor(tmp_path):
    folder, codes = eight_bit_folder(tmp_path, {"encoded": "linear"})
    dataset = load_dataset(folder)
    np.testing.assert_allclose(dataset.images, codes / INTENSITIES[:, None, None, :], rtol=1e-6)
    assert dataset.response == "linear" and dataset.meta["response"] == "linear"
    assert dataset.meta["bits"] == 8 and dataset.meta["pixel_type"] == "uint8"
    assert dataset.meta["saturation"]["raw_threshold"] == 255.0 and dataset.saturated[2, 0, 0]
    assert dataset.saturated.sum() == 1
    # one code step, uniform: variance 1/12 code^2, divided by the intensity squared per light and channel
    np.testing.assert_allclose(dataset.quantisation_variance, (1 / 12) / INTENSITIES ** 2)
    np.testing.assert_allclose(channel_quantisation_variance(dataset, "mean"),
                               ((1 / 12) / INTENSITIES ** 2).sum(axis=1) / 9)
    np.testing.assert_allclose(channel_quantisation_variance(dataset, "G"), (1 / 12) / INTENSITIES[:, 1] ** 2)
    assert dataset.meta["quantisation"]["variance_raw"] == QUANTISATION_VARIANCE_CODES == 1 / 12


def test_undeclared_eight_bit_names_the_ways_to_declare_it(tmp_path):
    folder, _ = eight_bit_folder(tmp_path)
    with raises(DatasetError, folder / "001.png", "8-bit image", "{\"encoded\": \"linear\"}",
                "{\"response\": \"unknown\"}"):
        load_dataset(folder)


def test_srgb_and_float_stacks_record_no_quantisation(tmp_path):
    folder, _ = eight_bit_folder(tmp_path, {"encoded": "sRGB"})
    dataset = load_dataset(folder)
    assert dataset.response == "sRGB" and dataset.quantisation_variance is None
    assert channel_quantisation_variance(dataset) is None
    sixteen = load_dataset(make_ps_folder(tmp_path / "sixteen"))   # linear 16-bit counts: a floor of 1/12 too
    assert sixteen.response == "linear" and sixteen.meta["bits"] == 16
    np.testing.assert_allclose(sixteen.quantisation_variance, (1 / 12) / INTENSITIES ** 2)
    floating = load_dataset(make_ps_folder(tmp_path / "float", images="exr"))
    assert floating.quantisation_variance is None and floating.meta["bits"] is None


# -- "response": "unknown" ------------------------------------------------------------------------

def test_unknown_response_reads_raw_codes(tmp_path):
    folder, codes = eight_bit_folder(tmp_path, {"response": "unknown"}, equal_intensities=True)
    dataset = load_dataset(folder)
    np.testing.assert_allclose(dataset.images, codes / INTENSITIES[0], rtol=1e-6)   # not decoded
    assert dataset.response == "unknown" and dataset.meta["response"] == "unknown"
    assert "response unknown" in dataset.meta["units"]
    np.testing.assert_allclose(dataset.quantisation_variance[1], (1 / 12) / INTENSITIES[0] ** 2)
    # a 16-bit stack of unknown response is read as raw codes too
    sixteen = make_ps_folder(tmp_path / "sixteen")
    write_lines(sixteen / "light_intensities.txt", [[1.0, 1.0, 1.0]] * len(INTENSITIES))
    (sixteen / "rjfit.json").write_text('{"response": "unknown"}')
    assert load_dataset(sixteen).response == "unknown"


def test_unknown_response_refuses_unequal_intensities(tmp_path):
    folder, _ = eight_bit_folder(tmp_path, {"response": "unknown"})
    with raises(DatasetError, folder / "light_intensities.txt", "line 2: intensity", "response is unknown"):
        load_dataset(folder)


def test_unknown_response_and_an_encoding_contradict(tmp_path):
    folder, _ = eight_bit_folder(tmp_path, {"response": "unknown", "encoded": "linear"}, equal_intensities=True)
    with raises(DatasetError, folder, "response='unknown' and encoded='linear' contradict each other"):
        load_dataset(folder)


# -- every new key is checked ---------------------------------------------------------------------

@pytest.mark.parametrize("options, message", [
    ({"encoded": "gamma"}, "encoded is 'gamma'; it must be null (linear 16-bit or float data), \"linear\""),
    ({"response": "known"}, "response is 'known'; it must be \"unknown\""),
    ({"response": "linear"}, "response is 'linear'; it must be \"unknown\""),
    ({"bits": 12}, "bits is 12; it must be 8"),
    ({"bits": True}, "bits is True; it must be 8"),
    ({"mask": ""}, "mask is ''; it must be the file name of the object mask in this folder"),
    ({"mask": "../other/mask.png"}, "mask is '../other/mask.png'; it must be the file name"),
    ({"mask": 3}, "mask is 3"),
    ({"colour": "yes"}, "keys among saturation, dark, encoded, response, bits, mask, normals, crop, camera; unknown: "
                        "colour"),
])
def test_bad_declarations_name_the_file_and_what_is_allowed(tmp_path, options, message):
    folder, _ = eight_bit_folder(tmp_path, options)
    with raises(DatasetError, folder / "rjfit.json", message):
        load_dataset(folder)


# -- 8-bit codes in 16-bit files ------------------------------------------------------------------

def test_widening_factor():
    rng = np.random.default_rng(0)
    codes = rng.integers(0, 256, (6, 7, 3)).astype(np.uint16)
    assert widening_factor(codes * 257) == 257
    assert widening_factor(codes << 8) == 256
    assert widening_factor(rng.integers(0, 65536, (6, 7, 3)).astype(np.uint16)) is None   # real 16-bit counts
    clipped = np.where(codes > 128, 65535, 0).astype(np.uint16)    # black and clipped only: no evidence
    assert widening_factor(clipped) is None
    assert widening_factor(codes.astype(np.uint8)) is None


@pytest.mark.parametrize("factor, how", [(257, "every value is a multiple of 257"),
                                         (256, "every value is a multiple of 256, the low byte is always 0")])
def test_widened_eight_bit_is_refused_unless_declared(tmp_path, factor, how):
    folder, codes = eight_bit_folder(tmp_path)
    for index, image in enumerate(codes):
        write_png(folder / f"{index + 1:03d}.png", image.astype(np.uint16) * factor)
    with raises(DatasetError, folder / "001.png", f"16-bit file holding 8-bit data ({how}", "\"bits\": 8"):
        load_dataset(folder)
    # declared: divided back to the 8-bit codes, saturating at 255
    (folder / "rjfit.json").write_text('{"encoded": "linear", "bits": 8}')
    dataset = load_dataset(folder)
    np.testing.assert_allclose(dataset.images, codes / INTENSITIES[:, None, None, :], rtol=1e-6)
    assert dataset.meta["bits"] == 8 and dataset.meta["pixel_type"] == "uint16"
    assert dataset.meta["saturation"]["raw_threshold"] == 255.0 and dataset.saturated.sum() == 1
    np.testing.assert_allclose(dataset.quantisation_variance, (1 / 12) / INTENSITIES ** 2)
    # 8-bit codes still need to say what they are
    (folder / "rjfit.json").write_text('{"bits": 8}')
    with raises(DatasetError, folder / "001.png", "8-bit codes (bits=8), but linear data must have 16 bits"):
        load_dataset(folder)
    # "bits": 16 declares the 16 bits real: read as they are
    (folder / "rjfit.json").write_text('{"bits": 16}')
    np.testing.assert_allclose(load_dataset(folder).images, codes * float(factor) / INTENSITIES[:, None, None, :], rtol=1e-6)


def test_declared_eight_bits_on_real_sixteen_bit_data_is_refused(tmp_path):
    folder = make_ps_folder(tmp_path)
    (folder / "rjfit.json").write_text('{"encoded": "linear", "bits": 8}')
    with raises(DatasetError, folder / "001.png", "bits=8 was declared, but this 16-bit file is not 8-bit codes"):
        load_dataset(folder)
    eight, _ = eight_bit_folder(tmp_path / "eight", {"encoded": "linear", "bits": 16})
    with raises(DatasetError, eight / "001.png", "8-bit image, but bits=16 was declared"):
        load_dataset(eight)


# -- a named mask ---------------------------------------------------------------------------------

def test_named_mask(tmp_path):
    folder, _ = eight_bit_folder(tmp_path, {"encoded": "linear", "mask": "object.png"})
    (folder / "mask.png").rename(folder / "object.png")
    dataset = load_dataset(folder)
    assert dataset.meta["mask"] == "object.png" and dataset.object_mask.sum() == dataset.meta["mask_pixels"] > 0
    (folder / "rjfit.json").write_text('{"encoded": "linear", "mask": "missing.png"}')
    with raises(DatasetFileNotFoundError, folder / "missing.png", "no such file (the object mask that "
                "mask='missing.png' names"):
        load_dataset(folder)
    # the argument wins over the folder's declaration
    assert load_diligent(folder, mask="object.png").meta["mask"] == "object.png"


# -- the response estimator -----------------------------------------------------------------------

KAPPAS_TRUE = (1.0, 1.2, 2.2)
# 12 directions towards the lights: two rings (20 and 40 degrees from the view axis), as a
# photometric-stereo rig lights an object from around the camera.
_POLAR = np.radians(np.where(np.arange(12) % 2 == 0, 20.0, 40.0))
_AZIMUTH = np.radians(np.arange(12) * 30.0)
LIGHT_DIRECTIONS = np.stack([np.sin(_POLAR) * np.cos(_AZIMUTH), np.sin(_POLAR) * np.sin(_AZIMUTH), np.cos(_POLAR)],
                            axis=-1)


@pytest.fixture(scope="module")
def rendered_linear(tmp_path_factory):
    """paper_sphere (four materials) rendered by Mitsuba at 32 x 32, orthographic, 12 directional
    lights, no noise: the linear radiance to encode."""
    from rjfit.render.render import load_scene_definition, render_dataset

    scene = load_scene_definition("paper_sphere")
    scene["lights"] = [{"kind": "directional", "direction": d.tolist(), "intensity": 1.0} for d in LIGHT_DIRECTIONS]
    scene["camera"] = {"kind": "orthographic", "origin": [0, 0, 8], "target": [0, 0, 0], "up": [0, 1, 0],
                       "half_width": 1.05}
    scene["noise_variance"] = 0.0
    scene["reference_intensity"] = 1.0
    return load_dataset(render_dataset(scene, tmp_path_factory.mktemp("linear") / "dataset", resolution=32, seed=3))


def encoded_folder(folder, linear, kappa, seed):
    """A photometric-stereo folder of ``linear`` encoded as 8-bit codes ``rint(255 (x / white)^(1/kappa))``,
    with Gaussian noise of 0.5 % of the white level added before encoding (achromatic), declared
    ``{"response": "unknown"}``."""
    folder.mkdir(parents=True)
    rng = np.random.default_rng(seed)
    white = 1.1 * np.quantile(linear.images[:, linear.object_mask], 0.995)
    noisy = linear.images / white + rng.normal(0.0, 0.005, linear.images.shape[:3] + (1,))
    codes = np.rint(255.0 * np.clip(noisy, 0.0, 1.0) ** (1.0 / kappa)).astype(np.uint8)
    names = [f"{i + 1:03d}.png" for i in range(linear.n_lights)]
    for name, image in zip(names, codes):
        write_png(folder / name, image)
    (folder / "filenames.txt").write_text("".join(name + "\n" for name in names))
    write_lines(folder / "light_directions.txt", [light.direction for light in linear.lights])
    write_lines(folder / "light_intensities.txt", [[1.0, 1.0, 1.0]] * linear.n_lights)
    write_png(folder / "mask.png", np.repeat((linear.object_mask * 255).astype(np.uint8)[..., None], 3, axis=-1))
    np.save(folder / "normals.npy", np.where(linear.object_mask[..., None], linear.normals, 0.0))
    (folder / "rjfit.json").write_text('{"response": "unknown"}')
    return folder


@pytest.mark.parametrize("kappa", KAPPAS_TRUE)
def test_power_response_recovered_from_rendered_stack(tmp_path, rendered_linear, kappa):
    """Tolerance 0.03 in kappa. Measured on this stack (718 pixels, 12 lights) over noise seeds 0
    to 7: the estimate is biased up by 0.000 to 0.015 (kappa 2.2), 0.005 to 0.012 (1.0 and 1.2),
    with bootstrap standard deviations of 0.002 to 0.005: about half of the bias is the per-pixel
    fit's exponent grid (noise-free codes give +0.005), the rest the noise. 0.03 is twice the
    largest error seen; at 0.03 the linearised value raw^kappa is right to 2 % (0.03 x ln 2) at
    half the white level. The bootstrap interval does not cover that bias (it is sampling spread only)."""
    dataset = load_dataset(encoded_folder(tmp_path / "stack", rendered_linear, kappa, seed=1))
    assert dataset.response == "unknown"
    result = estimate_power_response(dataset, seed=0, tile=4)
    assert abs(result["kappa"] - kappa) <= 0.03, result["kappa"]
    assert not result["at_grid_edge"] and result["bootstrap"]["tiles"] >= 40
    low, high = result["kappa_interval"]
    assert low < high and 0 < result["kappa_std"] < 0.02
    assert result["exponent"] == pytest.approx(1.0 / result["kappa"])


def test_power_response_error_model_in_codes(tmp_path, rendered_linear):
    """The alternative error model (Gaussian in the codes) on the same stack at kappa 1.2, same tolerance."""
    dataset = load_dataset(encoded_folder(tmp_path / "stack", rendered_linear, 1.2, seed=1))
    result = estimate_power_response(dataset, seed=0, errors="codes", n_bootstrap=0)
    assert abs(result["kappa"] - 1.2) <= 0.03 and result["kappa_interval"] is None
    with pytest.raises(ValueError, match="errors must be one of"):
        estimate_power_response(dataset, errors="log")


def test_power_response_bootstrap_is_seeded(tmp_path, rendered_linear):
    dataset = load_dataset(encoded_folder(tmp_path / "stack", rendered_linear, 1.2, seed=1))
    first, again = (estimate_power_response(dataset, seed=5, tile=4, n_bootstrap=50) for _ in range(2))
    other = estimate_power_response(dataset, seed=6, tile=4, n_bootstrap=50)
    assert first["kappa_interval"] == again["kappa_interval"] and first["kappa"] == other["kappa"]
    assert first["kappa_interval"] != other["kappa_interval"]


# -- the shared measured stacks -------------------------------------------------------------------

PSM = {"psm-rock": 71_356, "psm-horse": 29_488}   # mask pixels stated in their READMEs


@pytest.mark.parametrize("name", sorted(PSM))
def test_psm_folders_load_with_no_option(name):
    folder = SHARED_DATA / name
    if not (folder / "filenames.txt").is_file():
        pytest.skip(f"measured data not found at {folder} (it lives in ../shared beside the checkout)")
    dataset = load_dataset(folder)
    assert dataset.response == "unknown" and dataset.meta["bits"] == 8 and dataset.meta["pixel_type"] == "uint8"
    assert dataset.images.shape == (12, 340, 512, 3) and int(dataset.object_mask.sum()) == PSM[name]
    inside = dataset.images[:, dataset.object_mask]
    assert inside.max() < 255 and np.array_equal(inside, np.rint(inside))   # raw codes, none clipped (README)
    assert dataset.meta["saturation"]["saturated_observations_in_mask"] == 0
    np.testing.assert_allclose(dataset.quantisation_variance, 1 / 12)


def test_gate_reads_psm_horse(tmp_path):
    """`rjfit validate` reads the folder with no option (the gate checks the geometry; about 6 s)."""
    from rjfit.render.gate import validate_dataset

    folder = SHARED_DATA / "psm-horse"
    if not (folder / "filenames.txt").is_file():
        pytest.skip(f"measured data not found at {folder} (it lives in ../shared beside the checkout)")
    result = validate_dataset(folder, tmp_path / "validation")
    assert result["passed"], result


def test_the_response_from_a_lattice_of_tiles_reads_whole_tiles_and_recovers_kappa(tmp_path, rendered_linear):
    """A quarter of the stack (every second 4-px tile each way) estimates kappa 1.2 within the full stack's
    tolerance of 0.03 (its bias, up to 0.015, is the fit's and stays; the lattice's sampling spread, about twice
    the full stack's 0.002 to 0.005, stays under the rest) and records which observations it read."""
    dataset = load_dataset(encoded_folder(tmp_path / "stack", rendered_linear, 1.2, seed=1))
    observations = dataset.observations("mean")
    observations = observations.subset(np.asarray(observations.y) > 0)
    kept, record = tile_lattice(observations, 4, observations.n_obs // 3)
    assert record["lattice"] == 2 and record["observations_used"] == kept.n_obs < observations.n_obs
    rows, cols = np.divmod(np.asarray(kept.pixel), dataset.object_mask.shape[1])
    assert np.all((rows // 4) % 2 == 0) and np.all((cols // 4) % 2 == 0)
    # every light of a kept pixel is kept: the lights stay balanced
    full_count = np.bincount(observations.pixel, minlength=dataset.object_mask.size)
    kept_count = np.bincount(kept.pixel, minlength=dataset.object_mask.size)
    assert np.array_equal(kept_count[kept_count > 0], full_count[kept_count > 0])
    assert tile_lattice(observations, 4, None)[1]["lattice"] == 1
    result = estimate_power_response(dataset, seed=0, tile=4, max_observations=observations.n_obs // 3)
    assert abs(result["kappa"] - 1.2) <= 0.03, result["kappa"]
    assert result["subset"]["lattice"] == 2 and result["bootstrap"]["tiles"] >= 10
