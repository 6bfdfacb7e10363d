"""Stage 5, verification: every step re-simulated with its summed drive; the coupling matrix.

:func:`check_step` gives the rows of plan.json's verification (with their readable
``cause``) and the same failures as :class:`Failure` records, which the repair stage
acts on.
"""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
from dataclasses import dataclass

import numpy as np
import pandas as pd

import model
from model import Drive
from planner.core.nodes import Node, device_key
from planner.planning.drives import program_of
from planner.planning.motion import by_node, device_travel, run_phase
from planner.planning.settings import Settings, tone_amplitudes
from planner.core.units import UM

#: Failure kinds: an idle impacter hits its slider; a moving slider is too slow from some
#: x0; an idle slider moves beyond the tolerance.
IDLE_RESPONSE, TOO_SLOW, IDLE_MOVES = "idle_response", "too_slow", "idle_moves"
#: Failure kinds of the motion checks: a slider travels more than
#: ``verification.max_travel_um`` in one step (burst and dwell); a step's sliders or
#: impacters still move at the end of the longest dwell; in the scene simulation
#: (state carried from step to step), an idle slider moves beyond the tolerance.
TRAVEL_OVER, UNSETTLED, CARRIED_IDLE = ("travel_over_limit", "unsettled",
                                        "carried_idle_motion")
#: Failure kind of a ``targets_um`` step: a slider ends further than
#: ``verification.position_tolerance_um`` from its target (from some initial state of
#: the per-step check, or in the carried-state scene simulation).
OFF_TARGET = "off_target"


@dataclass(frozen=True)
class Failure:
    """One failed check of one step.

    Attributes
    ----------
    step : int
        The step's index.
    device : str
        The device checked.
    impacter : Node or None
        The offending impacter for ``idle_response``; None otherwise.
    kind : str
        :data:`IDLE_RESPONSE`, :data:`TOO_SLOW`, :data:`IDLE_MOVES`,
        :data:`TRAVEL_OVER`, :data:`UNSETTLED`, :data:`CARRIED_IDLE` or
        :data:`OFF_TARGET`.
    value : float
        Worst response r [N], worst speed [m/s], displacement or travel [m], dwell
        [s] (unsettled), or position error [m] (off target), by kind.
    """

    step: int
    device: str
    impacter: Node | None
    kind: str
    value: float


def x0_grid(impacter, n):
    """``n`` initial positions [m] over [-c, c] (a fresh array)."""
    key = (float(impacter.gap), int(n))
    grid = _X0_GRIDS.get(key)
    if grid is None:
        if len(_X0_GRIDS) > 4096:
            _X0_GRIDS.clear()
        grid = _X0_GRIDS[key] = np.linspace(-impacter.gap, impacter.gap, n)
        grid.flags.writeable = False
    return grid.copy()


#: (gap [m], n) -> the x0 grid (np.linspace's own digits), read-only: a chip's checks
#: ask for the grid of each impacter many times over.
_X0_GRIDS = {}


def pair_responses(impacter, drive, n, duration, stop_at_first=False):
    """r [N] of eq. (12) from each of the ``n`` initial positions of :func:`x0_grid`;
    for a pair of unequal halves (:class:`model.PairHalves`) each half starts at the
    same point of its own grid over [-c, c] and the larger response of the two counts
    (the pair answers when either half does)."""
    out = None
    for half, _ in model.halves(impacter):
        # the grid is inside the gap and the duration a step's (> 0): nothing to check
        r = model.responses(half, drive, x0_grid(half, n), duration=duration,
                            stop_at_first=stop_at_first, check_input=False)
        out = r if out is None else np.maximum(out, r)
    return out


