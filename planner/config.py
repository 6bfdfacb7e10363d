"""Device configs: YAML with unit-suffixed keys, validated, converted once to SI.

A device config describes one microvibromotor: process constants, environment,
the impacters (shared defaults in ``impacter``, per-pair overrides in ``forward``
and ``backward``), the slider, the drive convention and simulation defaults.
Every key carries its unit (``gap_um``, ``viscosity_mpa_s``, ``static_friction_un``);
conversion to SI happens here and nowhere else.  The array spec
(:mod:`planner.arrayspec`) reuses these sections.

Example (``configs/paper_fig7.yaml``)::

    environment: {viscosity_mpa_s: 0.0}
    impacter: {area_um2: 1.5e4, width_um: 4.0, length_um: 1242, gap_um: 3.0,
               natural_frequency_hz: 5200}
    slider: {area_um2: 8.0e4, thickness_um: 2.0}
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

from pydantic import Field, model_validator

from model import Drive, Impacter, Slider
from model import devices as _d
from planner.core.strict import Strict
from planner.core.units import UM
from planner.files.yamlio import check_kind, load_yaml, validate

PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegFloat = Annotated[float, Field(ge=0, allow_inf_nan=False)]


_Strict = Strict


#: A GDSII layer and datatype, each 0 ... 255.
GdsLayer = tuple[Annotated[int, Field(ge=0, le=255)], Annotated[int, Field(ge=0, le=255)]]


class LayerMap(_Strict):
    """GDSII (layer, datatype) of every mask the layout draws (``process.layers``).

    The defaults follow the mask names and numbering of a PolyMUMPs-style three-poly
    surface-micromachining process, the paper's (Section IV): POLY0 is the ground
    plane under the devices, ANCHOR1 the cuts where POLY1 lands on POLY0, DIMPLE the
    bumps under POLY1, POLY1 the structural layer of beams, plates and sliders,
    POLY1_POLY2_VIA the cut that bonds POLY2 onto POLY1 (the impacter plates are
    POLY1 + POLY2, t = 3.5 um), ANCHOR2 the cuts of the POLY2 slider guides, POLY2 the
    second structural layer.  LABEL (text: ids and frequencies) and TRIM (outlines of
    the trim tabs) are no masks.  Check the numbers against the foundry's layer map
    and give only the names that differ, e.g. ``process: {layers: {POLY2: [50, 0]}}``.
    """

    POLY0: GdsLayer = (13, 0)
    ANCHOR1: GdsLayer = (43, 0)
    DIMPLE: GdsLayer = (50, 0)
    POLY1: GdsLayer = (45, 0)
    POLY1_POLY2_VIA: GdsLayer = (47, 0)
    ANCHOR2: GdsLayer = (52, 0)
    POLY2: GdsLayer = (49, 0)
    LABEL: GdsLayer = (100, 0)
    TRIM: GdsLayer = (101, 0)

    @model_validator(mode="after")
    def _distinct(self):
        seen = {}
        for name in type(self).model_fields:
            pair = tuple(getattr(self, name))
            if pair in seen:
                raise ValueError(f"{name} and {seen[pair]} are both on layer {list(pair)}; "
                                 "every mask needs its own (layer, datatype)")
            seen[pair] = name
        return self


class ProcessConfig(_Strict):
    """Process constants (Table I and Section III-B); defaults are the paper's MUMPs values."""

    density_kg_m3: PositiveFloat = _d.DENSITY
    youngs_modulus_gpa: PositiveFloat = _d.YOUNGS_MODULUS / 1e9
    beam_height_um: PositiveFloat = _d.BEAM_HEIGHT / UM
    mass_thickness_um: PositiveFloat = _d.MASS_THICKNESS / UM
    substrate_gap_um: PositiveFloat = _d.SUBSTRATE_GAP / UM
    beam_angle_deg: Annotated[float, Field(ge=0, lt=90)] = math.degrees(_d.BEAM_ANGLE)
    slider_thickness_um: PositiveFloat = _d.SLIDER_THICKNESS / UM
    #: GDSII layer and datatype of every mask of the layout (``vibroplan layout``).
    layers: LayerMap = LayerMap()
    #: Minimum line width [um] of the structural layers.  Unset: the layout is checked
    #: against the paper's 2 um minimum feature and the designer keeps its own lower
    #: bounds (17); set: every beam is at least this wide (designer bounds included).
    min_line_um: PositiveFloat | None = None
    #: Minimum space [um] between structures of one layer.  Unset: checked against 2 um,
    #: designer bounds unchanged; set: the designer keeps every impacter tip at least
    #: this far from its slider wall (c sin(theta) >= min_space_um).
    min_space_um: PositiveFloat | None = None
    #: How far POLY0, POLY1 and POLY2 must reach beyond an anchor cut [um].
    anchor_enclosure_um: PositiveFloat = 2.0

    def physics(self) -> "ProcessConfig":
        """This process with the layout-only fields (:data:`LAYOUT_FIELDS`) at their
        defaults.

        What a design depends on: the designer gets this copy, so that a new layer map
        or rule (which reach the designer through its bounds) never invalidates a
        cached design.
        """
        return self.model_copy(update={k: type(self).model_fields[k].default
                                       for k in LAYOUT_FIELDS})


