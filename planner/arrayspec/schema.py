"""The array spec's schema: every section and field of the YAML, its units and defaults.

Pydantic models (unknown keys refused, :class:`planner.core.strict.Strict`) of the
sections of an array spec (:class:`ArraySpec`): the array's grid, the device defaults
and per-device overrides, the drive, the designer, the verification, the fabrication
tolerances, the trim and the scenes' steps.  A field's unit is in its name; its
default is in the model.  Checks that need the whole spec (device ids, a step's
targets against the largest travel) are :mod:`planner.arrayspec.steps`'s; reading the YAML
and placing an error on its line is :mod:`planner.arrayspec.load`'s.
"""

from __future__ import annotations

import string
from typing import Annotated, Literal, Union

from pydantic import (Discriminator, Field, Tag, field_validator, model_serializer,
                      model_validator)

from planner.core.strict import Strict
from planner.config import (
    DEFAULT_IMPACTER,
    EnvironmentConfig,
    ImpacterConfig,
    ProcessConfig,
    SliderConfig,
)

PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegFloat = Annotated[float, Field(ge=0, allow_inf_nan=False)]
FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]


class ArrayConfig(Strict):
    """Grid of devices: ``rows`` x ``cols`` at ``pitch_um``."""

    rows: Annotated[int, Field(ge=1, le=26)] = 5
    cols: Annotated[int, Field(ge=1, le=99)] = 5
    pitch_um: PositiveFloat = 1000.0

    def device_ids(self) -> list[str]:
        return [f"{string.ascii_uppercase[r]}{c + 1}" for r in range(self.rows)
                for c in range(self.cols)]


class DeviceDefaults(Strict):
    """Impacter (both pairs) and slider defaults; ``forward``/``backward`` override per pair."""

    impacter: ImpacterConfig = DEFAULT_IMPACTER
    forward: ImpacterConfig | None = None
    backward: ImpacterConfig | None = None
    slider: SliderConfig = SliderConfig()
    #: Contact law of every impacter pair on its slider (:data:`model.CONTACTS`,
    #: docs/contact.md): ``two_body`` (the default of array specs) never creates energy;
    #: ``paper`` is eq. (10) as printed, the small-m/M limit.
    contact: Literal["paper", "two_body"] = "two_body"


class ChannelGrid(Strict):
    """The channel grid inside the band: ``count`` channels, log- or linearly spaced, or
    spaced by the fabrication tolerance.

    spacing : ``log`` or ``linear`` (``count`` channels), or ``tolerance``: channels
        placed bottom-up so that tones ``drive.guard.separation_channels`` channels
        apart are ``separation_hz`` plus z sigma apart, sigma the scatter of the
        difference of two as-built resonances under the ``fabrication:`` section at
        ``fabrication.target_yield`` (:func:`planner.manufacturability.tolerance_grid`):
        wider where the scatter in Hz is larger.  The count then follows from the band.
    count : the number of channels of a ``log`` or ``linear`` grid (default
        :data:`DEFAULT_CHANNELS`); refused with ``tolerance``.
    separation_hz : how close two as-built resonances may be and still be told apart by
        a drive re-planned for the chip [Hz]: about the width of an impacter's response
        band, 300-500 Hz in air at every frequency (``tolerance`` only; default
        :data:`DEFAULT_SEPARATION_HZ`).
    """

    spacing: Literal["log", "linear", "tolerance"] = "log"
    count: Annotated[int, Field(ge=2, le=100000)] | None = None
    separation_hz: PositiveFloat | None = None
    #: Which impacter takes which of the colouring's channels: ``coloring`` as the
    #: colouring gives them; ``neighbours``: within each block of channels that any of
    #: its impacters may take (every separation still kept), the tones rise along a
    #: serpentine walk of the devices, so that frequency neighbours sit on neighbouring
    #: devices and a line-width gradient across the die moves them alike
    #: (:func:`planner.assignment.placement.neighbour_coloring`, issue 39).
    placement: Literal["coloring", "neighbours"] = "coloring"

    @model_serializer(mode="wrap")
    def _default_placement_unwritten(self, handler):
        # a spec without placement dumps as before: plan.json and the design cache's
        # keys of today's specs stay byte for byte what they were
        data = handler(self)
        if self.placement == "coloring":
            data.pop("placement", None)
        return data

    @model_validator(mode="after")
    def _count_or_tolerance(self):
        if self.spacing == "tolerance" and self.count is not None:
            raise ValueError("count cannot be given with spacing: tolerance (the band and "
                             "the tolerance set how many channels there are)")
        if self.spacing != "tolerance" and self.separation_hz is not None:
            raise ValueError("separation_hz applies to spacing: tolerance only")
        return self

    @property
    def channel_count(self) -> int:
        """The count of a log or linear grid."""
        return DEFAULT_CHANNELS if self.count is None else self.count

    @property
    def resonance_separation_hz(self) -> float:
        """The separation of a tolerance grid [Hz]."""
        return DEFAULT_SEPARATION_HZ if self.separation_hz is None else self.separation_hz


