"""Exactness of the RJMCMC sampler against posteriors computed by enumeration and quadrature.

A 2 x 2 image with 3 lights (12 observations), at most one u and one v change point. The
likelihood depends on a change-point element only through which of three intervals of
[-1, 3] it lies in ([-1, 0.5), [0.5, 1.5), [1.5, 3]: lengths 1.5, 1, 1.5), so the exact
posterior over models and change-point intervals is a finite sum: model prior x interval
probabilities x product over regions of the region evidence. sigma^2 has an inverse-gamma
prior and is integrated analytically; I0, kd, gamma by the trapezoid rule on a 3-D grid in
the sampler's phi coordinates (the integrand is smooth and decays inside the box; halving
the grid spacing changes the log evidences by < 1e-4, see test_quadrature_converged).

Statistical tests. Chain draws are autocorrelated, so frequencies are compared with a
chi-square statistic scaled by the effective sample size (ArviZ bulk ESS of the cell
indicators, the smallest over cells): X^2 = N_eff * sum (p_hat - p)^2 / p, df = cells - 1.
A test passes at level 0.001 (p-value > 0.001; fixed seeds make the outcome deterministic).
Parameter marginals are compared by one-sample KS tests on draws thinned to about one per
effective sample (so the KS null distribution applies), also at level 0.001.
The negative control (the paper-style map without its Jacobian) must be rejected with
p < 1e-6, and must instead match the posterior that dropping the Jacobian actually targets.
"""
import numpy as np
import pytest
from scipy import stats
from threadpoolctl import threadpool_limits

from rjfit.sampler.forward import Problem
from rjfit.sampler.kernel import ChainContext, initial_state, step
from rjfit.sampler.regions.changepoints.grid import pixel_region_labels
from rjfit.sampler.state import SamplerConfig

from builders import CP_SMOOTH_SD as SMOOTH_SD
from builders import INTERVALS, Quadrature, ess_scaled_chi2, exact_changepoint_posterior, tiny_problem

LEVEL = 1e-3

def run(problem, prior, config, iterations, seed):
    rng = np.random.default_rng(seed)
    state = initial_state(problem, prior, config, rng, model=(0, 0))
    context = ChainContext()       # the chain's reusable work, as a fit's runner keeps it
    models = np.zeros((iterations, 2), int)
    u0 = np.full(iterations, -1)
    theta = np.zeros((iterations, 4))
    with threadpool_limits(1):
        for t in range(iterations):
            state, _ = step(state, rng, problem, prior, config, context)
            models[t] = state.layout.model_key
            if state.layout.n_u:
                x = state.layout.u[0, 0]
                u0[t] = 0 if x < 0.5 else (1 if x < 1.5 else 2)
            theta[t] = state.theta[0]
    return models, u0, theta


@pytest.fixture(scope="module")
def setup():
    obs, prior = tiny_problem()
    return obs, prior, Problem.from_observations(obs), Quadrature(obs, prior)


def test_quadrature_converged(setup):
    obs, prior, _, quad = setup
    coarse = Quadrature(obs, prior, points=41)
    for pixels in ([0], [0, 2], [1, 3], [0, 1, 2, 3]):
        assert coarse.log_evidence(pixels) == pytest.approx(quad.log_evidence(pixels), abs=1e-4)


def _chain(setup, config, iterations, seed):
    obs, prior, problem, quad = setup
    models, u0, _ = run(problem, prior, config, iterations, seed)
    burn = iterations // 10
    return models[burn:], u0[burn:]


def _model_and_cp_tests(models, u0, exact):
    model_cells = [(0, 0), (0, 1), (1, 0), (1, 1)]           # cell index n_u * 2 + n_v
    p_model = np.array([sum(p for k, p in exact.items() if k[:2] == m) for m in model_cells])
    p_val_model, freq, n_eff = ess_scaled_chi2([0, 1, 2, 3], models[:, 0] * 2 + models[:, 1], p_model)
    # interval of the row-0 u element, given n_u = 1
    with_u = models[:, 0] == 1
    p_u = np.array([sum(p for k, p in exact.items() if k[0] == 1 and k[2] == c) for c in range(3)])
    p_u /= p_u.sum()
    p_val_u, freq_u, _ = ess_scaled_chi2([0, 1, 2], u0[with_u], p_u)
    return p_val_model, p_val_u, {"freq": freq, "exact": p_model, "n_eff": n_eff, "freq_u": freq_u, "exact_u": p_u,
                                  "p_model": p_val_model, "p_u": p_val_u}


