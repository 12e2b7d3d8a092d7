"""A step's candidates are refitted on worker threads; the current model's Mitsuba features are
rendered before, on the calling thread (rjfit refine's second round, whose fit samples
interreflection, crashed there: a segfault, or "jit_var_gather(): attempted to gather from an
empty array" with RJFIT_DEBUG). Real Mitsuba, 16 x 16 at 4 spp; ~20 s."""
import numpy as np

from rjfit.diagnose.candidates import LOG_BF_THRESHOLD, try_candidates
from rjfit.diagnose.context import build_context
from rjfit.effects import get_effect
from rjfit.diagnose.gap import noise_variance
from rjfit.diagnose.refit import refit, standardised_residuals
from rjfit.render.datasets import load_dataset
from rjfit.render.hidden import render_hidden


def test_candidates_refit_on_threads_when_the_current_model_has_interreflection(tmp_path):
    dataset = load_dataset(render_hidden("interreflection", tmp_path / "d", resolution=16, spp=4))
    ctx = build_context(dataset, np.where(dataset.object_mask, dataset.truth_labels, -1))
    ctx.features["fit_region_params"] = refit(ctx, ()).region_params()
    current = refit(ctx, (get_effect("interreflection"),))
    # as the search does: the indirect light is then rendered at the current model's materials,
    # a feature not yet in the cache when the candidates start
    ctx.features["fit_region_params"] = current.region_params()
    residuals = standardised_residuals(ctx, current)
    outcomes = try_candidates(ctx, current, [get_effect("ambient"), get_effect("camera_srgb")], residuals,
                              noise_variance(ctx, residuals), seed=0, threshold=LOG_BF_THRESHOLD, jobs=2,
                              report=lambda effect, outcome: None)
    errors = {name: outcome for name, outcome in outcomes.items() if isinstance(outcome, Exception)}
    assert set(outcomes) == {"ambient", "camera_srgb"} and not errors
