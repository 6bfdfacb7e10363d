"""The stage order and the repair loop; each stage lives in its own module.

settings -> steps -> assign -> drives (acceleration limit) -> designs -> burst sizing
-> gates of the targets steps (scenes with carried state) -> verify (-> repair,
re-assign ...) -> scenes with carried state (-> motion repair: shorter bursts, longer
dwells) -> coupling -> manufacturability -> record.  Data flows one way; every stage reads the
:class:`~planner.planning.settings.Settings` and the earlier stages' results only.
"""

from __future__ import annotations

import time

import pandas as pd

from planner.assign import assign
from planner.errors import PlanningError
from planner.nodes import Node, device_key
from planner.planning.design_store import DesignStore
from planner.planning.designs import design_all
from planner.planning.drives import limit_acceleration, synthesize_steps
from planner.planning.manufacture import assess
from planner.planning.motion import size_bursts
from planner.planning.record import build_record
from planner.planning.repair import (reseed_idle, reseed_slow, scenes_and_motion,
                                     widen_separations)
from planner.planning.result import Plan
from planner.planning.settings import Settings, resolve_settings
from planner.planning.targets import place_targets
from planner.planning.verify import TRAVEL_OVER, UNSETTLED, check_steps, coupling_matrix


#: Failure kinds the motion repair (shorter bursts, longer dwells) acts on, after the
#: design rounds: they do not count against a design round.
MOTION_KINDS = (TRAVEL_OVER, UNSETTLED)


def design_problems(designs, settings):
    """One readable entry per infeasible design: which impacter, why, what to change."""
    out = []
    for n in sorted(designs):
        d = designs[n]
        if d.feasible:
            continue
        advice = ("widen the separations (drive.guard.separation_channels, "
                  "ensemble_separation_channels) or the band, so that its forbidden tones "
                  "sit further from its own")
        if d.checks.get("violated_drives"):
            advice += ("; it responds under the summed drive of a step it sits out: fewer "
                       "tones per step or a lower drive.power_m2_s3 also help")
        if getattr(d, "mass_ratio", 0.0) >= 0.99 * settings.max_mass_ratio:
            advice += (f"; it sits at the mass-ratio cap m/M = {settings.max_mass_ratio:g} "
                       "(design.max_mass_ratio, or a heavier slider)")
        out.append({"impacter": n, "frequency_hz": d.frequency_hz, "why": d.message,
                    "what_to_change": advice})
    return out


