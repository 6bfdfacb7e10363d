"""Worker processes that never outlive the run that started them.

:func:`process_pool` is a ``concurrent.futures.ProcessPoolExecutor`` (spawn context)
whose workers ignore SIGINT (Ctrl-C reaches the whole process group; the parent
decides) and are terminated, not waited for, when the block ends with an exception:
an interrupted plan stops within a second instead of waiting for every running design
to finish, and a SIGTERM to the main process leaves no orphaned worker behind.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import multiprocessing
import signal

#: Seconds to wait for a terminated worker before killing it.
TERMINATE_WAIT_S = 1.0


def _ignore_sigint():
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def terminate(pool: cf.ProcessPoolExecutor) -> None:
    """Stop every worker of ``pool`` now and drop the queued tasks."""
    procs = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        if p.is_alive():
            p.terminate()
    for p in procs:
        p.join(TERMINATE_WAIT_S)
        if p.is_alive():
            p.kill()
            p.join(TERMINATE_WAIT_S)


@contextlib.contextmanager
def process_pool(jobs: int):
    """A process pool of ``jobs`` spawned workers, terminated on any exception."""
    ctx = multiprocessing.get_context("spawn")
    pool = cf.ProcessPoolExecutor(max_workers=jobs, mp_context=ctx, initializer=_ignore_sigint)
    try:
        yield pool
    except BaseException:
        terminate(pool)
        raise
    pool.shutdown(wait=True)