#: Channels of a log or linear grid without ``count``.
DEFAULT_CHANNELS = 240
#: ``drive.channels.separation_hz`` of a tolerance grid without one [Hz].
DEFAULT_SEPARATION_HZ = 400.0


class GuardRules(Strict):
    """How far apart tones must be.

    separation_channels : the default separation [channels] between impacters that must
        be told apart, before designs exist (designs' measured response bands then set it).
    relative_bandwidth : half-width of an impacter's response band relative to its tone,
        used to reject harmonic and intermodulation products landing in it.
    harmonics : reject f_i ~ n f_j and f_i ~ f_j / n (n = 2, 3).
    intermodulation : reject f_i + f_j - f_k and 2 f_i - f_j of tones that play together.
    ensemble_separation_channels : the separation [channels] between an impacter that is
        idle in a step playing several tones and each of those tones (None: the default
        separation).  Off-resonant responses to the tones of a step add up, so an
        impacter that is silent under each tone alone can hit its slider under their
        sum when two of them sit at the default separation on either side of it.
    """

    separation_channels: Annotated[int, Field(ge=1)] = 8
    ensemble_separation_channels: Annotated[int, Field(ge=1)] | None = None
    relative_bandwidth: Annotated[float, Field(gt=0, lt=0.5)] = 0.02
    harmonics: bool = True
    intermodulation: bool = True


class ResonanceSpec(Strict):
    """One resonance of the drive chain (a piezo stack's mode): a second-order peak
    ``1 / (1 - u^2 + j u / q)``, ``u = f / frequency_hz``, 1 far below it, ``q`` at it."""

    frequency_hz: PositiveFloat
    q: Annotated[float, Field(gt=0.5, le=1e4, allow_inf_nan=False)]


class TransferModelSpec(Strict):
    """The chain's transfer as a model: a flat gain [um/V], times every resonance, times
    an optional first-order low-pass at ``low_pass_hz``."""

    gain_um_per_v: PositiveFloat
    resonances: tuple[ResonanceSpec, ...] = ()
    low_pass_hz: PositiveFloat | None = None


class TransferTableSpec(Strict):
    """The chain's transfer as a measured table, written inline: what
    :func:`planner.arrayspec.load_spec` makes of ``transfer: chain.csv`` (and what
    plan.json records, so that a plan read back needs no CSV).  ``file``: the CSV it
    was read from (for messages only)."""

    frequency_hz: tuple[PositiveFloat, ...]
    gain_um_per_v: tuple[PositiveFloat, ...]
    phase_deg: tuple[FiniteFloat, ...]
    file: str | None = None

    @model_validator(mode="after")
    def _table_shape(self):
        n = len(self.frequency_hz)
        if n < 2:
            raise ValueError(f"a transfer table needs at least 2 frequencies, {n} given")
        for name in ("gain_um_per_v", "phase_deg"):
            if len(getattr(self, name)) != n:
                raise ValueError(f"{name} has {len(getattr(self, name))} values for {n} "
                                 "frequencies")
        for i in range(1, n):
            if self.frequency_hz[i] <= self.frequency_hz[i - 1]:
                raise ValueError(f"frequency_hz must increase: row {i + 1} "
                                 f"({self.frequency_hz[i]:g} Hz) after "
                                 f"{self.frequency_hz[i - 1]:g} Hz")
        return self


def _transfer_kind(value):
    if isinstance(value, str):
        return "file"
    if isinstance(value, dict):
        return "table" if "frequency_hz" in value else "model"
    if isinstance(value, TransferTableSpec):
        return "table"
    return "model"


