"""Every check of a drive on one chip's models, counted by kind, with the impacters each
failure implicates (keyed by :class:`planner.core.nodes.Node`).

The checks are the plan's own (:func:`planner.planning.verify.check_step` per step, the
scenes with the state carried across steps): their structured
:class:`~planner.planning.verify.Failure` records are counted by kind, never the text of
a cause.  The kinds' names are yield.json's (:data:`KINDS`).
"""

from __future__ import annotations

from planner.core.nodes import Node
from planner.planning.verify import (CARRIED_IDLE, IDLE_MOVES, IDLE_RESPONSE, OFF_TARGET,
                                     TOO_SLOW, TRAVEL_OVER, UNSETTLED)

#: Check kinds, in the order reports list them (yield.json's ``failures`` keys).
KINDS = ("idle responds", "too slow", "idle slider moves",
         "idle slider moves (carried state)", "unbuildable", "travel over limit",
         "still moving", "off target", "travel over limit (carried state)",
         "still moving (carried state)", "off target (carried state)")
#: The carried-state check's idle-motion kind (part of a chip's pass, as in
#: ``vibroplan plan``).
CARRIED = "idle slider moves (carried state)"
#: Every kind of the carried-state check.
CARRIED_KINDS = (CARRIED, "travel over limit (carried state)", "still moving (carried state)",
                 "off target (carried state)")
#: A per-step failure's kind -> its name in :data:`KINDS`.
STEP_KIND = {IDLE_RESPONSE: "idle responds", TOO_SLOW: "too slow",
             IDLE_MOVES: "idle slider moves", TRAVEL_OVER: "travel over limit",
             UNSETTLED: "still moving", OFF_TARGET: "off target"}
#: A carried-state failure's kind -> its name in :data:`KINDS`.
CARRIED_KIND = {CARRIED_IDLE: CARRIED, TRAVEL_OVER: "travel over limit (carried state)",
                UNSETTLED: "still moving (carried state)",
                OFF_TARGET: "off target (carried state)"}


def _implicated(failure, own: list[Node], active: set[Node]) -> list[Node]:
    """The impacters a failure implicates: the one that answered; the driven ones of a
    slider too slow, travelling too far, still moving or off target; the idle ones of a
    slider that moved while idle."""
    if failure.impacter is not None:
        return [failure.impacter]
    if failure.kind in (IDLE_MOVES, CARRIED_IDLE):
        return [n for n in own if n not in active]
    return [n for n in own if n in active]


def check_drive(settings, steps, waveforms, dwells, impacters, sliders, *,
                first_failure=False, devices=None, scenes=True) -> dict:
    """Every check of a drive on one chip's models: the per-step checks and the
    carried-state check, as ``vibroplan plan`` runs them.

    With ``first_failure`` the checks stop at the first step that fails (its kinds are
    then the only ones counted, ``stopped`` says so): whether a drive passes is all a
    re-planning yield needs of the drive the chip is about to be re-planned away from.

    Parameters
    ----------
    settings : planner.planning.settings.Settings
        The plan's settings (checks, x0 grid, contact laws, dwell caps).
    steps : sequence of Step
        The drive's steps (plan.json's, or a re-plan's).
    waveforms : dict
        Step key -> what the step plays (a loop's tones, or a gated burst).
    dwells : dict
        Step key -> settle dwell [s] after the step in the scene simulation.
    impacters, sliders : dict
        The chip's models: node (or its id) -> :class:`model.Impacter`, device ->
        :class:`model.Slider`.
    devices : collection of str, optional
        Run the per-step checks on these devices only (each device's checks read only
        its own impacters and slider, so the others' are those of any chip that differs
        from this one only on these devices: a trim's draws, :func:`planner.afterfab.
        trim.trim_odds`).  The scene simulation, whose dwells settle the whole chip,
        still runs on every device.  Default: every device.
    scenes : bool
        False: skip the carried-state check (the per-step checks only).

    Returns
    -------
    dict
        ``passed`` (every check), ``steps_passed`` (the per-step checks only),
        ``failures`` (kind -> count of failed checks), ``nodes`` (set of
        :class:`~planner.core.nodes.Node`: the impacter pairs implicated), ``rows`` (the
        per-step verification rows), ``records`` (every
        :class:`~planner.planning.verify.Failure`, the carried-state ones last).
    """
    from planner.planning.motion import by_node
    from planner.planning.scenes import scene_failures, simulate_scenes
    from planner.planning.verify import check_step

    from planner.planning.chain import die_drives

    impacters = by_node(impacters)
    # through a distorting drive chain the chip feels the tones and their products
    waveforms = die_drives(settings, waveforms)
    by_device = {}
    for node in impacters:
        by_device.setdefault(node.device, []).append(node)
    in_scope = (sliders if devices is None else
                {d: s for d, s in sliders.items() if d in set(devices)})
    failures, nodes, rows, records = {}, set(), [], []
    for st in steps:
        active = {Node(d, r) for d, r in st.active_nodes()}
        step_rows, step_fails = check_step(settings, st, waveforms[st.key], impacters,
                                           in_scope)
        rows += step_rows
        for f in step_fails:
            kind = STEP_KIND.get(f.kind, f.kind)
            failures[kind] = failures.get(kind, 0) + 1
            nodes.update(_implicated(f, by_device.get(f.device, []), active))
            records.append(f)
        if first_failure and failures:
            return {"passed": False, "steps_passed": False, "failures": failures,
                    "nodes": nodes, "rows": rows, "records": records, "stopped": st.key}
    steps_passed = not failures
    if scenes and settings.scenes:
        by_index = {st.index: st for st in steps}
        scene_rows = simulate_scenes(settings, steps, waveforms, impacters, sliders, dwells)
        for f in scene_failures(settings, steps, scene_rows):
            kind = CARRIED_KIND.get(f.kind, f.kind)
            failures[kind] = failures.get(kind, 0) + 1
            records.append(f)
            st = by_index.get(f.step)
            if st is not None and f.device:
                active = {Node(d, r) for d, r in st.active_nodes()}
                nodes.update(_implicated(f, by_device.get(f.device, []), active))
    return {"passed": not failures, "steps_passed": steps_passed, "failures": failures,
            "nodes": nodes, "rows": rows, "records": records}


def drive_of(record):
    """(steps, step key -> recorded drive, step key -> settle dwell [s]) of a plan
    (a :class:`~planner.planfile.reader.PlanRecord`)."""
    from planner.planfile.reader import drives

    return tuple(st.step for st in record.steps), drives(record), dict(record.dwells)
