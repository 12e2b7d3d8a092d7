"""The forward model: the plain model builds today's Problem; the effects seam transforms its columns."""
import dataclasses

import numpy as np
import pytest

from rjfit.data.synthetic import sphere_stack
from rjfit.sampler.forward import Effect, ForwardModel, LambertBlinnPhong, Problem
from rjfit.sampler.likelihood import log_likelihood_from_stats, oracle_log_likelihood, region_stats


@pytest.fixture(scope="module")
def observations():
    return sphere_stack(16, n_lights=5, seed=2)[0]


def test_the_plain_model_builds_the_problem(observations):
    built = LambertBlinnPhong().problem(observations, likelihood_power=0.5)
    reference = Problem.from_observations(observations, likelihood_power=0.5)
    for field in dataclasses.fields(Problem):
        a, b = getattr(built, field.name), getattr(reference, field.name)
        if isinstance(a, np.ndarray):
            np.testing.assert_array_equal(a, b, err_msg=field.name)
        else:
            assert a == b, field.name
    same, log_jacobian = LambertBlinnPhong().transformed(built)
    assert same is built and log_jacobian == 0.0
    with pytest.raises(ValueError, match="effect parameter"):
        LambertBlinnPhong().transformed(built, [np.ones(2)])


class _Gain(Effect):
    """A global gain on the irradiance (the shape of issue 26's per-light gains, one light)."""

    name, n_params = "gain", 1

    def log_prior(self, params):
        return 0.0

    def transform(self, problem, params):
        return problem.y, problem.C * np.float32(params[0]), 0.0


class _WithGain(LambertBlinnPhong):
    effects = (_Gain(),)


def test_an_effect_transforms_the_columns_the_statistics_read(observations):
    """A gain g on C is the same likelihood as I0 times g: the seam hands the statistics the transformed columns."""
    model = _WithGain()
    problem = model.problem(observations)
    gained, log_jacobian = model.transformed(problem, [np.array([2.0])])
    assert log_jacobian == 0.0 and gained.C.dtype == np.float32
    np.testing.assert_array_equal(gained.C, problem.C * np.float32(2.0))
    labels = np.zeros(problem.n_obs, np.int8)
    theta = np.array([[40.0, 0.6, 8.0, 0.2]])
    scaled = theta * [2.0, 1.0, 1.0, 1.0]
    stats = region_stats(gained, labels, theta[:, 2], 1)
    assert log_likelihood_from_stats(stats, theta)[0] == pytest.approx(
        oracle_log_likelihood(problem, labels, scaled), rel=1e-9)
    with pytest.raises(ValueError, match="takes 1 parameters"):
        model.transformed(problem, [np.array([1.0, 2.0])])
    with pytest.raises(TypeError):
        ForwardModel()          # the contract is abstract
