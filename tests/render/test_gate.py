"""The cross-check gate: passes the right forward model, catches wrong ones."""
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from rjfit.data.lights import geometry_terms
from rjfit.model.blinn import log_cos_power
from rjfit.render.gate import (ValidationRequiredError, closed_form_radiance, outlier_note, require_validated,
                              validate_dataset)


def test_paper_sphere_passes_with_the_issue_tolerances(paper_sphere_small, tmp_path):
    result = validate_dataset(paper_sphere_small, tmp_path / "v", spp=1)
    assert result["passed"]
    assert result["median_rel_err"] <= 1e-4 and result["p99_rel_err"] <= 1e-3
    assert abs(result["unexplained_fraction"]) < 1e-5
    assert result["pixels_compared"] > 1000
    for name in ("validation.json", "validation_maps.exr", "relative_error.png", "unexplained_fraction.png"):
        assert (tmp_path / "v" / name).is_file()
    assert json.loads((tmp_path / "v" / "validation.json").read_text())["passed"] is True


def _without_normalisation(positions, normals, view_dirs, light, material, reference):
    cos_ln, cos_hn, irradiance = geometry_terms(positions, normals, view_dirs, light, reference)
    lobe = material["kd"] / np.pi + (1 - material["kd"]) * log_cos_power(cos_hn, material["gamma"])
    return material["I0"] * irradiance * lobe * np.maximum(cos_ln, 0)


def _half_vector_from_wrong_directions(positions, normals, view_dirs, light, material, reference):
    # A classic slip: h from the light direction and the *normal* instead of the view.
    return closed_form_radiance(positions, normals, normals, light, material, reference)


@pytest.mark.parametrize("wrong_model", [_without_normalisation, _half_vector_from_wrong_directions])
def test_gate_catches_wrong_closed_forms(paper_sphere_small, tmp_path, wrong_model):
    result = validate_dataset(paper_sphere_small, tmp_path / "v", forward_model=wrong_model, spp=1)
    assert not result["passed"]
    assert result["median_rel_err"] > 1e-2


def test_gate_catches_a_wrongly_scaled_emitter(paper_sphere_small, tmp_path):
    # Light values given as an equal-energy spectrum become (1.205, 0.948, 0.909) x I in RGB.
    result = validate_dataset(paper_sphere_small, tmp_path / "v", light_format="spectrum", spp=1)
    assert not result["passed"]
    assert result["unexplained_fraction"] == pytest.approx(np.mean([1.205, 0.948, 0.909]) - 1, abs=0.005)
    # Red is ~20 % off: the per-channel comparison sees it in every observation.
    assert result["median_rel_err"] == pytest.approx(0.205, abs=0.02)


def test_concave_object_reports_interreflection_instead_of_passing(dented_plaster_small, tmp_path):
    result = validate_dataset(dented_plaster_small, tmp_path / "v", spp=16)
    assert not result["passed"]
    # Light bouncing inside dents and the groove adds radiance the direct closed form lacks.
    assert 0.02 < result["unexplained_fraction"] < 0.5
    from rjfit.data.exr import read_exr

    maps = read_exr(tmp_path / "v" / "validation_maps.exr")
    unexplained = maps["unexplained_fraction"]
    assert unexplained.max() > 0.2 and np.median(unexplained) < 0.05
    # the count over the p99 tolerance, against the per-light maps written beside it (0 where not compared); the
    # maps are float32, so an error within its rounding of 1e-3 may fall either side
    per_light = np.stack([maps[name] for name in maps if name.startswith("rel_err_")])
    over = result["observations_over_p99_tolerance"]
    assert int((per_light > 1e-3 * (1 + 1e-6)).sum()) <= over <= int((per_light > 1e-3 * (1 - 1e-6)).sum())
    assert over > 0.01 * result["observations_compared"]        # the p99 failed, so more than 1 % are over
    assert outlier_note(result).startswith(f"{over} of {result['observations_compared']} observations (")


