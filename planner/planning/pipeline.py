"""The stage order and the repair loop; each stage lives in its own module.

settings -> steps -> assign -> drives (acceleration limit) -> designs -> burst sizing
-> gates of the targets steps (scenes with carried state) -> verify (-> repair,
re-assign ...) -> scenes with carried state (-> motion repair: shorter bursts, longer
dwells) -> coupling -> manufacturability -> record.  Data flows one way; every stage reads the
:class:`~planner.planning.settings.Settings` and the earlier stages' results only.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, field

import pandas as pd

from planner.runtime.cores import measured_free_cores, stage_threads
from planner.assignment.assign import Assignment, assign
from planner.core.errors import PlanningError
from planner.core.nodes import device_key
from planner.planning.chain import limit_drives
from planner.planning.design_store import DesignStore, stage_digest
from planner.planning.designs import design_all
from planner.planning.drives import synthesize_steps
from planner.planning.manufacture import assess
from planner.planning.motion import size_bursts
from planner.planning.reach import measure_reach
from planner.planning.record import build_record
from planner.planning.repair import (reseed_idle, reseed_slow, scenes_and_motion,
                                     widen_separations)
from planner.planning.result import Plan
from planner.planning.settings import Settings, resolve_settings
from planner.planning.targets import place_targets
from planner.planning.verify import (TRAVEL_OVER, UNSETTLED, check_steps, confirm_responses,
                                     coupling_matrix)


#: Failure kinds the motion repair (shorter bursts, longer dwells) acts on, after the
#: design rounds: they do not count against a design round.
MOTION_KINDS = (TRAVEL_OVER, UNSETTLED)


#: What to change for each kind of shortfall (:func:`planner.designer.design.shortfalls`).
ADVICE = {
    "silence": ("widen the separations (drive.guard.separation_channels) or the band "
                "(drive.band_hz), so that the tones it answers sit further from its own"),
    "silence_long": ("widen the separations (drive.guard.separation_channels) or the band "
                     "(drive.band_hz): it answers a tone late in the re-check window"),
    "response": ("it cannot respond from every x0 while silent at its neighbours: a wider "
                 "separation (drive.guard.separation_channels) or band"),
    "speed_floor": ("a lower floor (verification.min_speed_mm_s), a heavier impacter for its "
                    "slider (design.max_mass_ratio) or a lighter slider (device.slider."
                    "area_um2), or a band where designs are faster (the plan's reach)"),
    "mass_ratio": "a higher design.max_mass_ratio or a heavier slider",
    "bounds": "wider design.bounds",
    "sensitivity": ("a wider design.sensitivity_tolerance or another "
                    "design.sensitivity_per_um"),
}


def design_problems(designs, settings, rounds=(), confirmed=()):
    """One readable entry per infeasible design: which impacter, the constraint it
    misses and by how much, what the planner's loop tried, and what to change (but the
    designs in ``confirmed``: :func:`planner.planning.verify.confirm_responses`)."""
    tried = {}
    for rnd in rounds:
        for mv in rnd.get("moved", ()):
            tried.setdefault(mv["impacter"], []).append(
                f"moved {mv['from_hz']:.0f} -> {mv['to_hz']:.0f} Hz in round {rnd['round']}")
        blocked = rnd.get("no_channel")
        if blocked:
            for n in blocked["impacters"]:
                tried.setdefault(n, []).append(
                    f"no free channel kept its widened separations in round {rnd['round']}")
        for n in [*rnd.get("redesigned_slow", []), *rnd.get("redesigned_idle", [])]:
            tried.setdefault(n, []).append(f"re-designed from further seeds in round "
                                           f"{rnd['round']}")
    out = []
    for n in sorted(designs):
        d = designs[n]
        if d.feasible or n in confirmed:
            continue
        kinds = [sf["constraint"] for sf in d.shortfalls] or ["silence"]
        advice = [ADVICE.get(k, "") for k in dict.fromkeys(kinds)]
        drives = d.checks.get("violated_drives")
        if drives:
            advice.append("it answers the summed drive of " + ", ".join(map(repr, drives))
                          + " (a step it sits out): fewer tones per step, a lower "
                          "drive.max_acceleration_g or drive.power_m2_s3, or a wider "
                          "drive.guard.ensemble_separation_channels")
        if getattr(d, "mass_ratio", 0.0) >= 0.99 * settings.max_mass_ratio:
            advice.append(f"it sits at the mass-ratio cap m/M = {settings.max_mass_ratio:g} "
                          "(design.max_mass_ratio, or a heavier slider)")
        out.append({"impacter": n.text, "frequency_hz": d.frequency_hz,
                    "constraint": kinds[0], "shortfalls": [dict(sf) for sf in d.shortfalls],
                    "why": d.message, "tried": tried.get(n.text, []),
                    "what_to_change": "; ".join(a for a in advice if a)})
    return out


class _Clock:
    """Seconds per stage, summed over the rounds (``Plan.timings``)."""

    def __init__(self):
        self.t0 = time.perf_counter()
        self.timings = {}

    def add(self, stage, since):
        self.timings[stage] = self.timings.get(stage, 0.0) + time.perf_counter() - since

    def timed(self, stage, fn, *args, **kwargs):
        ts = time.perf_counter()
        out = fn(*args, **kwargs)
        self.add(stage, ts)
        return out


@dataclass(frozen=True)
class _Round:
    """What one design round made and found (the round the plan keeps is one of them).

    ``waveforms``: step key -> the drive as synthesised under the limits (the designs'
    forbidden drives); ``played``: what each step plays (a ``targets_um`` step's gated
    burst); ``run_steps``: the steps with their bursts sized and gated."""

    assignment: Assignment
    waveforms: dict
    played: dict
    drive_notes: dict
    gating: dict
    designs: dict
    impacters: dict
    sliders: dict
    run_steps: tuple
    sizing: dict
    ver_rows: list
    failures: list
    #: the infeasible designs whose steps' own simulation settles their one miss
    #: (:func:`planner.planning.verify.confirm_responses`): node -> entry
    confirmed: dict = field(default_factory=dict)

    @property
    def infeasible(self):
        """The infeasible designs' nodes, sorted, but those the steps confirm."""
        return sorted(n for n, d in self.designs.items()
                      if not d.feasible and n not in self.confirmed)

    @property
    def score(self):
        """Infeasible designs, then failures the motion repair cannot mend: a repair
        round can make things worse (a widened separation moves other tones into
        trouble), so the plan keeps the round with the lowest score."""
        return (len(self.infeasible),
                sum(1 for f in self.failures if f.kind not in MOTION_KINDS))


