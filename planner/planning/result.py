"""The plan's result: one declared object holding everything a later stage reads."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import pandas as pd

if TYPE_CHECKING:
    from planner.assignment.assign import Assignment
    from planner.planfile.schema import PlanFile, Replan
    from planner.planning.settings import Settings


@dataclass(frozen=True)
class Plan:
    """A verified array plan; the same content as ``plan.json``, as DataFrames.

    Built once, by the pipeline (:func:`planner.planning.run_plan`) or a re-plan
    (:func:`planner.afterfab.replan.replan`), and never changed: writing it somewhere
    gives a new one with its ``out_dir`` (:func:`planner.planning.plan`), a trim one
    with its ``trim`` block (:func:`planner.afterfab.trim.trim_chip`).

    Attributes
    ----------
    impacters : DataFrame
        One row per designed impacter (id, device, direction, channel, frequency_hz [Hz],
        mass_kg [kg], stiffness_n_per_m [N/m], gap_m [m], geometry [SI], ...).
    devices : DataFrame
        One row per device in scope, with its slider parameters (SI).
    steps : DataFrame
        One row per step: scene, name, duration_s [s], tones, crest factor, scale.
    verification : DataFrame
        One row per step and device: expected motion, predicted displacement [m], worst
        case (min_speed_m_s [m/s] or max_response_n [N]), pass flag and cause.
    coupling : DataFrame
        Cross-coupling matrix: worst response r [N] of every impacter (rows) to every
        tone (columns, Hz) alone.
    scenes : DataFrame
        Each scene simulated in order with the state carried across steps: one row per
        step and one for the drive switched off afterwards (``driven`` false), with the
        slider positions [m], the idle impacters that still hit and the idle sliders that
        moved beyond the tolerance (see :func:`planner.planning.scenes.simulate_scenes`).
    passed : bool
        Every step passed re-simulation.
    data : dict
        The ``plan.json`` content (a re-plan's with ``as_built`` and ``replan``): the
        dump of ``plan_file``.
    plan_file : planner.planfile.schema.PlanFile
        The same content as its schema's typed record, which later stages read
        (:attr:`replan`) rather than ``data`` (keyword only).
    settings : planner.planning.settings.Settings
        The spec in SI units, as every stage read it (keyword only).
    assignment : planner.assignment.assign.Assignment
        Channels [-] and frequencies [Hz] of every node (keyword only).
    timings : dict
        Seconds per stage (not in plan.json, which is deterministic; ``outputs`` once
        written).
    out_dir : Path or None
        Where the outputs were written (None: not written).
    waveforms : dict
        Step key (``"scene/step"``) -> :class:`planner.synthesis.Waveform` (keyword only).
    designs : dict
        Node text -> :class:`planner.designer.DesignResult` (keyword only).
    failures : tuple
        :class:`planner.planning.verify.Failure` of the last verification round
        (keyword only).
    design_cache : dict or None
        With an on-disk design cache: its ``path``, the designs ``read`` from it and
        ``written`` to it, the reach's ``probes`` ({"read": n, "written": m}, apart
        from the designs), and the distinct designs of the plan (``designed``, every
        repair round's), and ``stages``: per later stage cached beside the designs
        (``verify``: steps, ``manufacturability``: the block) the results ``read`` and
        ``written``; None without one (keyword only; not in plan.json).
    run_steps : tuple of Step
        The steps as they play (bursts sized, gated): with ``waveforms`` and ``dwells``
        the drive a chip's check replays in memory (:func:`planner.afterfab.checks.
        check_drive`) (keyword only).
    dwells : dict
        Step key -> the settle dwell after the step [s] (keyword only).
    """

    impacters: pd.DataFrame
    devices: pd.DataFrame
    steps: pd.DataFrame
    verification: pd.DataFrame
    coupling: pd.DataFrame
    scenes: pd.DataFrame
    passed: bool
    data: dict
    settings: Settings = field(kw_only=True, repr=False)
    assignment: Assignment = field(kw_only=True, repr=False)
    timings: dict = field(default_factory=dict)
    out_dir: Path | None = None
    waveforms: dict = field(default_factory=dict, kw_only=True, repr=False)
    designs: dict = field(default_factory=dict, kw_only=True, repr=False)
    failures: tuple = field(default=(), kw_only=True, repr=False)
    design_cache: dict | None = field(default=None, kw_only=True, repr=False)
    run_steps: tuple = field(default=(), kw_only=True, repr=False)
    dwells: dict = field(default_factory=dict, kw_only=True, repr=False)
    plan_file: PlanFile | None = field(default=None, kw_only=True, repr=False)

    @property
    def replan(self) -> Replan | None:
        """A re-plan's ``replan`` block (:class:`planner.planfile.schema.Replan`: what
        moved, the original drive on the chip, the impacters no drive tells apart, the
        steps split, the tones beyond the band); None for a plan."""
        return None if self.plan_file is None else self.plan_file.replan