def test_no_outlier_note_without_observations_over_the_tolerance():
    result = {"observations_over_p99_tolerance": 0, "observations_compared": 10, "max_rel_err": 1e-4}
    assert outlier_note(result) is None
    assert outlier_note({"max_rel_err": 1.0}) is None         # a validation.json written before the count


def test_direct_only_path_tracing_explains_the_concave_object(dented_plaster_small, tmp_path):
    """Negative control for the interreflection finding: with max_depth 2 (direct light
    only) the same concave scene passes, so the gap above is interreflection."""
    result = validate_dataset(dented_plaster_small, tmp_path / "v", spp=1, max_depth=2)
    assert result["passed"], result


def test_fitter_gate_refuses_unvalidated_failed_and_changed_data(paper_sphere_small, tmp_path):
    dataset = tmp_path / "copy"
    shutil.copytree(paper_sphere_small, dataset)
    with pytest.raises(ValidationRequiredError, match="rjfit validate"):
        require_validated(dataset)
    assert require_validated(dataset, allow_unvalidated=True) is None
    validate_dataset(dataset, spp=1, light_format="spectrum")
    with pytest.raises(ValidationRequiredError, match="failed the cross-check"):
        require_validated(dataset)
    validate_dataset(dataset, spp=1)
    assert require_validated(dataset)["passed"]
    # every file a fit reads is covered: the description, the geometry, a mesh
    original = {name: (dataset / name).read_bytes() for name in ("dataset.json", "geometry.exr", "meshes/part_001.ply")}
    meta = json.loads(original["dataset.json"])
    meta["lights"][0]["intensity"] *= 1.2
    changes = {"dataset.json": json.dumps(meta).encode(), "geometry.exr": original["geometry.exr"][:-8] + bytes(8),
               "meshes/part_001.ply": original["meshes/part_001.ply"] + b"\n"}
    for name, changed in changes.items():
        (dataset / name).write_bytes(changed)
        with pytest.raises(ValidationRequiredError, match="changed since"):
            require_validated(dataset)
        (dataset / name).write_bytes(original[name])
        assert require_validated(dataset)["passed"], name


def test_normal_map_data_is_checked_with_one_facet_per_pixel(tmp_path):
    """A measured photometric-stereo folder has no mesh: the gate path-traces one facet per
    pixel with the pixel's normal under the folder's directional lights (orthographic
    camera, v = (0, 0, 1)). The right conventions pass; a closed form that takes the light
    direction as the direction of travel (a sign slip) fails."""
    from builders import make_ps_folder

    folder = make_ps_folder(tmp_path / "ps")
    result = validate_dataset(folder, tmp_path / "v", spp=1)
    assert result["passed"], result
    assert result["geometry"] == "one facet per pixel from the normal map"
    assert result["max_normal_angle_deg"] < 0.05

    def travel_direction(positions, normals, view_dirs, light, material, reference):
        from rjfit.data.lights import Light

        flipped = Light(kind="directional", intensity=light.intensity, direction=tuple(-np.asarray(light.direction)))
        return closed_form_radiance(positions, normals, view_dirs, flipped, material, reference)

    assert not validate_dataset(folder, tmp_path / "w", spp=1, forward_model=travel_direction)["passed"]
    # The gate's record lives outside a read-only data folder and the fitter finds it there.
    assert require_validated(folder, tmp_path / "v" / "validation.json")["passed"]
    # ... and so does the fit's report, figures included
    from rjfit.pipeline.fit_dataset import fit_dataset
    from rjfit.pipeline.report import build_report

    fit_dataset(folder, tmp_path / "fit", validation_path=tmp_path / "v" / "validation.json", n_chains=1,
                iterations=20, processes=1, figures=False, progress=False)
    report = build_report(tmp_path / "fit").read_text()
    assert "No validation found" not in report and 'class="pass">passed' in report
    assert 'alt="relative error"' in report