def _design_round(settings, steps, assignment, clock, tick, design_cache, draws=None,
                  free_cores=None, **design_kw):
    """Drives, designs, burst sizing, gates and the per-step verification for one
    assignment (``draws``: step key -> phase draw, :func:`synthesize_steps`;
    ``free_cores``: the probe the verification's thread count is chosen from,
    :func:`planner.runtime.cores.stage_threads`)."""
    # the drives depend on the frequencies only, so they come before the designs,
    # which must be silent under the summed drive of every step they sit out
    synthesized = clock.timed("drive", synthesize_steps, settings, steps, assignment,
                              draws=draws)
    # the acceleration limit, and with a chain the amplifier input's volts: a tone the
    # chain cannot deliver is refused, a step over the limit lowered (the designs below
    # are made for it as lowered)
    waveforms, drive_notes = clock.timed("drive", limit_drives, settings, synthesized, steps,
                                         assignment.frequencies)
    tick("design", total=len(assignment.frequencies))
    designs = clock.timed("design", design_all, settings, steps, assignment, design_cache,
                          progress=lambda n: tick("design", n), waveforms=waveforms,
                          **design_kw)
    impacters = {n: d.impacter for n, d in designs.items()}
    devices = sorted({n.device for n in impacters}, key=device_key)
    sliders = {d: settings.sliders[d] for d in devices}
    with stage_threads(free_cores):
        # steps that give travel_um get their burst from the predicted speed
        run_steps, sizing = clock.timed("verify", size_bursts, settings, steps, waveforms,
                                        impacters, sliders)
        # targets steps play a gated burst, found from the carried state of their scene;
        # its tones play one after the other, so at their amplitudes as synthesised, not
        # as lowered for the peak of their whole sum
        played, gating = waveforms, {}
        targeted = {st.key: synthesized[st.key] for st in run_steps
                    if st.targets_m is not None}
        if targeted:
            tick("targets", total=len(targeted))
            run_steps, played, gating = clock.timed(
                "targets", place_targets, settings, run_steps, {**waveforms, **targeted},
                assignment.frequencies, impacters, sliders,
                progress=lambda k: tick("targets", k))
            if settings.chain is not None:
                from planner.planning.chain import check_bursts

                check_bursts(settings, played)
        tick("verify", total=len(steps))
        ts = time.perf_counter()
        ver_rows, failures = [], []
        # with a distorting chain, what the die feels: the tones and their products
        checked = played
        if settings.chain is not None:
            from planner.planning.chain import die_drives

            checked = die_drives(settings, played)
        for rows, fails in check_steps(settings, run_steps, checked, impacters, sliders,
                                       progress=lambda k: tick("verify", k),
                                       scheduler=design_kw.get("scheduler"),
                                       store=design_kw.get("store")):
            ver_rows += rows
            failures += fails
        # a design that misses only its response under a summed drive within the
        # designer's short window, while every step it plays in moves its slider
        confirmed = confirm_responses(settings, run_steps, checked, designs, sliders)
        clock.add("verify", ts)
    return _Round(assignment, waveforms, played, drive_notes, gating, designs, impacters,
                  sliders, run_steps, sizing, ver_rows, failures, confirmed)