def program_responses(impacter, program, n, stop_at_first=False):
    """:func:`pair_responses` under a step's program (:func:`planner.planning.drives.
    program_of`): r [N] of eq. (12) over the whole program from each of the ``n``
    initial positions, the state carried from stretch to stretch and only the first
    impact of the whole program left out.  One stretch is :func:`pair_responses`."""
    if len(program) == 1:
        (duration, drive), = program
        return pair_responses(impacter, drive, n, duration, stop_at_first=stop_at_first)
    total = sum(d for d, _ in program)
    out = None
    for half, _ in model.halves(impacter):
        r = np.zeros(n)
        for k, x0 in enumerate(x0_grid(half, n)):
            x, v, stuck, sum_v, first = float(x0), 0.0, False, 0.0, True
            for duration, drive in program:
                res = model.simulate(half, drive, x, v, duration, stuck=stuck or None,
                                     max_events=1_000_000)
                sum_v += float(np.sum(res.velocities) + np.sum(res.chatter_sums))
                if first and res.times.size:
                    # the first impact is the initial position's, not a response (eq. 12)
                    sum_v -= float(res.velocities[0])
                    first = False
                x, v, stuck = min(res.x_end, half.gap), res.v_end, res.stuck_end
            r[k] = half.mass * sum_v / total
        out = r if out is None else np.maximum(out, r)
    return out


def pair_starts(impacter, n):
    """The ``n`` initial states of :func:`x0_grid` at rest (a state per half for a pair
    of unequal halves, each on its own grid)."""
    parts = model.halves(impacter)
    if len(parts) == 1:
        return [(x0, 0.0, False) for x0 in x0_grid(impacter, n)]
    grids = [x0_grid(h, n) for h, _ in parts]
    return [tuple((g[k], 0.0, False) for g in grids) for k in range(n)]


def kicks(impacter, slider, res, direction):
    """Times [s] and slider velocity kicks [m/s] of a simulation's impacts (eq. 10, the
    "paper" law; the plan itself uses :func:`planner.planning.motion.run_phase`)."""
    times = np.concatenate([res.times, res.chatter_times])
    dv = model.kick(impacter, slider, np.concatenate([res.velocities, res.chatter_sums]),
                    direction)
    return times, dv


def device_motion(impacters, slider, drive, duration, starts, contact="paper", memo=None):
    """Slider displacement [m] and end velocity [m/s] of one device under ``contact``;
    ``starts`` maps node -> (x0, v0, stuck); ``memo``: the simulations already run
    (:func:`planner.planning.motion.run_phase`)."""
    if not impacters:
        _, _, z, v, _ = model.slider_motion(slider, drive, np.empty(0), np.empty(0), duration)
        return z, v
    dev = next(iter(impacters)).device
    states, sl = dict(starts), {dev: (0.0, 0.0)}
    run_phase(impacters, {dev: slider}, {dev: contact}, drive, duration, states, sl, memo)
    return sl[dev]


#: The device checks shared inside :func:`shared_device_checks` (None outside it).
_DEVICE_CHECKS = contextvars.ContextVar("vibroplan_device_checks", default=None)


@contextlib.contextmanager
def shared_device_checks():
    """Within this block (in this thread), :func:`check_step` answers a device it has
    already checked with the same inputs from memory instead of simulating it again.

    A device's check reads only its own impacters and slider, the step's program, which
    of its impacters the step drives (and its move) and the settings' check thresholds;
    those, compared by value, are the memo's key, so a hit gives the very rows and
    failures the simulation would.  A yield study's chip is checked several times over
    (the re-plan on its measured models, the drive on its true ones, the same again
    after the tune and after a trim), and most of its single-tone steps keep their tone
    and most of its devices their models from one check to the next.  Like
    ``numpy.errstate``, the memo is scoped: it lives for the block only (one chip), in
    a :mod:`contextvars` variable, so threads and other callers never see it.
    """
    token = _DEVICE_CHECKS.set({})
    try:
        yield
    finally:
        _DEVICE_CHECKS.reset(token)


def _program_key(program):
    """A step's program (:func:`planner.planning.drives.program_of`) by value."""
    return tuple((float(d), drive.frequencies.tobytes(), drive.amplitudes.tobytes(),
                  drive.phases.tobytes()) for d, drive in program)


