"""Compatibility module: the array plan now lives in :mod:`planner.planning`.

Re-exports the names code imported from ``planner.pipeline``; the stage functions
that took a :class:`~planner.spec.LoadedSpec` still accept one (it is converted to
:class:`~planner.planning.settings.Settings`).
"""

from __future__ import annotations

from planner.planning import Plan, plan, run_plan, step_tones, write_outputs
from planner.planning import designs as _designs
from planner.planning import drives as _drives
from planner.planning import verify as _verify
from planner.planning.designs import DESIGN_RETRIES, SPEED_MARGIN
from planner.planning.outputs import (
    RESPONSE_GRID_POINTS,
    RESPONSE_PEAK_SPAN,
    RESPONSE_X0_POINTS,
)
from planner.planning.record import EXPORT_FORMATS
from planner.planning.scenes import RINGING_V, SETTLE_NAME, scene_overshoot, simulate_scenes
from planner.planning.settings import SETTLE_S, SINGLE_STEP_S, Settings, resolve_settings
from planner.planning.verify import Failure
from planner.units import UM

__all__ = ["DESIGN_RETRIES", "EXPORT_FORMATS", "Failure", "Plan", "RESPONSE_GRID_POINTS",
           "RESPONSE_PEAK_SPAN", "RESPONSE_X0_POINTS", "RINGING_V", "SETTLE_NAME", "SETTLE_S",
           "SINGLE_STEP_S", "SPEED_MARGIN", "UM", "coupling_matrix", "design_all", "plan",
           "run_plan", "scene_overshoot", "simulate_scenes", "step_tones", "synthesize_steps",
           "verify_step", "write_outputs"]


def _settings(spec_or_settings):
    if isinstance(spec_or_settings, Settings):
        return spec_or_settings
    return resolve_settings(spec_or_settings)


def design_all(loaded, steps, assignment, cache, progress=None, waveforms=None, jobs=1):
    """:func:`planner.planning.designs.design_all` from a LoadedSpec or Settings."""
    return _designs.design_all(_settings(loaded), steps, assignment, cache, progress=progress,
                               waveforms=waveforms, jobs=jobs)


def synthesize_steps(loaded, steps, assignment, seed):
    """:func:`planner.planning.drives.synthesize_steps` from a LoadedSpec or Settings."""
    return _drives.synthesize_steps(_settings(loaded), steps, assignment, seed)


def verify_step(loaded, step, waveform, impacters, sliders):
    """:func:`planner.planning.verify.verify_step` from a LoadedSpec or Settings."""
    return _verify.verify_step(_settings(loaded), step, waveform, impacters, sliders)


def coupling_matrix(impacters, tones, spec, duration):
    """:func:`planner.planning.verify.coupling_matrix`; ``spec`` an ArraySpec, LoadedSpec
    or Settings."""
    from planner.spec import ArraySpec, LoadedSpec

    if isinstance(spec, ArraySpec):
        spec = LoadedSpec(spec, (), "<spec>")
    return _verify.coupling_matrix(impacters, tones, _settings(spec), duration)