def _unmoved(designs, new, old):
    """The designs whose impacter plays the same tone in assignment ``new`` as in
    ``old`` (a moved one is designed again)."""
    return {n: d for n, d in designs.items()
            if new.frequencies.get(n) == old.frequencies.get(n)}


def _design_stats(designs, before):
    """How the round's distinct designs were made: {"designed", "kept", "reused"} (a
    re-check kept a design whose inputs changed; reused: unchanged since the last
    round)."""
    out = {"designed": 0, "kept": 0, "reused": 0}
    seen = set()
    for n, d in designs.items():
        # impacters sharing every design input share one design: count it once
        if id(d) in seen:
            continue
        seen.add(id(d))
        if before is not None and any(b is d for b in before.values()):
            out["reused"] += 1
        elif d.checks.get("kept_by_recheck") and before is not None:
            out["kept"] += 1
        else:
            out["designed"] += 1
    return out


def _repair_rounds(settings, clock, tick, on_assignment, design_kw, first, free_cores=None):
    """The assigner and the designer in one loop: assign, design and verify, then change
    what the failures point at and repeat, up to ``settings.repair_rounds`` times.

    An infeasible design (:func:`planner.planning.repair.design_levers`) gets a new
    phase draw of the summed drive it answers, a channel further from the tones it
    answers (the movers placed alone on free positions, every other channel kept:
    :func:`planner.assignment.reassign.move_groups`; the whole graph coloured again only when no
    free position fits) or a re-design from further seeds; the verification's
    failures widen separations or re-design the impacters that answered or were slow
    (:mod:`planner.planning.repair`).  A design whose own tone did not move is kept
    when it passes a re-check against what changed (:func:`design_all`'s
    ``previous``): a move re-designs what it touches, not the array.

    ``first`` is the first assignment (:func:`planner.planning.reach.measure_reach`'s),
    on the channels the spec's reach offers; every later one keeps its reach.

    Returns
    -------
    (kept, rounds, designed)
        The round kept (the lowest :attr:`_Round.score`, the later one on a tie),
        plan.json's ``repair_rounds`` log and the distinct designs made over the rounds.
    """
    from planner.planning.designs import design_keys
    from planner.planning.repair import design_levers, pick_draw
    from planner.assignment.reassign import move_groups

    steps, sep = settings.steps, settings.separation_channels
    pair_sep, design_cache, rounds, reseed, idle_redesigned = {}, {}, [], {}, set()
    # draws: step key -> new draws made (the levers' count); picks: step key -> the
    # draw each plays, chosen among candidates by what the round's designs do under it
    draws, picks, reseeded = {}, {}, set()
    best, previous, before = None, None, None
    assignment = first
    reach = first.reach
    if on_assignment is not None:
        on_assignment(settings, steps, assignment)
    for round_ in range(settings.repair_rounds + 1):
        got = _design_round(settings, steps, assignment, clock, tick, design_cache,
                            draws=dict(picks), reseed=dict(reseed), previous=previous,
                            free_cores=free_cores, **design_kw)
        failed_rows = sum(1 for r in got.ver_rows if not r["passed"])
        infeasible = got.infeasible
        entry = {"round": round_, "span": assignment.span, "failures": failed_rows,
                 "infeasible": [n.text for n in infeasible],
                 "designs": _design_stats(got.designs, before)}
        if got.confirmed:
            entry["confirmed"] = [n.text for n in sorted(got.confirmed)]
        rounds.append(entry)
        if best is None or got.score <= best[0].score:
            best = (got, round_)
        if (not failed_rows and not infeasible) or round_ == settings.repair_rounds:
            break
        offsets, drawn_before = dict(reseed), dict(draws)
        actions, away = design_levers(got.designs, steps, assignment, draws, pair_sep, sep,
                                      reseed, reseeded, confirmed=got.confirmed,
                                      previous=before)
        answered = reseed_idle(got.failures, got.designs, reseed, idle_redesigned)
        for n, near in widen_separations(got.failures, got.designs, steps, assignment,
                                         pair_sep, sep, skip=answered).items():
            away.setdefault(n, set()).update(near)
            actions.append(f"{n}: moved away from " + ", ".join(m.text for m in sorted(near))
                           + " (it answered in a step it sits out)")
        reseeded_slow = reseed_slow(got.failures, got.designs, steps, reseed)
        if reseeded_slow:
            entry["redesigned_slow"] = [n.text for n in reseeded_slow]
        if answered:
            entry["redesigned_idle"] = [n.text for n in answered]
        new = assignment
        if away:
            ts = time.perf_counter()
            moved = move_groups(settings, steps, assignment, away, pair_sep, away=away)
            if moved is not None:
                new, moves = moved
                entry["moved"] = [{"impacter": n.text, "from_hz": a, "to_hz": b}
                                  for n, (a, b) in sorted(moves.items())]
            else:
                try:
                    new = assign(settings, steps, separation=sep, pair_separation=pair_sep,
                                 reach=reach)
                except PlanningError as exc:
                    # no channel keeps the tightened separations: the movers stay
                    entry["no_channel"] = {"impacters": sorted(n.text for n in away),
                                           "why": str(exc)}
                else:
                    entry["recoloured"] = sum(1 for n in new.frequencies
                                              if new.frequencies[n] != assignment.frequencies[n])
            clock.add("assign", ts)
        for k in sorted(draws):
            if draws[k] != drawn_before.get(k, 0):
                ts = time.perf_counter()
                picks[k], table = pick_draw(settings, steps, new, _unmoved(got.designs, new,
                                                                           assignment),
                                            k, draws[k])
                clock.add("drive", ts)
                entry.setdefault("phase_picks", {})[k] = {
                    "draw": picks[k],
                    "candidates": [{"draw": d, "failing": f} for d, f in table]}
                fails = dict(table)[picks[k]]
                which = [d for d, _ in table].index(picks[k]) + 1
                actions.append(
                    f"{k}: candidate {which} of {len(table)} new phase draws plays: "
                    + (f"under it {len(fails)} design(s) of this round fail "
                       f"({', '.join(fails)})" if fails else
                       "under it every design of this round holds")
                    + "; under the others " + ", ".join(str(len(f)) for d, f in table
                                                        if d != picks[k]) + " fail")
        if actions:
            entry["actions"] = actions
        drawn = {k: v for k, v in draws.items() if v}
        if drawn:
            entry["phase_draws"] = dict(sorted(drawn.items()))
        changed = (new is not assignment or reseed != offsets or draws != drawn_before)
        if not changed:
            break
        previous = design_keys(settings, steps, assignment, got.waveforms, got.designs,
                               offsets)
        before = dict(got.designs)
        assignment = new
    kept, kept_round = best
    if kept_round != rounds[-1]["round"]:
        rounds.append({"round": None, "kept_round": kept_round,
                       "why": "fewer infeasible designs and failures than the last round"})
    return kept, rounds, len(design_cache)