def check_step(settings: Settings, step, waveform, impacters, sliders):
    """Re-simulate one step with its actual summed drive.

    Besides the response and speed checks, every device is run from rest through the
    burst and the settle dwell (:func:`planner.planning.motion.device_travel`): its
    travel (``travel_m``) must stay within ``max_travel_m`` and the dwell it needs
    (``settle_s``) within the cap.  ``waveform`` is the step's loop, played for
    ``step.duration_s``, or its gated burst (:class:`planner.synthesis.gating.Burst`), played as
    it is exported; then each moving slider of a ``targets_um`` step must travel its
    move (``step.moves``) within ``settings.position_tolerance_m`` from every initial
    position of its impacter, instead of the speed check.

    ``impacters``: Node -> model (the nodes' text is accepted: :func:`planner.planning.
    motion.by_node`); ``sliders``: device -> model.Slider.

    Returns
    -------
    rows : list of dict
        One per device in scope (plan.json's verification record).
    failures : list of Failure
        Every failed check, structured.
    """
    impacters = by_node(impacters)
    program = program_of(waveform, step.duration_s)
    moves = step.moves if step.targets_m is not None else {}
    active = step.active_nodes()
    rows, failures = [], []
    shared = _DEVICE_CHECKS.get()
    if shared is not None:
        # everything a device's check reads but its own models, move and activity
        common = (_program_key(program), step.scene, step.name, step.index,
                  settings.x0_points, settings.max_settle_s, settings.max_travel_m,
                  settings.min_speed_m_s, settings.idle_tolerance_m,
                  settings.position_tolerance_m)
    by_device = _by_device(impacters)
    for dev in sorted(sliders, key=device_key):
        own = by_device.get(dev, {})
        if shared is not None:
            key = (common, dev, settings.contacts[dev], sliders[dev], moves.get(dev),
                   tuple((n, imp, n in active) for n, imp in own.items()))
            if key in shared:
                got_rows, got_failures = shared[key]
                rows.append(dict(got_rows))
                failures += got_failures
                continue
            n_failures = len(failures)
        moving = [n for n in own if n in active]
        expected = moving[0].direction if moving else "idle"
        causes = []
        # every impacter that must be idle: r = 0 from every x0 of the grid (eq. 14)
        worst_idle_r = 0.0
        for n, imp in own.items():
            if n in active:
                continue
            x0s = x0_grid(imp, settings.x0_points)
            r = program_responses(imp, program, settings.x0_points, stop_at_first=True)
            if np.any(r > 0):
                full = program_responses(imp, program, settings.x0_points)
                worst_idle_r = max(worst_idle_r, float(full.max()))
                causes.append(f"{n} responds (r = {full.max():.3g} N from x0 = "
                              f"{x0s[int(np.argmax(full))] / UM:.2f} um)")
                failures.append(Failure(step.index, dev, n, IDLE_RESPONSE, float(full.max())))
        contact = settings.contacts[dev]
        # the device's runs from rest and from its x0 grid share what they simulate
        # alike (an idle impacter from rest, the x0 = 0 start): computed once
        memo = {}
        displacement, travel, dwell, calm = device_travel(own, dev, sliders[dev], contact,
                                                          program, settings.max_settle_s,
                                                          memo=memo)
        if abs(travel) > settings.max_travel_m:
            causes.append(f"travel {travel / UM:.4g} um over the limit "
                          f"{settings.max_travel_m / UM:g} um")
            failures.append(Failure(step.index, dev, None, TRAVEL_OVER, float(travel)))
        if not calm:
            causes.append(f"still moving {dwell * 1e3:g} ms after the drive stops")
            failures.append(Failure(step.index, dev, None, UNSETTLED, float(dwell)))
        if moving and dev in moves:
            n = moving[0]
            # the gates were set for the state the scene leaves; from every x0 of the
            # grid the slider must still end within the tolerance of its move
            errors = [device_travel(own, dev, sliders[dev], contact, program,
                                    settings.max_settle_s, {n: start}, memo)[1] - moves[dev]
                      for start in pair_starts(own[n], settings.x0_points)]
            worst = float(max(errors, key=abs))
            if abs(worst) > settings.position_tolerance_m:
                causes.append(f"off target: travels {(moves[dev] + worst) / UM:.4g} um "
                              f"for a move of {moves[dev] / UM:.4g} um from some x0 (off "
                              f"by {worst / UM:+.3g} um > "
                              f"{settings.position_tolerance_m / UM:g} um)")
                failures.append(Failure(step.index, dev, None, OFF_TARGET, worst))
            worst_case = {"move_m": moves[dev], "worst_position_error_m": worst}
        elif moving:
            worst = _slowest(own, moving[0], sliders[dev], contact, program,
                             settings.x0_points, memo)
            if worst < settings.min_speed_m_s:
                causes.append(f"too slow: {worst * 1e3:.3g} mm/s < "
                              f"{settings.min_speed_m_s * 1e3:g} mm/s from some x0")
                failures.append(Failure(step.index, dev, None, TOO_SLOW, worst))
            worst_case = {"min_speed_m_s": worst}
        else:
            worst_case = {"max_response_n": worst_idle_r}
            if abs(travel) > settings.idle_tolerance_m:
                causes.append(f"idle slider moves {travel / UM:.3g} um > "
                              f"{settings.idle_tolerance_m / UM:g} um")
                failures.append(Failure(step.index, dev, None, IDLE_MOVES, float(travel)))
        if moving:
            worst_case["max_idle_response_n"] = worst_idle_r
        rows.append({"scene": step.scene, "step": step.name, "index": step.index,
                     "device": dev, "expected": expected,
                     "predicted_displacement_m": float(displacement),
                     "travel_m": float(travel), "settle_s": float(dwell),
                     **worst_case, "passed": not causes, "cause": "; ".join(causes)})
        if shared is not None:
            shared[key] = (dict(rows[-1]), tuple(failures[n_failures:]))
    return rows, failures