def _no_unread_file(value):
    raise ValueError(f"the transfer CSV {value!r} is read relative to the spec file when "
                     "the spec is loaded (planner.arrayspec.load_spec); here give the "
                     "table inline ({frequency_hz: [...], gain_um_per_v: [...], "
                     "phase_deg: [...]}) or a model")


class ChainSpec(Strict):
    """``drive.chain``: what stands between the waveform file and the die (issue 46).

    transfer : the die's displacement per volt of the amplifier input, a complex
        function of frequency: a CSV path relative to the spec
        (``frequency_hz,gain_um_per_v,phase_deg``, interpolated in log frequency and
        refused outside the frequencies it covers), a model
        (:class:`TransferModelSpec`) or the table inline (:class:`TransferTableSpec`).
    harmonics_db : the 2nd and 3rd harmonics' levels below the fundamental [dB, < 0]
        at the stroke ``at_stroke_um``: the nonlinearity, a polynomial of the die's
        displacement ``z = y + a2 y^2 + a3 y^3`` fitted to them.
    at_stroke_um : the die's amplitude the harmonic levels were measured at [um]
        (default ``drive.peak_limit_um``: full stroke).
    max_input_v : the largest peak voltage the generator may put on the amplifier's
        input [V] (None: no limit).
    max_output_v : the largest peak voltage of the amplifier's output [V]: the input
        times ``drive.amplifier_gain`` (None: no limit).

    With a chain every exported waveform is the amplifier input in volts, each tone
    divided by the transfer at its frequency so that the die feels the designed tones.
    """

    transfer: Annotated[Union[Annotated[TransferTableSpec, Tag("table")],
                              Annotated[TransferModelSpec, Tag("model")],
                              Annotated[str, Tag("file")]],
                        Discriminator(_transfer_kind)]
    harmonics_db: dict[int, Annotated[float, Field(lt=0, allow_inf_nan=False)]] = {}
    at_stroke_um: PositiveFloat | None = None
    max_input_v: PositiveFloat | None = None
    max_output_v: PositiveFloat | None = None

    @field_validator("harmonics_db", mode="before")
    @classmethod
    def _orders(cls, value):
        # YAML writes {2: -40} with int keys, JSON (plan.json) with string ones
        if isinstance(value, dict):
            out = {}
            for k, v in value.items():
                key = int(k) if isinstance(k, str) and k.strip().isdigit() else k
                if key not in (2, 3):
                    raise ValueError(f"harmonics_db has the 2nd and 3rd harmonics (keys 2 "
                                     f"and 3), {k!r} was given")
                out[key] = v
            return out
        return value

    @field_validator("transfer")
    @classmethod
    def _read(cls, value):
        if isinstance(value, str):
            _no_unread_file(value)
        return value


class DriveSpec(Strict):
    """The piezo drive: band, tone amplitude convention, limits and sampling."""

    band_hz: tuple[PositiveFloat, PositiveFloat] = (2000.0, 20000.0)
    power_m2_s3: PositiveFloat = 50.0
    amplitude_um: PositiveFloat | None = None
    peak_limit_um: PositiveFloat = 10.0
    #: Largest peak base acceleration of any step's summed drive [g] (None: no limit);
    #: a step above it has every tone amplitude lowered by one factor.
    max_acceleration_g: PositiveFloat | None = None
    sample_rate_hz: PositiveFloat = 200000.0
    over_limit: Literal["scale", "split"] = "scale"
    channels: ChannelGrid = ChannelGrid()
    guard: GuardRules = GuardRules()
    piezo_um_per_v: PositiveFloat | None = None
    amplifier_gain: PositiveFloat | None = None
    #: The measured drive chain (:class:`ChainSpec`); None: the ideal, flat, linear
    #: chain of ``piezo_um_per_v`` (the waveforms are the die's displacement).
    chain: ChainSpec | None = None

    @model_serializer(mode="wrap")
    def _no_chain_unwritten(self, handler):
        # a spec without a chain dumps as before: plan.json and the design cache's keys
        # of today's specs stay byte for byte what they were
        data = handler(self)
        if self.chain is None:
            data.pop("chain", None)
        return data

    @model_validator(mode="after")
    def _chain_rules(self):
        if self.chain is None:
            return self
        if self.piezo_um_per_v is not None:
            raise ValueError("piezo_um_per_v and chain cannot be given together: the "
                             "chain's transfer is the die's um per volt of the input")
        if self.chain.max_output_v is not None and self.amplifier_gain is None:
            raise ValueError("chain.max_output_v needs amplifier_gain (the amplifier's "
                             "output is its input times the gain)")
        return self

    @field_validator("band_hz")
    @classmethod
    def _band_order(cls, band):
        if band[1] <= band[0]:
            raise ValueError(f"band_hz[1] must be greater than band_hz[0], got {list(band)}")
        return band

    @model_validator(mode="after")
    def _nyquist(self):
        if self.sample_rate_hz <= 2 * self.band_hz[1]:
            raise ValueError(f"sample_rate_hz ({self.sample_rate_hz:g}) must exceed twice the "
                             f"band's top ({self.band_hz[1]:g} Hz)")
        return self


