"""The threads the main process's parallel kernels use in a stage: as many as the cores
other processes leave free when the stage starts.

Why: verification, the scenes and the coupling matrix, and manufacturability run in the
main process and call numba's parallel response kernel
(:func:`model.kernels.impacter.response_grid`) thousands of times on batches of 1 to 36
runs of microseconds each.  Every call is a fork-join over numba's thread pool (the
OpenMP layer: the caller waits at the region's barrier for each thread of the team).  On
free cores a call of the default plan costs 10-35 us; when another job keeps the cores
busy, the second thread of each call waits for a time slice first, and every call costs
about 16 ms, whatever its size (measured with two plans on 2 cores: 2520 calls made the
verification 40 s instead of 1.2 s, 5349 made manufacturability 87 s instead of 2.2 s).
On one thread a call runs at once, in the caller.  So each such stage asks
:func:`stage_threads` for the threads its kernels use: all of numba's when the cores are
free, one when another job holds them, and the stage takes its share of the machine,
not the other job's time slices.

The thread count does not change a result: every run of the kernel is independent of
the others and of the thread that runs it (no reduction across runs), so plan.json is
the same on any number of threads.

:func:`measured_free_cores` measures the free cores with a sampler thread (every
:data:`SAMPLE_PERIOD_S`, the CPU time of the allowed cores minus that of this process and
its worker processes, over the last :data:`SAMPLE_WINDOW_S`), so that a stage starts
without waiting for a sample.  The plan's own workers count as its own: they have just
finished the designs when the verification starts, and the last of them would otherwise
look like another job's.
"""

from __future__ import annotations

import collections
import contextlib
import math
import threading
import time

from planner.runtime.limits import cores

#: Seconds between two samples of the cores' CPU time (one read of /proc/stat and of this
#: process's times on Linux, ~50 us).
SAMPLE_PERIOD_S = 0.05
#: Seconds over which the other processes' use of the cores is averaged: long enough for
#: the 10 ms ticks of the kernel's CPU accounting to resolve a tenth of a core on 2 cores,
#: short enough that a stage starts from what the machine does now.
SAMPLE_WINDOW_S = 0.25
#: Seconds between two looks for this process's worker processes (a look reads every
#: process's parent, ~4 ms on a machine of 100 processes; the plan starts its pool once).
CHILDREN_REFRESH_S = 2.0
#: A core counts as free when the other processes leave at least this fraction of it
#: idle: a job's busy process takes a whole core (free 1.0 of 2 leaves one thread), stray
#: daemons take a few percent (free 1.9 of 2 keeps two).
FREE_CORE_FRACTION = 0.5


def threads_for(free: float, most: int) -> int:
    """Threads for a stage's parallel kernels: the free cores (a core counts when at least
    :data:`FREE_CORE_FRACTION` of it is free), at least 1, at most ``most``.

    Parameters
    ----------
    free : float
        Cores the other processes leave free [cores]; NaN when unknown (then ``most``).
    most : int
        The caller's numba thread count (the CLI's ``--jobs`` caps it).

    Examples
    --------
    >>> threads_for(0.1, 2), threads_for(1.0, 2), threads_for(1.6, 2), threads_for(4.0, 2)
    (1, 1, 2, 2)
    >>> threads_for(float("inf"), 2), threads_for(float("nan"), 2), threads_for(8.0, 1)
    (2, 2, 1)
    """
    most = max(1, int(most))
    if math.isnan(free):
        return most
    return max(1, math.floor(min(float(most), free + 1.0 - FREE_CORE_FRACTION)))


@contextlib.contextmanager
def stage_threads(free_cores):
    """Run the block with numba's thread count set by :func:`threads_for` from
    ``free_cores()``; the caller's count comes back afterwards.

    Parameters
    ----------
    free_cores : callable or None
        No arguments, returns the free cores [cores] (:func:`measured_free_cores`; tests
        inject their own).  None leaves the caller's count as it is.

    Yields
    ------
    int
        The threads the block's kernels use.
    """
    import numba

    before = numba.get_num_threads()
    if free_cores is None:
        yield before
        return
    # numba's thread count is per calling thread: set and restored in the caller's own
    threads = threads_for(free_cores(), before)
    numba.set_num_threads(threads)
    try:
        yield threads
    finally:
        numba.set_num_threads(before)


def _cpu_sampler(allowed, refresh_s=CHILDREN_REFRESH_S):
    """A function of no arguments giving (time [s], CPU time spent on the cores in
    ``allowed`` [s], {process: CPU time [s]} of this process and its descendants), from
    ``psutil``; the descendants are looked for every ``refresh_s`` seconds."""
    import psutil

    me = psutil.Process()
    found = {"at": -math.inf, "kids": {}}

    def cpu(p):
        t = p.cpu_times()
        return t.user + t.system

    def sample():
        per_cpu = psutil.cpu_times(percpu=True)
        busy = 0.0
        for i in allowed:
            if i < len(per_cpu):
                c = per_cpu[i]
                # time a core ran some process (iowait and steal are no process's)
                busy += (c.user + c.system + getattr(c, "nice", 0.0)
                         + getattr(c, "irq", 0.0) + getattr(c, "softirq", 0.0))
        now = time.monotonic()
        if now - found["at"] >= refresh_s:
            kids = {}
            for p in me.children(recursive=True):
                with contextlib.suppress(psutil.Error):
                    # the start time tells a reused process id from the process it was
                    kids[(p.pid, p.create_time())] = p
            found.update(at=now, kids=kids)
        own = {"self": cpu(me)}
        for key, p in found["kids"].items():
            with contextlib.suppress(psutil.Error):   # a worker that has ended
                own[key] = cpu(p)
        return now, busy, own

    return sample


