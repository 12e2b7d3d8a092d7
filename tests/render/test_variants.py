"""Mitsuba variants through ``rjfit render`` / ``rjfit validate`` (real Mitsuba, 16 px images).

- the scalar variant renders and passes the gate, and gives the LLVM variant's data set (the
  same pixel-centre rays: geometry, visibility and images agree to float rounding);
- spectral and polarized variants are refused up front with one line that names the
  supported variants (they used to run and report a gate failure, median error 0.42, that
  was the set-up's, not the forward model's), and nothing is written.
"""
from __future__ import annotations

import json

import mitsuba as mi
import numpy as np
import pytest
from click.testing import CliRunner

from rjfit.cli import main
from rjfit.data.exr import read_exr
from rjfit.render.datasets import load_dataset
from rjfit.render.mitsuba_scene import UnsupportedVariantError, activate, supported_variant
from rjfit.render.render import render_dataset

REFUSED = ["llvm_ad_spectral", "scalar_spectral", "llvm_ad_mono_polarized", "llvm_ad_spectral_polarized"]


@pytest.fixture(autouse=True)
def restore_variant():
    previous = mi.variant()
    yield
    if previous is not None:
        mi.set_variant(previous)


@pytest.fixture(scope="module")
def llvm_sphere(tmp_path_factory):
    return render_dataset("paper_sphere", tmp_path_factory.mktemp("llvm") / "dataset", resolution=16,
                          variant="llvm_ad_rgb")


def _invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def _assert_same_dataset(a_path, b_path, image_tolerance):
    a, b = load_dataset(a_path), load_dataset(b_path)
    assert np.array_equal(a.object_mask, b.object_mask)
    np.testing.assert_allclose(a.normals, b.normals, atol=1e-5)
    np.testing.assert_allclose(a.positions, b.positions, atol=1e-5)
    vis_a, vis_b = read_exr(a_path / "visibility.exr"), read_exr(b_path / "visibility.exr")
    assert vis_a.keys() == vis_b.keys() and all(np.array_equal(vis_a[k], vis_b[k]) for k in vis_a)
    scale = np.abs(b.images).max()
    np.testing.assert_allclose(a.images, b.images, atol=image_tolerance * scale)


def test_scalar_rgb_renders_and_passes_the_gate_like_llvm(tmp_path, llvm_sphere):
    out = tmp_path / "scalar"
    rendered = _invoke("render", "paper_sphere", "--variant", "scalar_rgb", "--resolution", 16, "--out", out)
    assert rendered.exit_code == 0, rendered.output
    assert json.loads((out / "dataset.json").read_text())["variant"] == "scalar_rgb"
    validated = _invoke("validate", out, "--variant", "scalar_rgb")
    assert validated.exit_code == 0, validated.output
    assert "(scalar_rgb): PASSED" in validated.output
    result = json.loads((out / "validation" / "validation.json").read_text())
    assert result["settings"]["variant"] == "scalar_rgb" and result["median_rel_err"] < 1e-6
    # Same rays, same seeds for the noise: the data sets agree to float32 rounding.
    _assert_same_dataset(out, llvm_sphere, 1e-5)
    # The scalar gate on the LLVM-rendered data set passes too.
    cross = _invoke("validate", llvm_sphere, "--variant", "scalar_rgb", "--out", tmp_path / "cross")
    assert cross.exit_code == 0 and "PASSED" in cross.output, cross.output


def test_scalar_rgb_path_traces_interreflection_and_shadows(tmp_path):
    """The concave dented plaster (cast shadows, indirect light, 4 spp): visibility and the
    direct light agree with LLVM exactly; the indirect light is Monte Carlo (other random
    streams), so the images agree to its noise, and the gate fails the same way."""
    scalar = render_dataset("dented_plaster", tmp_path / "scalar", resolution=16, spp=4, noise_variance=0.0,
                            variant="scalar_rgb")
    llvm = render_dataset("dented_plaster", tmp_path / "llvm", resolution=16, spp=4, noise_variance=0.0,
                          variant="llvm_ad_rgb")
    a, b = load_dataset(scalar), load_dataset(llvm)
    assert np.array_equal(a.object_mask, b.object_mask)
    vis_a, vis_b = read_exr(scalar / "visibility.exr"), read_exr(llvm / "visibility.exr")
    assert any(not v[a.object_mask].all() for v in vis_a.values()), "the scene should cast shadows"
    assert all(np.array_equal(vis_a[k], vis_b[k]) for k in vis_a)
    mean_a, mean_b = a.images[:, a.object_mask].mean(), b.images[:, b.object_mask].mean()
    # the difference of the two means has a Monte Carlo standard error of 0.6 % of the mean
    # (from the spread of the per-observation differences; measured difference 0.96 %):
    # 0.02 is about 3 se
    assert abs(mean_a / mean_b - 1) < 0.02, (mean_a, mean_b)
    gate = _invoke("validate", scalar, "--variant", "scalar_rgb", "--spp", 2)
    assert gate.exit_code == 1 and "FAILED" in gate.output      # interreflection: as in LLVM


@pytest.mark.parametrize("variant", REFUSED)
def test_spectral_and_polarized_variants_are_refused_up_front(tmp_path, llvm_sphere, variant):
    if variant not in mi.variants():
        pytest.skip(f"{variant} is not in this Mitsuba build")
    validated = _invoke("validate", llvm_sphere, "--variant", variant, "--out", tmp_path / "validation")
    assert validated.exit_code == 1
    lines = validated.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"Error: Mitsuba variant '{variant}' is not supported"), lines
    assert "Traceback" not in validated.output
    for usable in ("scalar_rgb", "llvm_ad_rgb", "llvm_ad_mono"):
        assert usable in lines[0]
    assert not (tmp_path / "validation" / "validation.json").exists()
    rendered = _invoke("render", "paper_sphere", "--variant", variant, "--resolution", 16, "--out", tmp_path / "data")
    assert rendered.exit_code == 1 and "is not supported" in rendered.output, rendered.output
    assert not (tmp_path / "data").exists()
    with pytest.raises(UnsupportedVariantError):
        activate(variant)


def test_supported_variants_are_the_rgb_and_mono_ones(llvm_sphere, tmp_path):
    assert [v for v in mi.variants() if supported_variant(v)] == [
        v for v in ("scalar_rgb", "llvm_ad_rgb", "llvm_ad_mono", "cuda_ad_rgb", "cuda_ad_mono") if v in mi.variants()]
    unknown = _invoke("validate", llvm_sphere, "--variant", "llvm_ad_rgbx", "--out", tmp_path / "v")
    assert unknown.exit_code == 1 and "is not available" in unknown.output