class DesignBoundsSpec(Strict):
    """Upper and lower bounds of the design variables, [lo, hi] each (paper's (17) below)."""

    area_um2: tuple[PositiveFloat, PositiveFloat] | None = None
    width_um: tuple[PositiveFloat, PositiveFloat] | None = None
    length_um: tuple[PositiveFloat, PositiveFloat] | None = None
    gap_um: tuple[PositiveFloat, PositiveFloat] | None = None


class DesignSpec(Strict):
    """Designer settings for every impacter of the array."""

    bounds: DesignBoundsSpec = DesignBoundsSpec()
    window_ms: PositiveFloat = 3.0
    seed: Annotated[int, Field(ge=0)] = 0
    budget: Literal["fast", "full"] = "fast"
    #: Relative half-width of the band around every forbidden tone in which a design
    #: must also be silent: the margin for model and fabrication error (the paper's
    #: Section V) [-].
    guard: Annotated[float, Field(ge=0, lt=0.5)] = 0.02
    #: Robust design: every impacter must respond and stay silent with its natural
    #: frequency shifted by +-robust_k sigma, sigma from the ``fabrication`` section's
    #: tolerances at the candidate's own geometry (planner.fabrication.tolerances.RobustShift).
    robust: bool = False
    robust_k: Annotated[float, Field(gt=0, le=6, allow_inf_nan=False)] = 2.0
    #: Upper bound on m/M, one impacter's mass over its slider's [-]: eq. (10) is the
    #: small-m/M limit of an impact, and the paper's measured devices had 0.23 and 0.38.
    max_mass_ratio: PositiveFloat = 0.4
    #: Every impacter of the array gets the same line-width sensitivity d ln nu_n / dw
    #: (within ``sensitivity_tolerance``), so that a die-level line-width error moves
    #: every resonance by one factor, which a re-plan absorbs (planner.manufacturability).
    match_sensitivity: bool = True
    #: Relative half-width of the matched sensitivity band [-].
    sensitivity_tolerance: Annotated[float, Field(gt=0, lt=0.5, allow_inf_nan=False)] = 0.05
    #: One beam width for every impacter [um] (None: the designer chooses it).
    beam_width_um: PositiveFloat | None = None
    #: The array's common line-width sensitivity [1/um] (None: that of a beam of
    #: ``beam_width_um``, else 5 um, carrying a plate of 80 % of the mass: 1.4 / w).
    sensitivity_per_um: PositiveFloat | None = None
    #: Half-width of every design's tone window [%]: each design must move its slider
    #: from every x0 with its tone anywhere within +- this of where it was designed, so
    #: that a tone re-planned from a measured resonance still drives it (None: three
    #: sigmas of ``fabrication.measurement_noise_pct``, 0.15 % by default; 0: the tone
    #: alone, the paper's max-min).
    tone_window_pct: Annotated[float, Field(ge=0, lt=2, allow_inf_nan=False)] | None = None

    @model_validator(mode="after")
    def _width_rules(self):
        if self.beam_width_um is not None and self.bounds.width_um is not None:
            raise ValueError("beam_width_um fixes the width: it cannot be given with "
                             "bounds.width_um")
        if self.sensitivity_per_um is not None and not self.match_sensitivity:
            raise ValueError("sensitivity_per_um needs match_sensitivity: true")
        return self


class VerificationSpec(Strict):
    """Pass criteria of the verification by simulation."""

    x0_points: Annotated[int, Field(ge=3, le=201)] = 9
    min_speed_mm_s: NonNegFloat = 0.2
    idle_tolerance_um: NonNegFloat = 0.5
    repair_rounds: Annotated[int, Field(ge=0, le=20)] = 3
    #: Largest travel of any slider in one step (burst and settle dwell) [um]; None:
    #: half the array pitch.
    max_travel_um: PositiveFloat | None = None
    #: How far from its target a slider of a ``targets_um`` step may end [um]: after the
    #: step (state carried through the scene), and from every initial state of the
    #: per-step check; and where every slider may end a scene that asks for positions.
    position_tolerance_um: PositiveFloat = 2.0


