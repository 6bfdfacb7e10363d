"""The one place that runs many independent, seeded tasks: in-process, or on Dask.

:func:`run_tasks` calls ``func(shared, *args)`` for every ``args`` of a list and
returns the results in the list's order.  Where they run:

- ``jobs == 1`` and no scheduler: a plain loop in this process (no Dask at all);
- ``jobs > 1``: a private ``distributed.LocalCluster`` of ``jobs`` single-threaded
  worker processes, no dashboard, closed on any exit (an exception, Ctrl-C, SIGTERM);
- ``scheduler="tcp://host:port"``: a ``distributed.Client`` on an existing cluster; the
  cluster is left running, only this run's tasks are cancelled on an exception.

Every connect and every wait is bounded: the address is checked first
(:func:`check_scheduler`: a well-formed address of a protocol a run can reach, and a
handshake within :data:`CONNECT_TIMEOUT_S` -- distributed's own ``Client(timeout=...)``
waits for ever on a peer that accepts the connection and never answers); a wait that
sees no task finish for :data:`PROGRESS_POLL_S` asks the scheduler whether it is still
there and gives up when it does not answer within :data:`REPLY_TIMEOUT_S`; a scheduler
that goes away mid-run ends the run.  Each of these is a
:class:`planner.core.errors.SchedulerError` naming the address (the CLI's exit 3).  Local
worker processes (``jobs > 1``) end with the main process however it ends: distributed
gives each a pipe from its parent and exits it when the pipe closes.

``shared`` (e.g. a plan) is sent to every worker once (``Client.scatter(broadcast=True)``),
not with each task.  Results never depend on where or in which order tasks ran: every
task must take its randomness from its own arguments (a seed and its index), never
from global state.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import os
import threading
from typing import Any, Callable, Sequence

from planner.core.errors import SchedulerError

#: Seconds to wait for a LocalCluster / Client to close.
CLOSE_TIMEOUT_S = 10
#: Seconds to connect to a scheduler, handshake included (the environment variable
#: ``VIBROPLAN_CONNECT_TIMEOUT_S`` overrides it, for a slow network or a test).
CONNECT_TIMEOUT_S = 20
#: Seconds without a finished task after which the scheduler is asked whether it lives.
PROGRESS_POLL_S = 30
#: Seconds a scheduler has to answer a request (that question, the shared data's upload).
REPLY_TIMEOUT_S = 60
#: Protocols of a scheduler that a run can reach (``inproc://`` lives inside one process).
PROTOCOLS = ("tcp", "tls", "ws", "wss", "ucx")


def check_scheduler(address: str) -> str:
    """Check that ``address`` is a dask.distributed scheduler that answers, before any work.

    Returns
    -------
    str
        The address.

    Raises
    ------
    ValueError
        Not an address a run can use (no ``host:port``, an ``inproc://`` address, an
        unknown protocol): bad input.
    planner.core.errors.SchedulerError
        Nothing answers there within :data:`CONNECT_TIMEOUT_S` (refused, unreachable,
        a peer that accepts and stays silent, a protocol this installation lacks).
    """
    text = str(address).strip()
    scheme, sep, loc = text.rpartition("://")
    if not sep:
        scheme, loc = "tcp", text
    if scheme not in PROTOCOLS:
        raise ValueError(f"--scheduler {address}: a scheduler is reached over "
                         f"{', '.join(p + '://' for p in PROTOCOLS)}, not {scheme}:// "
                         "(e.g. tcp://10.0.0.5:8786)")
    host, _, port = loc.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"--scheduler {address}: expected {scheme}://HOST:PORT, e.g. "
                         f"{scheme}://10.0.0.5:8786")
    if scheme == "tcp":
        _refused(host.strip("[]"), int(port), text)
    _probe(f"{scheme}://{loc}")
    return text


def _connect_timeout() -> float:
    """:data:`CONNECT_TIMEOUT_S`, or ``VIBROPLAN_CONNECT_TIMEOUT_S`` when set (> 0)."""
    text = os.environ.get("VIBROPLAN_CONNECT_TIMEOUT_S", "").strip()
    try:
        value = float(text)
    except ValueError:
        return CONNECT_TIMEOUT_S
    return value if 0 < value < 3600 else CONNECT_TIMEOUT_S


def _refused(host: str, port: int, address: str) -> None:
    """Refuse at once a TCP address where nothing listens (distributed's connect would
    retry a refused connection until its timeout, 20 s of a user's wait)."""
    import socket

    try:
        with socket.create_connection((host, port), timeout=_connect_timeout()):
            return
    except ConnectionRefusedError:
        raise SchedulerError(errno.ECONNREFUSED, "nothing listens there (connection "
                             "refused): no dask.distributed scheduler", address) from None
    except OSError:
        return   # unreachable, a name that does not resolve ...: the handshake says why


def _probe(address: str) -> None:
    """Connect to ``address`` and complete distributed's handshake within the timeout."""
    from distributed.comm import connect

    timeout = _connect_timeout()

    async def handshake():
        comm = await asyncio.wait_for(connect(address, timeout=timeout), timeout)
        await comm.close()

    box = {}

    def run():  # in a thread of its own: the caller may already run an event loop
        try:
            asyncio.run(handshake())
        except BaseException as exc:  # noqa: BLE001 - every failure is reported below
            box["error"] = exc

    thread = threading.Thread(target=run, name="vibroplan-scheduler-probe", daemon=True)
    thread.start()
    thread.join(timeout + 10)
    exc = box.get("error")
    if thread.is_alive() or isinstance(exc, (asyncio.TimeoutError, TimeoutError)):
        raise SchedulerError(errno.ETIMEDOUT, f"no dask.distributed scheduler answered within "
                             f"{timeout:g} s (is it a scheduler's address?)", address)
    if exc is not None:
        reason = (getattr(exc, "strerror", None) or str(exc).strip()
                  or type(exc).__name__).splitlines()[0]
        if isinstance(exc, TypeError) and "abstract" in reason:  # distributed without ucx
            reason = "this installation cannot speak its protocol"
        raise SchedulerError(errno.ECONNREFUSED, f"cannot connect to the scheduler: {reason}",
                             address)


@contextlib.contextmanager
def _quiet_distributed():
    """distributed's own log records (a lost connection, with its traceback) stay out of
    the user's terminal for the block: every failure reaches the caller as an exception."""
    names = ["distributed"] + [n for n in logging.root.manager.loggerDict
                               if n.startswith("distributed.")]
    saved = {n: logging.getLogger(n).level for n in names}
    for n in names:   # distributed gives some of its loggers levels of their own
        logging.getLogger(n).setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        for n, level in saved.items():
            logging.getLogger(n).setLevel(level)


@contextlib.contextmanager
def dask_client(jobs: int = 1, scheduler: str | None = None):
    """A ``distributed.Client``: on ``scheduler`` if given (checked with
    :func:`check_scheduler`), else on a private quiet ``LocalCluster`` of ``jobs``
    single-threaded processes; closed when the block ends."""
    with _quiet_distributed():
        with _client(jobs, scheduler) as client:
            yield client


@contextlib.contextmanager
def _signals_held():
    """Hold SIGINT, SIGTERM and SIGHUP back (recorded, not raised) for the block, and
    deliver the first one after it.

    A ``LocalCluster`` interrupted while it starts is left half-made with no name to
    close it by: its workers were orphaned, ``distributed``'s exit hook printed
    tracebacks, and a run could wait minutes for them (issue 44: ``yield --chips
    100000`` ignoring SIGTERM).  Held back, the signal arrives once the cluster is
    bound and inside the block that closes it.  Not in the main thread: nothing to do.
    """
    import signal

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    sigs = [signal.SIGINT, signal.SIGTERM] + ([signal.SIGHUP] if hasattr(signal, "SIGHUP")
                                              else [])
    got = []
    saved = {sig: signal.signal(sig, lambda signum, frame: got.append(signum))
             for sig in sigs}
    try:
        yield
    finally:
        for sig, old in saved.items():
            signal.signal(sig, old)
        if got:
            signal.raise_signal(got[0])


#: Dask settings of a private local cluster's workers (a worker process takes the
#: config its nanny had when it was made).  distributed sets ``MALLOC_TRIM_THRESHOLD_``
#: in a worker's environment before spawning it; set, it turns glibc's dynamic mmap
#: threshold off, so every array over 128 kB (a simulation's event buffers, a few a
#: run, thousands of runs a chip) was mapped and unmapped afresh, each page faulted in:
#: a fifth of a chip worker's CPU was system time.  Left unset (a user's own
#: ``MALLOC_TRIM_THRESHOLD_`` in the environment still passes through).  The worker's
#: statistical profiler (its stack sampled every 10 ms, for a dashboard a private
#: cluster does not have) is off.  Neither changes what a task computes.
LOCAL_WORKER_CONFIG = {
    "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
    "distributed.worker.profile.enabled": False,
}


@contextlib.contextmanager
def _client(jobs, scheduler):
    from distributed import Client, LocalCluster

    if scheduler:
        check_scheduler(scheduler)
        try:
            client = Client(scheduler, timeout=f"{CONNECT_TIMEOUT_S}s")
        except (OSError, asyncio.TimeoutError) as exc:
            raise SchedulerError(errno.ECONNREFUSED, f"cannot connect to the scheduler: {exc}",
                                 scheduler) from None
        try:
            yield client
        finally:
            with contextlib.suppress(Exception):
                client.close(timeout=CLOSE_TIMEOUT_S)
        return
    import dask

    cluster = client = None
    try:
        # a signal while they start is delivered once both are bound (to be closed)
        with _signals_held(), dask.config.set(LOCAL_WORKER_CONFIG):
            cluster = LocalCluster(n_workers=int(jobs), threads_per_worker=1,
                                   processes=True, dashboard_address=None,
                                   silence_logs=logging.ERROR)
            client = Client(cluster)
        yield client
    finally:
        try:
            if client is not None:
                client.close(timeout=CLOSE_TIMEOUT_S)
        finally:
            if cluster is not None:
                cluster.close(timeout=CLOSE_TIMEOUT_S)


#: Seconds between looks at the finished tasks.
POLL_S = 0.2


def _gather(client, futures, tick, address, on_result=None):
    """The futures' results in order, each wait bounded (see the module docstring);
    ``on_result(index, result)`` as each arrives."""
    import time

    from distributed import as_completed

    index = {f.key: i for i, f in enumerate(futures)}
    out = [None] * len(futures)
    finished = as_completed(futures)
    last = time.monotonic()
    left = len(futures)
    while left:
        batch = finished.next_batch(block=False)
        if not batch:
            if time.monotonic() - last > PROGRESS_POLL_S:
                _alive(client, address)   # no task finished: is the scheduler still there?
                last = time.monotonic()
            time.sleep(POLL_S)
            continue
        last = time.monotonic()
        for fut in batch:
            if fut.status == "cancelled":
                raise SchedulerError(errno.ECONNRESET, "the scheduler dropped this run's "
                                     "tasks (did it stop?)", address)
            out[index[fut.key]] = fut.result()
            left -= 1
            if on_result is not None:
                on_result(index[fut.key], out[index[fut.key]])
            tick()
    return out


def _alive(client, address):
    """Raise :class:`SchedulerError` unless the scheduler answers within the timeout."""
    try:
        client.sync(client.scheduler.identity, callback_timeout=REPLY_TIMEOUT_S)
    except Exception as exc:  # noqa: BLE001 - a timeout, a closed comm: all mean gone
        raise SchedulerError(errno.ETIMEDOUT, f"the scheduler stopped answering "
                             f"({type(exc).__name__})", address) from None


def run_tasks(func: Callable, shared: Any, args_list: Sequence[tuple], *, jobs: int = 1,
              scheduler: str | None = None, progress: Callable | None = None,
              on_result: Callable | None = None) -> list:
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
    on_result : callable, optional
        Called as ``on_result(index, result)`` with each task's result as it finishes
        (in completion order, in this process): a caller that keeps results as they
        come (a batch that resumes) writes them there.

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
            if on_result is not None:
                on_result(len(out) - 1, out[-1])
            tick()
        return out
    from distributed.comm.core import CommClosedError

    address = scheduler or "the local cluster"
    with dask_client(jobs, scheduler) as client:
        futures = []
        try:
            try:
                remote = client.scatter(shared, broadcast=True, timeout=REPLY_TIMEOUT_S)
            except (OSError, asyncio.TimeoutError, CommClosedError) as exc:
                raise SchedulerError(errno.ETIMEDOUT, "cannot send the run's data to the "
                                     f"cluster ({type(exc).__name__})", address) from None
            futures = [client.submit(func, remote, *args, pure=False) for args in args_list]
            try:
                return _gather(client, futures, tick, address, on_result)
            except (CommClosedError, asyncio.CancelledError) as exc:
                raise SchedulerError(errno.ECONNRESET, f"the scheduler went away "
                                     f"({type(exc).__name__})", address) from None
        except BaseException:
            # stop this run's tasks at once (a shared cluster keeps running)
            with contextlib.suppress(Exception):
                client.cancel(futures, force=True)
            raise
