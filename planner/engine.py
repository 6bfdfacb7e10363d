"""The one place that runs many independent, seeded tasks: in-process, or on Dask.

:func:`run_tasks` calls ``func(shared, *args)`` for every ``args`` of a list and
returns the results in the list's order.  Where they run:

- ``jobs == 1`` and no scheduler: a plain loop in this process (no Dask at all);
- ``jobs > 1``: a private ``distributed.LocalCluster`` of ``jobs`` single-threaded
  worker processes, no dashboard, closed on any exit (an exception, Ctrl-C, SIGTERM);
- ``scheduler="tcp://host:port"``: a ``distributed.Client`` on an existing cluster; the
  cluster is left running, only this run's tasks are cancelled on an exception.

``shared`` (e.g. a plan) is sent to every worker once (``Client.scatter(broadcast=True)``),
not with each task.  Results never depend on where or in which order tasks ran: every
task must take its randomness from its own arguments (a seed and its index), never
from global state.
"""

from __future__ import annotations

import contextlib
import logging
from typing import Any, Callable, Sequence

#: Seconds to wait for a LocalCluster / Client to close.
CLOSE_TIMEOUT_S = 10


@contextlib.contextmanager
def dask_client(jobs: int = 1, scheduler: str | None = None):
    """A ``distributed.Client``: on ``scheduler`` if given, else on a private quiet
    ``LocalCluster`` of ``jobs`` single-threaded processes; closed when the block ends."""
    from distributed import Client, LocalCluster

    if scheduler:
        client = Client(scheduler, timeout="20s")
        try:
            yield client
        finally:
            client.close(timeout=CLOSE_TIMEOUT_S)
        return
    cluster = LocalCluster(n_workers=int(jobs), threads_per_worker=1, processes=True,
                           dashboard_address=None, silence_logs=logging.ERROR)
    try:
        client = Client(cluster)
        try:
            yield client
        finally:
            client.close(timeout=CLOSE_TIMEOUT_S)
    finally:
        cluster.close(timeout=CLOSE_TIMEOUT_S)


def run_tasks(func: Callable, shared: Any, args_list: Sequence[tuple], *, jobs: int = 1,
              scheduler: str | None = None, progress: Callable | None = None) -> list:
    """``[func(shared, *args) for args in args_list]``, in process or on Dask.

    Parameters
    ----------
    func : callable
        A module-level function (workers import it by name).
    shared : object
        Passed to every call; sent to each worker once.
    args_list : sequence of tuple
        One tuple of further arguments per task.
    jobs : int
        Worker processes of the local cluster (>= 1); 1 runs in this process.
    scheduler : str, optional
        Address of an existing ``dask.distributed`` scheduler; overrides ``jobs``.
    progress : callable, optional
        Called with no argument after each finished task (in completion order).

    Returns
    -------
    list
        The results, in the order of ``args_list``.

    Raises
    ------
    ValueError
        ``jobs`` < 1.
    """
    jobs = int(jobs)
    if jobs < 1:
        raise ValueError(f"jobs must be >= 1, {jobs} was given")
    tick = progress or (lambda: None)
    if jobs == 1 and not scheduler:
        out = []
        for args in args_list:
            out.append(func(shared, *args))
            tick()
        return out
    from distributed import as_completed

    with dask_client(jobs, scheduler) as client:
        futures = []
        try:
            remote = client.scatter(shared, broadcast=True)
            futures = [client.submit(func, remote, *args, pure=False) for args in args_list]
            index = {f.key: i for i, f in enumerate(futures)}
            out = [None] * len(futures)
            for fut in as_completed(futures):
                out[index[fut.key]] = fut.result()
                tick()
            return out
        except BaseException:
            # stop this run's tasks at once (a shared cluster keeps running)
            with contextlib.suppress(Exception):
                client.cancel(futures, force=True)
            raise
