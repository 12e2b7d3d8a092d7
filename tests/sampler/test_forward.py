"""The forward model: the plain model builds today's Problem; effects transform its columns (issue 26)."""
import dataclasses

import numpy as np
import pytest

from rjfit.data.synthetic import sphere_stack
from rjfit.effects.base import FitForm, Param
from rjfit.model.priors import LogNormal
from rjfit.sampler.forward import ForwardModel, LambertBlinnPhong, Problem, transformed
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
    assert built.effects is None and built.lobe is None
    with pytest.raises(ValueError, match="no effects"):
        transformed(built, [])


@dataclasses.dataclass(frozen=True, eq=False)
class _Gain(FitForm):
    """A global gain on the irradiance (the shape of the per-light gains, one light)."""

    params: tuple = (Param("gain", LogNormal(0.0, 1.0), 1.0),)
    name: str = "gain"
    stage: str = "light"

    def apply(self, columns, theta):
        columns.scale(theta[0])


def test_an_effect_transforms_the_columns_the_statistics_read(observations):
    """A gain g on C is the same likelihood as I0 times g: the transformed problem hands the statistics its columns."""
    model = LambertBlinnPhong([_Gain()])
    problem = model.problem(observations)
    assert problem.effects.names == ["gain.gain"]
    gained, log_jacobian = transformed(problem, [np.log(2.0)])
    assert log_jacobian == 0.0 and gained.C.dtype == np.float32 and gained.lobe is not None
    np.testing.assert_allclose(gained.C, problem.C * 2.0, rtol=1e-7)
    labels = np.zeros(problem.n_obs, np.int8)
    theta = np.array([[40.0, 0.6, 8.0, 0.2]])
    scaled = theta * [2.0, 1.0, 1.0, 1.0]
    stats = region_stats(gained, labels, theta[:, 2], 1)
    assert log_likelihood_from_stats(stats, theta)[0] == pytest.approx(
        oracle_log_likelihood(problem, labels, scaled), rel=1e-6)
    with pytest.raises(ValueError, match="effect parameters"):
        transformed(problem, [1.0, 2.0])
    with pytest.raises(ValueError, match="named twice"):
        LambertBlinnPhong([_Gain(), _Gain()])
    with pytest.raises(TypeError):
        ForwardModel()          # the contract is abstract


def test_the_compiled_rows_give_the_array_form_s_log_likelihood():
    """log_likelihood_from_stats of (R, 7) statistics (the moves' case: one compiled call) against its array
    form (the same call on a leading axis of 1): random rows, an empty region (0) and a row whose b exceeds
    AB_PLAIN_MAX (the general path's overflow-free sum takes it). 1e-13 relative: exp2 and log differ by an ulp
    between NumPy's kernels and the compiled ones."""
    rng = np.random.default_rng(3)
    R = 6
    stats = np.abs(rng.normal(size=(R, 7))) * [100.0, 50.0, 10.0, 5.0, 10.0, 3.0, 4.0]
    stats[:, 0] = np.round(stats[:, 0])
    stats[2] = 0.0
    theta = np.column_stack([rng.uniform(1, 50, R), rng.uniform(0.05, 0.95, R), rng.uniform(0.5, 80, R),
                             rng.uniform(0.01, 2, R)])
    compiled = log_likelihood_from_stats(stats, theta)
    np.testing.assert_allclose(compiled, log_likelihood_from_stats(stats[None], theta[None])[0], rtol=1e-13)
    assert compiled[2] == 0.0
    huge = theta.copy()
    huge[4, 0] = 1e120                      # I0 (1 - kd) N(g) far beyond AB_PLAIN_MAX
    mixed = log_likelihood_from_stats(stats, huge)
    np.testing.assert_allclose(mixed, log_likelihood_from_stats(stats[None], huge[None])[0], rtol=1e-13)
    np.testing.assert_allclose(np.delete(mixed, 4), np.delete(compiled, 4), rtol=1e-13)
