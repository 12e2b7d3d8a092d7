"""The kernel's parts: the one accept step, a pure step (a chain's context changes no draw), the region records."""
import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from rjfit.data.synthetic import sphere_stack
from rjfit.sampler.forward import Problem
from rjfit.sampler.kernel import ChainContext, initial_state, log_posterior, step
from rjfit.sampler.moves.accept import accept
from rjfit.sampler.priors import ParamPrior, make_prior, to_phi
from rjfit.sampler.regions.base import RegionModel
from rjfit.sampler.regions.changepoints import ChangepointRegions
from rjfit.sampler.runner import ChainRecord, ChainRecorder, ChainSpec
from rjfit.sampler.state import SamplerConfig, StepInfo


@pytest.fixture(scope="module")
def small():
    obs, labels, _ = sphere_stack(20, n_lights=6, seed=3)
    problem = Problem.from_observations(obs)
    return problem, make_prior("default", y=problem.y, diffuse_scale=problem.A), labels


def test_accept_rejects_nan_and_counts_it():
    info = StepInfo()
    assert accept(-0.5, 0.0, info, "ab") and not accept(-0.5, -1.0, info, "ab")
    assert not accept(-0.5, -np.inf, info, "ab") and info.nan_rejected == {}        # invalid: a plain rejection
    assert not accept(-0.5, np.nan, info, "ab") and info.nan_rejected == {"ab": 1}
    decided = accept(np.log([0.5, 0.5, 0.5, 0.5]), np.array([0.0, np.nan, -np.inf, -2.0]), info, "cp_u")
    np.testing.assert_array_equal(decided, [True, False, False, False])
    assert info.nan_rejected == {"ab": 1, "cp_u": 1}


def _run(problem, prior, config, steps, context_per_chain):
    rng = np.random.default_rng(21)
    state = initial_state(problem, prior, config, rng)
    context = ChainContext() if context_per_chain else None
    states = []
    with threadpool_limits(1):
        for _ in range(steps):
            state, _ = step(state, rng, problem, prior, config, context)
            states.append(state)
    return states


def test_a_step_is_pure_the_context_only_saves_work(small):
    """The same seed with one context for the chain, or none (each step builds what it needs): the same states."""
    problem, prior, _ = small
    config = SamplerConfig.from_flat(max_u=2, max_v=2, burn_in=30, anneal=20, jump_prob=0.5, block_prob=0.3)
    with_context, without = _run(problem, prior, config, 60, True), _run(problem, prior, config, 60, False)
    for a, b in zip(with_context, without):
        np.testing.assert_array_equal(a.theta, b.theta)
        np.testing.assert_array_equal(a.layout.u, b.layout.u)
        np.testing.assert_array_equal(a.layout.v, b.layout.v)
        np.testing.assert_array_equal(a.labels, b.labels)
        assert a.log_g_scale == b.log_g_scale
    assert len({s.layout.model_key for s in with_context}) > 1, "the chain should change model"
    last = with_context[-1]
    expected = (np.sum(last.log_lik) + np.sum(prior.logpdf_phi(to_phi(last.theta)))
                + config.regions.prior.log_density(last.layout.u, last.layout.v, problem.image_shape))
    assert log_posterior(problem, prior, last, config) == pytest.approx(float(expected), rel=1e-15)



def test_a_start_outside_the_prior_s_support_is_refused(small):
    """From a state of zero density every ratio is -inf - (-inf) = NaN and the chain never moves: refused."""
    problem, prior, _ = small
    narrow = ParamPrior("uniform", 1e-9, 2e-9)        # far below the data's noise variance
    prior = type(prior)(params=prior.params[:3] + (narrow,))
    config = SamplerConfig.from_flat(max_u=1, max_v=1, update_changepoints=False, jumps=False)
    theta = np.tile([np.exp(prior.params[0].a), 0.5, 10.0, 1.0], (4, 1))       # sigma^2 = 1: outside the support
    with pytest.raises(ValueError, match=r"start of region 0: sigma2 = 1 lies outside its prior's support"):
        initial_state(problem, prior, config, np.random.default_rng(1), theta=theta, model=(1, 1))


def test_nan_rejections_reach_the_chain_record(small):
    """What the accept step counts reaches the record, per move kind, next to the proposals."""
    problem, prior, _ = small
    spec = ChainSpec(problem=problem, prior=prior, config=SamplerConfig.from_flat(max_u=1, max_v=1), seed=1, chain=0,
                     n_chains=1, iterations=3)
    recorder = ChainRecorder(spec)
    for decided in (0.0, np.nan, np.nan):
        info = StepInfo()
        info.count("vector_u", accept(-0.5, decided, info, "vector_u"))
        recorder.add_counts(info)
    record = recorder.result(0)
    assert record.nan_rejected == {"vector_u": 2}
    assert record.proposed == {"vector_u": 3} and record.accepted == {"vector_u": 1}


def test_the_region_model_names_the_records_fields():
    regions = ChangepointRegions(max_u=2, max_v=3)
    fields = set(ChainRecord.__dataclass_fields__)
    assert set(regions.key_names) <= fields
    problem = Problem.from_observations(sphere_stack(12, n_lights=4, seed=1)[0])
    shapes = regions.snapshot_shapes(problem)
    assert set(shapes) <= fields and shapes == {"cp_u": (12, 2), "cp_v": (12, 3)}
    assert regions.max_regions == 12
    with pytest.raises(ValueError, match="exceeds"):
        regions.initial_layout(problem, np.random.default_rng(0), model=(3, 0))
    with pytest.raises(TypeError):
        RegionModel()          # the contract is abstract
