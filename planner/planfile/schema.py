"""plan.json's schema: every block of the file declared once, as typed records.

The plan's pipeline writes plan.json through these records (:func:`planner.planning.
record.build_record`, :func:`through_schema`), and its reader (:mod:`planner.planfile.
reader`) reads it back through them; the after-fabrication code reads a re-plan's
``replan`` block as :class:`Replan` (``Plan.replan``), never as the dict.  Units are in
the field names, as in the file (SI: ``_hz``, ``_m``, ``_kg``, ``_s``, ...).

A record declares its fields in the order the file holds them: a record dumped
(:func:`to_file`: only the fields that were given, JSON types) is the file's block, key
for key and byte for byte.  A block a later stage does not read is declared by its keys
with loose types (:data:`JSON`: the report's: verification rows, scenes, the
manufacturability model); its keys are still declared, so that a key the writer adds
and the schema does not know is an error (:class:`PlanSchemaError`), not a silent
second declaration.

Validation has two readers:

- **reading** a plan.json (the default): every type is checked and the bounds hold
  (:data:`Positive`, :data:`NonNegative`): a mass of 0 or a negative damping is no plan;
  the numbers that must agree with each other are the reader's checks
  (:func:`planner.planfile.reader.plan_record`);
- **writing** one (:func:`through_schema`, context :data:`WRITING`): the types are
  checked and the bounds are not (a failed plan is written as it is, to be read);
  the record must give back exactly what was written.
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import (AfterValidator, BaseModel, ConfigDict, Field, ValidationError,
                      ValidationInfo)
from pydantic_core import PydanticCustomError

from planner.arrayspec import Step
from planner.core.nodes import Node

#: The plan.json format this version writes and reads (``format_version``).  Raise it
#: when a key that a reader needs changes meaning or shape.
FORMAT_VERSION = 1
#: The validation context of :func:`through_schema` (writing: the bounds are not
#: checked, the types are).
WRITING = {"writing": True}


def _bound(gt: bool):
    """A validator of a reading's bound: > 0 (``gt``) or >= 0, with pydantic's own error
    type and words; not checked while writing (:data:`WRITING`)."""

    def check(value, info: ValidationInfo):
        if value is None or (info.context or {}).get("writing"):
            return value
        if gt and not value > 0:
            raise PydanticCustomError("greater_than", "Input should be greater than {gt}",
                                      {"gt": 0})
        if not gt and not value >= 0:
            raise PydanticCustomError("greater_than_equal",
                                      "Input should be greater than or equal to {ge}",
                                      {"ge": 0})
        return value

    return check


Number = Annotated[float, Field(strict=True, allow_inf_nan=False)]
#: > 0 when read
Positive = Annotated[float, Field(strict=True, allow_inf_nan=False),
                     AfterValidator(_bound(True))]
#: >= 0 when read
NonNegative = Annotated[float, Field(strict=True, allow_inf_nan=False),
                        AfterValidator(_bound(False))]
Int = Annotated[int, Field(strict=True)]
Bool = Annotated[bool, Field(strict=True)]
Text = Annotated[str, Field(strict=True, min_length=1)]
#: A value of a block no stage reads back (the report's), kept as written.
JSON = Any


class PlanSchemaError(RuntimeError):
    """plan.json's writer and its schema disagree (a key written but not declared, a
    value of another type): a fault of the code, named by its key."""


class _Record(BaseModel):
    """A block of plan.json: frozen; keys it does not declare are ignored on reading
    (the writer is held to them by :func:`through_schema`)."""

    model_config = ConfigDict(frozen=True, extra="ignore")


# ----------------------------------------------------------------------------- steps


class Tone(_Record):
    """One tone of a step's drive; a gated step's tones (``playback: once``) also carry
    when each starts and stops playing [s]."""

    frequency_hz: Positive
    amplitude_m: Positive
    phase_rad: Number
    start_s: NonNegative | None = None
    gate_s: NonNegative | None = None


class Sizing(_Record):
    """How a burst asked as a travel was sized: the slowest slider's speed on its probe
    [m/s], the probe's length [s] and the burst's [s]."""

    slowest_probe_speed_m_s: Number | None = None
    probe_s: Number | None = None
    sized_s: Number | None = None


class StepRecord(_Record):
    """One step of the drive: who moves, for how long, with which tones.

    ``settle_s`` is the dwell after the step [s] as recorded (None in plans from before
    it was recorded: then :attr:`planner.planfile.reader.PlanRecord.dwells` takes the
    longest its verification found).
    """

    scene: Text
    name: Text
    index: Int
    duration_s: Positive
    #: ``loop`` (a seamless loop played for ``duration_s``) or ``once`` (a gated burst:
    #: each tone between its ``start_s`` and ``gate_s``, :mod:`planner.synthesis.gating`).
    playback: str = "loop"
    #: A ``targets_um`` step's targets (device -> position [m], relative to
    #: ``relative_to``) and the moves its burst was gated for (device -> [m]); None for
    #: any other step.
    targets_m: dict[str, Number] | None = None
    relative_to: str | None = None
    moves_m: dict[str, Number] | None = None
    settle_s: NonNegative | None = None
    #: the summed drive's (a gated step's: the burst's) peaks [m, m/s^2, g]
    peak_displacement_m: Number | None = None
    peak_acceleration_m_s2: Number | None = None
    peak_acceleration_g: Number | None = None
    #: The factor the acceleration limit lowered the step's tones by (1: none; None in
    #: plans from before the limit).
    acceleration_scale: Positive | None = None
    #: device -> its slider's predicted travel in the step [m]
    travel_m: dict[str, Number] | None = None
    #: A gated step's gating (``ramp_s``, ``starts_s``, ``gates_s``,
    #: ``search_iterations``); its ramp is checked by the reader.
    gating: dict | None = None
    #: a burst asked as a travel: the travel [m] and how it was sized
    requested_travel_m: Number | None = None
    sizing: Sizing | None = None
    forward: tuple[Text, ...]
    backward: tuple[Text, ...]
    tones: tuple[Tone, ...]
    crest_factor: Number | None = None
    scale: Number | None = None
    loop_length_s: Number | None = None
    #: format -> the waveform file, relative to the plan's folder
    files: dict[str, str] | None = None

    @property
    def key(self) -> str:
        """``scene/name``."""
        return f"{self.scene}/{self.name}"

    @property
    def step(self) -> Step:
        """The step as the planner's stages take it (a ``targets_um`` step with its
        targets and moves, so that its checks are the position checks)."""
        if self.targets_m is None:
            return Step(self.scene, self.name, self.index, self.duration_s, self.forward,
                        self.backward)
        from planner.core.nodes import device_key

        def ordered(d):
            return tuple(sorted(((k, float(v)) for k, v in (d or {}).items()),
                                key=lambda kv: device_key(kv[0])))

        return Step(self.scene, self.name, self.index, self.duration_s, self.forward,
                    self.backward, targets_m=ordered(self.targets_m),
                    relative_to=self.relative_to or "scene_start",
                    moves_m=ordered(self.moves_m if self.moves_m is not None
                                    else self.targets_m))

    @property
    def gated(self) -> bool:
        """A burst played once (``playback: once``), its tones gated."""
        return self.playback == "once"


# ----------------------------------------------------------------------------- impacters


class GeometryRecord(_Record):
    """An impacter's designed geometry (A, w, l, c) [m^2, m, m, m]."""

    area_m2: Positive
    width_m: Positive
    length_m: Positive
    gap_m: Positive