def run_plan(loaded, *, seed=None, progress=None, jobs=None, settings: Settings | None = None,
             on_assignment=None, scheduler=None, cache_dir=None):
    """Run every stage; returns a :class:`Plan` (files are written by :func:`plan`).

    ``loaded``: a :class:`~planner.spec.LoadedSpec`; ``settings`` (optional) its
    already resolved :class:`Settings`.  ``jobs``: worker processes for the designs
    (default 1).  ``on_assignment(settings, steps, assignment)`` is called once, after
    the first assignment and before any design (the CLI prints the work left and a
    time estimate there).  ``scheduler``: address of a ``dask.distributed`` scheduler
    to run the designs and the verification steps on (without it, the designs run in
    ``jobs`` local worker processes and the steps in this process).  ``cache_dir``: the
    on-disk design cache's folder (:class:`~planner.planning.design_store.DesignStore`;
    None: designs are cached for this run only).
    """
    jobs = max(1, int(jobs or 1))
    if settings is None:
        settings = resolve_settings(loaded, seed)
    tick = progress or (lambda stage, item=None, total=None: None)
    timings = {}
    t0 = time.perf_counter()
    steps = settings.steps
    pair_sep, cache, rounds, reseed, best = {}, {}, [], {}, None
    idle_redesigned = set()
    store = DesignStore(cache_dir) if cache_dir is not None else None
    sep = settings.separation_channels

    def timed(stage, fn, *args, **kwargs):
        ts = time.perf_counter()
        out = fn(*args, **kwargs)
        timings[stage] = timings.get(stage, 0.0) + time.perf_counter() - ts
        return out

    for round_ in range(settings.repair_rounds + 1):
        ts = time.perf_counter()
        try:
            assignment = assign(settings, steps, separation=sep, pair_separation=pair_sep)
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
        synthesized = timed("drive", synthesize_steps, settings, steps, assignment)
        waveforms, drive_notes = timed("drive", limit_acceleration, settings, synthesized)
        tick("design", total=len(assignment.frequencies))
        designs = timed("design", design_all, settings, steps, assignment, cache,
                        progress=lambda n: tick("design", n), waveforms=waveforms, jobs=jobs,
                        scheduler=scheduler, reseed=reseed, store=store)
        impacters = {n: d.impacter for n, d in designs.items()}
        devices = sorted({Node.parse(n).device for n in impacters}, key=device_key)
        sliders = {d: settings.sliders[d] for d in devices}
        ts = time.perf_counter()
        # steps that give travel_um get their burst from the predicted speed
        run_steps, sizing = size_bursts(settings, steps, waveforms, impacters, sliders)
        # targets steps play a gated burst, found from the carried state of their scene;
        # its tones play one after the other, so at their amplitudes as synthesised, not
        # as lowered for the peak of their whole sum
        played, gating = waveforms, {}
        targeted = {st.key: synthesized[st.key] for st in run_steps if st.targets_m is not None}
        if targeted:
            tick("targets", total=len(targeted))
            run_steps, played, gating = timed(
                "targets", place_targets, settings, run_steps, {**waveforms, **targeted},
                assignment.frequencies, impacters, sliders,
                progress=lambda k: tick("targets", k))
        tick("verify", total=len(steps))
        ver_rows, failures = [], []
        for rows, fails in check_steps(settings, run_steps, played, impacters, sliders,
                                       progress=lambda k: tick("verify", k),
                                       scheduler=scheduler):
            ver_rows += rows
            failures += fails
        timings["verify"] = timings.get("verify", 0.0) + time.perf_counter() - ts
        failed_rows = sum(1 for r in ver_rows if not r["passed"])
        rounds.append({"round": round_, "span": assignment.span, "failures": failed_rows})
        # a repair round can make things worse (a widened separation moves other tones
        # into trouble): the plan kept is the round with the fewest infeasible designs
        # and failures the motion repair cannot mend, the later one on a tie
        score = (sum(1 for d in designs.values() if not d.feasible),
                 sum(1 for f in failures if f.kind not in MOTION_KINDS))
        if best is None or score <= best[0]:
            best = (score, round_, (assignment, waveforms, played, drive_notes, gating, designs,
                                    impacters, devices, sliders, run_steps, sizing, ver_rows,
                                    failures))
        if not failed_rows or round_ == settings.repair_rounds:
            break
        # repair: widen the separations the failures point at, re-colour, re-design;
        # impacters that were only too slow, or idle ones that answered once although
        # their designs were feasible, are re-designed alone from further seeds
        answered = reseed_idle(failures, designs, reseed, idle_redesigned)
        widened = widen_separations(failures, designs, steps, assignment, pair_sep, sep,
                                    skip=answered)
        reseeded = reseed_slow(failures, designs, steps, reseed)
        if reseeded:
            rounds[-1]["redesigned_slow"] = reseeded
        if answered:
            rounds[-1]["redesigned_idle"] = answered
        if not (widened or reseeded or answered):
            break
    if best[1] != rounds[-1]["round"]:
        (assignment, waveforms, played, drive_notes, gating, designs, impacters, devices,
         sliders, run_steps, sizing, ver_rows, failures) = best[2]
        rounds.append({"round": None, "kept_round": best[1],
                       "why": "fewer infeasible designs and failures than the last round"})
    ts = time.perf_counter()
    # the scenes carry every impacter's and slider's state from step to step, each step
    # followed by its settle dwell; what they find counts in the verification, and the
    # motion repair acts on it (shorter bursts, longer dwells)
    (run_steps, ver_rows, failures, scene_rows, motion_repairs,
     step_settle) = scenes_and_motion(settings, run_steps, played, impacters, sliders,
                                      ver_rows, failures, scheduler=scheduler)
    tones = sorted(set(assignment.frequencies.values()))
    coupling = coupling_matrix(impacters, tones, settings, settings.single_step_s)
    timings["scenes_coupling"] = time.perf_counter() - ts
    # what a fabricated chip does to these designs: sensitivities, separations and the
    # predicted collision-free yield under the spec's tolerances
    manufacturability = timed("manufacturability", assess, settings, run_steps, assignment,
                              designs, waveforms)
    ver = pd.DataFrame(ver_rows)
    problems = design_problems(designs, settings)
    # an infeasible design fails the plan even if the steps happen to verify: it was
    # not shown silent at its forbidden tones on the designer's fine grid
    passed = bool(ver["passed"].all()) and not problems
    motion = {"sizing": sizing, "drive": drive_notes, "settle_s": step_settle,
              "repairs": motion_repairs, "design_problems": problems, "gating": gating}
    data, impacter_recs, device_recs, step_recs = build_record(
        settings, run_steps, assignment, designs, sliders, played, ver_rows, passed, rounds,
        scene_rows, motion, manufacturability)
    timings["total"] = time.perf_counter() - t0
    return Plan(
        impacters=pd.DataFrame(impacter_recs), devices=pd.DataFrame(device_recs),
        steps=pd.DataFrame(step_recs), verification=ver, coupling=coupling,
        scenes=pd.DataFrame(scene_rows), passed=passed, data=data, timings=timings,
        settings=settings, waveforms=played, designs=designs, assignment=assignment,
        failures=tuple(failures),
        design_cache=(None if store is None else
                      {"path": str(store.path), "read": store.hits, "written": store.writes,
                       "designed": len(cache)}))
