"""Stage 5b, scenes: each scene simulated in order with the state carried across steps."""

from __future__ import annotations

from planner.core.nodes import device_key
from planner.planning.drives import program_of
from planner.planning.motion import REST, by_node, rest_state, run_program, settle

#: Step name of the undriven tail in the scene rows (``"driven": false``).
SETTLE_NAME = "(drive off)"
#: |v| [m/s] above which an impacter counts as still ringing at the end of a step.
RINGING_V = 1e-6


def _scene_phase(settings, impacters, sliders, program, states, sl_states, active,
                 dwell=None):
    """Advance every impacter and slider through one phase (a step's ``program`` and
    its settle dwell, or the undriven tail) from the carried states; updates them in
    place and returns the scene row's fields.

    ``dwell`` [s]: None for the undriven tail (the program is then the drive off);
    else the dwell the verification found for the step, extended here in whole
    chunks while the carried state still moves, up to ``settings.max_settle_s``.  A
    slider none of whose impacters is driven and that moves more than the idle
    tolerance over the phase is listed in ``idle_moved_m``; every slider's travel over
    the phase is in ``travel_m``.
    """
    z_start = {d: sl_states[d][0] for d in sliders}
    hits = run_program(impacters, sliders, settings.contacts, program, states, sl_states)
    idle_hits = {n.text: h for n, h in hits.items() if h and n not in active}
    fields = {}
    if dwell is not None:
        burst_end = {d: sl_states[d][0] for d in sliders}
        cap = max(settings.max_settle_s, dwell)
        took, calm, dwell_hits = settle(impacters, sliders, settings.contacts, states,
                                        sl_states, cap, at_least=dwell)
        fields = {"settle_s": took, "settled": calm,
                  "dwell_hits": {n.text: h for n, h in dwell_hits.items()},
                  "burst_positions_m": burst_end}
    positions, moved, travel = {}, {}, {}
    driven_devices = {d for d, _ in active}
    for dev in sliders:
        z = sl_states[dev][0]
        positions[dev] = float(z)
        travel[dev] = float(z - z_start[dev])
        if abs(z - z_start[dev]) > settings.idle_tolerance_m and dev not in driven_devices:
            moved[dev] = float(z - z_start[dev])
    ringing = [n.text for n in sorted(states) if n not in active
               and any(abs(v) > RINGING_V for _, v, _ in _per_half(states[n]))]
    return {"positions_m": positions, "ringing_impacters": ringing, "idle_hits": idle_hits,
            "idle_moved_m": moved, "travel_m": travel, **fields}


def _per_half(state):
    """The (x, v, stuck) of each half of a state (one for a symmetric pair)."""
    return state if isinstance(state[0], tuple) else (state,)


def simulate_scenes(settings, steps, waveforms, impacters, sliders, dwells=None, place=None):
    """Each scene in order, carrying impacter and slider states across steps.

    ``impacters``: Node -> model (the nodes' text is accepted:
    :func:`planner.planning.motion.by_node`); ``sliders``: device -> model.Slider.  The
    rows are plan.json's ``scenes``: impacters in them by their text.

    Every scene starts from rest; each step starts from the state the previous one
    left, so an impacter that keeps ringing after its tone stops moves its slider in
    the next step.  Every step plays its waveform (a loop for ``duration_s``, or its
    gated burst, :func:`planner.planning.drives.program_of`) and is followed by its
    settle dwell with the drive off
    (``dwells``: step key -> dwell [s] the verification found, default 0), extended
    while the carried state still moves (:func:`planner.planning.motion.settle`, up
    to ``settings.max_settle_s``): a driven row's positions are at the end of its
    dwell, and it records ``settle_s`` (the dwell simulated), ``settled``,
    ``dwell_hits`` (node text -> impacts during the dwell),
    ``burst_positions_m`` (at the end of the burst) and ``travel_m`` (device ->
    travel over burst and dwell [m]).  After the last step the drive stays off for
    ``settings.settle_s`` (:data:`planner.planning.settings.SETTLE_S`) so that any
    overshoot left is counted too.

    A ``targets_um`` step's row also records ``targets_m`` (device -> where the step
    asks the slider to end, relative to the scene start [m]) and ``position_errors_m``
    (device -> where it ended minus that [m]).  The undriven tail's row records
    ``final_positions_m`` (device -> where every slider rests at the end of the scene
    [m]) and, in a scene with targets, ``expected_positions_m`` (device -> where the
    scene asked it to end: its last target, or where it started if no step moved it
    [m]; devices moved by a duration or travel step after their last target have
    none).

    ``place`` (optional): ``place(step, states, slider_states) -> waveform``, called
    for every ``targets_um`` step with the carried state it starts from (which it must
    not change); the step then plays what it returns (the pipeline finds the step's
    gates there, :func:`planner.planning.targets.place_targets`).

    Returns
    -------
    list of dict
        One row per step and one for the undriven tail of each scene (step
        :data:`SETTLE_NAME`, ``driven`` false): slider positions [m] at its end,
        the impacters still ringing then (idle ones moving faster than
        :data:`RINGING_V`), ``idle_hits``: node text -> impacts of every impacter that
        hit its slider while its step did not drive it, and ``idle_moved_m``: device ->
        displacement [m] of every slider that moved more than the spec's idle tolerance
        in a phase that drove none of its impacters (in the undriven tail: the
        overshoot).  The per-step verification starts every impacter from rest or
        the x0 grid; this is where the state a previous step left shows.
    """
    impacters = by_node(impacters)
    settle_s = settings.settle_s
    rows = []
    for scene in settings.scenes:
        states = {n: rest_state(imp) for n, imp in impacters.items()}
        sl_states = {d: (0.0, 0.0) for d in sliders}
        scene_steps = [s for s in steps if s.scene == scene]
        # where the scene asks each slider to end (None: moved by an amount the
        # planner sized after its last target)
        expected = {d: 0.0 for d in sliders}
        for st in scene_steps:
            active = st.active_nodes()
            waveform = waveforms[st.key]
            if place is not None and st.targets_m is not None:
                waveform = place(st, states, sl_states)
            program = program_of(waveform, st.duration_s)
            start = {d: sl_states[d][0] for d in sliders}
            fields = _scene_phase(settings, impacters, sliders, program, states, sl_states,
                                  active, dwell=(dwells or {}).get(st.key, 0.0))
            if st.targets_m is not None:
                asked = {d: (t if st.relative_to == "scene_start" else start[d] + t)
                         for d, t in st.targets_m if d in sliders}
                fields["targets_m"] = asked
                fields["position_errors_m"] = {d: fields["positions_m"][d] - t
                                               for d, t in asked.items()}
                expected.update(asked)
            else:
                expected.update({d: None for d in st.forward + st.backward})
            rows.append({"scene": scene, "step": st.name, "driven": True,
                         "duration_s": sum(d for d, _ in program), **fields})
        fields = _scene_phase(settings, impacters, sliders, ((settle_s, REST),), states,
                              sl_states, set())
        fields["final_positions_m"] = dict(fields["positions_m"])
        if any(st.targets_m is not None for st in scene_steps):
            fields["expected_positions_m"] = {d: z for d, z in sorted(
                expected.items(), key=lambda kv: device_key(kv[0])) if z is not None}
        rows.append({"scene": scene, "step": SETTLE_NAME, "driven": False,
                     "duration_s": settle_s, **fields})
    return rows