#: The fields of :class:`ProcessConfig` that only the layout reads (and the designer's
#: bounds, through the rules).
LAYOUT_FIELDS = ("layers", "min_line_um", "min_space_um", "anchor_enclosure_um")


class EnvironmentConfig(_Strict):
    """Environment: viscosity mu of the gas (0 at 10 mTorr, 0.0179 mPa s in air)."""

    viscosity_mpa_s: NonNegFloat = 0.0


class ImpacterConfig(_Strict):
    """An impacter's geometry and contact parameters (all optional in an override)."""

    area_um2: PositiveFloat | None = None
    width_um: PositiveFloat | None = None
    length_um: PositiveFloat | None = None
    gap_um: PositiveFloat | None = None
    mass_thickness_um: PositiveFloat | None = None
    #: at most 1 GHz, no MEMS resonance beyond (the lab files' bound, planner.lab.csv_files):
    #: 5.2e303 Hz overflowed the trajectory's sampling instead of being refused
    natural_frequency_hz: Annotated[float, Field(gt=0, le=1e9, allow_inf_nan=False)] | None \
        = None
    impact_angle_deg: Annotated[float, Field(ge=0, lt=90)] | None = None
    restitution: Annotated[float, Field(ge=0, le=1)] | None = None

    def merged(self, override: "ImpacterConfig | None") -> "ImpacterConfig":
        if override is None:
            return self
        data = self.model_dump()
        data.update({k: v for k, v in override.model_dump().items() if v is not None})
        return ImpacterConfig(**data)


class SliderConfig(_Strict):
    """The slider: planar area, thickness and friction (Table I defaults)."""

    area_um2: PositiveFloat = 8.0e4
    thickness_um: PositiveFloat | None = None
    static_friction_un: NonNegFloat = _d.STATIC_FRICTION / UM
    dynamic_friction_un: NonNegFloat = _d.DYNAMIC_FRICTION / UM


class DeviceDriveConfig(_Strict):
    """Drive convention of one tone: power Z0^2 w^3 or an explicit amplitude."""

    power_m2_s3: PositiveFloat = 50.0
    amplitude_um: PositiveFloat | None = None


class SimulationConfig(_Strict):
    """Defaults of ``vibroplan simulate``."""

    x0_um: float = 0.0
    v0_m_s: float = 0.0
    duration_ms: PositiveFloat = 3.0


# The paper's Fig. 7 device, the default impacter geometry.
DEFAULT_IMPACTER = ImpacterConfig(area_um2=1.5e4, width_um=4.0, length_um=1242.0, gap_um=3.0,
                                  impact_angle_deg=45.0, restitution=0.5)


