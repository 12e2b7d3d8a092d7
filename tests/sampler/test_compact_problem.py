"""Compact observation storage (float32, small integers) with every sum accumulated in float64."""
import dataclasses
import math

import numpy as np
import pytest

from rjfit.data.synthetic import sphere_stack
from rjfit.sampler import forward
from rjfit.sampler.forward import Problem
from rjfit.sampler.kernel import make_state
from rjfit.sampler.likelihood import RegionData, region_stats
from rjfit.sampler.regions.changepoints.grid import Changepoints


@pytest.fixture(scope="module")
def offset_problem():
    # A large offset makes Syy about 1e9 times the residual sum of squares: float32
    # accumulation (or np.dot of two float32 arrays) would lose the statistics entirely.
    obs, _, _ = sphere_stack(24, n_lights=6, seed=5)
    return Problem.from_observations(dataclasses.replace(obs, y=obs.y + 1.0e4))


def _reference_stats(problem, labels, gammas, n_regions):
    """Exactly rounded float64 sums (math.fsum) of the seven terms from the stored float32 data."""
    y = problem.y.astype(np.float64)
    A = problem.C.astype(np.float64) / np.pi
    B = problem.C.astype(np.float64) * np.exp(np.asarray(gammas)[labels] * problem.log_cos_hn.astype(np.float64))
    terms = (np.ones_like(y), y * y, y * A, A * A, y * B, A * B, B * B)
    return np.array([[math.fsum(t[labels == r]) for t in terms] for r in range(n_regions)])


def test_problem_arrays_are_compact(offset_problem):
    p = offset_problem
    for name in ("y", "C", "log_cos_hn"):
        assert getattr(p, name).dtype == np.float32, name
    assert p.row.dtype == p.col.dtype == np.int16
    for name in ("pixel", "pixel_start", "colmajor_order", "colmajor_start"):
        assert getattr(p, name).dtype == np.int32, name
    assert not any(hasattr(p, name) for name in ("yy", "yA", "AA", "observations"))
    assert p.A.dtype == np.float64
    u, v = np.full((p.height, 1), p.width / 2.0), np.full((p.width, 1), p.height / 2.0)
    state = make_state(p, Changepoints(u, v), np.tile([100.0, 0.5, 5.0, 0.1], (4, 1)))
    assert state.labels.dtype == np.int8


@pytest.mark.parametrize("chunk", [forward.CHUNK, 37])
def test_region_sums_are_float64_accurate(offset_problem, monkeypatch, chunk):
    monkeypatch.setattr(forward, "CHUNK", chunk)
    p = offset_problem
    u, v = np.full((p.height, 1), p.width / 2.0), np.full((p.width, 1), p.height / 2.0)
    gammas = np.array([5.0, 10.0, 5.0, 1.0])
    labels = make_state(p, Changepoints(u, v), np.column_stack([np.full(4, 100.0), np.full(4, 0.5), gammas,
                                                  np.full(4, 0.1)])).labels
    reference = _reference_stats(p, labels, gammas, 4)
    np.testing.assert_allclose(region_stats(p, labels, gammas, 4), reference, rtol=1e-12, atol=0)
    for r in range(4):
        data = RegionData.gather(p, np.flatnonzero(labels == r))
        np.testing.assert_allclose(data.stats_at(gammas[r]), reference[r], rtol=1e-12, atol=0)


def test_weighted_problem_stays_compact_and_float64_accurate(offset_problem):
    """Known noise scales: y / s and C / s stored in float32, the scales too, sums still exact in float64."""
    obs, _, _ = sphere_stack(24, n_lights=6, seed=5)
    obs = dataclasses.replace(obs, y=obs.y + 1.0e4)
    scale = np.random.default_rng(1).uniform(0.5, 3.0, obs.n_obs)
    p = Problem.from_observations(obs, noise_scale=scale)
    for name in ("y", "C", "log_cos_hn", "noise_scale"):
        assert getattr(p, name).dtype == np.float32, name
    np.testing.assert_allclose(p.y.astype(np.float64) * p.noise_scale, offset_problem.y, rtol=2e-7)
    np.testing.assert_allclose(p.C.astype(np.float64) * p.noise_scale, offset_problem.C, rtol=2e-7)
    u, v = np.full((p.height, 1), p.width / 2.0), np.full((p.width, 1), p.height / 2.0)
    gammas = np.array([5.0, 10.0, 5.0, 1.0])
    labels = make_state(p, Changepoints(u, v), np.column_stack([np.full(4, 100.0), np.full(4, 0.5), gammas,
                                                  np.full(4, 0.1)])).labels
    np.testing.assert_allclose(region_stats(p, labels, gammas, 4), _reference_stats(p, labels, gammas, 4),
                               rtol=1e-12, atol=0)
