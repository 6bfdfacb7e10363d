"""As-built re-plan: a new drive for a fabricated chip from its measured resonances.

After fabrication an impacter's geometry is fixed, but its drive is not.  Given a plan
(its plan.json) and each impacter's measured natural frequency (and optionally its
quality factor and gap, and each half of a pair), this module builds the as-built model
of every impacter and re-plans the drive only (:mod:`planner.afterfab.drive`):

1. **as-built models** (:func:`planner.afterfab.as_built.as_built`): the fabrication
   errors inferred from the measured resonances under the spec's tolerances, the chip
   rebuilt through eqs. (2)-(4) (mass, stiffness, damping, gap and sliders), each
   resonance exactly as measured; a measured quality factor sets the damping and a
   measured gap the gap; a pair measured half by half is two such models
   (:class:`model.PairHalves`);
2. **tones**: each impacter's tone moves with its measured resonance, keeping its place
   relative to it; every pair the steps must tell apart is checked against the plan's
   measured silent bands and tone windows (plan.json's ``manufacturability``), and a pair
   no drive can tell apart is named with its as-built resonances and the separation it
   would need: the re-plan then fails (exit 1); a trim can still rescue the chip
   (``vibroplan trim``);
3. **steps**: every step is synthesised with the new tones under
   ``drive.max_acceleration_g``; a multi-tone step the limit would weaken beyond the
   plan's verified drive is split into sub-steps of neighbouring tones; bursts asked as
   a travel are sized again for the as-built speeds;
4. **verification and motion repair** as the plan's: every step re-simulated on the
   as-built models, every scene with the state carried across steps, too-long travels
   shortened and slow settles given longer dwells.

The original plan's drive is verified on the as-built models too, so that the report
can say whether the chip needed the re-plan.  :func:`replan_chip` is the per-chip entry
point for a yield study.
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np
import pandas as pd

import model
from model import Drive
from planner.assignment.assign import Assignment, conflict_graph, guard_violations
from planner.core.markdown import Section, fmt, md_table
from planner.core.nodes import Node, device_key, node_key
from planner.planfile.reader import PlanRecord, drives
from planner.planfile.schema import Replan
from planner.planning.chain import die_drives
from planner.planning.record import build_record
from planner.planning.repair import scenes_and_motion
from planner.afterfab.as_built import AsBuilt, as_built, resonance_times, symmetric
from planner.afterfab.drive import (REPLAN_TRAVEL_MARGIN, move_tones, plan_phases, quieten,
                                    redraw_slow, rescue, reunite, split_weak)
from planner.planning.result import Plan
from planner.planning.settings import plan_settings, tone_amplitudes
from planner.planning.verify import (TOO_SLOW, check_step, check_steps, coupling_matrix,
                                     too_slow, x0_grid)

#: The re-plan's repairs by kind (plan.json's ``replan.repairs``, yield.json's and the
#: wafer summary's counts): a tone moved within its window, a step split into runs, a
#: step's phases drawn anew, a step played weaker, a burst shortened, a dwell lengthened.
TONE_MOVED, STEP_SPLIT, RE_PHASED, QUIETENED = ("tone_moved_in_window", "step_split",
                                                "re_phased", "quietened")
BURST_SHORTENED, DWELL_LENGTHENED = "burst_shortened", "dwell_lengthened"
#: A tone raised in a step its slider moved too slowly in: on the measured models where
#: no place in its window drives it (:func:`_raised`), or on the chip itself in the
#: loop's tune stage (:func:`planner.afterfab.loop._played_on_chip`).
AMPLITUDE_RAISED = "amplitude_raised"
#: A ``targets_um`` step's tone gates found again on the chip itself, its sliders'
#: positions read after each play (:func:`planner.afterfab.loop._played_on_chip`).
GATES_ON_CHIP = "gates_timed_on_chip"
REPAIR_KINDS = (TONE_MOVED, STEP_SPLIT, RE_PHASED, QUIETENED, BURST_SHORTENED,
                DWELL_LENGTHENED, AMPLITUDE_RAISED, GATES_ON_CHIP)

#: How far from its measured value a slider's impacter resonance is assumed to lie when
#: the re-plan checks the slider's speed with a margin (:func:`_speed_margin`), in sigmas
#: of the lab's measurement (``fabrication.measurement_noise_pct``) [-].  Issue 45: at
#: 0.05 %, 9 of 185 chips of the default were too slow on the chip (0.078-0.099 mm/s
#: against 0.1) where their measured models said 0.149-0.185: the top tones' (48-49 kHz)
#: speed falls within 24 Hz, one sigma.
SPEED_MARGIN_SIGMAS = 2.5
#: The steps :func:`_speed_margin` checks: those in which some slider is slower than this
#: many times the speed floor on the measured models [-] (a faster one keeps its speed a
#: sigma away: the speeds that fell on the chip were 1.5-1.85 times the floor).
SPEED_MARGIN_RATIO = 2.5


def verify_drive(plan: PlanRecord, models: AsBuilt, settings=None):
    """Verify a plan's recorded drive on a chip's models.

    Parameters
    ----------
    plan : PlanRecord
        A plan (:func:`planner.planfile.reader.read_plan`; its steps' tones are the
        drive).
    models : AsBuilt
        The chip's models (:func:`planner.afterfab.as_built.as_built`).
    settings : Settings, optional
        The plan's settings (re-resolved from its spec when omitted).

    Returns
    -------
    passed : bool
    rows : list of dict
        The verification rows (as plan.json's), one per step and device.
    """
    if settings is None:
        settings = plan_settings(plan)
    impacters = {r.node: models.impacters[r.id] for r in plan.impacters}
    # with a distorting drive chain, what the die feels: the tones and their products
    waves = die_drives(settings, drives(plan))
    rows = []
    for st in plan.steps:
        rows += check_step(settings, st.step, waves[st.key], impacters, models.sliders)[0]
    return bool(rows) and all(r["passed"] for r in rows), rows


def chip_models(plan: PlanRecord, measured: dict, noise_pct=None) -> AsBuilt:
    """The as-built models of a chip of ``plan`` measured as ``measured`` (id ->
    :class:`~planner.afterfab.measurement.Measurement`; an impacter without one keeps
    the die's errors): :func:`planner.afterfab.as_built.as_built` on the plan's designs,
    the measurement's noise the spec's ``fabrication.measurement_noise_pct`` unless
    given."""
    from planner.fabrication.tolerances import design_from_plan

    if noise_pct is None:
        noise_pct = plan.spec.fabrication.measurement_noise_pct
    return as_built(design_from_plan(plan), measured, noise_pct=noise_pct)


def resonances(plan: PlanRecord, measured: dict) -> dict:
    """Impacter id -> its measured resonance [Hz] (the halves' (a, b) where measured
    apart), the design's where not measured: what the tone rules read."""
    return {r.id: (measured[r.id].resonance if r.id in measured else r.natural_frequency_hz)
            for r in plan.impacters}


# --------------------------------------------------------------------------- the re-plan

def _design_like(rec, imp, tone, settings):
    """A DesignResult standing for the as-built impacter (the record, figures and the
    coupling read it like a design); a pair of unequal halves stands as the symmetric
    pair at their mean resonance."""
    from planner.designer.result import DesignResult

    imp = symmetric(imp)
    g = rec.geometry
    geometry = model.Geometry(g.area_m2, g.width_m, g.length_m, imp.gap)
    imp = model.Impacter(imp.mass, imp.stiffness, imp.damping, imp.gap, imp.impact_angle,
                         imp.restitution, geometry)
    x0s = x0_grid(imp, settings.x0_points)
    r_own = model.responses(imp, Drive([tone], [float(tone_amplitudes(settings, [tone])[0])]),
                            x0s, duration=settings.window_s)
    return DesignResult(
        impacter=imp, frequency_hz=tone, forbidden_hz=(),
        natural_frequency_hz=imp.natural_frequency, mass_kg=imp.mass,
        stiffness_n_per_m=imp.stiffness, damping_ns_per_m=imp.damping, gap_m=imp.gap,
        impact_angle_rad=imp.impact_angle, restitution=imp.restitution, geometry=geometry,
        worst_x0_m=float(x0s[int(np.argmin(r_own))]), r_min_n=float(np.min(r_own)),
        r_max_forbidden_n=(), margins_hz=(),
        predicted_slider_speed_m_s=rec.predicted_slider_speed_m_s or math.nan,
        feasible=bool(np.min(r_own) > 0), evaluations=0, seconds=0.0,
        status="as-built", message="as-built model: the design's mass and geometry, the "
                                   "measured resonance")


def replan(plan: PlanRecord, measured, *, seed=None, settings=None, progress=None,
           original=None, record=True, remeasure=(), models=None):
    """Re-plan the drive of a fabricated chip from its measured resonances.

    Parameters
    ----------
    plan : PlanRecord
        The original plan (:func:`planner.planfile.reader.read_plan`; a re-planned
        plan is a plan too).
    measured : dict
        Impacter id -> :class:`~planner.afterfab.measurement.Measurement`
        (:func:`~planner.afterfab.measurement.read_measured`); an impacter not in it keeps
        its design's resonance.
    seed : int, optional
        Drive phases' seed (default: the plan's).
    settings : Settings, optional
        The plan's settings, already resolved (:func:`planner.planning.settings.
        plan_settings`; a yield study resolves them once for every chip); ``seed`` is
        then theirs.
    progress : callable, optional
        ``progress(stage, item=None, total=None)`` as :func:`planner.planning.run_plan`.
    original : tuple, optional
        ``(passed, rows)`` of the original drive already verified on this chip (a yield
        study has just verified it on the chip's true models): recorded as
        ``replan.original_drive`` instead of verifying it again with
        :func:`verify_drive` on the measured models.
    record : bool
        False: skip what only the outputs read (the scene simulation on the measured
        models and the coupling matrix; ``scenes`` is then empty and ``coupling`` an
        empty table).  The drive and its verification are the same.
    remeasure : iterable of str
        Impacter ids whose silent bands and tone windows are measured again on their
        as-built models (a trim's moved impacters: :func:`planner.afterfab.drive.
        remeasured`) instead of taken from the plan's ``manufacturability`` block.
    models : AsBuilt, optional
        The chip's models when known otherwise (a trimmed chip's: the as-built models of
        its first measurement with the trims applied); default
        :func:`chip_models` of ``measured``.

    Returns
    -------
    Plan
        The re-planned drive verified on the as-built models; ``data`` is the plan.json
        contract plus ``as_built`` and ``replan`` (what moved, the original drive's
        verification on this chip, the impacters that can no longer be told apart).
    """
    tick = progress or (lambda stage, item=None, total=None: None)
    t0 = time.perf_counter()
    timings = {}
    if settings is None:
        settings = plan_settings(plan, seed)
    plan_imps = {r.node: r for r in plan.impacters}
    built = (models if models is not None else
             chip_models(plan, measured, 100.0 * settings.measurement_noise))
    params = built.parameters()
    models = {n: built.impacters[r.id] for n, r in plan_imps.items()}
    devices = sorted({n.device for n in models}, key=device_key)
    sliders = {d: built.sliders[d] for d in devices}

    # the original drive on this chip
    ts = time.perf_counter()
    tick("original", total=1)
    if original is None:
        orig_passed, orig_rows = verify_drive(plan, built, settings)
    else:
        orig_passed, orig_rows = bool(original[0]), list(original[1])
    timings["original_drive"] = time.perf_counter() - ts

    # the checks on the measured models keep a margin on the travel (REPLAN_TRAVEL_MARGIN);
    # the record states the spec's own limit
    strict = dataclasses.replace(settings,
                                 max_travel_m=settings.max_travel_m * REPLAN_TRAVEL_MARGIN)
    ts = time.perf_counter()
    windows = {n: m.window_hz for n, m in measured.items() if m.window_hz is not None}
    drive = rescue(plan, resonances(plan, measured), settings, models, sliders,
                   remeasure=remeasure, windows=windows)
    steps_, waveforms_, gating = regate(settings, drive.steps, drive.waveforms, drive.tones,
                                        models, sliders, plan_phases(plan))
    drive = dataclasses.replace(drive, steps=steps_, waveforms=waveforms_, gating=gating)
    if settings.chain is not None:
        # the new tones through the plan's drive chain: the amplifier input's limits
        # (a tone it cannot deliver refused, naming it; a step over the limit lowered)
        drive = _within_input_limit(settings, drive)
    timings["drive"] = time.perf_counter() - ts
    ts = time.perf_counter()
    tick("verify", total=len(drive.steps))
    # a step's checks by the step and its loop: the repairs below re-check whole drives
    # of which they changed a step or two (the loop is kept in the entry, so that its id
    # is not reused while the entry lives)
    checked = {}

    def check(steps, waveforms, progress=None):
        todo = [st for st in steps if (st, id(waveforms[st.key])) not in checked]
        # through a distorting chain the die feels the tones and their products
        done = check_steps(strict, todo, die_drives(settings, {st.key: waveforms[st.key]
                                                               for st in todo}),
                           models, sliders, progress=progress) if todo else []
        for st, got in zip(todo, done):
            checked[(st, id(waveforms[st.key]))] = (waveforms[st.key], got)
        rows, fails = [], []
        for st in steps:
            r, f = checked[(st, id(waveforms[st.key]))][1]
            rows += r
            fails += f
        return rows, fails

    ver_rows, failures = check(drive.steps, drive.waveforms, lambda k: tick("verify", k))
    # a row that shared one tone in the plan, now on a tone per member, and failing: on
    # one tone again, where that passes more checks
    drive, ver_rows, failures = reunite(plan, strict, drive, ver_rows, failures, models,
                                        sliders, check)
    # a step the acceleration limit weakened, failing by a slow slider: split it where
    # its sub-steps pass more checks
    drive, ver_rows, failures = split_weak(strict, drive, ver_rows, failures, models,
                                           sliders, check)
    # a multi-tone step a slider is still too slow in: its phases drawn anew, where a
    # draw passes more checks
    drive, ver_rows, failures = redraw_slow(strict, drive, ver_rows, failures, models,
                                            sliders, check)
    # a step an idle impacter answers on this chip: played weaker, where that passes
    drive, ver_rows, failures = quieten(strict, drive, ver_rows, failures, models,
                                        sliders, check)
    verified = drive, ver_rows, failures
    steps, ver_rows, failures, scene_rows, repairs, settle = scenes_and_motion(
        strict, drive.steps, die_drives(settings, drive.waveforms), models, sliders,
        ver_rows, failures, dwell_floor=drive.dwells)
    if (not all(r["passed"] for r in ver_rows) and not drive.inseparable
            and not drive.outside_band):
        # the drive still fails on the measured models: a tone that drives its slider too
        # slowly, or that an idle neighbour answers, moved within its window; the other
        # repairs then again on the steps it plays in.  Kept where fewer checks fail
        # (a chip whose re-plan passed is never touched)
        moved, rows_, fails_ = move_tones(strict, *verified, models, sliders, check)
        if moved.tone_moves:
            moved, rows_, fails_ = redraw_slow(strict, moved, rows_, fails_, models,
                                               sliders, check)
            moved, rows_, fails_ = quieten(strict, moved, rows_, fails_, models,
                                           sliders, check)
            got = _fewer_failing(strict, moved, rows_, fails_, models, sliders, ver_rows)
            if got is not None:
                drive = moved
                steps, ver_rows, failures, scene_rows, repairs, settle = got
    if (any(f.kind == TOO_SLOW for f in failures) and not drive.inseparable
            and not drive.outside_band):
        # a slider still too slow at every place its tone was tried: its tone raised in
        # that step (issue 45, item 2: the drive changed before the chip is scrapped),
        # kept where fewer checks fail
        raised = _raised(strict, drive, failures, models, sliders, check)
        got = (None if raised is None else
               _fewer_failing(strict, raised, *check(raised.steps, raised.waveforms), models,
                              sliders, ver_rows))
        if got is not None:
            drive = raised
            steps, ver_rows, failures, scene_rows, repairs, settle = got
    if (settings.measurement_noise > 0.0 and not drive.inseparable
            and not drive.outside_band):
        # a slider fast enough on the measured models but too slow where its resonance
        # is one measurement's error away: its tone raised in that step, kept where no
        # more checks fail on the measured models (issue 45, item 3)
        margined = _speed_margin(strict, drive, ver_rows, models, sliders, check,
                                 swept=windows)
        got = (None if margined is None else
               _fewer_failing(strict, margined, *check(margined.steps, margined.waveforms),
                              models, sliders, ver_rows, or_as_many=True))
        if got is not None:
            drive = margined
            steps, ver_rows, failures, scene_rows, repairs, settle = got
    timings["verify"] = time.perf_counter() - ts

    ts = time.perf_counter()
    assignment = _assignment(steps, settings, drive.tones, plan.lower_bound, warnings=record)
    designs = {n: _design_like(plan_imps[n], models[n], drive.tones[n], settings)
               for n in plan_imps}
    impacters = {n: d.impacter for n, d in designs.items()}
    coupling = (coupling_matrix(impacters, sorted(set(drive.tones.values())), settings,
                                settings.single_step_s) if record else pd.DataFrame())
    if not record:      # a yield study verifies the drive on the chip's true models itself
        scene_rows = []
    timings["coupling"] = time.perf_counter() - ts
    ver = pd.DataFrame(ver_rows)
    # an impacter no tone of the band drives fails the re-plan, whatever its
    # simulation at the band edge says (its window lies beyond the band)
    passed = bool(ver["passed"].all()) and not drive.inseparable and not drive.outside_band
    motion = {"sizing": drive.sizing, "drive": drive.notes, "settle_s": settle,
              "repairs": repairs, "design_problems": [], "gating": drive.gating}
    rounds = [{"round": 0, "span": assignment.span,
               "failures": sum(1 for r in ver_rows if not r["passed"])}]
    sections = {"as_built": params,
                "replan": _replan_record(plan, settings, params, drive, orig_passed,
                                         orig_rows, windows, repairs)}
    if settings.chain is not None:
        from planner.planning.chain import chain_record

        # plan.json's chain block, of the re-planned tones (the report's section)
        sections["chain"] = chain_record(settings, drive.waveforms, drive.notes, steps,
                                         drive.tones)
    rec = build_record(
        settings, steps, assignment, designs, sliders, drive.waveforms, ver_rows, passed,
        rounds, scene_rows, motion,
        # the designs' separations go with the re-plan (the designs are the chip's; a
        # trim or a re-plan of the re-plan reckons from them, as from the plan); the
        # plan's prediction of a yield is not about this chip and stays with the plan
        manufacturability=(None if plan.manufacturability is None else {
            "separation_hz": plan.manufacturability["separation_hz"],
            "note": "the designs' silent bands and tone windows, from the plan this chip "
                    "was made by (its predicted yield is the plan's)"}),
        sections=sections)
    timings["total"] = time.perf_counter() - t0
    return Plan(
        impacters=pd.DataFrame(rec.impacters), devices=pd.DataFrame(rec.devices),
        steps=pd.DataFrame(rec.steps), verification=ver, coupling=coupling,
        scenes=pd.DataFrame(scene_rows), passed=passed, data=rec.data, timings=timings,
        plan_file=rec.file, settings=settings, waveforms=drive.waveforms, designs=designs,
        assignment=assignment, failures=tuple(failures), run_steps=tuple(steps),
        dwells=dict(settle))


def _within_input_limit(settings, drive):
    """``drive`` (a :class:`~planner.afterfab.drive.RescuedDrive`) with its loops held to
    the drive chain's input limit (:func:`planner.planning.chain.limit_input`, as the
    plan's were) and its gated bursts checked against it; its ``synthesize_and_limit``
    (a split's sub-steps) does the same."""
    from planner.planning.chain import check_bursts, limit_input

    def within(waveforms, notes, steps):
        loops = {k: w for k, w in waveforms.items() if getattr(w, "gates_s", None) is None}
        kept, input_notes = limit_input(settings, loops, steps, drive.tones)
        check_bursts(settings, waveforms)
        notes = {k: {**v, **input_notes.get(k, {})} for k, v in notes.items()}
        return {**waveforms, **kept}, notes

    waveforms, notes = within(drive.waveforms, drive.notes, drive.steps)
    inner = drive.synthesize_and_limit

    def synthesize_and_limit(steps, freqs):
        w, nt = inner(steps, freqs)
        return within(w, nt, steps)

    return dataclasses.replace(drive, waveforms=waveforms, notes=notes,
                               synthesize_and_limit=synthesize_and_limit)


def regate(settings, steps, waveforms, tones, models, sliders, phases=None):
    """Gate every ``targets_um`` step again for the chip's models, as the plan gated it
    for its designs (:func:`planner.planning.targets.place_targets`: one tone at a time,
    each playing until its slider has gone its move, found by the scene simulated with
    its state carried).  A slider's speed is the chip's: the plan's gates would put it
    wherever the design's speed would have.

    Returns
    -------
    (steps, waveforms, gating)
        As :func:`~planner.planning.targets.place_targets` returns them; unchanged (and
        ``gating`` empty) when no step asks for positions.  A slider that cannot reach
        its target on this chip keeps the step as synthesised: its verification then
        says by how far it misses.
    """
    from planner.core.errors import PlanningError
    from planner.planning.drives import synthesize_steps
    from planner.planning.targets import place_targets

    targeted = tuple(st for st in steps if st.targets_m is not None)
    if not targeted:
        return steps, waveforms, {}
    # the tones play one at a time: at their amplitudes as synthesised, not as lowered
    # for the peak of their whole sum, which never plays (as the plan's)
    raw = synthesize_steps(settings, targeted, tones, phases=phases)
    try:
        return place_targets(settings, steps, {**waveforms, **raw}, tones, models, sliders)
    except PlanningError:
        return steps, waveforms, {}


def _assignment(steps, settings, chosen, lower_bound, warnings=True):
    """An :class:`~planner.assignment.assign.Assignment` of the chosen tones (the conflict graph as
    before; each impacter's channel is the grid channel of its tone).  ``warnings``:
    False leaves out the guard-rule warnings, which only plan.json's record reads (a
    yield study's re-plan is never written; they cost 0.1 s a re-plan on the 5 x 5)."""
    grid = np.asarray(settings.channel_grid_hz)
    graph, groups = conflict_graph(steps, settings.separation_channels, None,
                                   settings.ensemble_separation_channels)
    # in the nodes' order, not a set's (its order follows the strings' hashes, which
    # change from process to process: plan.json's guard notes would too)
    nodes = sorted({n for g in groups.values() for n in g}, key=lambda n: node_key(n.text))
    channels = {n: int(np.argmin(np.abs(grid - chosen[n]))) for n in nodes}
    freqs = {n: float(chosen[n]) for n in nodes}
    lo = min(channels.values())
    coloring = {g: channels[members[0]] - lo for g, members in groups.items()}
    span = max(channels.values()) - lo + 1
    return Assignment(graph, groups, coloring, span, int(lower_bound), False,
                      "as-built", 0.0, 1, lo, channels, freqs,
                      guard_violations(steps, freqs, settings.tone_rules) if warnings else [])


def _fewer_failing(settings, drive, rows, failures, models, sliders, than, *,
                   or_as_many=False):
    """:func:`planner.planning.repair.scenes_and_motion` of a repaired ``drive`` (its steps
    checked: ``rows``, ``failures``), or None unless fewer of its checks then fail than of
    ``than`` (the rows of the drive it would replace; ``or_as_many``: no more)."""
    got = scenes_and_motion(settings, drive.steps, die_drives(settings, drive.waveforms),
                            models, sliders, rows, failures, dwell_floor=drive.dwells)
    now, before = sum(not r["passed"] for r in got[1]), sum(not r["passed"] for r in than)
    if now < before or (or_as_many and now == before):
        return got
    return None


def _speed_margin(settings, drive, rows, models, sliders, check, swept=()):
    """``drive`` with the tones raised of the sliders that move fast enough on the
    measured models but too slowly where their impacters' resonances are
    :data:`SPEED_MARGIN_SIGMAS` measurement sigmas higher or lower; None when no step
    needed it or no raise helped.

    A measured resonance is off by the lab's noise (``settings.measurement_noise``), and
    near a tone window's edge a slider's speed falls within a sigma of detuning: the
    re-plan's checks on the measured models pass and the chip is too slow.  The steps in
    which some slider is slower than :data:`SPEED_MARGIN_RATIO` times the floor are
    checked again on the chip's models with every resonance shifted up, then down, by
    that margin (:func:`planner.afterfab.as_built.resonance_times`); a slider too slow on either has its tone raised in that step by
    :func:`planner.afterfab.drive.raise_slow`, every factor checked on the measured
    models (the idle impacters' silence among them) and kept only where the slider is
    fast enough on both shifted chips.

    The shift is at most the designs' tone window (``settings.tone_window``): beyond it
    no design was made to drive its slider, and at 0.1 % noise (2.5 sigmas 0.25 %
    against a 0.15 % window) the raises it asked for cost the loop 24 chips of 200.
    A slider whose impacters' working windows a tuning sweep measured on the chip
    (``swept``: impacter ids) needs no margin: its speed there was read, not inferred.
    ``check`` is the re-plan's ``(steps, waveforms) -> (rows, failures)`` on the
    measured models."""
    from planner.afterfab.drive import raise_slow

    if settings.chain is not None:
        return None
    limit = SPEED_MARGIN_RATIO * settings.min_speed_m_s
    near = {r["index"] for r in rows
            if r["passed"] and r.get("min_speed_m_s") is not None
            and np.isfinite(r["min_speed_m_s"]) and r["min_speed_m_s"] < limit}
    steps = [st for st in drive.steps if st.index in near and st.targets_m is None]
    if not steps:
        return None
    shift = SPEED_MARGIN_SIGMAS * settings.measurement_noise
    if settings.tone_window > 0.0:
        shift = min(shift, settings.tone_window)
    shifted = [{n: resonance_times(imp, 1.0 + s) for n, imp in models.items()}
               for s in (-shift, shift)]

    by_index = {st.index: st for st in steps}

    def unswept(f):
        # the slow slider's moving impacters in that step, not all swept on the chip
        st = by_index.get(f.step)
        return st is not None and any(
            Node(d, r).text not in swept for d, r in st.active_nodes() if d == f.device)

    # only the sliders' speeds on the shifted chips are read (the idle, travel and
    # settling checks are the measured models' to make): too_slow runs those alone, and
    # remembers them from one of raise_slow's tries to the next (one step changes)
    speeds = [{} for _ in shifted]

    def on_shifted(steps_, waveforms_):
        drives_ = die_drives(settings, waveforms_)
        fails_ = [f for m, memo in zip(shifted, speeds)
                  for f in too_slow(settings, steps_, drives_, m, sliders, memo)
                  if unswept(f)]
        return [], fails_

    _, slow = on_shifted(steps, drive.waveforms)
    if not slow:
        return None
    new_steps, waveforms, raised = raise_slow(
        settings, drive.steps, drive.waveforms, drive.tones, slow, models, sliders, check,
        on_shifted,
        why=f"its slider moved too slowly with its resonance {shift:.3%} off the measured")
    if not raised:
        return None
    notes = dict(drive.notes)
    for r in raised:
        notes[r["step"]] = {**notes.get(r["step"], {}), "raised_by": r["factor"],
                            "raised_ids": list(r["ids"])}
    return dataclasses.replace(drive, steps=tuple(new_steps), waveforms=waveforms,
                               notes=notes)


def _raised(settings, drive, failures, models, sliders, check):
    """``drive`` with the tones of its sliders too slow on the measured models raised
    (:func:`planner.afterfab.drive.raise_slow`, every factor checked on those models),
    each raised step's note saying by how much (``raised_by``); None when none was."""
    from planner.afterfab.drive import raise_slow

    steps, waveforms, raised = raise_slow(settings, drive.steps, drive.waveforms, drive.tones,
                                          failures, models, sliders, check, check)
    if not raised:
        return None
    notes = dict(drive.notes)
    for r in raised:
        notes[r["step"]] = {**notes.get(r["step"], {}), "raised_by": r["factor"],
                            "raised_ids": list(r["ids"])}
    return dataclasses.replace(drive, steps=tuple(steps), waveforms=waveforms, notes=notes)


def repair_counts(drive, motion_repairs=()) -> dict:
    """The re-plan's repairs by kind (:data:`REPAIR_KINDS`, in that order; only the kinds
    that fired): tones moved within their window (:func:`planner.afterfab.drive.
    move_tones`), steps split (:func:`~planner.afterfab.drive.split_weak`), steps played
    at phases drawn anew (:func:`~planner.afterfab.drive.redraw_slow`), steps played
    weaker (:func:`~planner.afterfab.drive.quieten`), and the motion repair's bursts
    shortened and dwells lengthened (:func:`planner.planning.repair.scenes_and_motion`'s
    rounds)."""
    notes = drive.notes.values()
    actions = [a for r in motion_repairs for a in r["actions"]]
    got = {TONE_MOVED: len(getattr(drive, "tone_moves", ()) or ()),
           STEP_SPLIT: len(drive.splits),
           RE_PHASED: sum(1 for nt in notes if "phases_drawn" in nt),
           QUIETENED: sum(1 for nt in notes if "quietened_by" in nt),
           AMPLITUDE_RAISED: sum(1 for nt in notes if "raised_by" in nt),
           BURST_SHORTENED: sum(1 for a in actions if ": burst " in a),
           DWELL_LENGTHENED: sum(1 for a in actions if ": dwell " in a)}
    return {k: got[k] for k in REPAIR_KINDS if got.get(k)}


def _replan_record(plan, settings, params, drive, orig_passed, orig_rows, windows=None,
                   motion_repairs=()):
    """plan.json's ``replan`` block: what moved (with a tuning sweep's working window,
    ``working_window_hz``, where one was measured), the original drive on this chip, the
    pairs no drive tells apart, the steps split, the tones beyond the band; where the
    re-plan repaired its drive, ``repairs`` (kind -> count, :func:`repair_counts`) and
    where it moved a tone within its window, ``tone_moves``."""
    moved = []
    for rec in sorted(plan.impacters, key=lambda r: node_key(r.id)):
        n = rec.id
        # the design's resonance (a re-planned plan's impacters are as built already)
        nu0, nu1 = plan.design_natural_frequency_hz[n], params[n]["natural_frequency_hz"]
        f0, f1 = rec.frequency_hz, drive.tones[rec.node]
        moved.append({"id": n, "design_natural_frequency_hz": nu0,
                      "design_frequency_hz": plan.design_frequency_hz[n],
                      "natural_frequency_hz": nu1, "natural_frequency_shift": nu1 / nu0 - 1,
                      "original_frequency_hz": f0, "frequency_hz": f1,
                      "tone_shift": f1 / f0 - 1})
        if windows and n in windows:
            moved[-1]["working_window_hz"] = [float(x) for x in windows[n]]
    fails = [r for r in orig_rows if not r["passed"]]
    outside = getattr(drive, "outside_band", {}) or {}
    # added only where a repair fired: a re-plan that needed none is written as before
    extra = {}
    counts = repair_counts(drive, motion_repairs)
    if counts:
        extra["repairs"] = counts
    if getattr(drive, "tone_moves", ()):
        extra["tone_moves"] = [dict(m) for m in drive.tone_moves]
    return {
        "moved": moved,
        "original_drive": {
            "passed": bool(orig_passed), "checks": len(orig_rows),
            "failed_checks": len(fails),
            "failures": [{"step": f"{r['scene']}/{r['step']}", "device": r["device"],
                          "cause": r["cause"]} for r in fails]},
        "inseparable": [{**c, "message": inseparable_message(c)} for c in drive.inseparable],
        "split_steps": drive.splits,
        # the impacters whose window lies beyond the band: their tone (frequency_hz)
        # is the band edge, the one they would need is outside_band_hz
        "outside_band": [m["id"] for m in moved if m["id"] in outside],
        "outside_band_hz": {m["id"]: float(outside[m["id"]]) for m in moved
                            if m["id"] in outside},
        **extra,
    }


def outside_band_message(replan: Replan, band_hz) -> str:
    """One line on the impacters whose window lies beyond the drive band ``band_hz``
    (lo, hi) [Hz] (a re-plan's ``outside_band``): the tone each needs, the tone played,
    and that the re-plan fails."""
    lo, hi = band_hz
    played = {m.id: m.frequency_hz for m in replan.moved}
    need = replan.outside_band_hz
    each = "; ".join(
        f"{n}'s working window is around {need[n]:.1f} Hz" if n in need else n
        for n in replan.outside_band)
    plays = ", ".join(f"{n} at {played[n]:.1f} Hz" for n in replan.outside_band)
    return (f"{each}, beyond the drive band {lo:g}-{hi:g} Hz (drive.band_hz), where no "
            f"tone is played; the drive plays the band edge ({plays}), where the slider "
            "is not known to move: the re-plan fails (trim the impacter, or widen the "
            "band if the piezo allows)")


def inseparable_message(c) -> str:
    """One line on impacters no drive tells apart (:func:`planner.afterfab.drive.rescue`'s
    ``inseparable``: a pair, or one impacter whose window several bands cover)."""
    names = [f"{n} ({hz:.0f} Hz as built)" for n, hz in zip(c["pair"], c["as_built_hz"])]
    if c.get("needs_hz") is None:
        return (f"{names[0]} cannot be told apart from {', '.join(names[1:])}: their silent "
                "bands together cover every tone that drives it; trim one of them "
                "(vibroplan trim)")
    return (f"{names[0]} and {names[1]} cannot be told apart: {c['apart_hz']:.0f} Hz "
            f"apart, they need {c['needs_hz']:.0f} Hz (one's tone window lies inside the "
            "other's silent band); trim one of them (vibroplan trim) or drive them together")


def replan_chip(plan: PlanRecord, measured: dict, seed=None, *, settings=None, original=None,
                record=True, remeasure=(), models=None):
    """Re-plan one chip for a yield study: ``(passed, plan)``.

    Parameters
    ----------
    plan : PlanRecord
        The nominal plan.
    measured : dict
        Impacter id -> :class:`~planner.afterfab.measurement.Measurement`.
    seed : int, optional
        Drive phases' seed (default: the plan's).
    settings : Settings, optional
        The plan's settings, resolved once for every chip (:func:`replan`).
    original, record, remeasure, models :
        As :func:`replan`: the original drive's ``(passed, rows)`` when already known
        (not verified again), False to skip the scenes and the coupling matrix
        (``vibroplan yield --replan`` passes both), the impacters whose separations are
        measured again (a trim's), and the chip's models when known otherwise.

    Returns
    -------
    passed : bool
        The re-planned drive verifies on the measured chip's models and no impacters
        collide.
    plan : Plan
        The re-plan: ``plan.data`` is its plan.json; ``plan.run_steps``,
        ``plan.waveforms`` and ``plan.dwells`` its drive, which a yield study checks on
        the chip's true models in memory (:func:`planner.afterfab.checks.check_drive`).
    """
    result = replan(plan, measured, seed=seed, settings=settings, original=original,
                    record=record, remeasure=remeasure, models=models)
    return result.passed, result


# --------------------------------------------------------------------------- outputs

def write_replan_outputs(result: Plan, out_dir, *, figures=True, sections=(), timings=True):
    """Write the re-plan as :func:`planner.planning.outputs.write_outputs` does (plan.json
    with ``as_built`` and ``replan``, CSVs, waveforms, figures); report.md holds the
    re-plan's section (:func:`replan_section`) before the frequency assignment, and
    ``sections`` (a trim's) where the plan's report places them.  ``timings=False``
    leaves the timings out of report.md (a wafer's die: its outputs depend on its inputs
    only)."""
    from planner.planning.outputs import write_outputs

    write_outputs(result, Path(out_dir), figures=figures, timings=timings,
                  sections=[replan_section(result.replan, result.settings.band_hz),
                            *sections])


def replan_section(replan: Replan, band_hz) -> Section:
    """The report's re-plan section: as-built against design, tones moved, the original
    drive on this chip, impacters that can no longer be told apart (``band_hz``: the
    drive band (lo, hi) [Hz])."""
    rp, od = replan, replan.original_drive
    lines = ["Every impacter's as-built model is rebuilt through eqs. (2)-(4) from the "
             "fabrication errors its measured resonance implies under the spec's tolerances "
             "(the die's share common to all, the rest its own): mass, stiffness, damping, "
             "gap and the sliders move together, and each model's resonance is the measured "
             "one; a measured quality factor sets the damping, b = m 2 pi nu_n / Q, a "
             "measured gap the gap.  Each tone moves with its resonance, toward the middle of "
             "its design's measured tone window (within the designed window, "
             "design.tone_window_pct), or to the middle of the working window a tuning sweep "
             "measured on the chip.  Only the drive is re-planned; every check above and "
             "below is on the as-built models.", "",
             f"**The original drive on this chip: {'PASSES' if od.passed else 'FAILS'}** "
             f"({od.checks - od.failed_checks} of {od.checks} step x device checks "
             "pass).", ""]
    if od.failures:
        lines += ["<details><summary>the original drive's failures on this chip</summary>", ""]
        lines += [f"- {f.step} {f.device}: {f.cause}" for f in od.failures[:40]]
        if len(od.failures) > 40:
            lines.append(f"- ... and {len(od.failures) - 40} more (plan.json)")
        lines += ["", "</details>", ""]
    rows = []
    tuned = any(m.working_window_hz is not None for m in rp.moved)
    for m in rp.moved:
        rows.append([m.id, fmt(m.design_natural_frequency_hz, ".1f"),
                     fmt(m.natural_frequency_hz, ".1f"),
                     fmt(100 * m.natural_frequency_shift, "+.2f"),
                     fmt(m.original_frequency_hz, ".1f"), fmt(m.frequency_hz, ".1f"),
                     fmt(100 * m.tone_shift, "+.2f")]
                    + ([("-" if m.working_window_hz is None else
                         "{:.1f}-{:.1f}".format(*m.working_window_hz))] if tuned else []))
    lines += ["### What moved", ""]
    lines += md_table(["impacter", "design nu_n [Hz]", "as-built nu_n [Hz]", "shift [%]",
                       "original tone [Hz]", "new tone [Hz]", "tone shift [%]"]
                      + (["working window [Hz]"] if tuned else []), rows)
    lines.append("")
    if rp.outside_band:
        lines += [f"**Outside the drive band**: {outside_band_message(rp, band_hz)}", ""]
    if rp.split_steps:
        lines += ["### Steps split", "",
                  "The acceleration limit would have lowered these steps' tones further than "
                  "the plan's verified drive; each plays as sub-steps of neighbouring tones, "
                  "one after the other:", ""]
        lines += [f"- {k} -> {', '.join(v)}" for k, v in rp.split_steps.items()] + [""]
    if rp.repairs:
        # only where a repair fired (a re-plan that needed none reads as before)
        lines += ["### Repairs", "",
                  "The re-planned drive's repairs on the measured models, by kind: "
                  + ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in rp.repairs.items())
                  + ".", ""]
        lines += [f"- {m.id}'s tone moved {m.from_hz:.1f} -> {m.to_hz:.1f} Hz within its "
                  + ("window" if m.window_hz is None else
                     "window {:.1f}-{:.1f} Hz".format(*m.window_hz))
                  + f" ({m.tries} positions tried; failed checks of its steps "
                  f"{m.failures_before} -> {m.failures_after})" for m in rp.tone_moves]
        lines += [""] if rp.tone_moves else []
    if rp.inseparable:
        lines += ["### Impacters no drive can tell apart (the re-plan fails)", ""]
        lines += [f"- {c.message}" for c in rp.inseparable] + [""]
    return Section("As-built re-plan", lines)