class DeviceConfig(_Strict):
    """One device: ``vibroplan simulate`` and ``vibroplan sweep`` read this."""

    name: str | None = None
    process: ProcessConfig = ProcessConfig()
    environment: EnvironmentConfig = EnvironmentConfig()
    impacter: ImpacterConfig = DEFAULT_IMPACTER
    forward: ImpacterConfig | None = None
    backward: ImpacterConfig | None = None
    slider: SliderConfig = SliderConfig()
    drive: DeviceDriveConfig = DeviceDriveConfig()
    simulation: SimulationConfig = SimulationConfig()

    @model_validator(mode="after")
    def _complete(self):
        for pair in ("forward", "backward"):
            cfg = DEFAULT_IMPACTER.merged(self.impacter).merged(getattr(self, pair))
            for key in ("area_um2", "width_um", "length_um", "gap_um"):
                if getattr(cfg, key) is None:
                    raise ValueError(f"{pair} impacter needs {key}")
        if self.simulation.x0_um * UM > self.impacter_config("forward").gap_um * UM:
            raise ValueError("simulation.x0_um must be <= the gap (the wall)")
        return self

    def impacter_config(self, pair: str) -> ImpacterConfig:
        return DEFAULT_IMPACTER.merged(self.impacter).merged(getattr(self, pair))


def build_impacter(cfg: ImpacterConfig, process: ProcessConfig,
                   environment: EnvironmentConfig) -> Impacter:
    """SI :class:`model.Impacter` from a complete impacter config."""
    thickness = cfg.mass_thickness_um if cfg.mass_thickness_um is not None else process.mass_thickness_um
    return Impacter.from_geometry(
        cfg.area_um2 * UM**2, cfg.width_um * UM, cfg.length_um * UM, cfg.gap_um * UM,
        thickness=thickness * UM, beam_height=process.beam_height_um * UM,
        density=process.density_kg_m3, youngs_modulus=process.youngs_modulus_gpa * 1e9,
        viscosity=environment.viscosity_mpa_s * 1e-3,
        substrate_gap=process.substrate_gap_um * UM,
        beam_angle=math.radians(process.beam_angle_deg),
        impact_angle=math.radians(cfg.impact_angle_deg if cfg.impact_angle_deg is not None else 45.0),
        restitution=cfg.restitution if cfg.restitution is not None else _d.RESTITUTION,
        natural_frequency=cfg.natural_frequency_hz)


def build_slider(cfg: SliderConfig, process: ProcessConfig,
                 environment: EnvironmentConfig) -> Slider:
    """SI :class:`model.Slider` from a slider config."""
    thickness = cfg.thickness_um if cfg.thickness_um is not None else process.slider_thickness_um
    return Slider.from_geometry(
        cfg.area_um2 * UM**2, thickness * UM, density=process.density_kg_m3,
        viscosity=environment.viscosity_mpa_s * 1e-3, substrate_gap=process.substrate_gap_um * UM,
        static_friction=cfg.static_friction_un * UM, dynamic_friction=cfg.dynamic_friction_un * UM)


@dataclass(frozen=True)
class Device:
    """A device config converted to SI model objects."""

    config: DeviceConfig
    forward: Impacter
    backward: Impacter
    slider: Slider

    def impacter(self, pair: str) -> Impacter:
        if pair not in ("forward", "backward"):
            raise ValueError(f"pair must be 'forward' or 'backward', {pair!r} was given")
        return getattr(self, pair)

    def drive(self, frequency_hz: float, phase: float = 0.0) -> Drive:
        """One tone at ``frequency_hz`` [Hz] by the config's drive convention."""
        d = self.config.drive
        if d.amplitude_um is not None:
            return Drive([frequency_hz], [d.amplitude_um * UM], [phase])
        return Drive.tone(frequency_hz, d.power_m2_s3, phase)


def load_device(path: str | Path) -> Device:
    """Read and validate a device config; raise :class:`planner.core.errors.SpecError` if bad."""
    data, lines = load_yaml(Path(path))
    check_kind(data, "device config", source=str(path))
    cfg = validate(DeviceConfig, data, lines, source=str(path))
    return Device(cfg,
                  build_impacter(cfg.impacter_config("forward"), cfg.process, cfg.environment),
                  build_impacter(cfg.impacter_config("backward"), cfg.process, cfg.environment),
                  build_slider(cfg.slider, cfg.process, cfg.environment))
