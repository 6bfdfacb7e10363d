"""The plan.json record: deterministic, rounded to 12 significant digits, written
through its schema.

The file boundary: the stages key impacters by :class:`planner.core.nodes.Node`, plan.json
by the node's text (``"A1.forward"``).

Every block is declared once, in :mod:`planner.planfile.schema` (its ``format_version``
is that module's :data:`~planner.planfile.schema.FORMAT_VERSION`); :func:`build_record`
gathers the stages' results under the schema's keys and passes them through it
(:func:`~planner.planfile.schema.through_schema`): plan.json is the record's dump, and a
key the schema does not declare, or a value of another type, is an error.  Read back by
:mod:`planner.planfile.reader`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from planner.files import version_string
from planner.assignment.assign import node_order, verify_assignment
from planner.lab.exporters import EXPORTERS
from planner.planning.motion import PROBE_S
from planner.planfile.schema import FORMAT_VERSION, PlanFile, through_schema
from planner.core.nodes import Node, device_key

#: Standard gravity [m/s^2].
G0 = 9.80665
#: Formats every step's waveform is exported in.
EXPORT_FORMATS = ("wav", "wav16", "csv", "arb")


def round_floats(x, digits=12):
    """Round floats for plan.json so it is stable to the last byte across runs."""
    if isinstance(x, float):
        return float(f"{x:.{digits}g}") if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: round_floats(v, digits) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [round_floats(v, digits) for v in x]
    if isinstance(x, np.floating):
        return round_floats(float(x), digits)
    if isinstance(x, np.integer):
        return int(x)
    return x


def impacter_record(n: Node, assignment, design):
    """One designed impacter's plan.json entry."""
    rec = {"id": n.text, "device": n.device, "direction": n.direction,
           "channel": int(assignment.channels[n]), "frequency_hz": assignment.frequencies[n]}
    d = design.to_dict()
    for key in ("mass_kg", "stiffness_n_per_m", "damping_ns_per_m", "gap_m",
                "impact_angle_rad", "restitution", "natural_frequency_hz", "geometry"):
        rec[key] = d[key]
    for key in ("r_min_n", "worst_x0_m", "predicted_slider_speed_m_s", "feasible",
                "shortfalls"):
        if key in d:
            rec[key] = d[key]
    w = d.get("tone_window")
    if w:
        # the tones the design was made to drive its slider at from every x0
        f = assignment.frequencies[n]
        rec["tone_window_hz"] = [f * (1.0 - w), f * (1.0 + w)]
    rec["mass_ratio"] = getattr(design, "mass_ratio", None)
    rec["contact"] = getattr(design, "contact", None)
    return rec


def step_record(step, waveform, motion=None):
    """One step's plan.json entry: its tones, crest factor and waveform files; with
    ``motion`` (the pipeline's motion notes, see :func:`build_record`) its settle dwell,
    the summed drive's peaks and every slider's predicted travel.

    A ``targets_um`` step also records ``targets_m`` (device -> target [m] as the spec
    gives it, relative to ``relative_to``), ``moves_m`` (device -> the move [m] its
    burst was gated for, from where the scene left the slider) and ``gating`` (the
    ramp, each node's start and gate [s] and the search's iterations), and each of its
    tones its ``start_s`` and ``gate_s`` (gate 0: not played); its ``playback`` is
    ``once`` (a gated burst, :class:`planner.synthesis.gating.Burst`) where other steps
    ``loop``, and its peaks and acceleration scale are the burst's."""
    from planner.synthesis.gating import Burst

    stem = f"{step.scene}__{step.name}"
    w = waveform
    extra = {}
    if motion is not None:
        drive = dict(motion["drive"][step.key])
        gating = (motion.get("gating") or {}).get(step.key)
        if gating is not None:
            # the burst's own tones, not the loop's (lowered for a sum that never plays)
            drive = {"peak_displacement_m": gating["peak_displacement_m"],
                     "peak_acceleration_m_s2": gating["peak_acceleration_m_s2"],
                     "acceleration_scale": gating["acceleration_scale"]}
        extra = {"settle_s": motion["settle_s"].get(step.key, 0.0),
                 "peak_displacement_m": drive["peak_displacement_m"],
                 "peak_acceleration_m_s2": drive["peak_acceleration_m_s2"],
                 "peak_acceleration_g": drive["peak_acceleration_m_s2"] / G0,
                 "acceleration_scale": drive["acceleration_scale"],
                 "travel_m": motion["travel"].get(step.key, {})}
        if gating is not None:
            extra["gating"] = {"ramp_s": gating["ramp_s"],
                               "starts_s": {n.text: t for n, t in gating["starts_s"].items()},
                               "gates_s": {n.text: t for n, t in gating["gates_s"].items()},
                               "search_iterations": gating["iterations"]}
        if step.travel_m is not None:
            sized = motion["sizing"].get(step.key, {})
            extra["requested_travel_m"] = step.travel_m
            extra["sizing"] = {"slowest_probe_speed_m_s": sized.get("slowest_m_s"),
                               "probe_s": PROBE_S, "sized_s": sized.get("sized_s")}
    if step.targets_m is not None:
        extra = {"targets_m": dict(step.targets_m), "relative_to": step.relative_to,
                 "moves_m": dict(step.moves_m), **extra}
    return {
        "scene": step.scene, "name": step.name, "index": step.index,
        "duration_s": step.duration_s,
        "playback": "once" if isinstance(w, Burst) else "loop", **extra,
        "forward": list(step.forward), "backward": list(step.backward),
        "tones": [{"frequency_hz": float(f), "amplitude_m": float(z), "phase_rad": float(p),
                   **({"start_s": float(w.starts_s[i]), "gate_s": float(w.gates_s[i])}
                      if isinstance(w, Burst) else {})}
                  for i, (f, z, p) in enumerate(zip(w.frequencies, w.amplitudes, w.phases))],
        "crest_factor": float(w.crest_factor), "scale": float(w.scale),
        "loop_length_s": float(w.loop_length),
        "files": {fmt: f"waveforms/{stem}{EXPORTERS[fmt].suffix}" for fmt in EXPORT_FORMATS},
    }


