"""The pixel blocks and the thinning of chains.nc's log_likelihood group (rjfit.posterior.inference_data)."""
import numpy as np

from rjfit.data.synthetic import sphere_stack
from rjfit.posterior import inference_data
from rjfit.sampler.forward import Problem


def test_a_large_object_is_cut_into_at_most_the_cap_of_square_blocks():
    obs, _, _ = sphere_stack(64, n_lights=4, seed=1)
    problem = Problem.from_observations(obs)
    observed = np.diff(problem.pixel_start).reshape(problem.image_shape) > 0
    assert observed.sum() > inference_data.LOG_LIK_POINTS_MAX      # the case under test: more pixels than blocks
    blocks, side = inference_data.pixel_blocks(problem)
    n_blocks = blocks.max() + 1
    assert side == 2 and n_blocks <= inference_data.LOG_LIK_POINTS_MAX
    # every observed pixel in exactly one block, every block used, a block within one side x side square
    assert np.all((blocks >= 0) == observed) and np.unique(blocks[observed]).size == n_blocks
    rows, cols = np.nonzero(observed)
    for block in (0, n_blocks // 2, n_blocks - 1):
        mine = blocks[rows, cols] == block
        assert np.ptp(rows[mine]) < side and np.ptp(cols[mine]) < side
        assert len({r // side for r in rows[mine]}) == 1 and len({c // side for c in cols[mine]}) == 1


def test_a_small_object_keeps_one_pixel_per_block():
    obs, _, _ = sphere_stack(16, n_lights=4, seed=1)
    problem = Problem.from_observations(obs)
    blocks, side = inference_data.pixel_blocks(problem)
    assert side == 1 and blocks.max() + 1 == np.count_nonzero(np.diff(problem.pixel_start))


class _Record:
    def __init__(self, snapshots):
        self.cp_iteration = np.arange(0, 10 * snapshots, 10)


def test_the_draws_are_thinned_evenly_to_the_cap_of_values():
    records = [_Record(400), _Record(390)]          # chains of unequal length: cut to the shorter one's
    chosen = inference_data._snapshot_draws(records, burn_in=1000, n_points=2000)
    most = inference_data.LOG_LIK_VALUES_MAX // (2 * 2000)
    assert len(chosen[0]) == len(chosen[1]) <= most and len(chosen[0]) > most // 2
    assert np.all(records[0].cp_iteration[chosen[0]] >= 1000) and np.ptp(np.diff(chosen[0])) == 0


def test_the_blocks_density_is_the_per_observation_oracle_summed_per_block():
    """The per-draw density written to chains.nc (factors taken per row of theta, one exponential per
    observation) against the oracle that evaluates eq. 1-2 term by term, with known noise scales and four
    regions of different parameters. Tolerance 1e-10 relative: the two differ only in the order of float64
    operations (about 1e-16 per observation); a wrong factor, row or scale moves a block by far more."""
    from rjfit.sampler.likelihood import observation_log_likelihood
    obs, labels, truth = sphere_stack(16, n_lights=5, seed=2)
    rng = np.random.default_rng(3)
    problem = Problem.from_observations(obs, noise_scale=rng.uniform(0.5, 2.0, obs.n_obs))
    rows = labels.ravel()[problem.pixel]
    theta = np.array([[t["I0"], t["kd"], t["gamma"], t["sigma2"]] for t in truth])
    theta *= rng.uniform(0.8, 1.2, theta.shape)         # off the truth: the residuals are not noise alone
    blocks, _ = inference_data.pixel_blocks(problem)
    block = blocks.ravel()[problem.pixel]
    n_blocks = int(block.max()) + 1
    expected = np.bincount(block, weights=observation_log_likelihood(problem, rows, theta), minlength=n_blocks)
    got = inference_data._BlockLikelihood(problem, block, n_blocks)(rows, theta)
    np.testing.assert_allclose(got, expected, rtol=1e-10)
    plain = Problem.from_observations(obs)
    expected = np.bincount(block, weights=observation_log_likelihood(plain, rows, theta), minlength=n_blocks)
    np.testing.assert_allclose(inference_data._BlockLikelihood(plain, block, n_blocks)(rows, theta), expected,
                               rtol=1e-10)
