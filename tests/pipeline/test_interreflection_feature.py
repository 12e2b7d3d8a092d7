"""Interreflection's feature in a refit (``rjfit fit --effects-from DIAGNOSIS``, issue 26).

The feature is the indirect light of a model, rendered once per fit: at the region parameters
of the diagnosis' final model (fitted with interreflection, so its materials no longer absorb
the indirect light), not at the diagnosed plain fit's, whose brightened materials make the
indirect light wrong in shape and scale. A 12 x 12 dented_plaster stack (its two materials
are the truth segmentation, used as the MAP labels of a fit folder whose posterior means are
the plain fit's kind of error: brighter); the diagnosis is written by hand with the fields the
refit reads. Cost: three renders of the indirect light at 12 x 12 x 8 lights, about 10 s.
"""
import json

import numpy as np
import pytest

from rjfit.diagnose.context import build_context
from rjfit.effects.interreflection import FEATURE_SPP, Interreflection
from rjfit.pipeline.fit_effects import FINAL_MODEL, FIT_MEANS, _order_in, fit_effects
from rjfit.pipeline.fit_folder import read_map_labels
from rjfit.pipeline.options import FitOptions
from rjfit.pipeline.resolve import resolve_options
from rjfit.render.datasets import load_dataset

from builders import truth_fit_folder

# I0, kd, gamma, sigma2 per region: the plain fit's (brightened by the indirect light it misses)
# and the diagnosis' final model's (dented_plaster's true materials)
FIT_MEANS_TABLE = np.array([[118.0, 0.97, 30.0, 0.3], [82.0, 0.72, 26.0, 0.2]])
FINAL_TABLE = np.array([[100.0, 0.85, 8.0, 0.1], [70.0, 0.6, 20.0, 0.1]])


@pytest.fixture(scope="module")
def plaster(tmp_path_factory):
    from rjfit.render.hidden import render_hidden

    return render_hidden("interreflection", tmp_path_factory.mktemp("plaster") / "dataset", resolution=12)


def _diagnosed_fit(dataset_path, folder, final_parameters):
    """A fit folder (truth labels as MAP labels, ``FIT_MEANS_TABLE`` as posterior means) and a
    diagnosis of it naming interreflection, whose final model holds ``final_parameters``."""
    fit_dir = truth_fit_folder(dataset_path, folder / "fit")
    regions = [{"region": r, **{name: {"mean": float(value)} for name, value in
                                zip(("I0", "kd", "gamma", "sigma2"), FIT_MEANS_TABLE[r])}} for r in range(2)]
    (fit_dir / "summary.json").write_text(json.dumps({"dataset": str(dataset_path), "regions": regions}))
    diagnosis_dir = folder / "diagnosis"
    diagnosis_dir.mkdir()
    (diagnosis_dir / "diagnosis.json").write_text(json.dumps({
        "fit_dir": str(fit_dir), "named_effects": ["interreflection"], "n_regions": 2,
        "final_model": {"effects": ["interreflection"], "parameters": final_parameters}}))
    return fit_dir, diagnosis_dir


def _feature_at(dataset, fit_dir, table, options, observations):
    """The refit's feature rendered directly at ``table`` (the fit's MAP labels), in the fit's order."""
    ctx = build_context(dataset, read_map_labels(fit_dir, dataset.object_mask), channel=options.channel,
                        seed=options.seed)
    ctx.features["fit_region_params"] = table
    ctx.features["indirect_spp"] = FEATURE_SPP
    return Interreflection().prepare(ctx)[_order_in(ctx, observations)]


def test_the_refit_s_feature_is_rendered_at_the_diagnosis_final_model(plaster, tmp_path):
    final = {f"{name}[{r}]": {"map": float(FINAL_TABLE[r, i]), "sd": 0.01}
             for r in range(2) for i, name in enumerate(("I0", "kd", "gamma", "sigma2"))}
    final["interreflection.beta"] = {"map": 0.97, "sd": 0.01}
    fit_dir, diagnosis_dir = _diagnosed_fit(plaster, tmp_path, final)
    dataset, options = load_dataset(plaster), resolve_options(FitOptions(effects_from=diagnosis_dir))
    observations = dataset.observations(options.channel)
    (effect,), source = fit_effects(dataset, observations, options)
    record = source["interreflection"]
    assert record["feature_model"] == FINAL_MODEL
    np.testing.assert_allclose(record["feature_region_params"], FINAL_TABLE[:, :3])
    assert record["feature_spp"] == FEATURE_SPP and 0.0 <= record["beta_attenuation_share"] < 1.0
    # the same render (same seed and streams) as at the final model's parameters; the plain
    # fit's brighter materials give a different indirect light
    np.testing.assert_array_equal(effect.feature, _feature_at(dataset, fit_dir, FINAL_TABLE, options, observations))
    assert not np.allclose(effect.feature, _feature_at(dataset, fit_dir, FIT_MEANS_TABLE, options, observations))


def test_a_diagnosis_without_final_model_parameters_falls_back_to_the_fit_s_means(plaster, tmp_path):
    fit_dir, diagnosis_dir = _diagnosed_fit(plaster, tmp_path, {"interreflection.beta": {"map": 0.97}})
    dataset, options = load_dataset(plaster), resolve_options(FitOptions(effects_from=diagnosis_dir))
    _, source = fit_effects(dataset, dataset.observations(options.channel), options)
    assert source["interreflection"]["feature_model"] == FIT_MEANS
    np.testing.assert_allclose(source["interreflection"]["feature_region_params"], FIT_MEANS_TABLE[:, :3])
