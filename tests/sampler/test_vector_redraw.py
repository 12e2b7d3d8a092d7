"""The whole-vector redraw (forward filtering, backward sampling) against exact conditionals.

A 2 x 3 image (two rows, so one u vector has two elements), three lights, parameters and
the model held fixed. The likelihood of the vector depends on its elements only through
their cells (4 per row: [-1, 0.5), [0.5, 1.5), [1.5, 2.5), [2.5, 4]), so the exact
conditional over the 16 cell pairs is the likelihood times the prior mass of the pair of
cells, computed by quadrature for the 'smooth' prior (x0 uniform, x1 - x0 normal) and
as the product of the cell widths for the 'paper' prior. Frequencies from the move alone
are compared by a chi-square test scaled by the effective sample size at level 0.001
(fixed seed), as in tests/sampler/test_exact_rj.py.
"""
import numpy as np
import pytest
from scipy import integrate, stats

from rjfit.data.observations import Observations
from rjfit.model.blinn import radiance
from rjfit.sampler.forward import Problem
from rjfit.sampler.kernel import make_state
from rjfit.sampler.regions.changepoints.vector_redraw import accept_vector_redraw, propose_vector_redraw
from rjfit.sampler.regions.changepoints.grid import ChangepointPrior, Changepoints
from rjfit.sampler.state import Work

LEVEL = 1e-3
EDGES = np.array([-1.0, 0.5, 1.5, 2.5, 4.0])
SMOOTH_SD = 0.8


def small_problem(height, width, boundary, seed=0, n_lights=3, noise=0.05):
    rng = np.random.default_rng(seed)
    pixel = np.repeat(np.arange(height * width), n_lights)
    light = np.tile(np.arange(n_lights), height * width).astype(np.int32)
    cos_ln = rng.uniform(0.3, 1.0, pixel.size)
    cos_hn = rng.uniform(0.6, 1.0, pixel.size)
    irradiance = rng.uniform(0.5, 1.5, pixel.size)
    theta = np.array([[1.0, 0.8, 5.0, noise], [1.0, 0.3, 20.0, noise]])
    truth = theta[(pixel % width >= boundary).astype(int)]
    y = radiance(truth[:, 0], truth[:, 1], truth[:, 2], cos_ln, cos_hn, irradiance) + rng.normal(0, np.sqrt(noise), pixel.size)
    obs = Observations(image_shape=(height, width), n_lights=n_lights, pixel=pixel.astype(np.int64), light=light, y=y,
                       cos_ln=cos_ln, cos_hn=cos_hn, irradiance=irradiance, object_mask=np.ones((height, width), bool))
    problem = Problem.from_observations(obs)
    return problem, theta


def _cell(x):
    return np.searchsorted(EDGES, x, side="right") - 1


def exact_cell_pairs(problem, theta, cp_prior):
    """Exact conditional probabilities (4, 4) of the cells of the vector's two elements."""
    log_w = np.zeros((4, 4))
    for j0 in range(4):
        for j1 in range(4):
            u = np.array([[0.5 * (EDGES[j0] + EDGES[j0 + 1])], [0.5 * (EDGES[j1] + EDGES[j1 + 1])]])
            log_lik = make_state(problem, Changepoints(u, np.zeros((3, 0))), theta).total_log_lik
            if cp_prior == "paper":
                mass = np.diff(EDGES)[j0] * np.diff(EDGES)[j1]
            else:
                def inner(x0):
                    return stats.norm.cdf((EDGES[j1 + 1] - x0) / SMOOTH_SD) - stats.norm.cdf((EDGES[j1] - x0) / SMOOTH_SD)
                mass, _ = integrate.quad(inner, EDGES[j0], EDGES[j0 + 1], epsabs=1e-13, epsrel=1e-11)
            log_w[j0, j1] = log_lik + np.log(mass)
    p = np.exp(log_w - log_w.max())
    return p / p.sum()


def _work(state):
    return Work(layout=state.layout, theta=state.theta, stats=state.stats, log_lik=state.log_lik, labels=state.labels)


def _redraw(work, rng, problem, cp_prior):
    """One vector redraw of the u vector, tested and (if accepted) applied; returns its log ratio (-inf: no path)."""
    proposal = propose_vector_redraw(work, rng, problem, cp_prior, "u")
    if proposal is None:
        return -np.inf
    if np.log(rng.random()) < proposal.log_ratio:
        accept_vector_redraw(work, problem, "u", proposal)
    return proposal.log_ratio


