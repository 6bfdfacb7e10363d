"""Design configs for ``vibroplan design``: YAML with unit-suffixed keys, converted once to SI.

A design config reuses the device sections of :mod:`planner.config` (``process``,
``environment``, ``slider``, ``drive``) and adds a ``design`` section: the two drive
frequencies, the bounds of the design variables, the window, the seed and the
search budget.

Example (``configs/paper_table2.yaml``)::

    environment: {viscosity_mpa_s: 0.0179}      # air
    design:
      forward_hz: 6000
      backward_hz: 3000
      area_um2: [20, 50000]                      # (17) below, footprint above
      width_um: [2, 10]
      length_um: [8, 1500]
      gap_um: [2, 10]
      window_ms: 3.0
      seed: 0
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator

from planner.config import DeviceDriveConfig, EnvironmentConfig, ProcessConfig, SliderConfig
from planner.designer import DEFAULT_UPPER, GUARD, PAPER_LOWER, DesignBounds
from planner.core.strict import Strict
from planner.core.units import UM
from planner.files.yamlio import check_kind, load_yaml, validate

PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
Range = tuple[PositiveFloat, PositiveFloat]


_Strict = Strict


class DesignSection(_Strict):
    """The ``design:`` section: frequencies, bounds of p = (A, w, l, c), search settings."""

    forward_hz: PositiveFloat | None = None
    backward_hz: PositiveFloat | None = None
    area_um2: Range = (PAPER_LOWER[0] / UM**2, DEFAULT_UPPER[0] / UM**2)
    width_um: Range = (PAPER_LOWER[1] / UM, DEFAULT_UPPER[1] / UM)
    length_um: Range = (PAPER_LOWER[2] / UM, DEFAULT_UPPER[2] / UM)
    gap_um: Range = (PAPER_LOWER[3] / UM, DEFAULT_UPPER[3] / UM)
    window_ms: PositiveFloat = 3.0
    seed: Annotated[int, Field(ge=0)] = 0
    budget: Literal["full", "fast"] = "full"
    x0_points: Annotated[int, Field(ge=3, le=4097)] | None = None
    guard: Annotated[float, Field(ge=0, lt=0.5)] = GUARD
    impact_angle_deg: Annotated[float, Field(ge=0, lt=90)] = 45.0
    restitution: Annotated[float, Field(ge=0, le=1)] = 0.5

    @field_validator("area_um2", "width_um", "length_um", "gap_um")
    @classmethod
    def _ordered(cls, value, info):
        if not value[1] > value[0]:
            raise ValueError(f"{info.field_name}[1] must be greater than "
                             f"{info.field_name}[0], got [{value[0]:g}, {value[1]:g}]")
        return value

    @field_validator("x0_points")
    @classmethod
    def _odd(cls, value):
        if value is not None and value % 2 == 0:
            raise ValueError(f"must be odd (so that -c, 0 and +c are grid nodes), {value} "
                             "was given")
        return value

    @model_validator(mode="after")
    def _distinct(self):
        if (self.forward_hz is not None and self.backward_hz is not None
                and self.forward_hz == self.backward_hz):
            raise ValueError("forward_hz and backward_hz must differ")
        return self

    def bounds(self) -> DesignBounds:
        """The bounds in SI units."""
        return DesignBounds.from_spec(area_um2=self.area_um2, width_um=self.width_um,
                                      length_um=self.length_um, gap_um=self.gap_um)


class DesignConfig(_Strict):
    """A whole design config; see the module docstring."""

    name: str | None = None
    process: ProcessConfig = ProcessConfig()
    environment: EnvironmentConfig = EnvironmentConfig()
    slider: SliderConfig = SliderConfig()
    drive: DeviceDriveConfig = DeviceDriveConfig()
    design: DesignSection = DesignSection()

    def design_kwargs(self) -> dict:
        """Keyword arguments of :func:`planner.designer.design_impacter` (SI units)."""
        from planner.config import build_slider
        from planner.designer.bounds import narrow_bounds

        d = self.design
        return {
            "process": self.process.physics(),
            "environment": self.environment,
            "power": self.drive.power_m2_s3,
            "amplitude": None if self.drive.amplitude_um is None else self.drive.amplitude_um * UM,
            # the process rules the config sets keep the beams and tips drawable
            "bounds": narrow_bounds(d.bounds(), self.process, [math.radians(d.impact_angle_deg)]),
            "window": d.window_ms * 1e-3,
            "budget": d.budget,
            "x0_points": d.x0_points,
            "guard": d.guard,
            "slider": build_slider(self.slider, self.process, self.environment),
            "impact_angle": math.radians(d.impact_angle_deg),
            "restitution": d.restitution,
        }


def load_design_config(path: str | Path) -> DesignConfig:
    """Read and validate a design config; raise :class:`planner.core.errors.SpecError` if bad."""
    data, lines = load_yaml(Path(path))
    check_kind(data, "design config", source=str(path))
    return validate(DesignConfig, data, lines, source=str(path))
