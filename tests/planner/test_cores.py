"""The threads of the main process's parallel kernels follow the free cores (issue 38
item 3): the choice from a probe, the probe's arithmetic, and a plan that is the same
on one thread and on all of them.  No wall-clock assertion: the speed is measured in
benchmarks/sharing.py."""

from __future__ import annotations

import itertools
import json
import math
import time
from pathlib import Path

import numba
import pytest

from planner.runtime.cores import (
    FREE_CORE_FRACTION,
    free_from,
    measured_free_cores,
    stage_threads,
    threads_for,
)

TINY = (Path(__file__).resolve().parents[2] / "configs" / "tiny_1x2.yaml").read_text()

needs_two_threads = pytest.mark.skipif(
    numba.config.NUMBA_NUM_THREADS < 2,
    reason="needs two numba threads to tell the thread counts apart")


@pytest.mark.parametrize("free, most, threads", [
    (0.0, 2, 1),                            # every core busy: one thread, never none
    (1.0, 2, 1),                            # another job's busy process holds a core
    (2.0 - FREE_CORE_FRACTION - 1e-9, 2, 1),    # less than half a core free: no core
    (2.0 - FREE_CORE_FRACTION, 2, 2),
    (1.95, 2, 2),                           # a few percent of daemons: both cores
    (2.0, 2, 2),
    (7.0, 4, 4),                            # never more than the caller's count (--jobs)
    (7.0, 1, 1),
    (2.7, 8, 3),
    (float("inf"), 2, 2),
    (float("nan"), 3, 3),                   # unknown: the caller's count
])
def test_threads_follow_the_free_cores(free, most, threads):
    assert threads_for(free, most) == threads


@needs_two_threads
@pytest.mark.parametrize("free, inside", [(0.2, 1), (1.0, 1), (2.0, 2), (64.0, 2)])
def test_stage_threads_sets_and_restores_numba_threads(free, inside):
    before = numba.get_num_threads()
    numba.set_num_threads(2)
    try:
        calls = []

        def probe():
            calls.append(1)
            return free

        with stage_threads(probe) as n:
            assert n == inside
            assert numba.get_num_threads() == inside
        assert calls == [1]                 # probed once, when the stage starts
        assert numba.get_num_threads() == 2
    finally:
        numba.set_num_threads(before)


def test_stage_threads_without_a_probe_keeps_the_callers_count():
    before = numba.get_num_threads()
    with stage_threads(None) as n:
        assert n == before == numba.get_num_threads()
    assert numba.get_num_threads() == before


def test_free_cores_are_the_cores_left_by_the_others():
    # 2 cores; over 2 s the cores ran 3 s of CPU, 1 s of it this process's: others 1 core
    assert free_from((10.0, 100.0, {"self": 20.0}), (12.0, 103.0, {"self": 21.0}),
                     2) == pytest.approx(1.0)
    # this process alone on the machine: both cores free, whatever it used itself
    assert free_from((0.0, 5.0, {"self": 5.0}), (1.0, 7.0, {"self": 7.0}),
                     2) == pytest.approx(2.0)
    # its worker processes are its own: the plan's last design is no other job
    assert free_from((0.0, 5.0, {"self": 1.0, 7: 3.0}), (1.0, 6.0, {"self": 1.0, 7: 4.0}),
                     2) == pytest.approx(2.0)
    # a process in one sample only is not counted as its own (it may be a new process
    # with a reused id): its time counts as another's
    assert free_from((0.0, 5.0, {"self": 1.0}), (1.0, 6.0, {"self": 1.0, 8: 1.0}),
                     2) == pytest.approx(1.0)
    # clamped to [0, cores] (ticks of the accounting can overshoot a little)
    assert free_from((0.0, 0.0, {"self": 0.0}), (1.0, 2.3, {"self": 0.0}), 2) == 0.0
    assert free_from((0.0, 0.0, {"self": 1.0}), (1.0, 0.0, {"self": 1.2}), 2) == 2.0
    # one sample only: unknown
    assert math.isnan(free_from((1.0, 2.0, {}), (1.0, 2.0, {}), 2))


def _until(cond, timeout_s=5.0):
    end = time.monotonic() + timeout_s
    while not cond() and time.monotonic() < end:
        time.sleep(0.005)
    return cond()