class ImpacterRecord(_Record):
    """One designed impacter pair (SI; as built, in a re-planned plan)."""

    id: Text
    device: Text
    direction: Text
    channel: Int
    frequency_hz: Positive
    mass_kg: Positive
    stiffness_n_per_m: Positive
    damping_ns_per_m: NonNegative
    gap_m: Positive
    impact_angle_rad: NonNegative
    restitution: NonNegative
    natural_frequency_hz: Positive
    geometry: GeometryRecord
    #: the designer's worst response to its own tone [N] and where it is [m]
    r_min_n: Number | None = None
    worst_x0_m: Number | None = None
    predicted_slider_speed_m_s: Number | None = None
    feasible: Bool | None = None
    #: the constraints an infeasible design misses (the designer's words and numbers)
    shortfalls: list[JSON] | None = None
    #: the tones the design was made to drive its slider at from every x0 [Hz]
    tone_window_hz: tuple[Number, Number] | None = None
    mass_ratio: Number | None = None
    contact: str | None = None

    @property
    def node(self) -> Node:
        return Node(self.device, self.direction)

    def impacter(self):
        """The :class:`model.Impacter` this record describes (with its geometry)."""
        import model

        g = self.geometry
        return model.Impacter(self.mass_kg, self.stiffness_n_per_m, self.damping_ns_per_m,
                              self.gap_m, self.impact_angle_rad, self.restitution,
                              model.Geometry(g.area_m2, g.width_m, g.length_m, self.gap_m))


