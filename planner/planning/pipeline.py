"""The stage order and the repair loop; each stage lives in its own module.

settings -> steps -> assign -> drives -> designs -> verify (-> repair, re-assign ...)
-> scenes and coupling -> record.  Data flows one way; every stage reads the
:class:`~planner.planning.settings.Settings` and the earlier stages' results only.
"""

from __future__ import annotations

import time

import pandas as pd

from planner.assign import assign
from planner.errors import PlanningError
from planner.nodes import Node, device_key
from planner.planning.designs import design_all
from planner.planning.drives import synthesize_steps
from planner.planning.record import build_record
from planner.planning.repair import widen_separations
from planner.planning.result import Plan
from planner.planning.scenes import simulate_scenes
from planner.planning.settings import Settings, resolve_settings
from planner.planning.verify import check_step, coupling_matrix


def run_plan(loaded, *, seed=None, progress=None, jobs=None, settings: Settings | None = None,
             on_assignment=None, scheduler=None):
    """Run every stage; returns a :class:`Plan` (files are written by :func:`plan`).

    ``loaded``: a :class:`~planner.spec.LoadedSpec`; ``settings`` (optional) its
    already resolved :class:`Settings`.  ``jobs``: worker processes for the designs
    (default 1).  ``on_assignment(settings, steps, assignment)`` is called once, after
    the first assignment and before any design (the CLI prints the work left and a
    time estimate there).  ``scheduler``: address of a ``dask.distributed`` scheduler
    to run the designs on instead of a local cluster of ``jobs`` workers.
    """
    jobs = max(1, int(jobs or 1))
    if settings is None:
        settings = resolve_settings(loaded, seed)
    tick = progress or (lambda stage, item=None, total=None: None)
    timings = {}
    t0 = time.perf_counter()
    steps = settings.steps
    pair_sep, cache, rounds = {}, {}, []
    sep = settings.separation_channels

    def timed(stage, fn, *args, **kwargs):
        ts = time.perf_counter()
        out = fn(*args, **kwargs)
        timings[stage] = timings.get(stage, 0.0) + time.perf_counter() - ts
        return out

    for round_ in range(settings.repair_rounds + 1):
        ts = time.perf_counter()
        try:
            assignment = assign(settings.loaded, steps, separation=sep, pair_separation=pair_sep)
        except PlanningError as exc:
            if round_ == 0:
                raise
            # the widened separations no longer fit the band: keep the last plan and
            # report what still fails
            rounds.append({"round": round_, "span": None, "failures": None,
                           "stopped": str(exc)})
            break
        timings["assign"] = timings.get("assign", 0.0) + time.perf_counter() - ts
        if round_ == 0 and on_assignment is not None:
            on_assignment(settings, steps, assignment)
        # the drives depend on the frequencies only, so they come before the designs,
        # which must be silent under the summed drive of every step they sit out
        waveforms = timed("drive", synthesize_steps, settings, steps, assignment)
        tick("design", total=len(assignment.frequencies))
        designs = timed("design", design_all, settings, steps, assignment, cache,
                        progress=lambda n: tick("design", n), waveforms=waveforms, jobs=jobs,
                        scheduler=scheduler)
        impacters = {n: d.impacter for n, d in designs.items()}
        devices = sorted({Node.parse(n).device for n in impacters}, key=device_key)
        sliders = {d: settings.sliders[d] for d in devices}
        ts = time.perf_counter()
        tick("verify", total=len(steps))
        ver_rows, failures = [], []
        for st in steps:
            rows, fails = check_step(settings, st, waveforms[st.key], impacters, sliders)
            ver_rows += rows
            failures += fails
            tick("verify", st.key)
        timings["verify"] = timings.get("verify", 0.0) + time.perf_counter() - ts
        failed_rows = sum(1 for r in ver_rows if not r["passed"])
        rounds.append({"round": round_, "span": assignment.span, "failures": failed_rows})
        if not failed_rows or round_ == settings.repair_rounds:
            break
        # repair: widen the separations the failures point at, re-colour, re-design
        if not widen_separations(failures, designs, steps, assignment, pair_sep, sep):
            break
    ts = time.perf_counter()
    scene_rows = simulate_scenes(settings, steps, waveforms, impacters, sliders)
    tones = sorted(set(assignment.frequencies.values()))
    coupling = coupling_matrix(impacters, tones, settings, settings.single_step_s)
    timings["scenes_coupling"] = time.perf_counter() - ts
    ver = pd.DataFrame(ver_rows)
    passed = bool(ver["passed"].all())
    data, impacter_recs, device_recs, step_recs = build_record(
        settings, steps, assignment, designs, sliders, waveforms, ver_rows, passed, rounds,
        scene_rows)
    timings["total"] = time.perf_counter() - t0
    return Plan(
        impacters=pd.DataFrame(impacter_recs), devices=pd.DataFrame(device_recs),
        steps=pd.DataFrame(step_recs), verification=ver, coupling=coupling,
        scenes=pd.DataFrame(scene_rows), passed=passed, data=data, timings=timings,
        settings=settings, waveforms=waveforms, designs=designs, assignment=assignment,
        failures=tuple(failures))