def test_measured_free_cores_from_injected_samples():
    from planner.runtime.cores import _allowed_cores

    n = len(_allowed_cores())
    ticks = itertools.count()

    def sample():
        # every sample 1 s later: the cores ran 1.5 s, this process 0.5 s of it
        k = next(ticks)
        return float(k), 1.5 * k, {"self": 0.5 * k}

    with measured_free_cores(period_s=0.001, window_s=0.003, sample=sample) as free:
        assert _until(lambda: not math.isnan(free()))
        assert free() == pytest.approx(max(0.0, n - 1.0))


def test_a_probe_that_cannot_read_the_cpu_times_keeps_the_callers_threads():
    def broken():
        raise PermissionError("no /proc here")

    before = numba.get_num_threads()
    with measured_free_cores(sample=broken) as free:
        assert math.isnan(free())
        with stage_threads(free) as n:
            assert n == before


def test_a_sampler_that_fails_later_gives_no_stale_answer():
    calls = []

    def sample():
        calls.append(1)
        if len(calls) > 3:
            raise OSError("the accounting went away")
        return float(len(calls)), 0.0, {}

    with measured_free_cores(period_s=0.001, window_s=0.01, sample=sample) as free:
        # three samples give an answer; the failed fourth leaves none (not the old one)
        assert _until(lambda: len(calls) > 3 and math.isnan(free()))


def test_measured_free_cores_reads_this_machine():
    from planner.runtime.cores import _allowed_cores

    with measured_free_cores(period_s=0.01, window_s=0.05) as free:
        assert _until(lambda: not math.isnan(free()))
        assert 0.0 <= free() <= len(_allowed_cores())


def test_the_sampler_counts_this_processs_workers_as_its_own():
    import subprocess
    import sys

    from planner.runtime.cores import _allowed_cores, _cpu_sampler

    sample = _cpu_sampler(_allowed_cores(), refresh_s=0.0)
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        assert _until(lambda: any(k != "self" and k[0] == child.pid for k in sample()[2]))
    finally:
        child.kill()
        child.wait()


@needs_two_threads
def test_plan_json_is_the_same_on_one_thread_and_on_all(monkeypatch):
    """The stages that run parallel kernels in the main process take the thread count the
    probe gives when they start, and the plan does not depend on it."""
    import planner.planning.pipeline as pipeline
    from planner.planning import run_plan
    from planner.arrayspec import load_spec

    seen = []

    def spy(name, fn):
        def wrapped(*args, **kwargs):
            seen.append((name, numba.get_num_threads()))
            return fn(*args, **kwargs)
        return wrapped

    for name in ("check_steps", "coupling_matrix", "assess"):
        monkeypatch.setattr(pipeline, name, spy(name, getattr(pipeline, name)))
    before = numba.get_num_threads()
    numba.set_num_threads(2)
    try:
        texts = {}
        for free, threads in [(0.0, 1), (64.0, 2)]:
            seen.clear()
            plan = run_plan(load_spec(TINY), seed=3, free_cores=lambda free=free: free)
            assert {name for name, _ in seen} == {"check_steps", "coupling_matrix", "assess"}
            assert all(n == threads for _, n in seen), seen
            assert numba.get_num_threads() == 2      # the caller's count came back
            # the bytes plan.json is written with (planner.planning.outputs)
            texts[threads] = json.dumps(plan.data, indent=2, sort_keys=False) + "\n"
    finally:
        numba.set_num_threads(before)
    assert texts[1] == texts[2]


def test_thread_map_gives_the_serial_results_in_order():
    """planner.runtime.cores.thread_map (the separations of a plan's designs on the
    stage's threads): the same list as the serial map, in order, on 1 and 2 threads,
    and serial before numba's threading layer is known."""
    import numpy as np

    import model
    from planner.runtime.cores import thread_map

    imp = model.Impacter.from_geometry(3e-8, 5e-6, 4e-4, 4e-6)
    freqs = np.linspace(0.8, 1.2, 7) * imp.natural_frequency

    def r(f):
        return model.sweep(imp, np.array([f]), np.linspace(-imp.gap, imp.gap, 5), 50.0,
                           3e-3).tolist()

    serial = [r(f) for f in freqs]
    assert thread_map(r, freqs, 1) == serial
    assert thread_map(r, freqs, 2) == serial
    assert any(v > 0 for row in serial for v in row[0])