class DeviceRecord(_Record):
    """One device's slider as planned."""

    id: Text
    slider_mass_kg: Positive
    slider_damping_ns_per_m: NonNegative
    static_friction_n: NonNegative
    dynamic_friction_n: NonNegative


# ----------------------------------------------------------------------------- blocks


class AssignmentRecord(_Record):
    """plan.json's ``assignment``: the channels' span [channels] and its lower bound,
    how they were found, the conflict graph's size, the separations it misses and the
    guard rules' warnings, and the measured reach the positions were laid on."""

    span: Int | None = None
    lower_bound: Int = 0
    optimal: Bool | None = None
    method: str | None = None
    stride: Int | None = None
    offset: Int | None = None
    graph_nodes: Int | None = None
    graph_edges: Int | None = None
    separation_problems: list[JSON] | None = None
    guard_violations: tuple[str, ...] | None = None
    reach: JSON = None


class VerificationRecord(_Record):
    """plan.json's ``verification``: passed or not, the repair rounds, the travel limit
    and position tolerance [m], and every step's check rows (step key -> device ->
    row: the report's)."""

    passed: Bool
    repair_rounds: list[JSON] | None = None
    motion_repairs: list[JSON] | None = None
    design_problems: list[JSON] | None = None
    #: infeasible designs whose one miss (the response under a summed drive within the
    #: designer's window) the steps' own simulation settles
    #: (:func:`planner.planning.verify.confirm_responses`); absent when there are none
    confirmed_designs: list[JSON] | None = None
    max_travel_m: Number | None = None
    position_tolerance_m: Number | None = None
    steps: dict[str, dict[str, dict]] | None = None


class SeparationRecord(_Record):
    """One design's silent band and tone window (plan.json's
    ``manufacturability.separation_hz.<id>``, :class:`planner.manufacturability.
    Separation`) [Hz]: the band reaches of a design that answers its own tone are > 0,
    a tone window's reaches >= 0 (0: its tone may not move that way)."""

    #: the larger band reach and the smaller window reach (the report's columns)
    silent_beyond: Positive
    responds_within: NonNegative
    silent_below: Positive
    silent_above: Positive
    responds_below: NonNegative
    responds_above: NonNegative


class ManufacturabilityRecord(_Record):
    """plan.json's ``manufacturability`` (:func:`planner.planning.manufacture.assess`):
    each impacter's sensitivities and separations and the predicted collision-free
    yield; a re-plan's holds its design's separations and a ``note``."""

    model: str | None = None
    sensitivity: JSON = None
    line_width_sensitivity_per_um: JSON = None
    separation_hz: dict[str, SeparationRecord]
    target_yield: JSON = None
    sensitivity_band_per_um: JSON = None
    collision_free_yield: JSON = None
    #: the share of chips whose *measured* resonances (the spec's measurement noise on
    #: top) have no colliding pair: what a re-plan can tell apart
    told_apart_yield: JSON = None
    die_only_yield: JSON = None
    device_only_yield: JSON = None
    closest_pair_hz: JSON = None
    limiting_pairs: JSON = None
    nominal_collisions: JSON = None
    meets_target: JSON = None
    pair_sigma_rel: JSON = None
    z_for_target: JSON = None
    note: str | None = None


class AsBuiltHalfRecord(_Record):
    """One half of a pair measured half by half (plan.json's ``as_built.<id>.halves``)."""

    half: Text
    natural_frequency_hz: Positive
    stiffness_n_per_m: Positive
    damping_ns_per_m: NonNegative
    gap_m: Positive
    mass_kg: Positive | None = None
    #: the fabrication errors inferred for it (:data:`planner.afterfab.as_built.ERRORS`)
    errors: dict[str, Number] | None = None