def run_redraws(problem, theta, cp_prior, iterations, seed):
    rng = np.random.default_rng(seed)
    work = _work(make_state(problem, Changepoints(np.array([[2.0], [2.0]]), np.zeros((3, 0))), theta))
    cells, log_ratios = np.zeros((iterations, 2), int), []
    for t in range(iterations):
        log_ratios.append(_redraw(work, rng, problem, cp_prior))
        cells[t] = _cell(work.layout.u[:, 0])
    return cells[:, 0] * 4 + cells[:, 1], np.array(log_ratios)


@pytest.mark.parametrize("cp_prior", ["smooth", "paper"])
def test_vector_redraw_samples_the_exact_conditional(cp_prior):
    import arviz as az

    problem, theta = small_problem(2, 3, boundary=2)
    exact = exact_cell_pairs(problem, theta, cp_prior).ravel()
    assert np.sort(exact)[-1] < 0.9, "the conditional should spread over several cells for the test to bite"
    draws, log_ratios = run_redraws(problem, theta, ChangepointPrior(cp_prior, SMOOTH_SD), 6000, seed=11)
    # cells of exact probability <= 1e-4 (an expected count below 1) are pooled into one bin,
    # so draws landing there still count; a cell of probability 0 must never be drawn
    assert not np.any(np.isin(draws, np.flatnonzero(exact == 0))), "a draw landed in an impossible cell"
    cells = [c for c in range(16) if exact[c] > 1e-4]
    rare = [c for c in range(16) if exact[c] <= 1e-4]
    freq = np.array([np.mean(draws == c) for c in range(16)])
    n_eff = min(float(az.ess((draws == c).astype(float)[None], method="bulk")) for c in cells if 0 < freq[c] < 1)
    observed = np.append(freq[cells], freq[rare].sum())
    expected = np.append(exact[cells], exact[rare].sum())
    x2 = n_eff * np.sum((observed - expected) ** 2 / np.maximum(expected, 1e-12))
    p_value = float(stats.chi2.sf(x2, len(cells) - (0 if rare else 1)))
    print(cp_prior, "p", p_value, "n_eff", n_eff, np.round(freq, 3), np.round(exact, 3))
    assert p_value > LEVEL, (freq, exact, n_eff)
    if cp_prior == "paper":
        # the chain of cells is then the exact conditional: every proposal is accepted
        assert np.max(np.abs(log_ratios)) < 1e-9


def test_vector_redraw_carries_a_misplaced_vector_to_the_boundary():
    """A vector far from the only boundary (column 3 of 24 vs 16) reaches it in a few redraws.

    Element-wise steps of 2 pixels would need many sweeps, each crossing pixels whose
    likelihood opposes it; the redraw proposes the whole path from the conditional.
    """
    problem, theta = small_problem(24, 24, boundary=16, seed=3, n_lights=4, noise=1e-4)
    rng = np.random.default_rng(4)
    work = _work(make_state(problem, Changepoints(np.full((24, 1), 3.2), np.zeros((24, 0))), theta))
    for _ in range(5):
        _redraw(work, rng, problem, ChangepointPrior())      # the default smooth prior
    u = work.layout.u
    at_boundary = (u[:, 0] > 15.5) & (u[:, 0] < 16.5)
    assert np.all(at_boundary), np.round(u[:, 0], 2)
    # the accepted redraws moved labels and statistics incrementally: they equal a fresh computation
    fresh = make_state(problem, work.layout, work.theta)
    np.testing.assert_array_equal(work.labels, fresh.labels)
    np.testing.assert_allclose(work.stats, fresh.stats, rtol=1e-10, atol=1e-9)
    assert float(np.sum(work.log_lik)) == pytest.approx(fresh.total_log_lik, rel=1e-12)


def test_a_vector_whose_gaps_jump_beyond_the_steps_reach_gives_no_nan_ratio():
    """Three vectors that jump 39 pixels between rows 11 and 12 of a 24 x 48 image: the gaps of
    those rows lie further apart than the chain's steps reach (23 cells for the smooth prior's sd
    of 2), so the backward draw meets a dead end and the current vector's own path has density 0.
    The proposal is invalid (-inf, a plain rejection), never NaN (-inf - (-inf))."""
    problem, theta = small_problem(24, 48, boundary=24, seed=2, n_lights=3)
    u = np.where(np.arange(24)[:, None] < 12, [1.2, 2.7, 4.1], [40.2, 42.6, 45.3])
    state = make_state(problem, Changepoints(u, np.zeros((48, 0))), np.tile(theta[0], (4, 1)))
    rng = np.random.default_rng(0)
    for _ in range(6):
        proposal = propose_vector_redraw(_work(state), rng, problem, ChangepointPrior(), "u")
        assert proposal is not None and proposal.log_ratio == -np.inf, proposal and proposal.log_ratio
