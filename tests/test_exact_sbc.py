"""Simulation-based calibration (Talts et al. 2018) for the parameters of a fixed segmentation.

For each of N replicates: draw theta from the prior, simulate the 12 observations of the
tiny 2 x 2 problem (one region), run the default sampler from an independent prior draw,
discard a burn-in and keep L = 19 draws thinned by 20 iterations (well beyond the chain's
autocorrelation time here, so the draws are close to independent), and record the rank of
the true value among them. If the sampler draws from the posterior, each parameter's ranks
are uniform on {0, ..., L}. Uniformity is tested by a chi-square test on 5 bins of 4 ranks
at level 0.001 per parameter (fixed seed). A sampler that, for example, left out the
log-Jacobian of the phi transform or of the (a, b) coordinates fails this test.
"""
import numpy as np
from scipy import stats
from threadpoolctl import threadpool_limits

from rjfit.data.observations import Observations
from rjfit.model.blinn import radiance
from rjfit.sampler.kernel import initial_state, step
from rjfit.sampler.likelihood import Problem
from rjfit.sampler.state import SamplerConfig

from test_exact_rj import tiny_problem

REPLICATES, DRAWS, THIN, BURN = 100, 19, 20, 200


def test_sbc_ranks_are_uniform_for_a_fixed_segmentation():
    base, prior = tiny_problem()
    rng = np.random.default_rng(2024)
    config = SamplerConfig(max_u=0, max_v=0, update_changepoints=False, jumps=False, burn_in=BURN // 2)
    ranks = np.zeros((REPLICATES, 4), int)
    with threadpool_limits(1):
        for i in range(REPLICATES):
            theta = prior.sample(rng)
            mu = radiance(theta[0], theta[1], theta[2], base.cos_ln, base.cos_hn, base.irradiance)
            y = mu + rng.normal(0.0, np.sqrt(theta[3]), mu.shape)
            obs = Observations(image_shape=base.image_shape, n_lights=base.n_lights, pixel=base.pixel,
                               light=base.light, y=y, cos_ln=base.cos_ln, cos_hn=base.cos_hn,
                               irradiance=base.irradiance, object_mask=base.object_mask)
            problem = Problem.from_observations(obs)
            state = initial_state(problem, prior, config, rng, theta=prior.sample(rng)[None])
            draws = []
            for t in range(BURN + DRAWS * THIN):
                state, _ = step(state, rng, problem, prior, config)
                if t >= BURN and (t - BURN) % THIN == THIN - 1:
                    draws.append(state.theta[0].copy())
            ranks[i] = (np.array(draws) < theta).sum(axis=0)
    for k in range(4):
        counts = np.bincount(ranks[:, k] // 4, minlength=5)
        p_value = stats.chisquare(counts).pvalue
        assert p_value > 1e-3, (k, counts, p_value)