def _by_device(impacters):
    """Device -> its impacters (node -> model), in the order of ``impacters`` (one pass,
    not one per device; the nodes' text is accepted, :func:`planner.planning.motion.
    by_node`)."""
    out = {}
    for n, imp in by_node(impacters).items():
        out.setdefault(n.device, {})[n] = imp
    return out


def _slowest(own, n, slider, contact, program, x0_points, memo=None):
    """The least speed [m/s] of the slider that ``n`` (of the device's impacters ``own``)
    drives through ``program``, from every start of its pair (:func:`pair_starts`): the
    speed check of :func:`check_step` (a step played for a whole program)."""
    drive = program[0][1]
    duration = sum(d for d, _ in program)
    speeds = []
    for start in pair_starts(own[n], x0_points):
        z, _ = device_motion(own, slider, drive, duration, {n: start}, contact, memo)
        speeds.append(n.sign * z / duration)
    return float(min(speeds))


def too_slow(settings: Settings, steps, waveforms, impacters, sliders, memo=None):
    """The :data:`TOO_SLOW` failures :func:`check_steps` would report, and only those:
    the speed check of every slider a step drives (not to a target), without the idle,
    travel and settling checks; the same failures, in the same order.

    ``memo`` (optional, a dict): speeds already computed, by step program, device and
    the device's models (for a caller that checks steps again with one step changed).
    """
    by_device = _by_device(impacters)
    out = []
    for st in steps:
        program = program_of(waveforms[st.key], st.duration_s)
        moves = st.moves if st.targets_m is not None else {}
        active = st.active_nodes()
        for dev in sorted(sliders, key=device_key):
            own = by_device.get(dev, {})
            moving = [n for n in own if n in active]
            if not moving or dev in moves:
                continue
            key = None
            if memo is not None:
                key = (_program_key(program), dev, settings.contacts[dev], sliders[dev],
                       tuple(own.items()), moving[0], settings.x0_points)
                worst = memo.get(key)
            if key is None or worst is None:
                worst = _slowest(own, moving[0], sliders[dev], settings.contacts[dev],
                                 program, settings.x0_points, {})
                if key is not None:
                    memo[key] = worst
            if worst < settings.min_speed_m_s:
                out.append(Failure(st.index, dev, None, TOO_SLOW, worst))
    return out