def test_measured_stack_with_mesh_camera_and_point_lights(paper_sphere_small, tmp_path):
    """A measured stack given as images + a mesh (PLY) + a calibrated camera + point lights:
    the geometry is traced from the mesh with Mitsuba, the gate path-traces the mesh, and
    the observations agree with the rendered data set the images came from."""
    import trimesh

    from rjfit.render.datasets import load_dataset

    source = json.loads((paper_sphere_small / "dataset.json").read_text())
    folder = tmp_path / "stack"
    folder.mkdir()
    parts = [trimesh.load(paper_sphere_small / entry["file"], process=False) for entry in source["meshes"]]
    trimesh.util.concatenate(parts).export(folder / "object.ply", vertex_normal=True)
    for name in source["images"]:
        shutil.copy(paper_sphere_small / name, folder / Path(name).name)
    (folder / "stack.json").write_text(json.dumps({
        "format": "rjfit-mesh-stack/1", "images": [Path(n).name for n in source["images"]], "mesh": "object.ply",
        "camera": source["camera"], "resolution": source["resolution"], "lights": source["lights"],
        "reference_intensity": source["reference_intensity"],
        "noise_variance": source["noise_variance"]}))      # the rendered images' noise dips below 0
    stack = load_dataset(folder)
    rendered = load_dataset(paper_sphere_small)
    assert np.array_equal(stack.object_mask, rendered.object_mask)
    np.testing.assert_allclose(stack.normals, rendered.normals, atol=1e-5)
    assert stack.observations().n_obs == rendered.observations().n_obs
    assert stack.too_dark is None
    # a declared dark threshold flags the observations whose every channel is at or below it
    description = json.loads((folder / "stack.json").read_text())
    threshold = max(float(np.quantile(stack.images[:, stack.object_mask].mean(axis=-1), 0.2)), 0.0)
    (folder / "stack.json").write_text(json.dumps({**description, "dark": threshold}))
    darkened = load_dataset(folder)
    np.testing.assert_array_equal(darkened.too_dark, (stack.images <= threshold).all(axis=-1))
    assert 0 < darkened.too_dark[:, stack.object_mask].sum() and not darkened.valid_mask()[darkened.too_dark].any()
    (folder / "stack.json").write_text(json.dumps(description))
    result = validate_dataset(folder, tmp_path / "v", spp=1)
    assert result["passed"] and result["geometry"] == "the data set's meshes"
    # the gate covers the mesh (and the images) the fit reads: a changed mesh voids it
    assert require_validated(folder, tmp_path / "v" / "validation.json")["passed"]
    (folder / "object.ply").write_bytes((folder / "object.ply").read_bytes() + b"\n")
    with pytest.raises(ValidationRequiredError, match="changed since"):
        require_validated(folder, tmp_path / "v" / "validation.json")


def test_mesh_stack_description_errors_name_the_file_and_entry(tmp_path):
    from rjfit.errors import DatasetError
    from rjfit.render.datasets import load_dataset

    folder = tmp_path / "stack"
    folder.mkdir()
    good = {"format": "rjfit-mesh-stack/1", "images": ["a.png"], "mesh": "object.ply",
            "camera": {"kind": "perspective", "origin": [0, 0, 5], "target": [0, 0, 0], "up": [0, 1, 0], "fov": 20},
            "resolution": [8, 8], "lights": [{"kind": "point", "position": [1, 1, 3], "intensity": 1.0}]}
    broken = [({"format": "something-else/9"}, "format is 'something-else/9'"),
              ({"resolution": [32]}, "resolution is [32]; it must be [height, width]"),
              ({"camera": {k: v for k, v in good["camera"].items() if k != "fov"}}, "camera.fov is missing"),
              ({"reference_intensity": 0}, "reference_intensity is 0; it must be a number > 0"),
              ({"saturation": "high"}, "saturation is 'high'"),
              ({"dark": -5}, "dark is -5; it must be a value >= 0"),
              ({"lights": [{"kind": "directional", "intensity": 1.0}]}, "lights[0].direction is missing"),
              ({"lights": [{"kind": "point", "position": [1, 1, 3], "intensity": -100}]}, "lights[0].intensity is -100")]
    for change, message in broken:
        (folder / "stack.json").write_text(json.dumps({**good, **change}))
        with pytest.raises(DatasetError, match=re.escape(f"{folder / 'stack.json'}: {message}")):
            load_dataset(folder)


