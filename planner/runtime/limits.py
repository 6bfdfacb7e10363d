"""Bounds on what one run may ask of the machine: cores, memory, input size.

A count, rate or step that would need more memory than the machine has is refused up
front with the figure (:func:`check_memory`), instead of starting an allocation that
fails minutes later or drives the machine into swap; ``--jobs`` beyond the cores is
refused (:func:`check_jobs`); an input file must be a regular file of at most
:data:`MAX_INPUT_BYTES` (:func:`planner.files.read_input`).
"""

from __future__ import annotations

import os

from planner.core.errors import LimitError

#: Largest input file read [bytes]: a spec, plan.json, sweep or measured CSV, band file.
#: The default 5 x 5 plan.json is ~2 MB; a lab sweep of 100 impacters x 1000 points ~4 MB.
MAX_INPUT_BYTES = 64 * 2**20

#: Fraction of the available memory one run may plan to use: the rest is for the
#: interpreter, numba's compiled code and whatever else the machine runs.
MEMORY_FRACTION = 0.5


def cores() -> int:
    """CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def check_jobs(jobs: int, option: str = "--jobs") -> int:
    """``jobs`` if it is between 1 and :func:`cores`, else :class:`LimitError` naming both.

    Worker processes beyond the cores only compete for them (and each holds a copy of
    the plan and numba's compiled code, ~250 MB).
    """
    n = cores()
    if not 1 <= int(jobs) <= n:
        raise LimitError(f"{option} {jobs}: must be between 1 and {n} (the cores this "
                         f"machine gives this process)")
    return int(jobs)


def available_memory() -> int:
    """Memory available to a new allocation without swapping [bytes]."""
    import psutil

    return int(psutil.virtual_memory().available)


def _size(n: float) -> str:
    for unit in ("B", "KB", "MB", "GB", "TB", "PB"):
        if abs(n) < 1000 or unit == "PB":
            return f"{n:.3g} {unit}"
        n /= 1000
    return f"{n:.3g} PB"   # pragma: no cover


def check_memory(need_bytes: float, what: str) -> None:
    """Refuse, before any work, a request that needs more than :data:`MEMORY_FRACTION` of
    the available memory.

    Parameters
    ----------
    need_bytes : float
        The estimated peak memory of the request [bytes].
    what : str
        The request in the user's terms, e.g. ``"--sample-rate 1e+12: a loop of up to
        1 s"``; the message adds the figures.

    Raises
    ------
    LimitError
        With the estimate and the memory available.
    """
    have = available_memory()
    if not need_bytes <= MEMORY_FRACTION * have:
        raise LimitError(f"{what} needs about {_size(need_bytes)} of memory, more than this "
                         f"machine can give it ({_size(have)} available)")
