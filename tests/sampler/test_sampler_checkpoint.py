"""Checkpoint / resume: a resumed chain yields exactly the samples of an uninterrupted run."""
import os
import pickle
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from rjfit.data.synthetic import sphere_stack
from rjfit.sampler.forward import Problem
from rjfit.sampler.priors import make_prior
from rjfit.sampler.runner import ChainSpec, run_chain
from rjfit.sampler.state import SamplerConfig

ITERATIONS = 400


def _spec(checkpoint_path=None, **kwargs):
    obs, labels, _ = sphere_stack(16, n_lights=5, seed=2)
    problem = Problem.from_observations(obs)
    prior = make_prior("default", y=problem.y, diffuse_scale=problem.A)
    config = SamplerConfig.from_flat(max_u=2, max_v=2, burn_in=100, jump_prob=0.5, split_scale=0.5)
    return ChainSpec(problem=problem, prior=prior, config=config, seed=123, chain=1, n_chains=3,
                     iterations=ITERATIONS, checkpoint_path=checkpoint_path, checkpoint_every=25, cp_thin=5,
                     truth_labels=labels, **kwargs)


def _assert_same(a, b):
    for name in ("n_u", "n_v", "theta", "log_lik", "log_post", "exact_truth", "cp_iteration", "cp_u", "cp_v",
                 "jumped"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.accepted == b.accepted and a.proposed == b.proposed


@pytest.fixture(scope="module")
def uninterrupted():
    return run_chain(_spec())


MARKER = 12345.678


def _mark(path):
    """Put a marker into the checkpoint's record of iteration 0: a resume carries it into its
    result, a restart (which would give the same samples, the run being seeded) does not."""
    with open(path, "rb") as handle:
        payload = pickle.load(handle)
    payload["recorder"].log_lik[0] = MARKER
    with open(path, "wb") as handle:
        pickle.dump(payload, handle)
    return payload["t"]


def _assert_resumed(uninterrupted, resumed):
    assert resumed.log_lik[0] == MARKER, "the chain restarted instead of resuming its checkpoint"
    assert uninterrupted.resumed_from == () and len(resumed.resumed_from) == 1
    resumed.log_lik[0] = uninterrupted.log_lik[0]
    _assert_same(uninterrupted, resumed)


def test_resume_after_stop_yields_identical_samples(tmp_path, uninterrupted):
    path = str(tmp_path / "chain.pkl")
    partial = run_chain(_spec(path, stop_after=137))     # "crashes" after 137 iterations
    assert partial.iterations_done == 137
    assert _mark(path) == 125
    resumed = run_chain(_spec(path))                      # resumes from the checkpoint at 125
    _assert_resumed(uninterrupted, resumed)


def test_a_checkpoint_from_before_the_jump_record_resumes_with_its_past_unknown(tmp_path, uninterrupted):
    """A recorder pickled before ChainRecord.jumped existed: the resumed chain records its earlier
    iterations as jumps (unknown: their draws then count through their own snapshots only) and
    its later ones as they happen."""
    path = str(tmp_path / "chain.pkl")
    run_chain(_spec(path, stop_after=137))
    with open(path, "rb") as handle:
        payload = pickle.load(handle)
    del payload["recorder"].jumped
    with open(path, "wb") as handle:
        pickle.dump(payload, handle)
    resumed = run_chain(_spec(path))
    t = payload["t"]
    assert np.all(resumed.jumped[:t] == 1)
    np.testing.assert_array_equal(resumed.jumped[t:], uninterrupted.jumped[t:])
    np.testing.assert_array_equal(resumed.theta, uninterrupted.theta)


def test_resume_after_sigkill_yields_identical_samples(tmp_path, uninterrupted):
    path = tmp_path / "chain.pkl"
    spec_file = tmp_path / "spec.pkl"
    spec_file.write_bytes(pickle.dumps(_spec(str(path), stop_after=None)))
    code = ("import pickle, sys; from rjfit.sampler.runner import run_chain; "
            f"run_chain(pickle.load(open({str(spec_file)!r}, 'rb')))")
    proc = subprocess.Popen([sys.executable, "-c", code], cwd=os.getcwd())
    try:
        deadline = time.time() + 120
        # kill it as soon as its first checkpoint (iteration 25 of 400) is there: mid-run
        while not path.exists() and time.time() < deadline and proc.poll() is None:
            time.sleep(0.005)
        assert proc.poll() is None, "the chain ended before its first checkpoint was seen"
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == -signal.SIGKILL
    done_at_kill = _mark(path)
    assert 0 < done_at_kill < ITERATIONS
    resumed = run_chain(_spec(str(path)))
    _assert_resumed(uninterrupted, resumed)


def test_seeded_runs_are_reproducible_and_chains_differ(uninterrupted):
    again = run_chain(_spec())
    _assert_same(uninterrupted, again)
    spec = _spec()
    spec.chain = 0
    other = run_chain(spec)
    assert not np.array_equal(other.log_lik, uninterrupted.log_lik)


def test_checkpoint_of_another_run_is_refused(tmp_path):
    """A checkpoint left by other settings is not resumed (it would mix two chains): the error names it and why."""
    path = str(tmp_path / "chain.pkl")
    run_chain(_spec(path, stop_after=30))
    other_seed = _spec(path)
    other_seed.seed = 124
    with pytest.raises(ValueError, match=r"chain\.pkl belongs to another run \(its chain differs"):
        run_chain(other_seed)
    other_config = _spec(path)
    other_config.config = SamplerConfig.from_flat(max_u=2, max_v=2, burn_in=100, jump_prob=0.3, split_scale=0.5)
    with pytest.raises(ValueError, match="its config differs"):
        run_chain(other_config)
    other_data = _spec(path)
    other_data.problem = Problem.from_observations(sphere_stack(16, n_lights=5, seed=3)[0])
    with pytest.raises(ValueError, match="its data differs"):
        run_chain(other_data)


@pytest.mark.parametrize("content", [b"garbage\n", b"", b"\x80\x04N."])   # text, empty, a pickled None
def test_an_unreadable_checkpoint_is_named_not_a_traceback(tmp_path, content):
    path = tmp_path / "chain.pkl"
    path.write_bytes(content)
    with pytest.raises(ValueError, match=r"checkpoint .*chain\.pkl (is unreadable|has version None).*delete it"):
        run_chain(_spec(str(path)))


def test_run_fingerprint_depends_on_content_not_on_print_options():
    """The digests read values (arrays by their bytes, floats exactly), not reprs that NumPy's print options change."""
    from rjfit.sampler.runner import run_fingerprint

    before = run_fingerprint(_spec("x"))
    with np.printoptions(precision=2, legacy="1.13"):
        assert run_fingerprint(_spec("x")) == before
    nudged = _spec("x")
    nudged.problem.y[7] = np.nextafter(nudged.problem.y[7], np.float32(np.inf))     # one ulp of one observation
    assert run_fingerprint(nudged)["data"] != before["data"]


def test_a_chain_gives_the_same_samples_on_one_thread_and_on_two():
    """Threads within a chain cut its large passes into fixed pieces (rjfit.sampler.passes.sums), so the
    samples do not depend on the number of threads: checked on a problem large enough for them."""
    import numba

    from rjfit.sampler.passes import sums

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("Numba has one thread here: nothing to compare")
    obs, labels, _ = sphere_stack(96, n_lights=10, seed=2)
    problem = Problem.from_observations(obs)
    assert problem.n_obs >= sums.PARALLEL_MIN_OBS
    prior = make_prior("default", y=problem.y, diffuse_scale=problem.A)
    config = SamplerConfig.from_flat(max_u=2, max_v=2, burn_in=40, jump_prob=0.5)
    spec = ChainSpec(problem=problem, prior=prior, config=config, seed=5, chain=0, n_chains=2, iterations=80,
                     cp_thin=5, truth_labels=labels)
    one, two = run_chain(spec, threads=1), run_chain(spec, threads=2)
    _assert_same(one, two)
    assert sum(one.proposed.values()) > 0 and len(set(zip(one.n_u, one.n_v))) > 1, "the chain must move between models"


def test_a_lone_chain_takes_the_free_cores_unless_threads_would_not_pay(monkeypatch):
    """run_chains' default: the cores the chains at once leave free, but one thread where Numba
    could only fall back to its workqueue layer (no OpenMP or TBB runtime: threads made it slower)."""
    import dataclasses
    import importlib

    import numba

    from rjfit.sampler import runner

    spec = dataclasses.replace(_spec(), iterations=20, checkpoint_path=None)
    expected = min(runner.available_cores(), numba.config.NUMBA_NUM_THREADS)
    assert [r.threads for r in runner.run_chains([spec])] == [expected]
    assert [r.threads for r in runner.run_chains([spec], threads=1)] == [1]

    real_import = importlib.import_module

    def without_thread_runtimes(name, *args, **kwargs):
        if name in ("numba.np.ufunc.omppool", "numba.np.ufunc.tbbpool"):
            raise ImportError(f"{name}: its runtime library is not installed (simulated)")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(importlib, "import_module", without_thread_runtimes)
    assert not runner.threads_pay()
    assert [r.threads for r in runner.run_chains([spec])] == [1]