def scene_overshoot(scene_rows):
    """Scene -> {device: overshoot [m]}: how far each slider moved once the drive was
    switched off after the scene's last step (the rows of :func:`simulate_scenes`)."""
    out = {}
    for scene in dict.fromkeys(r["scene"] for r in scene_rows):
        rows = [r for r in scene_rows if r["scene"] == scene]
        driven = [r for r in rows if r["driven"]]
        tail = [r for r in rows if not r["driven"]]
        if not tail:
            continue
        last = driven[-1]["positions_m"] if driven else {}
        out[scene] = {dev: z - last.get(dev, 0.0) for dev, z in tail[0]["positions_m"].items()}
    return out


def scene_failures(settings, steps, scene_rows):
    """The carried-state checks of the scene rows, as :class:`Failure` records.

    - :data:`~planner.planning.verify.CARRIED_IDLE`: a slider none of whose impacters
      the step drives moves more than the idle tolerance over the step and its dwell;
    - :data:`~planner.planning.verify.TRAVEL_OVER`: a slider travels more than
      ``settings.max_travel_m`` over a step and its dwell;
    - :data:`~planner.planning.verify.UNSETTLED`: something still moves at the end of
      the longest dwell;
    - :data:`~planner.planning.verify.OFF_TARGET`: a slider of a ``targets_um`` step
      ends the step further than ``settings.position_tolerance_m`` from its target, or
      a slider of a scene with targets rests that far from where the scene asked it to
      end (its last target or its start) once the drive is off (on the last step);
    - after the scene's last dwell, a slider that still moves beyond the idle tolerance
      in the undriven tail (CARRIED_IDLE, on the last step).
    """
    from planner.planning.verify import (CARRIED_IDLE, OFF_TARGET, TRAVEL_OVER, UNSETTLED,
                                         Failure)

    by_name = {(s.scene, s.name): s for s in steps}
    tol = settings.position_tolerance_m
    out = []
    for scene in dict.fromkeys(r["scene"] for r in scene_rows):
        rows = [r for r in scene_rows if r["scene"] == scene]
        last = None
        for r in rows:
            if r["driven"]:
                st = by_name[(scene, r["step"])]
                last = st
                for dev, z in sorted(r["idle_moved_m"].items()):
                    out.append(Failure(st.index, dev, None, CARRIED_IDLE, z))
                for dev, z in sorted(r["travel_m"].items()):
                    if abs(z) > settings.max_travel_m:
                        out.append(Failure(st.index, dev, None, TRAVEL_OVER, z))
                if not r.get("settled", True):
                    out.append(Failure(st.index, "", None, UNSETTLED, r["settle_s"]))
                for dev, err in sorted(r.get("position_errors_m", {}).items()):
                    if abs(err) > tol:
                        out.append(Failure(st.index, dev, None, OFF_TARGET, err))
            elif last is not None:
                for dev, z in sorted(r["idle_moved_m"].items()):
                    out.append(Failure(last.index, dev, None, CARRIED_IDLE, z))
                failed = {f.device for f in out if f.step == last.index
                          and f.kind == OFF_TARGET}
                for dev, want in r.get("expected_positions_m", {}).items():
                    err = r["final_positions_m"][dev] - want
                    if abs(err) > tol and dev not in failed:
                        out.append(Failure(last.index, dev, None, OFF_TARGET, err))
    return out