class Tolerance(Strict):
    """One fabrication tolerance: standard deviations of a normal error, split in two.

    die : the per-die part, one draw shared by every device of a chip (a wafer-to-wafer
        or die-to-die process shift).
    device : the per-device part, one independent draw per impacter pair design (a
        node, device + direction) and per slider (local lithography / etch scatter).
    pair : the mismatch of the two halves of a pair: each cantilever of a pair gets its
        own draw of this sigma on top of the pair's, so the halves differ by sqrt(2)
        pair (the two cantilevers that strike one slider together, side by side).

    The unit is the one of the field that holds it (um or %).  All >= 0, default 0.
    """

    die: NonNegFloat = 0.0
    device: NonNegFloat = 0.0
    pair: NonNegFloat = 0.0

    @property
    def zero(self) -> bool:
        return self.die == 0.0 and self.device == 0.0 and self.pair == 0.0


#: Shortest correlation length of the across-wafer field [mm] (10 um, a fraction of any
#: device): shorter, the field would vary inside a device, and its squared length
#: underflows (1e-300 mm gives exp(-r^2 / 0) at every die).
MIN_CORRELATION_LENGTH_MM = 0.01


class WaferField(Strict):
    """A smooth line-width field across the wafer (a Gaussian random field).

    sigma_um : its standard deviation at any point of the wafer [um].
    correlation_length_mm : the length over which it decorrelates [mm]: the covariance
        of two points r apart is sigma^2 exp(-r^2 / (2 L^2)) (squared exponential).
    """

    sigma_um: NonNegFloat = 0.0
    correlation_length_mm: PositiveFloat = 30.0

    @field_validator("correlation_length_mm")
    @classmethod
    def _a_length_on_the_wafer(cls, v):
        if v < MIN_CORRELATION_LENGTH_MM:
            raise ValueError(f"must be at least {MIN_CORRELATION_LENGTH_MM:g} mm, {v:g} was "
                             "given: a field that decorrelates within a device is no "
                             "across-wafer field (the die and device levels of "
                             "line_width_um are that scatter)")
        return v


class WaferSpec(Strict):
    """Where a die sat on its wafer (``fabrication.wafer``, issue 39).

    diameter_mm : the wafer's diameter [mm].
    edge_exclusion_mm : the ring at the wafer's edge where no die is made [mm]: a die
        is on the wafer when its four corners lie within diameter / 2 - exclusion.
    die_size_mm : the die's width (along the array's columns) and height (along its
        rows) [mm]; default the array's cols x pitch by rows x pitch.
    line_width_field : the smooth across-wafer line-width field, drawn once per wafer
        at every die's centre and added to the die's line width.
    line_width_gradient_um_per_mm : one sigma of each component (x, y) of a linear
        line-width gradient inside a die [um/mm], drawn per die: a device at (x, y)
        from the die's centre gets g_x x + g_y y on its line width.

    The die, device and pair levels of ``line_width_um`` stay, on top of these.
    """

    diameter_mm: PositiveFloat = 150.0
    edge_exclusion_mm: NonNegFloat = 3.0
    die_size_mm: tuple[PositiveFloat, PositiveFloat] | None = None
    line_width_field: WaferField = WaferField()
    line_width_gradient_um_per_mm: NonNegFloat = 0.0

    @model_validator(mode="after")
    def _exclusion_inside(self):
        if 2 * self.edge_exclusion_mm >= self.diameter_mm:
            raise ValueError(f"edge_exclusion_mm ({self.edge_exclusion_mm:g}) leaves no "
                             f"wafer of diameter_mm {self.diameter_mm:g}")
        return self

    @property
    def zero(self) -> bool:
        return self.line_width_field.sigma_um == 0.0 and \
            self.line_width_gradient_um_per_mm == 0.0