def step_travels(ver_rows):
    """Step key -> {device: travel [m]} of every slider that moves in the step (burst and
    dwell, from rest, under the step's summed drive), in device order."""
    out = {}
    for r in ver_rows:
        key = f"{r['scene']}/{r['step']}"
        out.setdefault(key, {})
        if r["expected"] != "idle" or r.get("travel_m", 0.0) != 0.0:
            out[key][r["device"]] = r.get("travel_m", 0.0)
    return {k: dict(sorted(v.items(), key=lambda kv: device_key(kv[0])))
            for k, v in out.items()}


class Record(NamedTuple):
    """:func:`build_record`'s plan.json: the typed record and the dict the file holds
    (its dump), and the impacter, device and step rows as the stages gave them
    (unrounded: the result's tables)."""

    #: plan.json as its schema's record (:class:`~planner.planfile.schema.PlanFile`)
    file: PlanFile
    #: plan.json's content, the record's dump
    data: dict
    impacters: list
    devices: list
    steps: list


def build_record(settings, steps, assignment, designs, sliders, waveforms, ver_rows, passed,
                 rounds, scene_rows, motion=None, manufacturability=None,
                 sections=None) -> Record:
    """plan.json, through its schema (:class:`Record`).

    ``manufacturability``: the block of :func:`planner.planning.manufacture.assess`.

    ``sections`` (optional): further top-level blocks, last and in their order (a
    re-plan's ``as_built`` and ``replan``, a drive chain's ``chain``).

    ``motion``: {"sizing", "drive", "settle_s", "repairs", "gating"} of the pipeline
    (burst sizing notes, drive peaks and acceleration scales, settle dwells by step key,
    motion repairs, the gate search of each ``targets_um`` step); adds the per-step
    motion keys.
    """
    if motion is not None:
        motion = {**motion, "travel": step_travels(ver_rows)}
    impacter_recs = [impacter_record(n, assignment, designs[n])
                     for n in sorted(designs, key=node_order)]
    device_recs = [{"id": d, "slider_mass_kg": s.mass, "slider_damping_ns_per_m": s.damping,
                    "static_friction_n": s.static_friction,
                    "dynamic_friction_n": s.dynamic_friction} for d, s in sliders.items()]
    step_recs = [step_record(st, waveforms[st.key], motion) for st in steps]
    per_step = {}
    for r in ver_rows:
        per_step.setdefault(f"{r['scene']}/{r['step']}", {})[r["device"]] = {
            k: r[k] for k in r if k not in ("scene", "step", "index", "device")}
    data = {
        "format_version": FORMAT_VERSION,
        "vibroplan_version": version_string(),
        "seed": settings.seed,
        "spec": settings.spec_record,
        "assignment": {"span": assignment.span, "lower_bound": assignment.lower_bound,
                       "optimal": assignment.optimal, "method": assignment.method,
                       "stride": assignment.stride, "offset": assignment.offset,
                       "graph_nodes": assignment.graph.number_of_nodes(),
                       "graph_edges": assignment.graph.number_of_edges(),
                       "separation_problems": verify_assignment(assignment),
                       "guard_violations": [str(v) for v in assignment.violations],
                       "reach": (None if assignment.reach is None
                                 else assignment.reach.to_dict())},
        "impacters": impacter_recs,
        "devices": device_recs,
        "steps": step_recs,
        "verification": {"passed": passed, "repair_rounds": rounds,
                         "motion_repairs": (motion or {}).get("repairs", []),
                         "design_problems": (motion or {}).get("design_problems", []),
                         # only when a design was confirmed (plan.json as before otherwise)
                         **({"confirmed_designs": (motion or {})["confirmed_designs"]}
                            if (motion or {}).get("confirmed_designs") else {}),
                         "max_travel_m": settings.max_travel_m,
                         "position_tolerance_m": settings.position_tolerance_m,
                         "steps": per_step},
        "scenes": scene_rows,
    }
    if manufacturability is not None:
        data["manufacturability"] = manufacturability
    data.update(sections or {})
    file, data = through_schema(round_floats(data))
    return Record(file, data, impacter_recs, device_recs, step_recs)