def run_plan(loaded, *, seed=None, progress=None, jobs=None, settings: Settings | None = None,
             on_assignment=None, scheduler=None, cache_dir=None, free_cores=None) -> Plan:
    """Run every stage; returns a :class:`Plan` (files are written by :func:`plan`).

    ``loaded``: a :class:`~planner.arrayspec.LoadedSpec`; ``settings`` (optional) its
    already resolved :class:`Settings`.  ``jobs``: worker processes for the designs
    (default 1).  ``on_assignment(settings, steps, assignment)`` is called once, after
    the first assignment and before any design (the CLI prints the work left and a
    time estimate there).  ``scheduler``: address of a ``dask.distributed`` scheduler
    to run the designs and the verification steps on (without it, the designs run in
    ``jobs`` local worker processes and the steps in this process).  ``cache_dir``: the
    on-disk design cache's folder (:class:`~planner.planning.design_store.DesignStore`;
    None: designs are cached for this run only).  ``free_cores``: a function of no
    arguments giving the cores other processes leave free; the stages that run numba's
    parallel kernels in this process (verification, scenes and coupling,
    manufacturability) take their thread count from it when they start
    (:func:`planner.runtime.cores.stage_threads`; default measured,
    :func:`planner.runtime.cores.measured_free_cores`).  It changes no result, only the time.
    """
    if settings is None:
        settings = resolve_settings(loaded, seed)
    tick = progress or (lambda stage, item=None, total=None: None)
    clock = _Clock()
    store = DesignStore(cache_dir) if cache_dir is not None else None
    jobs = max(1, int(jobs or 1))
    with (contextlib.nullcontext(free_cores) if free_cores is not None
          else measured_free_cores()) as free:
        # a plan this cache saw through before starts its workers only if a task needs
        # them (a re-run reads everything: spawning them would only compete for the
        # cores); any other starts them at once, to load the kernels meanwhile
        seen = stage_digest("plan_seen", settings) if store is not None else None
        eager = not (store is not None and store.marked("plan_seen", seen))
        with plan_pool(jobs, scheduler, eager) as pool:
            # what a design can serve, the channels on it, and how far apart they must
            # be (the stage's time includes the first assignment's)
            _, first = clock.timed("reach", measure_reach, settings, jobs=jobs,
                                   scheduler=scheduler, pool=pool, store=store,
                                   progress=tick)
            kept, rounds, designed = _repair_rounds(
                settings, clock, tick, on_assignment,
                dict(jobs=jobs, scheduler=scheduler, store=store, pool=pool), first, free)
        result = _finish(settings, kept, rounds, clock, scheduler, store, free, designed)
    if store is not None and eager:
        store.mark("plan_seen", seen)
    return result