class FabricationSpec(Strict):
    """The fabrication tolerance model used by ``vibroplan yield`` (docs/yield.md).

    Each field is ``{die: sigma, device: sigma}`` (normal errors, mean 0); the as-built
    devices are computed from the design geometry through eqs. (2)-(4):

    line_width_um : lithographic line-width error dw [um]; every edge moves dw/2
        outward, so beams widen by dw (w + dw), gaps shrink by dw (c - dw) and the mass
        and slider plates, taken as squares of side sqrt(A), become (sqrt(A) + dw)^2.
        Beam lengths l are set by anchor positions and do not change.
    thickness_um : structural thickness error dt [um]: the beam height becomes h + dt
        and the mass (and slider) thickness scales by (h + dt) / h (the same layers).
    gap_um : an independent error of the impacter-to-wall gap dc [um] (c + dc), on
        top of the line-width part.
    youngs_modulus_pct : Young's modulus error [%]: E (1 + dE / 100), changes k.
    natural_frequency_pct : a direct natural-frequency scatter [%] covering what the
        model does not (residual stress, anchor compliance): k (1 + dnu / 100)^2.
    """

    line_width_um: Tolerance = Tolerance()
    thickness_um: Tolerance = Tolerance()
    gap_um: Tolerance = Tolerance()
    youngs_modulus_pct: Tolerance = Tolerance()
    natural_frequency_pct: Tolerance = Tolerance()
    #: The collision-free yield the channel grid is sized for (``drive.channels.spacing:
    #: tolerance``) and the plan's predicted yield is held against [-].
    target_yield: Annotated[float, Field(gt=0, lt=1, allow_inf_nan=False)] = 0.95
    #: One sigma of a lab's measured resonance, relative [%]: how far the as-built models
    #: may let a measurement be off (:mod:`planner.afterfab.as_built`), the noise a yield
    #: study's re-plan measures its chips with (``vibroplan yield --measure-noise``
    #: overrides it) and what a design's tone window is sized for
    #: (``design.tone_window_pct``).  A swept resonance fits to 1e-4 to 1e-3.
    measurement_noise_pct: Annotated[float, Field(ge=0, le=5, allow_inf_nan=False)] = 0.05
    #: Where a die sat on its wafer (:class:`WaferSpec`); None: every chip is a die of
    #: its own, as before issue 39.
    wafer: WaferSpec | None = None

    @model_serializer(mode="wrap")
    def _no_wafer_unwritten(self, handler):
        # a spec without a wafer dumps as before: yield.json's tolerance, plan.json and
        # the design cache's keys stay byte for byte what they were
        data = handler(self)
        if self.wafer is None:
            data.pop("wafer", None)
        return data

    @property
    def zero(self) -> bool:
        return all(getattr(self, k).zero for k in type(self).model_fields
                   if isinstance(getattr(self, k), Tolerance)) and (
            self.wafer is None or self.wafer.zero)


class TrimSpec(Strict):
    """Post-fabrication trimming of the impacters' resonances (``vibroplan trim``).

    range_pct : the largest move of one resonance [%] (a laser or FIB cut).
    direction : ``up`` removes plate mass (the resonance rises), ``down`` removes beam
        stiffness by cutting the beam free of its anchor over a length (it falls).  A
        trim moves a resonance one way only.
    precision_pct : one sigma of the error of a trim, relative to the resonance [%].
    passes : how often a lab measures, trims and measures again at most, each pass
        cutting what the last measurement says is still missing (every cut's error is
        drawn anew), within ``range_pct`` over all passes (``vibroplan yield --trim``;
        ``vibroplan trim`` says what one pass cuts).
    """

    range_pct: Annotated[float, Field(gt=0, le=20, allow_inf_nan=False)] = 1.0
    direction: Literal["up", "down"] = "up"
    #: > 0: a cut has an error (a lab's laser or FIB is not exact), and the layout's trim
    #: tabs are steps of this size (0 would need infinitely many); the yield's
    #: ``--trim-precision 0`` can still study an ideal trim
    precision_pct: Annotated[float, Field(gt=0, le=5, allow_inf_nan=False)] = 0.1
    passes: Annotated[int, Field(ge=1, le=10)] = 3

    @model_validator(mode="after")
    def _precision_within_range(self):
        if self.precision_pct > self.range_pct:
            raise ValueError(f"precision_pct ({self.precision_pct:g}) must not exceed "
                             f"range_pct ({self.range_pct:g}): one cut's step or error "
                             "cannot be larger than the whole trim")
        return self


