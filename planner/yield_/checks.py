"""The checks of a drive on one chip's models, counted by kind, with the impacters each
failure implicates (keyed by :class:`planner.nodes.Node`)."""

from __future__ import annotations

from planner.nodes import Node

#: Check kinds, in the order reports list them.
KINDS = ("idle responds", "too slow", "idle slider moves",
         "idle slider moves (carried state)", "unbuildable", "travel over limit",
         "still moving", "travel over limit (carried state)",
         "still moving (carried state)")
#: The carried-state check's idle-motion kind (part of a chip's pass, as in
#: ``vibroplan plan``).
CARRIED = "idle slider moves (carried state)"
#: Every kind of the carried-state check.
CARRIED_KINDS = (CARRIED, "travel over limit (carried state)", "still moving (carried state)")


def _kind(cause: str) -> str:
    if "responds" in cause:
        return "idle responds"
    if cause.startswith("too slow"):
        return "too slow"
    if cause.startswith("idle slider moves"):
        return "idle slider moves"
    if cause.startswith("travel") and "over the limit" in cause:
        return "travel over limit"
    if cause.startswith("still moving"):
        return "still moving"
    return cause.split(":")[0].strip() or "other"


def _step_nodes(step) -> set[Node]:
    """The impacters a step drives."""
    return {Node(d, r) for d, r in step.active_nodes()}


def _implicated(own: list[Node], cause: str, kind: str, active: set[Node]) -> list[Node]:
    """The impacters of a device that a failing cause implicates: those it names, the
    driven ones of a slider too slow, else (an idle slider moved) the idle ones."""
    if kind == "too slow":
        return [n for n in own if n in active]
    named = [n for n in own if cause.startswith(n.text + " ")]
    return named or [n for n in own if n not in active]


def check_drive(settings, steps, waveforms, dwells, impacters, sliders, *,
                first_failure=False) -> dict:
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
        Step key -> the step's tones (``frequencies`` [Hz], ``amplitudes`` [m],
        ``phases`` [rad]).
    dwells : dict
        Step key -> settle dwell [s] after the step in the scene simulation.
    impacters, sliders : dict
        The chip's models: node id -> :class:`model.Impacter`, device -> :class:`model.Slider`.

    Returns
    -------
    dict
        ``passed`` (every check), ``steps_passed`` (the per-step checks only),
        ``failures`` (kind -> failing rows), ``nodes`` (set of :class:`~planner.nodes.Node`:
        the impacter pairs implicated), ``rows`` (the per-step verification rows).
    """
    from planner.planning.scenes import scene_failures, simulate_scenes
    from planner.planning.verify import CARRIED_IDLE, TRAVEL_OVER, check_step

    by_device = {}
    for text in impacters:
        node = Node.parse(text)
        by_device.setdefault(node.device, []).append(node)
    failures, nodes, rows = {}, set(), []
    for st in steps:
        active = _step_nodes(st)
        step_rows = check_step(settings, st, waveforms[st.key], impacters, sliders)[0]
        rows += step_rows
        for row in step_rows:
            if row["passed"]:
                continue
            for cause in row["cause"].split("; "):
                kind = _kind(cause)
                failures[kind] = failures.get(kind, 0) + 1
                nodes.update(_implicated(by_device.get(row["device"], []), cause, kind, active))
        if first_failure and failures:
            return {"passed": False, "steps_passed": False, "failures": failures,
                    "nodes": nodes, "rows": rows, "stopped": st.key}
    steps_passed = not failures
    if settings.scenes:
        by_index = {st.index: st for st in steps}
        scene_rows = simulate_scenes(settings, steps, waveforms, impacters, sliders, dwells)
        for f in scene_failures(settings, steps, scene_rows):
            kind = {CARRIED_IDLE: CARRIED,
                    TRAVEL_OVER: "travel over limit (carried state)"}.get(
                        f.kind, "still moving (carried state)")
            failures[kind] = failures.get(kind, 0) + 1
            st = by_index.get(f.step)
            if f.kind == CARRIED_IDLE and st is not None:
                active = _step_nodes(st)
                nodes |= {n for n in by_device.get(f.device, []) if n not in active}
    return {"passed": not failures, "steps_passed": steps_passed, "failures": failures,
            "nodes": nodes, "rows": rows}