@pytest.mark.parametrize("split_map,cp_prior,iterations", [("conditional", "smooth", 20000), ("conditional", "paper", 12000),
                                                           ("mean", "paper", 12000), ("paper", "paper", 12000)])
def test_model_and_changepoint_frequencies_match_exact_changepoint_posterior(setup, split_map, cp_prior, iterations):
    exact = exact_changepoint_posterior(setup[3], cp_prior=cp_prior)
    config = SamplerConfig.from_flat(max_u=1, max_v=1, split_map=split_map, split_scale=0.6, jump_prob=1.0, cp_step=1.0,
                           cp_uniform_prob=0.3, burn_in=0, cp_prior=cp_prior, cp_smooth_sd=SMOOTH_SD)
    p_model, p_u, details = _model_and_cp_tests(*_chain(setup, config, iterations, 1), exact)
    print(split_map, cp_prior, details)
    assert min(details["exact"]) > 0.02, "the exact posterior should spread over the models for the test to bite"
    assert p_model > LEVEL, details
    assert p_u > LEVEL, details


def test_paper_map_without_jacobian_gives_a_different_wrong_model_posterior(setup):
    # free_jump_prob 0: every jump uses the paper's map (the rank-free pair is exact and
    # would pull the chain part of the way back to the true posterior)
    config = SamplerConfig.from_flat(max_u=1, max_v=1, split_map="paper", drop_jacobian=True, split_scale=0.6, jump_prob=1.0,
                           cp_step=1.0, cp_uniform_prob=0.3, burn_in=0, cp_prior="paper", free_jump_prob=0.0)
    models, u0 = _chain(setup, config, 12000, 2)
    p_model, _, details = _model_and_cp_tests(models, u0, exact_changepoint_posterior(setup[3]))
    print("no jacobian vs exact", details)
    assert p_model < 1e-6, details
    # ... and it samples exactly the distorted posterior that dropping |det J| = 3^4 per split implies
    distorted = exact_changepoint_posterior(setup[3], jacobian_power=4 * np.log(3.0))
    p_distorted, _, details = _model_and_cp_tests(models, u0, distorted)
    print("no jacobian vs distorted", details)
    assert p_distorted > LEVEL, details


@pytest.mark.parametrize("pixels", [[0, 1, 2, 3], [2]])
def test_parameter_marginals_match_quadrature_ks(setup, pixels):
    """Fixed segmentation (one region): KS of I0, kd, gamma, sigma^2 draws vs quadrature CDFs.

    ``[2]``: a one-pixel region (3 observations) runs the phi-space random-walk fallback;
    all pixels (12 observations) run the conditional moves.
    """
    import arviz as az

    obs, prior, _, quad = setup
    keep = np.isin(obs.pixel, pixels)
    sub = obs.subset(keep)
    problem = Problem.from_observations(sub)
    config = SamplerConfig.from_flat(max_u=0, max_v=0, update_changepoints=False, jumps=False, burn_in=500)
    _, _, theta = run(problem, prior, config, 20000, 3)
    theta = theta[1000:]
    cdfs = quad.marginal_cdfs(pixels)
    for k in range(4):
        ess = float(az.ess(theta[:, k][None], method="bulk"))
        thin = max(1, int(np.ceil(len(theta) / ess)))
        draws = theta[::thin, k]
        p_value = stats.kstest(draws, cdfs[k]).pvalue
        assert p_value > LEVEL, (k, p_value, len(draws))


def exact_posterior_u_only(quad, max_u=2):
    """Exact posterior over n_u in 0..max_u (no v vectors) and, for n_u = 2, the cell pair of row 0.

    'paper' prior: per row the sorted elements are order statistics of iid U(-1, 3), so a
    pair of cells a < b has mass 2 I_a I_b and a = b has I_a^2 (I: interval probabilities).
    """
    reps = (np.array([-1.0, 1.0, 2.0]), np.array([-0.9, 1.1, 2.1]))
    joint = {}
    for n_u in range(max_u + 1):
        per_row = [()] if n_u == 0 else ([(a,) for a in range(3)] if n_u == 1 else
                                         [(a, b) for a in range(3) for b in range(a, 3)])
        for cells in np.ndindex(*(len(per_row),) * (2 if n_u else 0)):
            rows = [per_row[c] for c in cells] if n_u else [(), ()]
            u = np.array([[reps[i][a] for i, a in enumerate(row)] for row in rows]).reshape(2, n_u)
            labels = pixel_region_labels(u, np.zeros((2, 0)), (2, 2)).ravel()
            log_w = 0.0
            for row in rows:
                if len(row) == 1:
                    log_w += np.log(INTERVALS[row[0]])
                elif len(row) == 2:
                    a, b = row
                    log_w += np.log(INTERVALS[a] ** 2 if a == b else 2 * INTERVALS[a] * INTERVALS[b])
            log_w += sum(quad.log_evidence(np.flatnonzero(labels == r)) for r in range(n_u + 1))
            key = (n_u, rows[0] if n_u == 2 else ())
            joint[key] = np.logaddexp(joint.get(key, -np.inf), log_w)
    keys = sorted(joint)
    log_w = np.array([joint[k] for k in keys])
    return dict(zip(keys, np.exp(log_w - np.logaddexp.reduce(log_w))))