class AsBuiltRecord(_Record):
    """A re-planned impacter's as-built model (plan.json's ``as_built``); a pair
    measured half by half also has each half's (``halves``; the fields above are then
    the symmetric pair at their mean resonance)."""

    natural_frequency_hz: Positive
    stiffness_n_per_m: Positive
    damping_ns_per_m: NonNegative
    gap_m: Positive
    #: the as-built mass [kg] (a re-plan since issue 37 infers it from the measurement;
    #: absent in older re-plans, whose mass was the design's)
    mass_kg: Positive | None = None
    halves: tuple[AsBuiltHalfRecord, ...] | None = None
    #: the fabrication errors inferred (a pair measured whole)
    errors: dict[str, Number] | None = None


class Moved(_Record):
    """One impacter of a re-plan (plan.json's ``replan.moved``): its designed and
    as-built resonance [Hz] and their relative shift, its tone before and after [Hz]
    and their shift, and a tuning sweep's working window [Hz] where one was measured."""

    id: Text
    design_natural_frequency_hz: Positive
    #: The designed tone [Hz] (absent in re-plans from before it was recorded: then
    #: ``original_frequency_hz``, the tone of the plan it was re-planned from).
    design_frequency_hz: Positive | None = None
    natural_frequency_hz: Number | None = None
    natural_frequency_shift: Number | None = None
    original_frequency_hz: Positive | None = None
    frequency_hz: Number | None = None
    tone_shift: Number | None = None
    working_window_hz: tuple[Number, Number] | None = None


class DriveFailure(_Record):
    """One check the original drive fails on the chip: its step key, device and cause."""

    step: str
    device: str
    cause: str


class OriginalDrive(_Record):
    """The plan's drive on the re-planned chip (plan.json's ``replan.original_drive``):
    whether it passes, its checks and the failed ones."""

    passed: Bool
    checks: Int
    failed_checks: Int
    failures: tuple[DriveFailure, ...] = ()


class Inseparable(_Record):
    """Impacters no drive tells apart (plan.json's ``replan.inseparable``,
    :func:`planner.afterfab.drive.rescue`): a pair, with how far apart they are and how
    far they need to be [Hz]; or one impacter whose window several bands cover
    (``apart_hz`` and ``needs_hz`` None); ``message`` says it in words."""

    pair: tuple[str, ...]
    as_built_hz: tuple[Number, ...]
    apart_hz: Number | None = None
    needs_hz: Number | None = None
    message: str = ""


class ToneMove(_Record):
    """A tone the re-plan moved within its window because a step failed by it on the
    measured models (plan.json's ``replan.tone_moves``,
    :func:`planner.afterfab.drive.move_tones`): the impacter, its tone before and after
    [Hz], the free interval of its window it moved in [Hz], the positions tried, and the
    failed checks (beyond the motion's) of the steps it plays in before and after."""

    id: Text
    from_hz: Positive
    to_hz: Positive
    window_hz: tuple[Number, Number] | None = None
    tries: Int
    failures_before: Int
    failures_after: Int


class Replan(_Record):
    """plan.json's ``replan`` block (:func:`planner.afterfab.replan.replan`): what
    moved, the original drive on this chip, the impacters no drive tells apart, the
    steps split (step key -> its sub-steps' keys) and the impacters whose working window
    lies beyond the band, with the tone [Hz] each would need."""

    moved: tuple[Moved, ...]
    original_drive: OriginalDrive | None = None
    inseparable: tuple[Inseparable, ...] = ()
    split_steps: dict[str, tuple[str, ...]] = {}
    outside_band: tuple[str, ...] = ()
    outside_band_hz: dict[str, Number] = {}
    #: the repairs the re-plan made, kind -> count (absent where none fired;
    #: :data:`planner.afterfab.replan.REPAIR_KINDS`)
    repairs: dict[str, Int] = {}
    #: the tones moved within their window (absent where none was)
    tone_moves: tuple[ToneMove, ...] = ()


class TrimRecord(_Record):
    """plan.json's ``trim`` block (:func:`planner.afterfab.trim.trim_chip`): the cut's
    direction, range and precision [%], the seed of its draws, the impacters moved,
    the first draw's trimmed models, the odds over the draws, the cuts that would raise
    them, and the next step in words."""

    direction: str
    range_pct: JSON = None
    precision_pct: JSON = None
    seed: JSON = None
    moved: JSON = None
    trimmed_models: JSON = None
    odds: JSON = None
    raise_odds: JSON = None
    next_step: str = ""