def _check_on_engine(shared, step, waveform):
    """:func:`check_step` as a :func:`planner.runtime.engine.run_tasks` task: ``shared`` is
    (settings, impacters, sliders), sent to each worker once."""
    settings, impacters, sliders = shared
    return check_step(settings, step, waveform, impacters, sliders)


def check_steps(settings: Settings, steps, waveforms, impacters, sliders, *, progress=None,
                scheduler=None, store=None):
    """:func:`check_step` of every step of ``steps``, in their order.

    The steps are independent (each starts every device from rest or from its x0 grid
    and reads nothing another step wrote), so with ``scheduler`` (the address of a
    ``dask.distributed`` scheduler) they run as tasks on that cluster
    (:func:`planner.runtime.engine.run_tasks`); without, in this process, one after another.
    The result is the same either way (the simulation kernels give the same digits on
    any number of threads).

    Parameters
    ----------
    settings : Settings
    steps : sequence of Step
    waveforms : dict
        Step key -> Waveform of its summed drive.
    impacters, sliders : dict
        Node -> model.Impacter; device -> model.Slider.
    progress : callable, optional
        Called with a step's key after each finished step (on Dask, in completion
        order with the keys in list order: the count is exact, not which step).
    scheduler : str, optional
    store : planner.planning.design_store.DesignStore, optional
        The on-disk cache: a step whose inputs (the settings, the step, its drive, the
        models) and code are those of a stored check is read from it, not simulated;
        every step simulated is stored (:func:`planner.planning.design_store.stage_digest`).

    Returns
    -------
    list of (rows, failures)
        One :func:`check_step` result per step.
    """
    steps = list(steps)
    if not steps:
        return []
    if store is not None:
        return _check_steps_cached(settings, steps, waveforms, impacters, sliders,
                                   progress=progress, scheduler=scheduler, store=store)
    if not scheduler:
        out = []
        for st in steps:
            out.append(check_step(settings, st, waveforms[st.key], impacters, sliders))
            if progress is not None:
                progress(st.key)
        return out
    from planner.runtime.engine import run_tasks

    done = iter(steps)
    tick = (lambda: progress(next(done).key)) if progress is not None else None
    return run_tasks(_check_on_engine, (settings, impacters, sliders),
                     [(st, waveforms[st.key]) for st in steps], scheduler=scheduler,
                     progress=tick)


def _check_steps_cached(settings, steps, waveforms, impacters, sliders, *, progress,
                        scheduler, store):
    """:func:`check_steps` through ``store``: the steps found there are read, the
    others checked (on ``scheduler`` if given) and stored; results in the steps' order."""
    from planner.planning.design_store import stage_digest

    # what every step shares, digested once
    shared = stage_digest("verify", settings, by_node(impacters), sliders)
    keys = [None if shared is None else stage_digest("verify", shared, st, waveforms[st.key])
            for st in steps]
    out = [store.get_stage("verify", k) for k in keys]
    if progress is not None:
        for st, got in zip(steps, out):
            if got is not None:
                progress(st.key)
    todo = [i for i, got in enumerate(out) if got is None]
    done = check_steps(settings, [steps[i] for i in todo], waveforms, impacters, sliders,
                       progress=progress, scheduler=scheduler)
    for i, got in zip(todo, done):
        store.put_stage("verify", keys[i], got)
        out[i] = got
    return out


