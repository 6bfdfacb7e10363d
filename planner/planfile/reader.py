"""plan.json read back: its one reader, its checks, and the drive it records.

:mod:`planner.planning.record` writes plan.json and this module reads it, both through
its schema (:mod:`planner.planfile.schema`, every block declared once as a typed
record, units in the field names); the reader reads it once into a frozen
:class:`PlanRecord`, and every command that takes a plan (``vibroplan yield``,
``replan``, ``trim``, ``drive``, ``layout``) reads it through :func:`read_plan` --
never the dict.  The blocks no command reads back (verification rows, scenes, the
manufacturability model) are the report's: declared by their keys, not read.

Validated once, here, with the key named on any fault (:class:`PlanFileError`, a
:class:`~planner.core.errors.SpecError`: exit 2 in the CLI):

- the JSON itself, and ``format_version`` (plans from before format versions are
  format 1; another version is refused);
- every key the schema requires present with its type (no bool or string read as a
  number, no NaN), and the bounds it declares (a mass > 0, a damping >= 0);
- the spec, as an :class:`~planner.arrayspec.ArraySpec` with its steps resolved;
- numbers that contradict each other: an impacter's ``natural_frequency_hz`` against its
  ``mass_kg`` and ``stiffness_n_per_m`` (nu = sqrt(k/m) / 2 pi); its mass, stiffness and
  damping against its ``geometry`` through the fabrication equations
  (:func:`planner.fabrication.tolerances.nominal_impacter`, eqs. (2)-(4)) on the spec's process; ids against
  devices and directions; steps against the impacters they drive.

A re-planned plan (``vibroplan replan``) is a plan: its impacters carry the as-built
stiffness, damping and gap (its ``as_built`` section, which must agree), and its
``replan.moved`` entries the designed natural frequency, which must follow from the
geometry as a plan's does.

:func:`step_drive` rebuilds a step's drive (its tones) from the record.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydantic import ValidationError

from planner.core.errors import SpecError
from planner.core.nodes import DIRECTIONS
from planner.arrayspec import ArraySpec, LoadedSpec, resolve_steps
from planner.arrayspec.load import check_sections
from planner.files.yamlio import format_loc, validate
from planner.planfile.schema import (FORMAT_VERSION, AsBuiltRecord, DeviceRecord,
                                     ImpacterRecord, PlanFile, StepRecord, Tone)

__all__ = ["FORMAT_VERSION", "AGREE_RTOL", "PlanFileError", "PlanRecord", "RecordedDrive",
           "read_plan", "plan_record", "step_drive", "drives", "AsBuiltRecord",
           "DeviceRecord", "ImpacterRecord", "StepRecord", "Tone"]

#: Relative tolerance of numbers that must agree (plan.json holds 12 significant digits).
AGREE_RTOL = 1e-6
#: Impacter fields the planner designs: left out of the spec read back (the record holds
#: their defaults, which a spec may not set).
DESIGNED_FIELDS = ("area_um2", "width_um", "length_um", "gap_um", "natural_frequency_hz")


class PlanFileError(SpecError):
    """A plan.json that cannot be used, naming the file and the key (``path``)."""


# ----------------------------------------------------------------------------- record


@dataclass(frozen=True)
class PlanRecord:
    """A plan.json read and checked (see the module docstring).

    Attributes
    ----------
    path : Path or None
        The file read (None for a record made from a dict in memory).
    format_version : int
    vibroplan_version : str
        The version that wrote it.
    seed : int
        The plan's seed (designs and drive phases).
    spec : ArraySpec
        Its spec, validated (designed impacter fields left to their defaults).
    loaded : LoadedSpec
        The spec with its steps resolved (the steps the spec asks for; a re-plan may
        have merged some: :attr:`steps` are the ones recorded).
    impacters : tuple of ImpacterRecord
        In the file's order.
    devices : tuple of DeviceRecord
    steps : tuple of StepRecord
        The recorded steps, in order, each with its tones.
    lower_bound : int
        The assignment's lower bound on the span [channels].
    verified : bool
        Whether the plan passed its own verification.
    dwells : dict
        Step key -> settle dwell after it [s] (recorded, else the longest its
        verification found, else 0).
    as_built : dict or None
        Impacter id -> :class:`~planner.planfile.schema.AsBuiltRecord` of a re-planned plan; None for a plan.
    design_natural_frequency_hz : dict
        Impacter id -> its designed natural frequency [Hz] (a re-plan's impacters are
        as built; this is what their geometry was designed for).
    manufacturability : dict or None
        plan.json's ``manufacturability`` block as written (sensitivities, separations,
        the predicted yield; :func:`planner.planning.manufacture.assess`), None in plans
        from before it.  Its ``separation_hz`` is checked: one entry per impacter, each
        reach a finite number within what its measurement can give.  A re-planned plan
        carries its design's block (the separations are the designs').
    design_frequency_hz : dict
        Impacter id -> its designed tone [Hz] (a plan's tone; a re-plan's impacters
        play as-built tones, and their separations and trims are reckoned from the
        design's).
    """

    path: Path | None
    format_version: int
    vibroplan_version: str
    seed: int
    spec: ArraySpec
    loaded: LoadedSpec
    impacters: tuple
    devices: tuple
    steps: tuple
    lower_bound: int
    verified: bool
    dwells: dict
    as_built: dict | None
    design_natural_frequency_hz: dict
    manufacturability: dict | None = None
    design_frequency_hz: dict | None = None

    @property
    def replanned(self) -> bool:
        """Whether this is the output of ``vibroplan replan``."""
        return self.as_built is not None

    @property
    def impacter_ids(self) -> list[str]:
        return [r.id for r in self.impacters]

    def impacter(self, node_id: str) -> ImpacterRecord:
        """The record of impacter ``node_id`` (KeyError naming it if the plan has none)."""
        for rec in self.impacters:
            if rec.id == node_id:
                return rec
        raise KeyError(f"the plan has no impacter {node_id!r}")

    def step(self, key: str) -> StepRecord:
        for st in self.steps:
            if st.key == key:
                return st
        raise KeyError(f"the plan has no step {key!r}")


@dataclass(frozen=True)
class RecordedDrive:
    """A step's drive as plan.json records it: what the verification reads of a
    :class:`planner.synthesis.Waveform` (its tones), in SI; a gated step's
    (``playback: once``) also each tone's start and gate and the ramp [s], which the
    verification plays as :class:`planner.synthesis.gating.Burst` plays them."""

    frequencies: np.ndarray
    amplitudes: np.ndarray
    phases: np.ndarray
    starts_s: np.ndarray | None = None
    gates_s: np.ndarray | None = None
    ramp_s: float = 0.0

    def program(self):
        """A gated drive as stretches of constant tones (:meth:`planner.synthesis.gating.Burst.
        program`): ((duration [s], model.Drive), ...)."""
        from planner.synthesis.gating import stretches

        if self.gates_s is None:
            raise ValueError("a loop's drive has no program of its own: it plays for its "
                             "step's duration (planner.planning.drives.program_of)")
        return stretches(self.frequencies, self.amplitudes, self.phases, self.starts_s,
                         self.gates_s, self.ramp_s)


def step_drive(step: StepRecord) -> RecordedDrive:
    """The drive of a recorded step: its tones' frequencies [Hz], amplitudes [m] and
    phases [rad], shape (n_tones,) each, and a gated step's starts, gates and ramp."""
    gated = {}
    if step.gated:
        gated = {"starts_s": np.array([t.start_s for t in step.tones], dtype=float),
                 "gates_s": np.array([t.gate_s for t in step.tones], dtype=float),
                 "ramp_s": float(step.gating["ramp_s"])}
    return RecordedDrive(np.array([t.frequency_hz for t in step.tones], dtype=float),
                         np.array([t.amplitude_m for t in step.tones], dtype=float),
                         np.array([t.phase_rad for t in step.tones], dtype=float), **gated)


def drives(record: PlanRecord) -> dict:
    """Step key -> :func:`step_drive` of every recorded step."""
    return {st.key: step_drive(st) for st in record.steps}


# ----------------------------------------------------------------------------- reading


def read_plan(path) -> PlanRecord:
    """Read a plan: a folder holding plan.json, or the plan.json file itself.

    Raises
    ------
    FileNotFoundError
        No plan.json there.
    PlanFileError
        Not JSON, of another format version, a declared key missing or of the wrong
        type, or numbers that contradict each other; the message names the file and the
        key (``impacters[0] (A1.forward).natural_frequency_hz: ...``).
    """
    from planner.files import read_input

    path = Path(path)
    file = path / "plan.json" if path.is_dir() else path
    if path.is_dir() and not file.exists():
        raise FileNotFoundError(2, f"no plan.json in the folder {path}", str(file))
    raw = read_input(file)
    try:
        data = json.loads(raw.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise PlanFileError(f"not a plan.json: not UTF-8 text (byte {exc.start})",
                            source=str(file)) from None
    except ValueError as exc:
        raise PlanFileError(f"not a plan.json: not JSON ({exc})", source=str(file)) from None
    return plan_record(data, source=str(file), path=file)


def plan_record(data, *, source: str = "plan.json", path: Path | None = None) -> PlanRecord:
    """A :class:`PlanRecord` of a plan.json's parsed content (``data``), checked as
    :func:`read_plan` checks a file; ``source`` names it in errors."""
    if not isinstance(data, dict):
        raise PlanFileError("not a plan.json: a plan is a JSON object", source=source)
    version = data.get("format_version", FORMAT_VERSION)
    if version != FORMAT_VERSION or isinstance(version, bool):
        raise PlanFileError(
            f"this plan is in format {version!r} (written by vibroplan "
            f"{data.get('vibroplan_version', '?')}); this vibroplan reads format "
            f"{FORMAT_VERSION}: plan again with it, or read the plan with the version that "
            "wrote it", path="format_version", source=source)
    missing = [k for k in ("spec", "impacters", "steps") if k not in data]
    if missing:
        raise PlanFileError(f"not a plan.json: no {', '.join(missing)}", path=missing[0],
                            source=source)
    try:
        raw = PlanFile.model_validate(data)
    except ValidationError as exc:
        raise _schema_error(exc, data, source) from None
    spec = _spec(raw.spec, source)
    loaded = LoadedSpec(spec, resolve_steps(spec, None, f"{source} spec"), source)
    record = PlanRecord(
        path=path, format_version=raw.format_version, vibroplan_version=raw.vibroplan_version,
        seed=raw.seed, spec=spec, loaded=loaded, impacters=raw.impacters,
        devices=raw.devices, steps=raw.steps, lower_bound=raw.assignment.lower_bound,
        verified=raw.verification.passed, dwells=_dwells(raw),
        as_built=dict(raw.as_built) if raw.as_built is not None else None,
        design_natural_frequency_hz=_design_frequencies(raw, source),
        manufacturability=data.get("manufacturability"),
        design_frequency_hz=_design_tones(raw))
    _check(record, source)
    return record


def _schema_error(exc: ValidationError, data: dict, source: str) -> PlanFileError:
    """The first schema fault, its key named (with the impacter's or step's name)."""
    err = exc.errors()[0]
    loc = tuple(p for p in err["loc"] if not (isinstance(p, str) and "[" in p))
    where = format_loc(loc)
    if len(loc) >= 2 and loc[0] in ("impacters", "steps", "devices") and isinstance(loc[1], int):
        items = data.get(loc[0])
        item = items[loc[1]] if isinstance(items, list) and loc[1] < len(items) else None
        name = None
        if isinstance(item, dict):
            name = item.get("id") if loc[0] != "steps" else f"{item.get('scene')}/{item.get('name')}"
        tail = format_loc(loc[2:])
        where = (format_loc(loc[:2]) + (f" ({name})" if isinstance(name, str) else "")
                 + (tail if not tail or tail.startswith("[") else "." + tail))
    msg = err["msg"]
    if err["type"] == "missing":
        msg = "missing (a key every plan.json has)"
    elif "input" in err and err["type"] not in ("missing",):
        msg += f", {json.dumps(err['input'])[:60]} was given"
    return PlanFileError(msg, path=where, source=source)


def _spec(spec_data: dict, source: str) -> ArraySpec:
    """The plan's spec, validated; the designed impacter fields left out."""
    spec = json.loads(json.dumps(spec_data))
    overrides = spec.get("devices") if isinstance(spec, dict) else None
    # a mistyped section is left for the validation below to name
    sections = ([spec.get("device") or {}] if isinstance(spec, dict) else []) + (
        list(overrides.values()) if isinstance(overrides, dict) else [])
    for sec in sections:
        for key in ("impacter", "forward", "backward"):
            cfg = sec.get(key) if isinstance(sec, dict) else None
            if isinstance(cfg, dict):
                for name in DESIGNED_FIELDS:
                    cfg.pop(name, None)
    out = validate(ArraySpec, spec, source=source, prefix=("spec",))
    check_sections(out, source=source, prefix=("spec",))
    return out


def _dwells(raw: PlanFile) -> dict:
    checked = raw.verification.steps or {}
    out = {}
    for st in raw.steps:
        if st.settle_s is not None:
            out[st.key] = st.settle_s
        else:
            rows = (checked.get(st.key) or {}).values()
            out[st.key] = max((float(r.get("settle_s") or 0.0) for r in rows
                               if isinstance(r, dict)), default=0.0)
    return out


def _design_frequencies(raw: PlanFile, source: str) -> dict:
    if raw.replan is None:
        if raw.as_built is not None:
            raise PlanFileError("a re-planned plan needs its replan section (the designed "
                                "natural frequencies)", path="replan", source=source)
        return {r.id: r.natural_frequency_hz for r in raw.impacters}
    if raw.as_built is None:
        raise PlanFileError("a re-planned plan needs its as_built section", path="as_built",
                            source=source)
    return {m.id: m.design_natural_frequency_hz for m in raw.replan.moved}


def _design_tones(raw: PlanFile) -> dict:
    if raw.replan is None:
        return {r.id: r.frequency_hz for r in raw.impacters}
    tones = {r.id: r.frequency_hz for r in raw.impacters}
    for m in raw.replan.moved:
        tones[m.id] = m.design_frequency_hz or m.original_frequency_hz or tones.get(m.id)
    return tones


# ----------------------------------------------------------------------------- checks

#: How far a step's recorded tone may sit from its impacter's planned tone [-]: the
#: synthesis snaps a loop's tones to its length by at most 0.1 % (and a single tone by
#: far less); further is an edited file.
TONE_RTOL = 2e-3


def _agree(got: float, want: float) -> bool:
    return math.isclose(got, want, rel_tol=AGREE_RTOL, abs_tol=0.0)


def _check(record: PlanRecord, source: str) -> None:
    """Numbers that must agree, ids that must exist (see the module docstring)."""
    from planner.fabrication.tolerances import NodeDesign, nominal_impacter

    def fail(where, message):
        raise PlanFileError(message, path=where, source=source)

    devices = set(record.spec.array.device_ids())
    if not record.impacters:
        fail("impacters", "a plan has at least one impacter")
    if not record.steps:
        fail("steps", "a plan has at least one step (a drive with nothing to play moves "
                      "nothing: there is nothing to verify)")
    seen = set()
    for i, rec in enumerate(record.impacters):
        where = f"impacters[{i}] ({rec.id})"
        if rec.direction not in DIRECTIONS:
            fail(f"{where}.direction", f"must be forward or backward, {rec.direction!r} "
                                       "was given")
        if rec.device not in devices:
            fail(f"{where}.device", f"{rec.device!r} is not a device of the spec's "
                                    f"{record.spec.array.rows} x {record.spec.array.cols} array")
        if rec.id != f"{rec.device}.{rec.direction}":
            fail(f"{where}.id", f"must be {rec.device}.{rec.direction} (device.direction)")
        if rec.id in seen:
            fail(f"{where}.id", f"{rec.id} is listed twice")
        seen.add(rec.id)
        nu = math.sqrt(rec.stiffness_n_per_m / rec.mass_kg) / (2 * math.pi)
        if not _agree(rec.natural_frequency_hz, nu):
            fail(f"{where}.natural_frequency_hz",
                 f"{rec.natural_frequency_hz:.6g} Hz does not follow from mass_kg and "
                 f"stiffness_n_per_m (sqrt(k/m) / 2 pi = {nu:.6g} Hz): the numbers contradict "
                 "each other (was the file edited?)")
        g = rec.geometry
        nominal = nominal_impacter(record.spec, NodeDesign(rec.id, rec.device, rec.direction,
                                                  g.area_m2, g.width_m, g.length_m, g.gap_m,
                                                  rec.impact_angle_rad, rec.restitution))
        ab = (record.as_built or {}).get(rec.id)
        # a re-plan's mass is as built (issue 37: inferred with the stiffness, the
        # damping and the gap from the measurement); a plan's follows from its geometry
        checks = [("mass_kg", rec.mass_kg,
                   ab.mass_kg if ab is not None and ab.mass_kg is not None else nominal.mass)]
        if record.as_built is None:
            checks += [("stiffness_n_per_m", rec.stiffness_n_per_m, nominal.stiffness),
                       ("damping_ns_per_m", rec.damping_ns_per_m, nominal.damping)]
            if not _agree(rec.gap_m, g.gap_m):
                fail(f"{where}.gap_m", f"{rec.gap_m:.6g} m is not its geometry's gap_m "
                                       f"{g.gap_m:.6g} m")
        else:
            # as built: the stiffness is the measured one; the design's follows from the
            # geometry as a plan's does
            design_nu = record.design_natural_frequency_hz.get(rec.id)
            if design_nu is None:
                fail("replan.moved", f"{rec.id} has no entry (its designed natural frequency)")
            if not _agree(design_nu, nominal.natural_frequency):
                fail(f"replan.moved ({rec.id}).design_natural_frequency_hz",
                     f"{design_nu:.6g} Hz does not follow from its geometry "
                     f"({nominal.natural_frequency:.6g} Hz through the fabrication equations): "
                     "the numbers contradict each other (was the file edited?)")
            if ab is None:
                fail(f"as_built.{rec.id}", "missing: a re-planned impacter has its as-built "
                                          "model")
            for key in ("natural_frequency_hz", "stiffness_n_per_m", "damping_ns_per_m",
                        "gap_m"):
                if not _agree(getattr(rec, key), getattr(ab, key)):
                    fail(f"{where}.{key}", f"{getattr(rec, key):.6g} differs from "
                                           f"as_built.{rec.id}.{key} {getattr(ab, key):.6g}")
        for key, got, want in checks:
            if not _agree(got, want):
                fail(f"{where}.{key}",
                     f"{got:.6g} does not follow from its geometry through the fabrication "
                     f"equations on the spec's process ({want:.6g}): the numbers contradict "
                     "each other (was the file edited, or the plan made with another "
                     "process section?)")
    _check_channels(record, fail)
    _check_separations(record, fail)
    tone_of = {rec.id: rec.frequency_hz for rec in record.impacters}
    keys = set()
    for j, st in enumerate(record.steps):
        where = f"steps[{j}] ({st.key})"
        if st.key in keys:
            fail(f"{where}.name", f"step {st.key} is listed twice")
        keys.add(st.key)
        if not st.tones:
            fail(f"{where}.tones", "a step has at least one tone")
        both = set(st.forward) & set(st.backward)
        if both:
            fail(f"{where}.backward", f"{', '.join(sorted(both))} cannot move both ways")
        if not st.forward and not st.backward:
            fail(f"{where}.forward", "a step moves at least one device")
        for key, devs, direction in (("forward", st.forward, "forward"),
                                     ("backward", st.backward, "backward")):
            for d in devs:
                if f"{d}.{direction}" not in seen:
                    fail(f"{where}.{key}", f"drives {d}.{direction}, which is not among the "
                                           "plan's impacters")
        # its tones once its impacters are known to be the plan's
        _check_step_tones(st, where, tone_of, fail)


def _check_channels(record: PlanRecord, fail) -> None:
    """Each impacter's tone on its channel of the spec's grid (a plan's assignment put
    it there; a re-plan's channel is the grid's nearest to its as-built tone)."""
    from planner.manufacturability import channel_grid

    grid = np.asarray(channel_grid(record.spec), dtype=float)
    for i, rec in enumerate(record.impacters):
        where = f"impacters[{i}] ({rec.id})"
        if not 0 <= rec.channel < grid.size:
            fail(f"{where}.channel", f"{rec.channel} is not a channel of the spec's grid "
                                     f"(0-{grid.size - 1})")
        if record.as_built is None:
            if not _agree(rec.frequency_hz, float(grid[rec.channel])):
                fail(f"{where}.frequency_hz",
                     f"{rec.frequency_hz:.6g} Hz is not its channel {rec.channel}'s "
                     f"{grid[rec.channel]:.6g} Hz on the spec's channel grid: the numbers "
                     "contradict each other (was the file edited?)")
        elif int(np.argmin(np.abs(grid - rec.frequency_hz))) != rec.channel:
            fail(f"{where}.channel",
                 f"{rec.channel} is not the channel nearest its tone {rec.frequency_hz:.6g} "
                 "Hz on the spec's channel grid (was the file edited?)")


def _check_separations(record: PlanRecord, fail) -> None:
    """``manufacturability.separation_hz``: one entry per impacter, each reach no
    further than :func:`planner.manufacturability.measure_separation` scans (a few
    per cent of the resonance beyond the tone's offset): a reach beyond it is no
    measurement (a typo or another unit) and would move every re-planned tone."""
    from planner.manufacturability.separation import (
        EDGE_TOL_HZ,
        SCAN_SPAN_REL,
        SCAN_STEP_MIN_HZ,
        SCAN_STEP_REL,
    )

    block = record.manufacturability
    if block is None:
        return
    seps = block["separation_hz"]
    ids = record.impacter_ids
    for n in ids:
        if n not in seps:
            fail(f"manufacturability.separation_hz.{n}",
                 "missing: every impacter has its silent band and tone window")
    for n in seps:
        if n not in ids:
            fail(f"manufacturability.separation_hz.{n}", "not an impacter of the plan")
    for n in ids:
        nu = record.design_natural_frequency_hz[n]
        tone = record.design_frequency_hz[n]
        top = max(nu, tone)
        # the scan's reach from its start (the resonance or the tone), one step and the
        # edge's bisection beyond it
        reach = (abs(tone - nu) + (SCAN_SPAN_REL + SCAN_STEP_REL) * top
                 + SCAN_STEP_MIN_HZ + EDGE_TOL_HZ)
        sep = seps[n]
        for key, want in (("silent_beyond", max(sep["silent_below"], sep["silent_above"])),
                          ("responds_within", min(sep["responds_below"],
                                                  sep["responds_above"]))):
            if not _agree(float(sep[key]), float(want)):
                fail(f"manufacturability.separation_hz.{n}.{key}",
                     f"{sep[key]:.6g} Hz is not the {key.split('_')[0]} reach "
                     f"{want:.6g} Hz of its own band (was the file edited?)")
        for key in ("silent_below", "silent_above", "responds_below", "responds_above"):
            value = float(seps[n][key])
            if value > reach:
                fail(f"manufacturability.separation_hz.{n}.{key}",
                     f"{value:.6g} Hz reaches further than its measurement can ({reach:.6g} "
                     f"Hz from a {nu:.6g} Hz resonance): was the file edited?")


def _check_step_tones(st: StepRecord, where: str, tone_of: dict, fail) -> None:
    """A step's tones are its impacters' planned tones (within the synthesis' snapping,
    :data:`TONE_RTOL`), each one of them, and a gated step's tones carry their gates."""
    wanted = []
    for devs, direction in ((st.forward, "forward"), (st.backward, "backward")):
        wanted += [tone_of[f"{d}.{direction}"] for d in devs if f"{d}.{direction}" in tone_of]
    for k, tone in enumerate(st.tones):
        near = min(wanted, key=lambda f: abs(f - tone.frequency_hz), default=None)
        if near is None or abs(tone.frequency_hz - near) > TONE_RTOL * near:
            fail(f"{where}.tones[{k}].frequency_hz",
                 f"{tone.frequency_hz:.6g} Hz is not the planned tone of an impacter the "
                 "step drives (" + ", ".join(f"{f:.6g}" for f in sorted(set(wanted)))
                 + " Hz): the numbers contradict each other (was the file edited?)")
    for f in wanted:
        if not any(abs(t.frequency_hz - f) <= TONE_RTOL * f for t in st.tones):
            fail(f"{where}.tones", f"no tone plays {f:.6g} Hz, the planned tone of an "
                                   "impacter the step drives")
    if st.playback not in ("loop", "once"):
        fail(f"{where}.playback", f"must be loop or once, {st.playback!r} was given")
    if st.gated:
        ramp = (st.gating or {}).get("ramp_s")
        if isinstance(ramp, bool) or not isinstance(ramp, (int, float)) or not (
                math.isfinite(ramp) and ramp > 0):
            fail(f"{where}.gating.ramp_s", "a gated step (playback: once) needs its ramp "
                                           f"[s] > 0, {json.dumps(ramp)} was given")
        for k, tone in enumerate(st.tones):
            if tone.start_s is None or tone.gate_s is None:
                fail(f"{where}.tones[{k}]", "a gated step's tone needs its start_s and "
                                            "gate_s")
            if tone.gate_s and tone.gate_s < tone.start_s + ramp * (1 - 1e-9):
                fail(f"{where}.tones[{k}].gate_s",
                     f"{tone.gate_s:.6g} s is before its start_s + ramp ("
                     f"{tone.start_s + ramp:.6g} s)")
        if st.targets_m is None:
            fail(f"{where}.targets_m", "a gated step (playback: once) is a targets_um "
                                       "step: its targets are missing")