class StepSpec(Strict):
    """One step of a scene: who moves which way, for how long, how far or to where.

    ``duration_ms`` is the burst's length; ``travel_um`` asks the planner to size the
    burst so that the slowest slider of the step moves that far (predicted under the
    step's summed drive); with both, ``duration_ms`` is the longest burst allowed.

    ``targets_um`` asks for positions instead: device selector (a device id, a row
    letter, a column number or ``all``) -> position [um].  With ``relative_to:
    scene_start`` (the default) a target is where the slider must be relative to where
    it was when the scene started (so ``{all: 0}`` brings every slider back); with
    ``relative_to: previous_step`` it is the move from where the slider ended the
    previous step.  The planner drives each targeted slider toward its target (forward
    for a positive move, backward for a negative one), switching each tone off when its
    slider has gone far enough (:mod:`planner.synthesis.gating`); devices without a target, or
    already at it, stay.  ``duration_ms`` is then the longest burst allowed, and
    ``forward``, ``backward`` and ``travel_um`` cannot be given.
    """

    name: str
    duration_ms: PositiveFloat | None = None
    travel_um: PositiveFloat | None = None
    targets_um: dict[str, FiniteFloat] | None = None
    relative_to: Literal["scene_start", "previous_step"] | None = None
    forward: list[str] = []
    backward: list[str] = []

    @field_validator("targets_um", mode="before")
    @classmethod
    def _selector_keys(cls, value):
        # a column selector written bare (``3: 10``) is an int key in YAML
        if isinstance(value, dict):
            return {str(k): v for k, v in value.items()}
        return value

    @model_validator(mode="after")
    def _how_long(self):
        if self.targets_um is not None:
            if not self.targets_um:
                raise ValueError("targets_um needs at least one device")
            if self.travel_um is not None:
                raise ValueError("targets_um and travel_um cannot be given together: a "
                                 "step either moves its sliders to targets or by a travel")
            if self.forward or self.backward:
                raise ValueError("targets_um says which devices move and which way: "
                                 "forward and backward cannot be given with it")
            return self
        if self.relative_to is not None:
            raise ValueError("relative_to applies to targets_um only")
        if self.duration_ms is None and self.travel_um is None:
            raise ValueError("a step needs duration_ms, travel_um or targets_um")
        return self


class DeviceOverride(Strict):
    """Per-device overrides of the device defaults."""

    impacter: ImpacterConfig | None = None
    forward: ImpacterConfig | None = None
    backward: ImpacterConfig | None = None
    slider: SliderConfig | None = None
    contact: Literal["paper", "two_body"] | None = None


class ArraySpec(Strict):
    """A whole array spec; see the module docstring."""

    name: str = "array"
    array: ArrayConfig = ArrayConfig()
    process: ProcessConfig = ProcessConfig()
    environment: EnvironmentConfig = EnvironmentConfig(viscosity_mpa_s=0.0179)
    device: DeviceDefaults = DeviceDefaults()
    devices: dict[str, DeviceOverride] = {}
    drive: DriveSpec = DriveSpec()
    design: DesignSpec = DesignSpec()
    verification: VerificationSpec = VerificationSpec()
    #: Fabrication tolerances for ``vibroplan yield``; all zero by default.
    fabrication: FabricationSpec = FabricationSpec()
    #: How a fabricated chip's resonances may be trimmed (``vibroplan trim``); None: the
    #: defaults of :class:`TrimSpec` when trimming is asked for.
    trim: TrimSpec | None = None
    independent: bool | None = None
    scenes: dict[str, list[StepSpec]] = {}

    @property
    def all_independent(self) -> bool:
        return self.independent if self.independent is not None else not self.scenes

    def impacter_config(self, device_id: str, direction: str) -> ImpacterConfig:
        cfg = DEFAULT_IMPACTER.merged(self.device.impacter).merged(getattr(self.device, direction))
        over = self.devices.get(device_id)
        if over is not None:
            cfg = cfg.merged(over.impacter).merged(getattr(over, direction))
        return cfg

    def contact(self, device_id: str) -> str:
        """The contact law of ``device_id`` (``devices.<id>.contact``, else ``device.contact``)."""
        over = self.devices.get(device_id)
        if over is not None and over.contact is not None:
            return over.contact
        return self.device.contact

    def slider_config(self, device_id: str) -> SliderConfig:
        over = self.devices.get(device_id)
        if over is not None and over.slider is not None:
            data = self.device.slider.model_dump()
            data.update(over.slider.model_dump(exclude_unset=True))
            return SliderConfig(**data)
        return self.device.slider