def coupling_matrix(impacters, tones, settings: Settings, duration, *, store=None):
    """Worst response r [N] over the x0 grid of every impacter (Node -> model) to every
    tone alone: a table indexed by the nodes' text (coupling.csv), a column per tone.
    ``store`` (optional): the on-disk cache it is read from when its inputs and code
    are those of a stored one, and stored to when computed (as :func:`check_steps`)."""
    if store is not None:
        from planner.planning.design_store import stage_digest

        key = stage_digest("coupling", impacters, sorted(set(tones)), settings, duration)
        out = store.get_stage("coupling", key)
        if out is None:
            out = coupling_matrix(impacters, tones, settings, duration)
            store.put_stage("coupling", key, out)
        return out
    freqs = sorted(set(tones))
    amps = tone_amplitudes(settings, freqs)
    names = sorted(impacters)
    mat = np.zeros((len(names), len(freqs)))
    for i, n in enumerate(names):
        imp = impacters[n]
        for j, (f, z) in enumerate(zip(freqs, amps)):
            mat[i, j] = float(np.max(pair_responses(imp, Drive([f], [z]), settings.x0_points,
                                                    duration)))
    return pd.DataFrame(mat, index=[n.text for n in names],
                        columns=[f"{f:.3f}" for f in freqs])


#: x0 points of :func:`confirm_responses`' check: twice the designer's refined re-check
#: grid of the default budget (~130 points), evenly over [-c, c].
CONFIRM_X0_POINTS = 257


def confirm_responses(settings: Settings, steps, drives, designs, sliders,
                      points=CONFIRM_X0_POINTS):
    """The infeasible designs whose one miss the steps' own simulation settles.

    The designer asks an impacter to respond under the summed drive of every
    multi-tone step it plays in from every x0 of its fine grid *within its short window*
    (``design.window_ms``, 3 ms by default): a proxy, cheap enough to ask of every
    candidate.  A step plays for its whole burst (10-60 ms), and what the plan needs of
    it is the check of :func:`check_step`: the slider moving (fast enough, or to its
    target) from every start.  A design that misses nothing but that response is
    confirmed when

    - it responds to its own tone and its tone window's edges *alone* from every x0 of
      the designer's fine grid (:func:`planner.designer.response_alone`), and
    - every step it plays in, simulated with the drive the die feels for its whole burst,
      passes its device's check from each of ``points`` x0 over [-c, c] (a grid 28 times
      the verification's nine).

    Parameters
    ----------
    settings : Settings
    steps : sequence of Step
        The steps as they play (bursts sized, gated).
    drives : dict
        Step key -> what the die feels in it (the played loop or burst, through the
        chain when the spec has one).
    designs : dict
        Node -> DesignResult.
    sliders : dict
        Device -> model.Slider.
    points : int
        x0 of each step's check.

    Returns
    -------
    dict
        Node -> plan.json's ``verification.confirmed_designs`` entry (the design's miss,
        the steps simulated, their worst speed or position error), for every design it
        confirms; the others keep their miss.
    """
    from planner.designer import response_alone

    out = {}
    dense = None
    for n in sorted(designs):
        d = designs[n]
        if d.feasible or {s["constraint"] for s in d.shortfalls} != {"response"}:
            continue
        if not d.checks.get("unanswered_target_drives"):
            continue
        missed, grid = response_alone(d, **settings.design_kwargs(n))
        if missed:
            continue
        if dense is None:
            dense = dataclasses.replace(settings, x0_points=int(points))
        own = {m: dm.impacter for m, dm in designs.items() if m.device == n.device}
        rows = []
        for st in steps:
            if n not in st.active_nodes():
                continue
            got, _ = check_step(dense, st, drives[st.key], own, {n.device: sliders[n.device]})
            rows.append((st.key, got[0]))
        if not rows or not all(row["passed"] for _, row in rows):
            continue
        out[n] = {"impacter": n.text, "frequency_hz": float(d.frequency_hz),
                  "shortfall": next(s["text"] for s in d.shortfalls),
                  "alone_x0_points": grid, "x0_points": int(points),
                  "steps": {key: {k: row[k] for k in ("min_speed_m_s",
                                                       "worst_position_error_m")
                                  if k in row} for key, row in rows}}
    return out
