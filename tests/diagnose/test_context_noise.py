"""The criticism weighs observations as the fit did, for every noise model (about 5 s on the 48 x 48 render)."""
import numpy as np
import pytest

from rjfit.data.noise import NOISE_MODELS, noise_scale
from rjfit.diagnose.context import build_context
from rjfit.render.datasets import load_dataset


@pytest.mark.parametrize("noise", NOISE_MODELS)
def test_the_context_s_noise_scales_are_the_fit_s(paper_sphere_small, noise):
    """Before, a context could not carry ``normals`` (its observations had no <l.h>), so
    ``rjfit diagnose`` failed on every ``--preset measured`` fit."""
    dataset = load_dataset(paper_sphere_small)
    labels = np.where(dataset.object_mask, 0, -1)
    ctx = build_context(dataset, labels, noise=noise)
    observations = dataset.observations("mean")
    np.testing.assert_array_equal(ctx.pixel, observations.pixel)
    expected = noise_scale(observations, noise)
    if expected is None:                       # the constant model: every scale 1
        assert ctx.noise_scale is None
    else:
        np.testing.assert_allclose(ctx.noise_scale, expected, rtol=1e-9)
