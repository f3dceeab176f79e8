"""The Dask cluster a fleet job runs on: an embedded LocalCluster, or an existing scheduler.

::

    with fleet_client() as client:                          # LocalCluster sized to the cores
        ...
    with fleet_client("tcp://10.0.0.5:8786") as client:     # a real cluster, same code
        ...

No option and no ``CNCTWIN_SCHEDULER`` in the environment: an embedded
:class:`distributed.LocalCluster` with one single-threaded worker process per core (the
analyses hold the GIL; processes, not threads, give parallel work). A scheduler address that
cannot be reached raises :class:`~cnctwin.exceptions.ClusterError`; there is no silent
fall-back to the embedded cluster.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any, TypeVar

from cnctwin.exceptions import ClusterError

__all__ = ["SCHEDULER_ENV", "WORKER_CONFIG", "fleet_client", "map_tasks"]

SCHEDULER_ENV = "CNCTWIN_SCHEDULER"
"""Environment variable naming the scheduler address when ``--scheduler`` is not given."""

T = TypeVar("T")


WORKER_CONFIG: dict[str, Any] = {
    # the statistical profiler samples the task's stack every 10 ms: ~25 % of a fleet task's
    # CPU; the dashboard's profile page is the only loss
    "distributed.worker.profile.enabled": False,
    # Dask's nanny gives workers MALLOC_TRIM_THRESHOLD_=65536: glibc then returns freed heap
    # to the system after nearly every analysis array and faults it back in for the next
    # (health: 29.5 s of worker CPU against 15.6 s in one process; 16-128 MiB: no difference
    # from the process)
    "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": 64 * 2**20,
}
"""Dask configuration of the embedded cluster's workers (docs/fleet.md gives it for workers
started by hand)."""


@contextmanager
def fleet_client(
    scheduler: str | None = None, *, n_workers: int | None = None, timeout_s: float = 10.0,
    memory_limit: str = "auto",
) -> Iterator[Any]:
    """A :class:`distributed.Client` for a fleet job; closed (with its cluster) on exit.

    Parameters
    ----------
    scheduler : str, optional
        Scheduler address (``tcp://HOST:8786``); default ``$CNCTWIN_SCHEDULER``, else an
        embedded LocalCluster.
    n_workers : int, optional
        Worker processes of the embedded cluster; default the CPU count.
    timeout_s : float, default 10
        How long to try to reach the scheduler [s].
    memory_limit : str, default 'auto'
        Memory limit per embedded worker (Dask syntax, e.g. ``"4GiB"``).

    Yields
    ------
    distributed.Client

    Raises
    ------
    ClusterError
        If the scheduler cannot be reached within ``timeout_s``.
    """
    from distributed import Client, LocalCluster

    address = scheduler or os.environ.get(SCHEDULER_ENV) or None
    if address is not None:
        try:
            client = Client(address, timeout=f"{timeout_s}s")
        except (OSError, TimeoutError) as exc:
            raise ClusterError(
                f"cannot reach the Dask scheduler at {address} ({exc}); start one with "
                "`dask scheduler` and `dask worker ADDRESS`, or leave --scheduler and "
                f"{SCHEDULER_ENV} unset to run on an embedded cluster"
            ) from None
        try:
            yield client
        finally:
            client.close()
        return
    n = n_workers or os.cpu_count() or 1
    import logging

    # silence_logs: the workers' own shutdown chatter ("failed to communicate with scheduler
    # during heartbeat" as the cluster closes) is not for the user; task errors reach the
    # client and are raised there
    import dask

    # WORKER_CONFIG: without it a fleet task cost its worker 1.9x the CPU it costs in this
    # process (docs/fleet.md)
    with dask.config.set(WORKER_CONFIG):
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                               memory_limit=memory_limit, dashboard_address=":0",
                               silence_logs=logging.CRITICAL)
    client = Client(cluster)
    try:
        yield client
    finally:
        client.close()
        cluster.close()


def map_tasks(
    client: Any, fn: Callable[..., T], items: Sequence[Any], *, key: str,
    progress: Callable[[int, int], None] | None = None, retries: int = 2, **kwargs: Any,
) -> list[T]:
    """Run ``fn(item, **kwargs)`` for every item on the cluster; results in item order.

    Tasks are pure and keyed by the job name and position, so a task lost with its worker is
    run again by the scheduler (and ``retries`` more times if it raises), and the result does
    not depend on which worker ran what.

    Parameters
    ----------
    client : distributed.Client
        The cluster (:func:`fleet_client`).
    fn : callable
        Task function (module level, importable on the workers).
    items : sequence
        One task per item.
    key : str
        Job name (prefix of the task keys, shown on the dashboard).
    progress : callable, optional
        ``progress(done, total)`` after each finished task.
    retries : int, default 2
        Retries of a task that raises.
    **kwargs
        Passed to every call.

    Returns
    -------
    list
        ``fn(item, **kwargs)`` per item.
    """
    from distributed import as_completed

    if not items:
        return []
    import uuid

    run = uuid.uuid4().hex[:8]
    keys = [f"{key}-{run}-{i}" for i in range(len(items))]
    futures = [client.submit(fn, item, key=k, retries=retries, pure=False, **kwargs)
               for item, k in zip(items, keys, strict=True)]
    index = {f.key: i for i, f in enumerate(futures)}
    out: list[Any] = [None] * len(items)
    done = 0
    try:
        for fut in as_completed(futures):
            out[index[fut.key]] = fut.result()
            done += 1
            if progress is not None:
                progress(done, len(items))
    finally:
        for f in futures:
            f.release()
    return out
