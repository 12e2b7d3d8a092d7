"""Each effect's Mitsuba-side change against its closed-form extension (the cross-check gate).

For every effect: Mitsuba renders the data set's scene WITH the effect's change; the
extended closed form must pass the gate and the plain closed form (without the effect) must
fail it, on the same path-traced stack; so must the closed form the fit samples with the
effect inside its likelihood (issue 26). Deterministic changes use rjfit.render.gate's thresholds
(median relative error <= 1e-4, p99 <= 1e-3); Monte Carlo ones (ambient, interreflection)
the statistical criterion of rjfit.diagnose.gate.gate.
"""
from __future__ import annotations

import pytest

from rjfit.effects import EFFECTS
from rjfit.diagnose.gate import gate


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    from rjfit.render.hidden import backlit_sphere_definition
    from rjfit.render.render import load_scene_definition, render_dataset

    root = tmp_path_factory.mktemp("gate")
    direct = load_scene_definition("dented_plaster")
    direct["max_depth"] = 2
    return {"sphere": render_dataset("paper_sphere", root / "sphere", resolution=24, noise_variance=0.0),
            "backlit": render_dataset(backlit_sphere_definition(), root / "backlit", resolution=24, noise_variance=0.0),
            "dented_direct": render_dataset(direct, root / "dented_direct", resolution=24, noise_variance=0.0),
            "dented": render_dataset("dented_plaster", root / "dented", resolution=24, spp=1, noise_variance=0.0)}


@pytest.mark.parametrize("scene, effects, thetas, reference, options", [
    ("backlit", ["fresnel"], [[0.1]], [], {}),
    ("backlit", ["masking"], [[1.0]], [], {}),
    ("backlit", ["ggx"], [[0.6]], [], {}),
    ("backlit", ["ggx", "fresnel", "masking"], [[1.0], [0.1], [0.5]], ["fresnel", "masking"], {}),
    ("backlit", ["coating"], [[0.9, 1.5]], [], {}),
    ("backlit", ["ggx", "coating", "masking"], [[1.0], [1.0, 1.33], [0.5]], ["masking"], {}),
    ("backlit", ["rough_coating"], [[0.9, 1.5, 0.3]], [], {}),
    ("backlit", ["ggx", "rough_coating"], [[1.0], [1.0, 1.5, 0.6]], ["ggx"], {}),
    ("sphere", ["second_lobe"], [[0.4, 0.15]], [], {}),
    ("dented_direct", ["second_lobe", "coating", "cast_shadows"], [[0.6, 0.3], [0.7, 1.8], [1.0]], ["second_lobe",
                                                                                                  "cast_shadows"], {}),
    ("dented_direct", ["second_lobe", "cast_shadows"], [[0.6, 0.3], [1.0]], ["cast_shadows"], {}),
    ("sphere", ["camera_gamma"], [[2.2]], [], {}),
    ("sphere", ["camera_srgb"], [[1.3]], [], {}),
    ("sphere", ["light_calibration"], [[0.15, -0.1, 0.0, 0.05, 0.0, 0.0, 0.0, 0.0, 0.0]], [], {}),
    ("dented_direct", ["cast_shadows"], [[1.0]], [], {}),
    ("sphere", ["ambient"], [[0.02]], [], {"spp": 256}),
    ("dented", ["cast_shadows", "interreflection"], [[1.0], [1.0]], ["cast_shadows"], {"spp": 64}),
])
def test_extended_model_passes_gate_and_plain_fails(scenes, scene, effects, thetas, reference, options):
    result = gate(scenes[scene], [EFFECTS[name] for name in effects], thetas, reference_effects=reference, **options)
    assert result["extended"]["passed"], result["extended"]
    assert not result["reference"]["passed"], result["reference"]
    assert result["fit"]["passed"], result["fit"]