@pytest.mark.parametrize("free_jump_prob", [1.0, 0.5])
def test_free_rank_birth_death_match_exact_changepoint_posterior(setup, free_jump_prob):
    """Up to two u vectors, so the free pair's elements really take either rank in each row.

    ``free_jump_prob`` 1: births and deaths only by the free pair; 0.5: mixed with the
    rank-keeping pair (each pair is reversible on its own).
    """
    obs, prior, problem, quad = setup
    exact = exact_posterior_u_only(quad)
    config = SamplerConfig.from_flat(max_u=2, max_v=0, jump_prob=1.0, free_jump_prob=free_jump_prob, cp_step=1.0,
                           cp_uniform_prob=0.3, burn_in=0, cp_prior="paper")
    rng = np.random.default_rng(7)
    state = initial_state(problem, prior, config, rng, model=(0, 0))
    context = ChainContext()       # the chain's reusable work, as a fit's runner keeps it
    iterations = 12000
    n_u = np.zeros(iterations, int)
    pair = np.full(iterations, -1)
    pairs = [(a, b) for a in range(3) for b in range(a, 3)]
    with threadpool_limits(1):
        for t in range(iterations):
            state, _ = step(state, rng, problem, prior, config, context)
            n_u[t] = state.layout.n_u
            if state.layout.n_u == 2:
                cells = tuple(int(np.searchsorted([0.5, 1.5], x, side="right")) for x in state.layout.u[0])
                pair[t] = pairs.index(cells)
    burn = iterations // 10
    n_u, pair = n_u[burn:], pair[burn:]
    p_model = np.array([sum(p for k, p in exact.items() if k[0] == m) for m in range(3)])
    p_val_model, freq, n_eff = ess_scaled_chi2([0, 1, 2], n_u, p_model)
    p_pair = np.array([exact[(2, c)] for c in pairs])
    p_pair /= p_pair.sum()
    p_val_pair, freq_pair, _ = ess_scaled_chi2(list(range(len(pairs))), pair[n_u == 2], p_pair)
    details = {"freq": freq, "exact": p_model, "n_eff": n_eff, "p_model": p_val_model, "freq_pair": freq_pair,
               "exact_pair": p_pair, "p_pair": p_val_pair}
    print(details)
    assert min(p_model) > 0.02, "the exact posterior should spread over the models for the test to bite"
    assert p_val_model > LEVEL, details
    assert p_val_pair > LEVEL, details


def test_coarsened_posterior_matches_exact_tempered_posterior(setup):
    """likelihood ** 0.4 (the coarsened posterior): models and change points vs the tempered enumeration.

    Also checks that the test bites: the tempered exact posterior differs from the plain one.
    """
    obs, prior, _, quad = setup
    zeta = 0.4
    tempered = exact_changepoint_posterior(Quadrature(obs, prior, likelihood_power=zeta))
    plain = exact_changepoint_posterior(quad)
    problem = Problem.from_observations(obs, likelihood_power=zeta)
    config = SamplerConfig.from_flat(max_u=1, max_v=1, jump_prob=1.0, cp_step=1.0, cp_uniform_prob=0.3, burn_in=0,
                           cp_prior="paper")
    models, u0, _ = run(problem, prior, config, 12000, 4)
    p_model, p_u, details = _model_and_cp_tests(models[1200:], u0[1200:], tempered)
    print("tempered", details)
    assert max(abs(sum(p for k, p in tempered.items() if k[:2] == m) - sum(p for k, p in plain.items() if k[:2] == m))
               for m in [(0, 0), (0, 1), (1, 0), (1, 1)]) > 0.05
    assert p_model > LEVEL, details
    assert p_u > LEVEL, details
