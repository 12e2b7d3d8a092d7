"""The effects inside the fit (issue 26) have the criticism's closed form: the same mean for the same parameters.

For every effect of the library, and for all of them at once, the mean the fit's likelihood
has (:func:`rjfit.diagnose.model.fit_prediction`: the sampler's forward model transforms the
problem, the mean goes back through the camera response) must equal the criticism's
extended closed form (:func:`rjfit.diagnose.model.predict`), which the gate checks against
Mitsuba (``test_diagnose_gate.py`` checks the fit's against Mitsuba too). Tolerance: 2e-6
relative, the float32 storage of the transformed columns (about 6e-8 each) with room for the
few roundings of a mean; a wrong stage order or a missing factor is off by percents.

The Mitsuba features (shadow-ray visibility, indirect light) are put into the context's
feature cache as random arrays: what is tested here is how each effect enters the two
closed forms, not the rendering (the gate renders them). Cost: one 12 x 12 render, ~1 s.
"""
from __future__ import annotations

import numpy as np
import pytest

from rjfit.diagnose.context import build_context
from rjfit.effects import EFFECTS
from rjfit.effects.interreflection import INDIRECT_SPP, feature_key
from rjfit.diagnose.model import fit_prediction, predict

THETAS = {"fresnel": [0.1], "masking": [0.8], "ggx": [0.7], "second_lobe": [0.4, 0.15], "coating": [0.8, 1.6],
          "rough_coating": [0.8, 1.6, 0.35], "cast_shadows": [0.7], "interreflection": [1.3], "ambient": [0.03],
          "camera_gamma": [2.2], "camera_srgb": [1.3]}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    from rjfit.render.datasets import load_dataset
    from rjfit.render.render import render_dataset

    return load_dataset(render_dataset("paper_sphere", tmp_path_factory.mktemp("fit_effects") / "d", resolution=12))


def _context(dataset, noise):
    ctx = build_context(dataset, dataset.truth_labels, noise=noise)
    rng = np.random.default_rng(3)
    materials = dataset.meta["materials"]
    used = np.unique(dataset.truth_labels[dataset.truth_labels >= 0])
    params = np.array([[materials[m]["I0"], materials[m]["kd"], materials[m]["gamma"], 1.0] for m in used])
    ctx.features["fit_region_params"] = params
    ctx.features["mitsuba_visibility"] = (rng.random(ctx.valid.shape) < 0.7).astype(float)
    ctx.features[feature_key(params, INDIRECT_SPP)] = rng.uniform(0.0, 0.05, ctx.valid.shape) * float(np.max(ctx.y))
    return ctx, params


def _thetas(names, ctx):
    gains = np.linspace(-0.2, 0.2, ctx.n_lights - 1)
    return [gains if name == "light_calibration" else np.array(THETAS[name]) for name in names]


ALL_BUT_GAMMA = ["fresnel", "masking", "cast_shadows", "interreflection", "light_calibration", "ambient", "camera_srgb"]


@pytest.mark.parametrize("names, noise", [([name], "constant") for name in sorted(EFFECTS)]
                         + [(ALL_BUT_GAMMA, "constant"), (ALL_BUT_GAMMA, "relative"),
                            (["masking", "fresnel", "ggx"], "relative"),      # ggx listed last, applied first
                            (ALL_BUT_GAMMA + ["ggx"], "relative"),
                            (ALL_BUT_GAMMA + ["second_lobe", "ggx"], "relative"),
                            (["second_lobe", "cast_shadows", "ambient"], "constant"),
                            (["cast_shadows", "coating", "second_lobe", "ggx"], "relative"),   # coating after the lobe
                            (ALL_BUT_GAMMA + ["coating", "ggx"], "relative"),
                            (["cast_shadows", "rough_coating", "second_lobe", "ggx"], "relative"),
                            (ALL_BUT_GAMMA + ["rough_coating", "ggx"], "relative"),
                            (["ambient", "camera_gamma"], "relative")])
def test_the_fit_s_mean_is_the_criticism_s_closed_form(dataset, names, noise):
    ctx, params = _context(dataset, noise)
    effects = [EFFECTS[name] for name in names]
    thetas = _thetas(names, ctx)
    expected = predict(ctx, effects, params, thetas, [effect.prepare(ctx) for effect in effects])
    plain = predict(ctx, (), params, (), ())
    assert not np.allclose(expected, plain, rtol=1e-3), "the effect must change the mean for the test to bite"
    got = fit_prediction(ctx, effects, params, thetas)
    np.testing.assert_allclose(got, expected, rtol=2e-6, atol=1e-9 * float(np.max(np.abs(expected))))


def test_one_camera_response_per_fit(dataset):
    ctx, params = _context(dataset, "constant")
    with pytest.raises(ValueError, match="one camera response"):
        fit_prediction(ctx, [EFFECTS["camera_gamma"], EFFECTS["camera_srgb"]], params, [[2.2], [1.3]])
