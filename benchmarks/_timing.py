"""Timing helper shared by the benchmarks: warm-up, autorange, median of repeats.

As timeit / pyperf / asv do: one warm-up call (numba loading or compilation,
caches), then enough calls per run that a run lasts at least ``min_time``
(so the clock's resolution and the loop's overhead do not matter), then the
median over ``repeat`` runs of the time per call.  The median resists the
outliers of a shared machine; the minimum is kept as well.
"""

from __future__ import annotations

import os
import platform
import re
import time
from dataclasses import dataclass

#: Default shortest run [s] and number of runs.
MIN_TIME = 0.2
REPEAT = 7
#: The stage times a plan prints (``vibroplan plan``'s last lines).
TIME_LINE = re.compile(r"^time: (.*)$", re.M)


@dataclass(frozen=True)
class Timing:
    """Time per call [s]: median and minimum over the runs, and how they were made."""

    median: float
    minimum: float
    calls_per_run: int
    runs: int


def measure(fn, *, min_time=MIN_TIME, repeat=REPEAT, max_calls=1_000_000):
    """Time ``fn()`` (no arguments): warm-up, autorange, median of ``repeat`` runs.

    Parameters
    ----------
    fn : callable
        The work to time.
    min_time : float
        Shortest run [s]; the number of calls per run doubles until it is reached.
    repeat : int
        Runs after the calibration.
    max_calls : int
        Cap on calls per run.

    Returns
    -------
    Timing
    """
    fn()  # warm-up
    calls = 1
    while True:
        t0 = time.perf_counter()
        for _ in range(calls):
            fn()
        elapsed = time.perf_counter() - t0
        if elapsed >= min_time or calls >= max_calls:
            break
        calls = min(max_calls, calls * 2 if elapsed <= 0 else
                    max(calls * 2, int(calls * min_time / elapsed * 1.2)))
    per_call = [elapsed / calls]
    for _ in range(repeat - 1):
        t0 = time.perf_counter()
        for _ in range(calls):
            fn()
        per_call.append((time.perf_counter() - t0) / calls)
    per_call.sort()
    n = len(per_call)
    median = per_call[n // 2] if n % 2 else 0.5 * (per_call[n // 2 - 1] + per_call[n // 2])
    return Timing(median=median, minimum=per_call[0], calls_per_run=calls, runs=n)


def machine():
    """A short description of the machine and its load, for the results' header."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        load = os.getloadavg()
    except OSError:
        load = (float("nan"),) * 3
    return {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(),
            "load": load}


def plan_stages(text):
    """{stage: seconds} from the ``time:`` line of a plan's output ({} without one)."""
    m = TIME_LINE.search(text)
    if not m:
        return {}
    out = {}
    for part in m.group(1).split(","):
        name, value = part.strip().rsplit(" ", 2)[:2]
        out[name] = float(value)
    return out