class PlanFile(_Record):
    """plan.json: every block, in the file's order.  The reader needs ``seed``,
    ``spec``, ``impacters``, ``devices``, ``steps`` and ``verification``; the others are
    optional (a plan of an older version, a block a plan has not: ``as_built``,
    ``replan``, ``chain`` and ``trim``)."""

    format_version: Int = FORMAT_VERSION
    vibroplan_version: str = "unknown"
    seed: Int
    #: the spec as planned (:attr:`planner.planning.settings.Settings.spec_record`)
    spec: dict
    assignment: AssignmentRecord = AssignmentRecord()
    impacters: tuple[ImpacterRecord, ...]
    devices: tuple[DeviceRecord, ...]
    steps: tuple[StepRecord, ...]
    verification: VerificationRecord
    #: each scene simulated with its state carried (the report's rows)
    scenes: list[JSON] | None = None
    manufacturability: ManufacturabilityRecord | None = None
    #: a re-plan's: impacter id -> its as-built model
    as_built: dict[str, AsBuiltRecord] | None = None
    replan: Replan | None = None
    #: with a drive chain: what the amplifier and piezo do to the tones (the report's)
    chain: JSON = None
    trim: TrimRecord | None = None


# ----------------------------------------------------------------------------- writing


def to_file(record: BaseModel) -> dict:
    """A record as plan.json holds it: the fields it was given, in declaration order,
    as JSON types (lists, not tuples)."""
    return record.model_dump(mode="json", exclude_unset=True)


def through_schema(data: dict, model: type[BaseModel] = PlanFile):
    """``data`` (a plan.json block as written, ``model`` its record) through its
    schema: ``(record, dict)``, the dict :func:`to_file` of the record.

    Raises
    ------
    PlanSchemaError
        The record does not give ``data`` back exactly -- a key the schema does not
        declare, a value of another type (an int where a float is declared), a key in
        another order -- or ``data`` is not of the declared types; the key is named.
    """
    try:
        record = model.model_validate(data, context=WRITING)
    except ValidationError as exc:
        err = exc.errors()[0]
        where = ".".join(str(p) for p in err["loc"])
        raise PlanSchemaError(f"plan.json as written does not follow its schema "
                              f"(planner/planfile/schema.py): {where}: {err['msg']}") from None
    back = to_file(record)
    where = difference(data, back)
    if where is not None:
        raise PlanSchemaError(f"plan.json as written is not what its schema gives back "
                              f"(planner/planfile/schema.py): {where}")
    return record, back


def _kind(x) -> str:
    if x is None or isinstance(x, (bool, str)):
        return type(x).__name__ if x is not None else "null"
    if isinstance(x, int):
        return "int"
    if isinstance(x, float):
        return "float"
    if isinstance(x, (list, tuple)):
        return "list"
    if isinstance(x, dict):
        return "dict"
    return type(x).__name__


def difference(a, b, path: str = "") -> str | None:
    """Where two JSON values differ (their key order and number types included): the
    key and what each holds; None when they are the same as JSON text."""
    ka, kb = _kind(a), _kind(b)
    here = path or "(the file)"
    if ka != kb:
        return f"{here}: {ka} {_short(a)} written, {kb} {_short(b)} declared"
    if ka == "dict":
        if list(a) != list(b):
            extra = [k for k in a if k not in b]
            lost = [k for k in b if k not in a]
            if extra:
                return (f"{path + '.' if path else ''}{extra[0]}: written but not declared "
                        "in the schema")
            if lost:
                return f"{path + '.' if path else ''}{lost[0]}: declared but not written"
            return f"{here}: keys written in the order {list(a)}, declared {list(b)}"
        for k in a:
            got = difference(a[k], b[k], f"{path}.{k}" if path else str(k))
            if got is not None:
                return got
        return None
    if ka == "list":
        if len(a) != len(b):
            return f"{here}: {len(a)} items written, {len(b)} given back"
        for i, (x, y) in enumerate(zip(a, b)):
            got = difference(x, y, f"{path}[{i}]")
            if got is not None:
                return got
        return None
    if ka == "float":
        return None if float(a) == float(b) or (a != a and b != b) else (
            f"{here}: {a!r} written, {b!r} given back")
    return None if a == b else f"{here}: {a!r} written, {b!r} given back"


def _short(x) -> str:
    text = repr(x)
    return text if len(text) <= 40 else text[:37] + "..."
