"""Independent work on a Dask cluster: chains of a fit, candidate refits, batches of fits.

rjfit does not schedule work itself: every unit of independent work is a picklable
function of one picklable argument (a chain spec with its checkpoint path, say), and Dask
distributed runs the list, on a local cluster by default or on an existing scheduler.
Results are independent of where a unit runs: each draws only from its own seed. A worker
lost mid-task makes the scheduler run the task again elsewhere; a chain then resumes from
its last checkpoint (on storage every worker can reach), so nothing is lost and the
samples equal those of an uninterrupted serial run.
"""
from __future__ import annotations

from contextlib import contextmanager

__all__ = ["dask_client", "dask_map"]

CONNECT_TIMEOUT_S = 10     # seconds to wait for a scheduler before saying it cannot be reached


@contextmanager
def dask_client(scheduler: str | None = None, *, n_workers: int = 2):
    """A Dask client: on ``scheduler`` (an address such as ``tcp://10.0.0.5:8786``) or, when
    None, on a local cluster of ``n_workers`` single-threaded worker processes on loopback.

    Raises
    ------
    ValueError
        If ``n_workers`` is not positive.
    """
    from dask.distributed import Client, LocalCluster

    if scheduler is not None:
        try:
            client = Client(scheduler, timeout=CONNECT_TIMEOUT_S)
        except (OSError, TimeoutError) as error:
            raise ValueError(f"cannot reach the Dask scheduler at {scheduler} ({error}); start one with "
                             f"`dask scheduler`, check the address, or use --scheduler local") from None
        try:
            yield client
        finally:
            client.close()
        return
    if n_workers < 1:
        raise ValueError(f"n_workers must be >= 1, got {n_workers}")
    # One thread per worker: the chains are single-threaded numpy and Mitsuba is not
    # thread-safe across variants; processes keep them apart.
    cluster = LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                           dashboard_address=None)
    client = Client(cluster)
    try:
        yield client
    finally:
        client.close()
        cluster.close()


def dask_map(function, items, *, scheduler: str | None = None, n_workers: int = 2, client=None, retries: int = 3,
             key_prefix: str = "rjfit"):
    """``[function(item) for item in items]`` on Dask; results in input order.

    Parameters
    ----------
    function : callable
        Importable (module-level) function of one argument.
    items : iterable
        Picklable arguments.
    scheduler, n_workers
        See :func:`dask_client`; ignored when ``client`` is given.
    retries : int
        How often a task whose worker died is run again (each run resumes from the task's
        own checkpoint if it writes one).
    """
    import uuid

    items = list(items)
    # Keys unique per call: a shared scheduler would otherwise hand back another call's results.
    batch = uuid.uuid4().hex[:12]

    def submit_all(active):
        futures = [active.submit(function, item, key=f"{key_prefix}-{batch}-{index}", retries=retries, pure=False)
                   for index, item in enumerate(items)]
        return active.gather(futures)

    if client is not None:
        return submit_all(client)
    with dask_client(scheduler, n_workers=n_workers) as local_client:
        return submit_all(local_client)
