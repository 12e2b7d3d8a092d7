"""Chains on a two-worker Dask cluster on loopback: same samples as serially, and a worker
killed mid-chain loses nothing (the chain resumes from its checkpoint on another worker)."""
import os
import signal
import time

import numpy as np
import pytest

from rjfit.data.synthetic import sphere_stack
from rjfit.pipeline.distributed import dask_client, dask_map
from rjfit.sampler.forward import Problem
from rjfit.sampler.priors import make_prior
from rjfit.sampler.runner import ChainSpec, run_chain
from rjfit.sampler.state import SamplerConfig

pytest.importorskip("dask.distributed")

ITERATIONS = 1500


def _specs(folder=None, n_chains=2):
    observations, labels, _ = sphere_stack(16, n_lights=5, seed=2)
    problem = Problem.from_observations(observations)
    prior = make_prior("default", y=problem.y, diffuse_scale=problem.A)
    config = SamplerConfig.from_flat(max_u=2, max_v=2, burn_in=200, jump_prob=0.5)
    return [ChainSpec(problem=problem, prior=prior, config=config, seed=11, chain=c, n_chains=n_chains,
                      iterations=ITERATIONS, checkpoint_path=None if folder is None else str(folder / f"chain_{c}.pkl"),
                      checkpoint_every=50, cp_thin=10, truth_labels=labels) for c in range(n_chains)]


def _assert_same(a, b):
    # resumed_from differs by design (it says whether a chain resumed)
    for name in ("n_u", "n_v", "theta", "log_lik", "log_post", "cp_u", "cp_v"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


@pytest.fixture(scope="module")
def serial_records():
    return [run_chain(spec) for spec in _specs()]


@pytest.fixture(scope="module")
def client():
    with dask_client(None, n_workers=2) as active:
        yield active


def test_two_worker_cluster_gives_the_serial_samples(client, serial_records):
    assert len(client.scheduler_info()["workers"]) == 2
    distributed = dask_map(run_chain, _specs(), client=client)
    for serial, remote in zip(serial_records, distributed):
        _assert_same(serial, remote)


def test_killed_worker_resumes_chain_from_checkpoint(client, serial_records, tmp_path):
    specs = _specs(tmp_path)
    futures = [client.submit(run_chain, spec, key=f"killed-{i}", retries=3, pure=False) for i, spec in enumerate(specs)]
    checkpoint = tmp_path / "chain_0.pkl"
    deadline = time.time() + 120
    while not checkpoint.exists() and time.time() < deadline:
        time.sleep(0.02)
    assert checkpoint.exists(), "chain 0 wrote no checkpoint in time"
    # Kill (SIGKILL, no clean-up) the worker process that runs chain 0.
    victim = next(address for address, keys in client.processing().items() if "killed-0" in keys)
    pid = client.run(os.getpid, workers=[victim])[victim]
    os.kill(pid, signal.SIGKILL)
    records = client.gather(futures)
    assert 0 < records[0].iterations_done == ITERATIONS
    # a resume, not a restart on another worker (which, seeded, would give the same samples)
    assert len(records[0].resumed_from) == 1 and 0 < records[0].resumed_from[0] < ITERATIONS, records[0].resumed_from
    for serial, recovered in zip(serial_records, records):
        _assert_same(serial, recovered)


def test_an_unreachable_scheduler_is_one_clear_error(monkeypatch):
    from rjfit.pipeline import distributed
    from rjfit.pipeline.distributed import dask_client

    monkeypatch.setattr(distributed, "CONNECT_TIMEOUT_S", 1)
    with pytest.raises(ValueError, match=r"cannot reach the Dask scheduler at tcp://127\.0\.0\.1:1 .*--scheduler local"):
        with dask_client("tcp://127.0.0.1:1"):
            pass