def test_any_non_negative_seed_renders_and_validates(tmp_path):
    """Seeds used to be combined arithmetically into Mitsuba's 32-bit sampler seed, so
    `validate --seed 1` and `render --seed 5000` crashed with a TypeError; every seed now
    maps to its own 32-bit stream per purpose, light and pass."""
    from rjfit.render.mitsuba_scene import mitsuba_seed
    from rjfit.render.render import render_dataset

    dataset = render_dataset("dented_plaster", tmp_path / "ds", resolution=8, spp=2, seed=2 ** 40)
    for seed in (1, 2 ** 63):
        assert validate_dataset(dataset, tmp_path / f"v{seed}", spp=2, seed=seed)["settings"]["seed"] == seed
    streams = {mitsuba_seed(*keys) for keys in [(0, 1, 1), (1, 1, 0), (0, 2, 1), (1, 1, 1, 0), (2 ** 63, 1, 1)]}
    assert len(streams) == 5 and all(0 <= s < 2 ** 32 for s in streams)
    with pytest.raises(ValueError, match="non-negative"):
        mitsuba_seed(-1)


def test_a_damaged_mesh_file_is_one_clear_error(paper_sphere_small, tmp_path):
    from rjfit.errors import DatasetError

    copy = tmp_path / "ds"
    shutil.copytree(paper_sphere_small, copy)
    (copy / "validation").exists() and shutil.rmtree(copy / "validation")
    part = sorted((copy / "meshes").glob("*.ply"))[0]
    part.write_bytes(part.read_bytes() + b"trailing junk\n")
    with pytest.raises(DatasetError, match=rf"Mitsuba cannot load the data set's scene: .*{part.name}.*damaged"):
        validate_dataset(copy, tmp_path / "v", spp=1)


def test_parts_sharing_one_material_validate_and_cast_shadows(paper_sphere_small, tmp_path):
    """Mitsuba merges the meshes of one BSDF into one shape without the parts' ids: the part lookup
    must still give each hit its material (it raised IndexError), for validate and cast shadows."""
    from rjfit.render.datasets import load_dataset
    from rjfit.render.effect_scenes import mitsuba_visibility

    copy = tmp_path / "ds"
    shutil.copytree(paper_sphere_small, copy)
    (copy / "validation").exists() and shutil.rmtree(copy / "validation")
    meta = json.loads((copy / "dataset.json").read_text())
    shared = meta["meshes"][0]["material"]
    meta["meshes"][1]["material"] = shared        # two parts, one material: Mitsuba merges them
    (copy / "dataset.json").write_text(json.dumps(meta))
    result = validate_dataset(copy, tmp_path / "v", spp=1)
    assert result["passed"], result
    visibility = mitsuba_visibility(load_dataset(copy))
    assert visibility.shape[1:] == tuple(meta["resolution"]) and visibility.any()


def test_shape_materials_of_merged_parts():
    from rjfit.render.mitsuba_scene import shape_materials

    assert shape_materials(["part_003", "", "part_000"], [0, 1, 1, 2]) == [2, 1, 0]
    assert shape_materials(["part_000", "part_001"], [3, 4]) == [3, 4]
    with pytest.raises(ValueError, match=r"merged mesh parts \[1, 2\] of materials \[1, 2\]"):
        shape_materials(["part_000", ""], [0, 1, 2])