#: The modules a plan's worker tasks import (designs, reach probes, step checks),
#: imported by each worker as it starts when numba's cache is warm.
WORKER_MODULES = ("planner.planning.designs", "planner.planning.reach",
                  "planner.planning.verify", "planner.designer")


def plan_pool(jobs, scheduler=None, eager=True):
    """The plan's local worker pool (None: serial, or a Dask cluster), kept over every
    repair round, started at once when ``eager``, else by the first task (none: no
    worker).  With numba's cache cold its first worker compiles the solver's kernels
    (:mod:`model.warmup`) while this process assigns the channels and synthesises the
    drives, and the first task waits for it; warm, every worker imports
    :data:`WORKER_MODULES` as it starts, and :func:`planner.planning.designs.dispatch`
    does tasks in this process until one is up (a spec of two probes is done first).
    Only where the tasks run changes, never their results."""
    if jobs <= 1 or scheduler:
        return contextlib.nullcontext(None)
    from model.warmup import compile_kernels, numba_cache_state
    from planner.runtime.workers import warm_pool

    cold, total = numba_cache_state()
    if cold or not total:
        # one worker compiles while the others wait: no kernel is compiled twice at once
        return warm_pool(jobs, compile_kernels, eager=eager)
    # numba's cache is warm: every worker imports the design and check tasks as it starts
    return warm_pool(jobs, eager=eager, preload=WORKER_MODULES)


