"""The driver of a yield run: every chip at every sigma scale, in this process or on Dask."""

from __future__ import annotations

import dataclasses

from planner.yield_.chip import verify_chip
from planner.yield_.inputs import Payload, check_chip_count
from planner.yield_.statistics import yield_record

#: Scale index of the nominal chip's task (scale 0: its draws are multiplied by 0).
NOMINAL_INDEX = 2**31 - 1


def run_yield(payload: Payload, chips: int, *, scales=(1.0,), jobs: int = 1,
              scheduler: str | None = None, progress=None, timings: dict | None = None
              ) -> dict:
    """The Monte Carlo: ``chips`` chips at every sigma scale, plus the nominal chip.

    ``timings``: when given a dict, it receives ``nominal_s`` and ``replan_s`` (lists of
    the wall times [s] of each chip's nominal checks and re-plan, with
    ``payload.replan``) and ``wall_s``; kept out of the returned dict so that
    ``yield.json`` depends on the seed only.

    Returns
    -------
    dict
        The content of ``yield.json`` (:func:`planner.yield_.statistics.yield_record`;
        see docs/yield.md).
    """
    import time

    t_start = time.perf_counter()
    from planner.runtime.engine import run_tasks

    chips = int(chips)
    scales = [float(s) for s in scales]
    check_chip_count(chips, len(scales))
    # the nominal chip (scale 0: every error 0) is task 0; it must reproduce the plan
    tasks = [(NOMINAL_INDEX, 0, 0.0)] + [(j, i, s) for j, s in enumerate(scales) for i in range(chips)]
    # one numba thread per chip everywhere: the chips are the parallelism, and the
    # kernels' own threads over a 5-9 point x0 grid cost more than they bring (on a
    # loaded 2-core machine a chip of the 5x5 plan took ~50 s threaded, ~5 s not)
    import numba

    before = numba.get_num_threads()
    payload = dataclasses.replace(payload, threads=1)
    try:
        results = run_tasks(verify_chip, payload, tasks, jobs=jobs, scheduler=scheduler,
                            progress=progress)
    finally:
        numba.set_num_threads(before)
    if timings is not None:
        timings["wall_s"] = time.perf_counter() - t_start
        timed = [r for r in results if r.seconds is not None]
        timings["nominal_s"] = [r.seconds.nominal for r in timed]
        timings["replan_s"] = [r.seconds.replan for r in timed
                               if "unbuildable" not in r.failures]
    return yield_record(payload, chips, scales, results[0], results[1:])
