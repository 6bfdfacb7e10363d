"""Stage 0, settings: the validated array spec converted to SI values, once.

Every later stage reads a :class:`Settings` and nothing of the spec.  Every spec field
either reaches a setting here or is refused with a :class:`planner.core.errors.SpecError`
naming the field and its YAML line (:func:`resolve_settings`): an impacter's geometry
is what the planner designs, so ``device.impacter.area_um2`` and the like are refused
(bound the search with ``design.bounds`` instead), while its contact parameters
(``impact_angle_deg``, ``restitution``) and ``mass_thickness_um`` go to the designer,
and hence into the as-designed impacter that the verification simulates;
``drive.over_limit: split`` is refused (see :func:`resolve_settings`).

tests/planner/test_settings.py walks the spec's schema: a field that reaches no setting
read by a stage fails it.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import model
from model import devices as _d
from planner.assignment.assign import plan_steps
from planner.config import EnvironmentConfig, ProcessConfig, SliderConfig, build_slider
from planner.core.errors import SpecError
from planner.fabrication.tolerances import Tolerances
from planner.manufacturability import channel_grid, pair_sigma_rel, sensitivity_target_per_um
from planner.core.nodes import DIRECTIONS, Node, device_key
from planner.arrayspec import ArraySpec, LoadedSpec, Step, TrimSpec
from planner.core.units import MS, UM
from planner.files.yamlio import format_loc, line_of

if TYPE_CHECKING:
    from planner.designer import DesignBounds

#: Duration of the implicit single-impacter steps of an independently addressable array [s].
SINGLE_STEP_S = 0.01
#: Undriven time simulated after a scene's last step [s].  An impacter still ringing when
#: its tone stops keeps hitting its slider until its swing no longer reaches the wall;
#: every impact takes (1 - e^2) of its kinetic energy, so the hits die out within a few
#: of its periods, and 10 ms is hundreds of periods anywhere in the band.
SETTLE_S = 0.01
#: Longest settle dwell after a step [s]: a step whose sliders or impacters still move
#: after it fails ("unsettled").  Film damping stops an impacter's ringing within a few
#: ms in air and friction a slider within microseconds once the kicks stop.
MAX_SETTLE_S = 0.05
#: Standard gravity [m/s^2] (drive.max_acceleration_g).
G0 = 9.80665
#: Impacter fields the planner designs: refused in an array spec.
DESIGNED_FIELDS = {
    "area_um2": "design.bounds.area_um2", "width_um": "design.bounds.width_um",
    "length_um": "design.bounds.length_um", "gap_um": "design.bounds.gap_um",
    "natural_frequency_hz": None,
}


@dataclass(frozen=True)
class ImpacterSettings:
    """What the designer needs of one impacter besides its tones (SI).

    Attributes
    ----------
    impact_angle_rad : float
        theta [rad].
    restitution : float
        e [-].
    process : ProcessConfig
        The spec's process with this impacter's ``mass_thickness_um`` if it sets one,
        its layout-only fields at their defaults (:meth:`ProcessConfig.physics`: no
        design depends on them; the rules reach the designer through ``bounds``).
    slider : SliderConfig
        Its device's slider (the designer's predicted speed).
    contact : str
        The contact law of its device (``device.contact`` / ``devices.<id>.contact``).
    """

    impact_angle_rad: float
    restitution: float
    process: ProcessConfig
    slider: SliderConfig
    contact: str = "two_body"


@dataclass(frozen=True)
class ToneRules:
    """What a product of playing tones may not hit (``drive.guard``), for
    :func:`planner.assignment.assign.guard_violations`.

    Attributes
    ----------
    relative_bandwidth : float
        Half-width of an impacter's response band relative to its tone [-].
    harmonics : bool
        Reject n f and f / n (n = 2, 3) of a playing tone in an idle impacter's band.
    intermodulation : bool
        Reject 2 f_i - f_j and f_i + f_j - f_k of tones that play together.
    """

    relative_bandwidth: float
    harmonics: bool
    intermodulation: bool


@dataclass(frozen=True)
class Settings:
    """The spec in SI units; see the module docstring.

    Attributes
    ----------
    name : str
        The spec's name (the report's and the array map's title).
    seed : int
        The plan's one seed (``seed`` argument, else ``design.seed``): the channel
        colouring's, the designer's and the drive phases' (so that ``vibroplan plan
        --seed N`` gives different channels, designs and phases); plan.json's ``seed``.
    steps : tuple of Step
        The spec's steps plus the implicit single-impacter steps.
    scenes : tuple of str
        Scene names in spec order.
    array_shape : (int, int)
        Rows and columns of the array (the array map).
    band_hz : (float, float)
        The drive band [Hz].
    channel_grid_hz : tuple of float
        Every channel's frequency [Hz], ascending (``drive.channels``:
        :func:`planner.manufacturability.channel_grid`).
    channel_spacing : str
        ``log``, ``linear`` or ``tolerance`` (``drive.channels.spacing``).
    channel_placement : str
        ``coloring`` (the colouring's order) or ``neighbours`` (tone neighbours on
        neighbouring devices, :func:`planner.assignment.placement.neighbour_coloring`;
        ``drive.channels.placement``).
    resonance_separation_hz : float
        How close two resonances may come and still be told apart on a tolerance grid
        [Hz] (``drive.channels.separation_hz``).
    all_independent : bool
        Every impacter must be drivable alone (``independent``, default: no scenes).
    power_m2_s3 : float
        Tone convention Z0^2 w^3 [m^2/s^3].
    amplitude_m : float or None
        A fixed tone amplitude [m] instead of the power convention.
    peak_limit_m : float
        The piezo's peak displacement [m]: a step's summed drive above it has every tone
        lowered by one factor (``drive.over_limit: scale``, the only mode a plan takes).
    sample_rate_hz : float
        Drive sample rate [Hz].
    um_per_v, amplifier_gain : float or None
        Piezo [um/V] and amplifier gain [V/V]: the exported waveforms' volt scale.
    separation_channels : int
        Default separation [channels] of impacters that must be told apart.
    ensemble_separation_channels : int or None
        Separation [channels] of an impacter idle in a multi-tone step from that step's
        tones (None: the default separation).
    tone_rules : ToneRules
        Harmonic and intermodulation rules of the assignment.
    environment : planner.config.EnvironmentConfig
        The spec's environment (the designs' film damping).
    bounds : planner.designer.DesignBounds
        Bounds of the design variables (SI): ``design.bounds`` narrowed by the
        ``process.min_line_um`` and ``process.min_space_um`` the spec sets.
    window_s : float
        The designer's window [s].
    budget : str
        The designer's budget.
    guard : float
        Relative guard band of the designs [-] (and of the assignment's positions).
    robust_k : float or None
        ``design.robust_k`` when ``design.robust`` is on, else None [-].
    impacters : dict
        :class:`~planner.core.nodes.Node` -> :class:`ImpacterSettings`, every impacter of
        every device.
    sliders : dict
        Device id -> model.Slider, every device, in device order.
    x0_points : int
        Initial positions of the verification grid over [-c, c].
    min_speed_m_s : float
        A moving slider's minimum speed [m/s].
    idle_tolerance_m : float
        An idle slider's largest displacement [m].
    repair_rounds : int
        Repair rounds after the first verification.
    single_step_s : float
        Duration of the implicit single-impacter steps [s].
    settle_s : float
        Undriven tail after each scene [s].
    array_pitch_m : float
        Device pitch [m] (the array map).
    contacts : dict
        Device id -> contact law ("paper" or "two_body").
    max_mass_ratio : float
        Upper bound of every design's m/M [-].
    max_travel_m : float
        Largest travel of any slider in one step [m] (default half the pitch).
    max_acceleration_m_s2 : float or None
        Largest peak base acceleration of a step's summed drive [m/s^2].
    max_settle_s : float
        Longest settle dwell after a step [s].
    position_tolerance_m : float
        How far from its target a slider of a ``targets_um`` step may end [m].
    sensitivity_band : (float, float) or None
        ``design.match_sensitivity``: the band (lo, hi) of the line-width sensitivity
        d ln nu_n / dw every design must lie in [1/m]; None when off.
    tone_window : float
        Relative half-width of every design's tone window [-] (``design.tone_window_pct``,
        else :data:`TONE_WINDOW_SIGMAS` x ``fabrication.measurement_noise_pct``).
    measurement_noise : float
        Relative sigma of a lab's measured resonance [-]
        (``fabrication.measurement_noise_pct`` / 100): the as-built models' and a yield
        study's.
    tolerances : planner.fabrication.tolerances.Tolerances
        The fabrication tolerance model: the sigma of every error at every level
        (die, device, pair), in the errors' own units (um, %: those of the
        sensitivities), read from ``fabrication:`` once
        (:meth:`~planner.fabrication.tolerances.Tolerances.from_spec`).
    target_yield : float
        The collision-free yield the plan is held to (``fabrication.target_yield``) [-].
    pair_sigma_rel : float
        Predicted relative sigma of the difference of two as-built resonances [-]
        (:func:`planner.manufacturability.pair_sigma_rel`; 0 without tolerances).
    trim : planner.arrayspec.TrimSpec
        How a fabricated chip is trimmed (``trim:``, else its defaults).
    chip_spec : planner.arrayspec.ArraySpec
        The validated spec as the fabrication equations take it
        (:mod:`planner.fabrication.tolerances`, :mod:`planner.manufacturability`: process,
        environment, design and tolerances together), for the models of an as-built
        chip only: the manufacturability stage, robust design and the yield predicted
        from the channels.  No stage reads a setting from it.
    spec_record : dict
        The spec as plan.json records it.
    chain : planner.synthesis.chain.DriveChain or None
        The measured drive chain (``drive.chain``, issue 46): the exported waveforms
        are then the amplifier input [V], each tone divided by its transfer; None: the
        ideal, flat, linear chain (the waveforms are the die's displacement).
    """

    name: str
    seed: int
    steps: tuple[Step, ...]
    scenes: tuple[str, ...]
    array_shape: tuple[int, int]
    band_hz: tuple[float, float]
    channel_grid_hz: tuple[float, ...]
    channel_spacing: str
    channel_placement: str
    resonance_separation_hz: float
    all_independent: bool
    power_m2_s3: float
    amplitude_m: float | None
    peak_limit_m: float
    sample_rate_hz: float
    um_per_v: float | None
    amplifier_gain: float | None
    separation_channels: int
    ensemble_separation_channels: int | None
    tone_rules: ToneRules
    environment: EnvironmentConfig
    bounds: DesignBounds
    window_s: float
    budget: str
    guard: float
    robust_k: float | None
    impacters: dict
    sliders: dict
    x0_points: int
    min_speed_m_s: float
    idle_tolerance_m: float
    repair_rounds: int
    single_step_s: float
    settle_s: float
    array_pitch_m: float
    contacts: dict
    max_mass_ratio: float
    max_travel_m: float
    max_acceleration_m_s2: float | None
    max_settle_s: float
    position_tolerance_m: float
    sensitivity_band: tuple | None
    tone_window: float
    measurement_noise: float
    tolerances: Tolerances
    target_yield: float
    pair_sigma_rel: float
    trim: TrimSpec
    chip_spec: ArraySpec = field(repr=False)
    spec_record: dict = field(repr=False)
    chain: object = field(default=None, repr=False)

    def design_kwargs(self, node: Node) -> dict:
        """Keyword arguments of :func:`planner.designer.design_impacter` for ``node``,
        besides its frequency, forbidden tones and drives."""
        imp = self.impacters[node]
        return dict(process=imp.process, environment=self.environment,
                    power=self.power_m2_s3, amplitude=self.amplitude_m, bounds=self.bounds,
                    window=self.window_s, seed=self.seed, budget=self.budget,
                    guard=self.guard, impact_angle=imp.impact_angle_rad,
                    restitution=imp.restitution,
                    slider=build_slider(imp.slider, imp.process, self.environment),
                    max_mass_ratio=self.max_mass_ratio, contact=imp.contact,
                    sensitivity=self.sensitivity_band,
                    # the speed the verification will measure: its single-impacter step's
                    # length, from every x0 of its grid
                    speed_window=self.single_step_s, speed_x0_points=self.x0_points,
                    tone_window=self.tone_window, direction=float(node.sign),
                    **self._robust_kwargs(imp))

    def separation_kwargs(self) -> dict:
        """Keyword arguments of :func:`planner.manufacturability.measure_separation`
        besides the design, its tone and its tone's amplitude: the drive's power (or
        amplitude), the designer's window for the tone window and, for the silent band,
        the longest an impacter sits idle under one tone (a single-impacter step)."""
        return dict(power=self.power_m2_s3, amplitude=self.amplitude_m, window=self.window_s,
                    silent_window=max(self.single_step_s, self.window_s))

    def _robust_kwargs(self, imp) -> dict:
        """``robust_shift`` for the designer when ``design.robust`` is on (k sigma of
        each candidate's natural frequency under the spec's fabrication tolerances)."""
        if self.robust_k is None:
            return {}
        from planner.fabrication.tolerances import RobustShift

        return {"robust_shift": RobustShift(self.chip_spec, self.robust_k,
                                            imp.impact_angle_rad, imp.restitution)}


def _refuse(loaded, loc, message):
    lines = loaded.lines or {}
    raise SpecError(message, path=format_loc(loc), line=line_of(lines, loc),
                    source=loaded.source)


def _check_impacter_sections(loaded):
    """Refuse impacter fields the planner cannot take: the designed geometry."""
    spec = loaded.spec
    sections = []
    for key in ("impacter", "forward", "backward"):
        if key in spec.device.model_fields_set and getattr(spec.device, key) is not None:
            sections.append((("device", key), getattr(spec.device, key)))
    for dev, over in spec.devices.items():
        for key in ("impacter", "forward", "backward"):
            if getattr(over, key) is not None:
                sections.append((("devices", dev, key), getattr(over, key)))
    from planner.config import DEFAULT_IMPACTER

    for loc, cfg in sections:
        for name in sorted(cfg.model_fields_set):
            value = getattr(cfg, name)
            # a spec read back from plan.json carries the device defaults verbatim: those
            # are no request for a fixed geometry
            if loc == ("device", "impacter") and value == getattr(DEFAULT_IMPACTER, name):
                continue
            if name in DESIGNED_FIELDS and value is not None:
                instead = DESIGNED_FIELDS[name]
                _refuse(loaded, loc + (name,),
                        "the array planner designs every impacter's geometry, so it cannot "
                        "take a fixed " + name
                        + (f"; bound the search with {instead} instead" if instead
                           else "; it follows from the designed geometry"))


def _impacter_settings(spec, device, direction):
    cfg = spec.impacter_config(device, direction)
    process = spec.process.physics()
    if cfg.mass_thickness_um is not None:
        process = process.model_copy(update={"mass_thickness_um": cfg.mass_thickness_um})
    angle = (math.radians(cfg.impact_angle_deg) if cfg.impact_angle_deg is not None
             else _d.IMPACT_ANGLE)
    e = cfg.restitution if cfg.restitution is not None else _d.RESTITUTION
    return ImpacterSettings(float(angle), float(e), process, spec.slider_config(device),
                            spec.contact(device))


def _bounds(loaded, impacters):
    """``design.bounds`` narrowed by the process rules the spec sets (the layout's
    beam width and tip space, :func:`planner.designer.bounds.narrow_bounds`)."""
    from planner.designer.bounds import DesignBounds, RuleBoundsError, narrow_bounds

    spec = loaded.spec
    b = spec.design.bounds
    kwargs = {key: tuple(getattr(b, key)) for key in ("area_um2", "width_um", "length_um",
                                                        "gap_um") if getattr(b, key) is not None}
    if spec.design.beam_width_um is not None:
        # one width for every beam: the designer's width bounds collapse onto it
        kwargs["width_um"] = (spec.design.beam_width_um, spec.design.beam_width_um)
    bounds = DesignBounds.from_spec(**kwargs) if kwargs else DesignBounds()
    try:
        return narrow_bounds(bounds, spec.process,
                             [imp.impact_angle_rad for imp in impacters.values()])
    except RuleBoundsError as exc:
        _refuse(loaded, exc.field, str(exc))


def _sensitivity_band(spec):
    """(lo, hi) [1/m] of ``design.match_sensitivity``, or None."""
    des = spec.design
    if not des.match_sensitivity:
        return None
    s = sensitivity_target_per_um(des) / UM
    return (s * (1.0 - des.sensitivity_tolerance), s * (1.0 + des.sensitivity_tolerance))


#: Sigmas of a measured resonance's noise a design's tone window covers by default
#: (``design.tone_window_pct``): a re-planned tone moves with the measurement, and the
#: design must still drive its slider there (issue 37: the max-min design's response
#: collapsed 25-96 Hz above its tone, 0.06 % at worst, while 0.05 % of noise is 22 Hz at
#: 44 kHz) [-].
TONE_WINDOW_SIGMAS = 3.0


def _tone_window(spec) -> float:
    """The designs' relative tone window [-]: ``design.tone_window_pct``, else
    :data:`TONE_WINDOW_SIGMAS` x ``fabrication.measurement_noise_pct``."""
    pct = spec.design.tone_window_pct
    if pct is None:
        pct = TONE_WINDOW_SIGMAS * spec.fabrication.measurement_noise_pct
    return pct / 100.0


def _check_over_limit(loaded):
    """Refuse ``drive.over_limit: split`` (see :func:`resolve_settings`)."""
    if loaded.spec.drive.over_limit != "scale":
        _refuse(loaded, ("drive", "over_limit"),
                "a plan cannot split a step over the peak or acceleration limit: its "
                "channels are assigned, and its designs made silent, for the steps the "
                "scenes give, so a split made afterwards would play sums of tones no "
                "design was made for; write the step as several steps of fewer tones in "
                "its scene instead (every stage then sees them), or leave over_limit at "
                "scale (every tone of the step lowered by one factor, as verified); "
                "`vibroplan drive --over-limit split` splits a stand-alone drive")


def resolve_settings(loaded: LoadedSpec, seed=None) -> Settings:
    """Convert a validated spec to :class:`Settings` (SI), refusing what cannot take effect.

    Refused (:class:`~planner.core.errors.SpecError` naming the field and its line): an
    impacter's designed geometry (see the module docstring), ``design.robust`` without
    tolerances, design rules no design can meet, and ``drive.over_limit: split``: a
    plan lowers a step over a limit by one factor (which its designs and verification
    see), and splitting it after the assignment would play sums of tones the designs
    were not made for; a user who wants fewer tones at a time writes them as steps.

    Parameters
    ----------
    loaded : LoadedSpec
        From :func:`planner.arrayspec.load_spec`.
    seed : int, optional
        Overrides ``design.seed``: the plan's one seed (:attr:`Settings.seed`).

    Raises
    ------
    SpecError
        A field that the planner cannot honour, with its YAML line.
    """
    spec = loaded.spec
    _check_impacter_sections(loaded)
    _check_over_limit(loaded)
    if spec.design.robust and spec.fabrication.zero:
        _refuse(loaded, ("design", "robust"), "design.robust needs fabrication tolerances "
                "(a fabrication section with a non-zero sigma) to be robust against")
    devices = sorted(loaded.device_ids, key=device_key)
    drive, ver, des = spec.drive, spec.verification, spec.design
    impacters = {Node(d, r): _impacter_settings(spec, d, r)
                 for d in devices for r in DIRECTIONS}
    return Settings(
        name=spec.name,
        seed=des.seed if seed is None else int(seed),
        steps=plan_steps(loaded, SINGLE_STEP_S),
        scenes=tuple(spec.scenes),
        array_shape=(spec.array.rows, spec.array.cols),
        band_hz=(float(drive.band_hz[0]), float(drive.band_hz[1])),
        channel_grid_hz=tuple(float(f) for f in channel_grid(spec)),
        channel_spacing=drive.channels.spacing,
        channel_placement=drive.channels.placement,
        resonance_separation_hz=float(drive.channels.resonance_separation_hz),
        all_independent=bool(spec.all_independent),
        power_m2_s3=drive.power_m2_s3,
        amplitude_m=drive.amplitude_um * UM if drive.amplitude_um else None,
        peak_limit_m=drive.peak_limit_um * UM,
        sample_rate_hz=drive.sample_rate_hz,
        um_per_v=drive.piezo_um_per_v,
        amplifier_gain=drive.amplifier_gain,
        separation_channels=drive.guard.separation_channels,
        ensemble_separation_channels=drive.guard.ensemble_separation_channels,
        tone_rules=ToneRules(float(drive.guard.relative_bandwidth),
                             bool(drive.guard.harmonics), bool(drive.guard.intermodulation)),
        environment=spec.environment,
        bounds=_bounds(loaded, impacters),
        window_s=des.window_ms * MS,
        budget=des.budget,
        guard=des.guard,
        robust_k=des.robust_k if des.robust else None,
        impacters=impacters,
        sliders={d: build_slider(spec.slider_config(d), spec.process, spec.environment)
                 for d in devices},
        x0_points=ver.x0_points,
        min_speed_m_s=ver.min_speed_mm_s * 1e-3,
        idle_tolerance_m=ver.idle_tolerance_um * UM,
        repair_rounds=ver.repair_rounds,
        single_step_s=SINGLE_STEP_S,
        settle_s=SETTLE_S,
        array_pitch_m=spec.array.pitch_um * UM,
        contacts={d: spec.contact(d) for d in devices},
        max_mass_ratio=float(des.max_mass_ratio),
        max_travel_m=(ver.max_travel_um * UM if ver.max_travel_um is not None
                      else 0.5 * spec.array.pitch_um * UM),
        max_acceleration_m_s2=(drive.max_acceleration_g * G0
                               if drive.max_acceleration_g is not None else None),
        max_settle_s=MAX_SETTLE_S,
        position_tolerance_m=ver.position_tolerance_um * UM,
        sensitivity_band=_sensitivity_band(spec),
        tone_window=_tone_window(spec),
        measurement_noise=spec.fabrication.measurement_noise_pct / 100.0,
        tolerances=Tolerances.from_spec(spec.fabrication),
        target_yield=float(spec.fabrication.target_yield),
        pair_sigma_rel=pair_sigma_rel(spec),
        trim=spec.trim or TrimSpec(),
        chip_spec=spec,
        spec_record=json.loads(spec.model_dump_json()),
        chain=_chain(loaded),
    )


def _chain(loaded):
    """``drive.chain`` in SI (:class:`planner.synthesis.chain.DriveChain`), or None;
    a table that does not cover the band is refused, naming the field and its line."""
    drive = loaded.spec.drive
    chain = drive_chain(drive)
    if chain is None:
        return None
    tr = drive.chain.transfer
    if hasattr(tr, "frequency_hz"):
        lo, hi = chain.transfer.band_hz
        if lo > drive.band_hz[0] or hi < drive.band_hz[1]:
            _refuse(loaded, ("drive", "chain", "transfer"),
                    f"the transfer table{' ' + tr.file if tr.file else ''} covers "
                    f"{lo:g}-{hi:g} Hz, not the whole band {drive.band_hz[0]:g}-"
                    f"{drive.band_hz[1]:g} Hz (drive.band_hz): a tone outside it cannot "
                    "be compensated; measure the chain over the band")
    return chain


def drive_chain(drive):
    """The :class:`planner.synthesis.chain.DriveChain` of a spec's ``drive`` block (its
    ``chain`` in SI), or None without one.  The spec's and a recorded plan's alike
    (``vibroplan drive PLAN`` reads it from plan.json's spec, whose table is inline)."""
    from planner.synthesis.chain import (DriveChain, ModelTransfer, Nonlinearity,
                                         TableTransfer)

    spec = drive.chain
    if spec is None:
        return None
    tr = spec.transfer
    if hasattr(tr, "frequency_hz"):
        transfer = TableTransfer(tr.frequency_hz, [g * UM for g in tr.gain_um_per_v],
                                 [math.radians(p) for p in tr.phase_deg], tr.file)
    else:
        transfer = ModelTransfer(tr.gain_um_per_v * UM,
                                 tuple((r.frequency_hz, r.q) for r in tr.resonances),
                                 tr.low_pass_hz)
    stroke = (spec.at_stroke_um if spec.at_stroke_um is not None else drive.peak_limit_um)
    return DriveChain(transfer, Nonlinearity.from_harmonics(spec.harmonics_db, stroke * UM),
                      spec.max_input_v, spec.max_output_v, drive.amplifier_gain)


def plan_settings(record, seed=None) -> Settings:
    """The :class:`Settings` of a recorded plan (a
    :class:`~planner.planfile.reader.PlanRecord`): its spec resolved once, with the
    plan's seed unless ``seed`` is given.  A re-plan, a trim and every chip of a yield
    study read this one resolution."""
    return resolve_settings(record.loaded, record.seed if seed is None else seed)


def tone_amplitudes(settings: Settings, freqs):
    """Amplitude [m] of each tone at ``freqs`` [Hz] by the spec's convention."""
    import numpy as np

    if settings.amplitude_m is not None:
        return np.full(len(freqs), settings.amplitude_m)
    return model.amplitude_from_power(np.asarray(freqs), settings.power_m2_s3)