def _cache_record(store, designed):
    """:attr:`Plan.design_cache`: the design cache's path, its designs read and written,
    the reach's probes read and written, the distinct designs, and per later stage
    (``verify``, ``manufacturability``) the results read and written (None without a
    cache)."""
    if store is None:
        return None
    return {"path": str(store.path), "read": store.hits, "written": store.writes,
            "probes": dict(store.probes),
            "designed": designed,
            "stages": {k: dict(v) for k, v in sorted(store.stages.items())}}


def _finish(settings, kept: _Round, rounds, clock, scheduler, store=None,
            free_cores=None, designed=0) -> Plan:
    """The kept round's scenes (with the motion repair), coupling matrix,
    manufacturability and record, as a :class:`Plan` (``store``: the on-disk cache
    the motion repair's checks and the manufacturability are read from and written to,
    or None; ``free_cores``: as :func:`run_plan`'s; ``designed``: the distinct designs
    of the rounds, for :attr:`Plan.design_cache`)."""
    ts = time.perf_counter()
    felt = kept.played
    if settings.chain is not None:
        from planner.planning.chain import die_drives

        felt = die_drives(settings, kept.played)
    with stage_threads(free_cores):
        # the scenes carry every impacter's and slider's state from step to step, each
        # step followed by its settle dwell; what they find counts in the verification,
        # and the motion repair acts on it (shorter bursts, longer dwells)
        (run_steps, ver_rows, failures, scene_rows, motion_repairs,
         step_settle) = scenes_and_motion(settings, kept.run_steps, felt,
                                          kept.impacters, kept.sliders, kept.ver_rows,
                                          kept.failures, scheduler=scheduler,
                                          store=store)
        assignment, designs = kept.assignment, kept.designs
        tones = sorted(set(assignment.frequencies.values()))
        coupling = coupling_matrix(kept.impacters, tones, settings, settings.single_step_s,
                                   store=store)
    clock.timings["scenes_coupling"] = time.perf_counter() - ts
    # what a fabricated chip does to these designs: sensitivities, separations and the
    # predicted collision-free yield under the spec's tolerances
    with stage_threads(free_cores):
        manufacturability = clock.timed("manufacturability", assess, settings, run_steps,
                                        assignment, designs, kept.waveforms, store=store)
    ver = pd.DataFrame(ver_rows)
    # the kept round's confirmations again, on the steps as they now play (the motion
    # repair may have shortened a burst)
    ts = time.perf_counter()
    confirmed = (confirm_responses(settings, run_steps, felt, designs, kept.sliders)
                 if kept.confirmed else {})
    clock.add("verify", ts)
    problems = design_problems(designs, settings, rounds, confirmed)
    # an infeasible design fails the plan even if the steps happen to verify: it was
    # not shown silent at its forbidden tones on the designer's fine grid
    passed = bool(ver["passed"].all()) and not problems
    motion = {"sizing": kept.sizing, "drive": kept.drive_notes, "settle_s": step_settle,
              "repairs": motion_repairs, "design_problems": problems,
              "confirmed_designs": [confirmed[n] for n in sorted(confirmed)],
              "gating": kept.gating}
    sections = {}
    if settings.chain is not None:
        from planner.planning.chain import chain_record

        # plan.json's chain block (the report's section)
        sections["chain"] = chain_record(settings, kept.played, kept.drive_notes, run_steps,
                                         assignment.frequencies)
    record = build_record(
        settings, run_steps, assignment, designs, kept.sliders, kept.played, ver_rows,
        passed, rounds, scene_rows, motion, manufacturability, sections)
    clock.timings["total"] = time.perf_counter() - clock.t0
    return Plan(
        impacters=pd.DataFrame(record.impacters), devices=pd.DataFrame(record.devices),
        steps=pd.DataFrame(record.steps), verification=ver, coupling=coupling,
        scenes=pd.DataFrame(scene_rows), passed=passed, data=record.data,
        timings=clock.timings, plan_file=record.file,
        settings=settings, waveforms=kept.played, designs=designs, assignment=assignment,
        failures=tuple(failures), design_cache=_cache_record(store, designed),
        run_steps=tuple(run_steps),
        dwells=dict(step_settle))
