"""Worker processes that never outlive the run that started them, and the BLAS thread
pin that makes a task's result independent of the process it ran in.

:func:`process_pool` is a ``concurrent.futures.ProcessPoolExecutor`` (spawn context)
whose workers ignore SIGINT (Ctrl-C reaches the whole process group; the parent
decides) and are terminated, not waited for, when the block ends with an exception:
an interrupted plan stops within a second instead of waiting for every running design
to finish, and a SIGTERM to the main process leaves no orphaned worker behind.  A main
process that dies without running any clean-up (SIGKILL, the OOM killer, a crash) is
noticed by the workers themselves: each watches its parent (:func:`watch_parent`) and
exits within :data:`PARENT_POLL_S` of its death, and the resource tracker, whose pipe
they held open, exits with them.

:func:`single_thread_blas` runs a block with BLAS limited to one thread: the
designer's SQP (scipy) moves in its 8th significant digit with the BLAS thread count, which
differs between the main process (all cores), the spawned pool workers and Dask workers
(``OMP/OPENBLAS/MKL_NUM_THREADS=1``); pinned to one thread, every path computes the same
digits.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import importlib
import multiprocessing
import os
import signal
import threading
import time

#: Seconds to wait for a terminated worker before killing it.
TERMINATE_WAIT_S = 1.0
#: Seconds between a worker's checks that the process that started it still lives.
PARENT_POLL_S = 0.5
#: Exit status of a worker that found its parent gone.
ORPHANED_EXIT = 70


#: Blocks inside :func:`single_thread_blas` in this process, and the limiter that the first
#: of them started (restored when the last one ends: the BLAS thread count is global to the
#: process, so a block in one thread must not restore it while another still runs).
_blas_lock = threading.Lock()
_blas_depth = 0
_blas_limiter = None


@contextlib.contextmanager
def single_thread_blas():
    """Run the block with the BLAS thread pools (numpy's and scipy's) limited to one thread.

    Reentrant and safe across threads of one process: the limit holds from the first
    entry to the last exit, then the previous thread counts come back.
    """
    # threadpoolctl limits the libraries loaded so far: load numpy's and scipy's BLAS first
    import numpy  # noqa: F401
    import scipy.linalg  # noqa: F401
    from threadpoolctl import threadpool_limits

    global _blas_depth, _blas_limiter
    with _blas_lock:
        if _blas_depth == 0:
            _blas_limiter = threadpool_limits(limits=1, user_api="blas")
        _blas_depth += 1
    try:
        yield
    finally:
        with _blas_lock:
            _blas_depth -= 1
            if _blas_depth == 0:
                _blas_limiter.restore_original_limits()
                _blas_limiter = None


def watch_parent(parent_pid: int, poll_s: float = PARENT_POLL_S) -> threading.Thread:
    """Exit this process (``os._exit``, no clean-up to hang in) once ``parent_pid`` is no
    longer its parent: the parent died and the process was re-parented.

    A daemon thread polls ``os.getppid()`` every ``poll_s`` seconds; it costs nothing
    measurable beside a design.  Returns the thread.
    """
    def watch():
        while os.getppid() == parent_pid:
            time.sleep(poll_s)
        os._exit(ORPHANED_EXIT)

    thread = threading.Thread(target=watch, name="vibroplan-watch-parent", daemon=True)
    thread.start()
    return thread


def _init_worker(parent_pid: int, preload=()):
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    watch_parent(parent_pid)
    for name in preload:
        # what the tasks will import, imported as the worker starts (beside the parent's
        # own work) rather than when the first task arrives
        importlib.import_module(name)


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
    # the pool's manager thread sees its workers gone and closes its wake-up pipe; let it
    # finish before the interpreter exits: concurrent.futures' exit hook writes to that
    # pipe without the pool's lock, and a close between its check and its write printed
    # "OSError: [Errno 9] Bad file descriptor" after a SIGTERM (seen under load)
    manager = getattr(pool, "_executor_manager_thread", None)
    if manager is not None and manager.is_alive():
        manager.join(TERMINATE_WAIT_S)


@contextlib.contextmanager
def process_pool(jobs: int):
    """A process pool of ``jobs`` spawned workers, terminated on any exception."""
    ctx = multiprocessing.get_context("spawn")
    pool = cf.ProcessPoolExecutor(max_workers=jobs, mp_context=ctx, initializer=_init_worker,
                                  initargs=(os.getpid(),))
    try:
        yield pool
    except BaseException:
        terminate(pool)
        raise
    pool.shutdown(wait=True)


class WarmPool:
    """A process pool whose first worker runs a warm-up (numba's compilation) while the
    caller goes on with other work; the first task submitted waits for it, so that no
    second worker compiles the same kernels at the same time.

    Used through :func:`warm_pool`.  The workers are started by :meth:`start` (at once
    when the pool is made eager) or by the first :meth:`submit` or :meth:`wait_warm`:
    a plan read wholly from the design cache starts none.  ``pool`` is the
    ``ProcessPoolExecutor`` (None until started).
    """

    def __init__(self, jobs: int, warm_up=None, preload=()):
        self.jobs = int(jobs)
        self.pool = None
        self._warm_up = warm_up
        self._warm = None
        self._preload = tuple(preload)
        self._ready = None

    def start(self) -> "WarmPool":
        """Start the workers (and the warm-up in the first) if not started yet."""
        if self.pool is None:
            ctx = multiprocessing.get_context("spawn")
            self.pool = cf.ProcessPoolExecutor(max_workers=self.jobs, mp_context=ctx,
                                               initializer=_init_worker,
                                               initargs=(os.getpid(), self._preload))
            if self._preload:
                # every worker starts now, each importing what the tasks need while the
                # parent goes on: the executor spawns a worker per task submitted while
                # none is idle, so one no-op task per worker; they answer once the
                # workers have imported
                self._ready = [self.pool.submit(os.getpid) for _ in range(self.jobs)]
            if self._warm_up is not None:
                self._warm = self.pool.submit(self._warm_up)
        return self

    def wait_warm(self) -> float | None:
        """Wait for the warm-up (starting the workers if need be); its result (None if
        there was none, or once read)."""
        self.start()
        warm, self._warm = self._warm, None
        return None if warm is None else warm.result()

    def warming(self) -> bool:
        """Whether the workers are still importing what their tasks need (a pool with
        ``preload``, none of whose workers has yet; the workers are started if they were
        not): the caller may do a task itself meanwhile rather than wait for them."""
        self.start()
        return self._ready is not None and not any(f.done() for f in self._ready)

    def submit(self, fn, /, *args, **kwargs) -> cf.Future:
        self.wait_warm()
        return self.pool.submit(fn, *args, **kwargs)


@contextlib.contextmanager
def warm_pool(jobs: int, warm_up=None, *, eager=True, preload=()):
    """A :class:`WarmPool` of ``jobs`` spawned workers, one of which starts ``warm_up()``
    (a picklable function of no arguments) as soon as the workers start: at once when
    ``eager``, else at the first task.  Terminated on any exception, shut down (waiting
    for its tasks) on leaving."""
    wp = WarmPool(jobs, warm_up, preload)
    if eager:
        wp.start()
    try:
        yield wp
    except BaseException:
        if wp.pool is not None:
            terminate(wp.pool)
        raise
    if wp.pool is not None:
        wp.pool.shutdown(wait=True)