def _allowed_cores():
    import os

    try:
        return sorted(os.sched_getaffinity(0))
    except AttributeError:  # not Linux: every core
        return list(range(cores()))


class _Sampler:
    """A daemon thread keeping the samples of the last :data:`SAMPLE_WINDOW_S`."""

    def __init__(self, sample, period_s, window_s):
        self._sample = sample
        self._period = period_s
        self._samples = collections.deque(maxlen=max(2, math.ceil(window_s / period_s) + 1))
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._failed = False
        self._samples.append(sample())
        self._thread = threading.Thread(target=self._run, name="vibroplan-core-sampler",
                                        daemon=True)
        self._thread.start()

    def _run(self):
        while not self._stop.wait(self._period):
            try:
                s = self._sample()
            except Exception:  # noqa: BLE001 - no more samples: the stages go on as asked
                with self._lock:
                    self._failed = True
                return
            with self._lock:
                self._samples.append(s)

    def close(self):
        self._stop.set()
        self._thread.join()

    def free(self, n_cores):
        """:func:`free_from` the oldest and the newest sample kept; NaN before a second
        sample, or once sampling failed (old samples would describe another moment)."""
        with self._lock:
            if self._failed:
                return float("nan")
            return free_from(self._samples[0], self._samples[-1], n_cores)


def free_from(first, last, n_cores):
    """Cores the other processes left free between two samples of :func:`_cpu_sampler`
    [cores], in [0, ``n_cores``]; NaN when the samples are less than a period apart.

    A sample is (time [s], CPU time of the cores [s], {process: its CPU time [s]} of this
    process and its workers).  A process seen in one sample only (started or ended
    between them) is not counted as this run's: its time there counts as another's.

    Examples
    --------
    >>> free_from((0.0, 10.0, {"self": 5.0}), (1.0, 11.5, {"self": 5.9}), 2)  # others 0.6
    1.4
    """
    dt = last[0] - first[0]
    if dt <= 0.0:
        return float("nan")
    own = sum(t - first[2][k] for k, t in last[2].items() if k in first[2])
    others = ((last[1] - first[1]) - own) / dt
    return min(float(n_cores), max(0.0, round(n_cores - others, 6)))


@contextlib.contextmanager
def measured_free_cores(*, period_s=SAMPLE_PERIOD_S, window_s=SAMPLE_WINDOW_S, sample=None):
    """Yields a function of no arguments that gives the cores of this process's affinity
    that the other processes (not this one nor its workers) left free over the last
    ``window_s`` seconds [cores].

    Samples every ``period_s`` seconds in a daemon thread, stopped when the block ends.
    Where the CPU times cannot be read (``psutil`` refused, at the start or later), the
    function gives NaN: every stage then keeps the caller's thread count.

    Parameters
    ----------
    sample : callable, optional
        Returns (time [s], busy CPU time of the allowed cores [s], {process: CPU time
        [s]} of this process and its workers); default from ``psutil`` (tests inject
        their own).
    """
    allowed = _allowed_cores()
    try:
        sampler = _Sampler(sample or _cpu_sampler(allowed), period_s, window_s)
    except Exception:  # noqa: BLE001 - no CPU accounting here: keep the caller's threads
        yield lambda: float("nan")
        return
    try:
        yield lambda: sampler.free(len(allowed))
    finally:
        sampler.close()


#: numba's threading layers that take parallel kernels called from several threads at
#: once (numba's docs: the workqueue layer does not).
THREADSAFE_LAYERS = ("omp", "tbb")


def thread_map(func, items, threads: int) -> list:
    """``[func(x) for x in items]`` on ``threads`` threads of this process, in order.

    For work whose time is in numba's ``nogil`` kernels (the separations of a plan's
    designs): the threads run the kernels at once, each on one numba thread.  Serial
    when ``threads`` < 2, fewer than two items, or numba's threading layer does not take
    kernels from several threads (:data:`THREADSAFE_LAYERS`; unknown before the first
    parallel kernel ran).  Every call is independent, so the results are the same either
    way.
    """
    import concurrent.futures as cf

    import numba

    items = list(items)
    try:
        layer = numba.threading_layer()
    except ValueError:
        layer = None
    if threads < 2 or len(items) < 2 or layer not in THREADSAFE_LAYERS:
        return [func(x) for x in items]
    with cf.ThreadPoolExecutor(max_workers=min(int(threads), len(items)),
                               initializer=numba.set_num_threads, initargs=(1,),
                               thread_name_prefix="vibroplan-stage") as pool:
        return list(pool.map(func, items))
