"""As-built re-plan: a new drive for a fabricated chip from its measured resonances.

After fabrication an impacter's geometry is fixed, but its drive is not.  Given a plan
(its plan.json) and each impacter's measured natural frequency (and optionally its
quality factor and gap, and each half of a pair), this module builds the as-built model
of every impacter and re-plans the drive only (:mod:`planner.afterfab.drive`):

1. **as-built models** (:func:`as_built_parameters`): the design's mass m; stiffness
   k = m (2 pi nu_n)^2 from the measured nu_n; damping b = m 2 pi nu_n / Q when a
   quality factor is given, else the design's; the measured gap when given, else the
   design's; a pair measured half by half is two such models
   (:class:`model.PairHalves`);
2. **tones**: each impacter's tone moves with its measured resonance, keeping its place
   relative to it; every pair the steps must tell apart is checked against the plan's
   measured silent bands and tone windows (plan.json's ``manufacturability``), and a pair
   no drive can tell apart is named with its as-built resonances and the separation it
   would need: the re-plan then fails (exit 1); a trim can still rescue the chip
   (``vibroplan trim``);
3. **steps**: every step is synthesised with the new tones under
   ``drive.max_acceleration_g``; a multi-tone step the limit would weaken beyond the
   plan's verified drive is split into sub-steps of neighbouring tones; bursts asked as
   a travel are sized again for the as-built speeds;
4. **verification and motion repair** as the plan's: every step re-simulated on the
   as-built models, every scene with the state carried across steps, too-long travels
   shortened and slow settles given longer dwells.

The original plan's drive is verified on the as-built models too, so that the report
can say whether the chip needed the re-plan.  :func:`replan_chip` is the per-chip entry
point for a yield study.
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np
import pandas as pd

import model
from model import Drive
from planner.assign import Assignment, conflict_graph, guard_violations
from planner.nodes import device_key, node_key
from planner.planning.plan_file import PlanRecord, drives
from planner.planning.record import build_record
from planner.planning.repair import scenes_and_motion
from planner.afterfab.drive import (REPLAN_TRAVEL_MARGIN, as_built_models, plan_phases,
                                    quieten, rescue, split_weak)
from planner.planning.result import Plan
from planner.planning.settings import plan_settings, tone_amplitudes
from planner.planning.verify import check_step, check_steps, coupling_matrix, x0_grid
from planner.units import UM

#: Columns of measured.csv: required, optional, and ignored (calibrate's uncertainties).
MEASURED_REQUIRED = ("impacter", "natural_frequency_hz")
MEASURED_OPTIONAL = ("quality_factor", "gap_um", "half")
#: The halves of a pair in measured.csv's ``half`` column.
HALVES = ("a", "b")


# --------------------------------------------------------------------------- inputs

#: How far a measured resonance may lie from its design's, as a factor [-]: a fabricated
#: chip's resonances move by a few per cent (1.2 % per line-width sigma on the default);
#: one 4 x off is no measurement of this design (a typo, kHz for Hz, another chip),
#: while a chip as far off as a study asks (a neighbour's resonance, 0.38 x) is read.
MAX_MEASURED_FACTOR = 4.0
#: The smallest gap a measurement may give [um]: the process's gaps are microns; a
#: smaller number is a gap typed in metres (3e-6) or nm.
MIN_GAP_UM = 0.05


def read_measured(path, impacter_ids, design_hz=None) -> dict:
    """Read and check a lab's measured.csv.

    Parameters
    ----------
    path : str or os.PathLike
        CSV with header ``impacter,natural_frequency_hz`` and optionally
        ``quality_factor`` and ``gap_um`` (any order); columns ending in ``_std`` or
        ``_std_hz`` (:func:`planner.calibrate.write_measured`'s uncertainties) are
        ignored.  Blank lines and lines starting with ``#`` are skipped.
    impacter_ids : iterable of str
        The plan's impacters; any other name is an error.
    design_hz : dict, optional
        Impacter id -> its designed natural frequency [Hz]: a measured one further than
        a factor :data:`MAX_MEASURED_FACTOR` from it is refused (another unit, a typo).

    Returns
    -------
    dict
        Impacter id -> ``{"natural_frequency_hz": [Hz], "quality_factor": [-] or None,
        "gap_m": [m] or None}``; a pair measured half by half (``half`` column, a and b)
        also has ``halves_hz`` (a, b) [Hz], ``halves_quality`` (a, b) [-] and
        ``halves_gap_m`` (a, b) [m] (an entry None where that half's cell is blank; the
        whole None where no half gives one), its ``natural_frequency_hz`` the halves'
        mean and its ``gap_m`` the wider half's gap.

    Raises
    ------
    planner.errors.SpecError
        ``FILE: row N, column C: ...`` (N the 1-based line) for a missing or unknown
        column, an unknown or repeated impacter, a value that is not a finite number, or
        a frequency, quality factor or gap <= 0.
    """
    from planner.lab_csv import csv_number, read_csv_rows

    known = set(impacter_ids)
    # calibrate writes uncertainties beside the values: accepted and left alone
    header_line, header, rows, fail = read_csv_rows(
        path, MEASURED_REQUIRED, MEASURED_OPTIONAL, what="measured.csv",
        ignore=lambda c: c.endswith("_std") or c.endswith("_std_hz"))
    out, first_line = {}, {}
    halves = {}                       # name -> {half: (line, rec)}
    for line, row in rows:
        if len(row) != len(header):
            raise fail(line, header[min(len(row), len(header) - 1)],
                       f"{len(row)} values where the header has {len(header)} columns")
        values = dict(zip(header, (v.strip() for v in row)))
        name = values["impacter"]
        if not name:
            raise fail(line, "impacter", "empty impacter name")
        if name not in known:
            raise fail(line, "impacter", f"unknown impacter {name!r} (the plan has: "
                                         f"{', '.join(sorted(known, key=node_key))})")
        half = values.get("half", "").lower()
        if half and half not in HALVES:
            raise fail(line, "half", f"must be a or b (one cantilever of the pair), "
                                     f"{values['half']!r} was given")
        key = (name, half)
        if key in first_line:
            what = f"half {half} of {name}" if half else name
            raise fail(line, "impacter", f"{what} measured twice (rows {first_line[key]} "
                                         f"and {line})")
        if (half and (name, "") in first_line) or (not half and name in halves):
            other = (first_line[(name, "")] if half else
                     min(row_line for row_line, _ in halves[name].values()))
            raise fail(line, "half", f"{name} measured both as a whole and by halves "
                                     f"(rows {other} and {line})")
        rec = {"natural_frequency_hz": None, "quality_factor": None, "gap_m": None}
        for column in MEASURED_REQUIRED[1:] + MEASURED_OPTIONAL[:-1]:
            if column not in header:
                continue
            text = values[column]
            if text == "" and column in MEASURED_OPTIONAL:
                continue        # an optional value left blank: the design's
            x = csv_number(text, line, column, fail)
            if x <= 0:
                raise fail(line, column, f"must be > 0, {text} was given")
            if column == "gap_um" and x < MIN_GAP_UM:
                raise fail(line, column, f"{text} um is no gap of this process (at least "
                                         f"{MIN_GAP_UM:g} um): a gap in metres? gap_um is "
                                         "in um (3e-6 m is 3)")
            nu0 = (design_hz or {}).get(name)
            if column == "natural_frequency_hz" and nu0 and not (
                    1 / MAX_MEASURED_FACTOR <= x / nu0 <= MAX_MEASURED_FACTOR):
                raise fail(line, column, f"{text} Hz is {x / nu0:.3g} x the design's "
                                         f"{nu0:.6g} Hz: a fabricated chip's resonance "
                                         f"lies within a factor {MAX_MEASURED_FACTOR:g} of "
                                         "its design's (a typo, another unit such as kHz, "
                                         "or another chip?)")
            if column == "natural_frequency_hz":
                rec["natural_frequency_hz"] = x
            elif column == "quality_factor":
                rec["quality_factor"] = x
            else:
                rec["gap_m"] = x * UM
        first_line[key] = line
        if half:
            halves.setdefault(name, {})[half] = (line, rec)
        else:
            out[name] = rec
    for name, got in halves.items():
        if len(got) < 2:
            (only, (line, _)), = got.items()
            raise fail(line, "half", f"only half {only} of {name} measured: give both "
                                     "halves, or the pair as a whole")
        (_, a), (_, b) = got["a"], got["b"]
        gaps = (a["gap_m"], b["gap_m"])
        qs = (a["quality_factor"], b["quality_factor"])
        # a value given for one half only is that half's (the other keeps its design's)
        out[name] = {"natural_frequency_hz": 0.5 * (a["natural_frequency_hz"]
                                                    + b["natural_frequency_hz"]),
                     "halves_hz": (a["natural_frequency_hz"], b["natural_frequency_hz"]),
                     "halves_quality": qs if any(qs) else None,
                     "halves_gap_m": gaps if any(gaps) else None,
                     "quality_factor": None,
                     "gap_m": max(g for g in gaps if g) if any(gaps) else None}
    if not out:
        raise fail(header_line + 1, "impacter", "no impacters after the header")
    return out


def as_built_parameters(plan: PlanRecord, measured) -> dict:
    """Impacter id -> ``{natural_frequency_hz, stiffness_n_per_m, damping_ns_per_m,
    gap_m}`` of the as-built model (plan.json's ``as_built``).

    ``measured``: impacter id -> mapping with ``natural_frequency_hz`` [Hz] and
    optionally ``quality_factor`` [-], ``damping_ns_per_m`` [N s/m] (used when no
    quality factor is given) and ``gap_m`` [m]; an impacter not in it keeps its design.
    """
    out = {}
    for rec in plan.impacters:
        n = rec.id
        m = rec.mass_kg
        meas = measured.get(n) or {}
        nu = meas.get("natural_frequency_hz") or rec.natural_frequency_hz
        w = 2.0 * math.pi * float(nu)
        if meas.get("quality_factor"):
            b = m * w / float(meas["quality_factor"])
        elif meas.get("damping_ns_per_m") is not None:
            b = float(meas["damping_ns_per_m"])
        else:
            b = rec.damping_ns_per_m
        gap = meas.get("gap_m") or rec.gap_m
        out[n] = {"natural_frequency_hz": float(nu), "stiffness_n_per_m": m * w * w,
                  "damping_ns_per_m": b, "gap_m": float(gap)}
        if meas.get("halves_hz"):
            # each half as measured, what the chip's models are (measured_models), kept
            # in plan.json's as_built; the pair's own record is their symmetric stand-in
            model_ = _halves_model(plan, n, meas)
            sym = symmetric(model_)
            out[n].update(natural_frequency_hz=float(sym.natural_frequency),
                          stiffness_n_per_m=float(sym.stiffness),
                          damping_ns_per_m=float(sym.damping), gap_m=float(sym.gap))
            out[n]["halves"] = [
                {"half": h, "natural_frequency_hz": float(imp.natural_frequency),
                 "stiffness_n_per_m": float(imp.stiffness),
                 "damping_ns_per_m": float(imp.damping), "gap_m": float(imp.gap)}
                for h, (imp, _) in zip(HALVES, model.halves(model_))]
    return out


def symmetric(imp):
    """The symmetric pair standing for a pair of unequal halves (plan.json's impacter
    record and ``as_built`` of a pair measured half by half): their mean resonance,
    mean damping and the wider gap (:attr:`model.PairHalves.gap`); a symmetric pair is
    itself."""
    if not isinstance(imp, model.PairHalves):
        return imp
    parts = [h for h, _ in model.halves(imp)]
    w = 2.0 * math.pi * float(imp.natural_frequency)
    m = float(imp.mass)
    return model.Impacter(m, m * w * w, float(np.mean([h.damping for h in parts])),
                          float(imp.gap), imp.a.impact_angle, imp.a.restitution)


def _impacter(rec, params=None):
    """model.Impacter of a plan's impacter record, with as-built ``params``."""
    p = params or {}
    return model.Impacter(rec.mass_kg,
                          float(p.get("stiffness_n_per_m", rec.stiffness_n_per_m)),
                          float(p.get("damping_ns_per_m", rec.damping_ns_per_m)),
                          float(p.get("gap_m", rec.gap_m)),
                          rec.impact_angle_rad, rec.restitution)


def verify_drive(plan: PlanRecord, as_built: dict, settings=None):
    """Verify a plan's recorded drive on as-built impacter models.

    Parameters
    ----------
    plan : PlanRecord
        A plan (:func:`planner.planning.plan_file.read_plan`; its steps' tones are the
        drive).
    as_built : dict
        Impacter id -> as-built parameters, as :func:`as_built_parameters` takes them
        (``natural_frequency_hz`` and optionally ``quality_factor``,
        ``damping_ns_per_m``, ``gap_m``).
    settings : Settings, optional
        The plan's settings (re-resolved from its spec when omitted).

    Returns
    -------
    passed : bool
    rows : list of dict
        The verification rows (as plan.json's), one per step and device.
    """
    if settings is None:
        settings = plan_settings(plan)
    # the chip as measured: a pair measured half by half is its two halves
    built = measured_models(plan, as_built)
    models = {r.node: built[r.id] for r in plan.impacters}
    devices = sorted({r.device for r in plan.impacters}, key=device_key)
    sliders = {d: settings.sliders[d] for d in devices}
    waves = drives(plan)
    rows = []
    for st in plan.steps:
        rows += check_step(settings, st.step, waves[st.key], models, sliders)[0]
    return bool(rows) and all(r["passed"] for r in rows), rows


# --------------------------------------------------------------------------- the re-plan

def _design_like(rec, imp, tone, settings):
    """A DesignResult standing for the as-built impacter (the record, figures and the
    coupling read it like a design); a pair of unequal halves stands as the symmetric
    pair at their mean resonance."""
    from planner.designer.result import DesignResult

    imp = symmetric(imp)
    g = rec.geometry
    geometry = model.Geometry(g.area_m2, g.width_m, g.length_m, imp.gap)
    imp = model.Impacter(imp.mass, imp.stiffness, imp.damping, imp.gap, imp.impact_angle,
                         imp.restitution, geometry)
    x0s = x0_grid(imp, settings.x0_points)
    r_own = model.responses(imp, Drive([tone], [float(tone_amplitudes(settings, [tone])[0])]),
                            x0s, duration=settings.window_s)
    return DesignResult(
        impacter=imp, frequency_hz=tone, forbidden_hz=(),
        natural_frequency_hz=imp.natural_frequency, mass_kg=imp.mass,
        stiffness_n_per_m=imp.stiffness, damping_ns_per_m=imp.damping, gap_m=imp.gap,
        impact_angle_rad=imp.impact_angle, restitution=imp.restitution, geometry=geometry,
        worst_x0_m=float(x0s[int(np.argmin(r_own))]), r_min_n=float(np.min(r_own)),
        r_max_forbidden_n=(), margins_hz=(),
        predicted_slider_speed_m_s=rec.predicted_slider_speed_m_s or math.nan,
        feasible=bool(np.min(r_own) > 0), evaluations=0, seconds=0.0,
        status="as-built", message="as-built model: the design's mass and geometry, the "
                                   "measured resonance")


def replan(plan: PlanRecord, measured, *, seed=None, settings=None, progress=None,
           original=None, record=True, remeasure=()):
    """Re-plan the drive of a fabricated chip from its measured resonances.

    Parameters
    ----------
    plan : PlanRecord
        The original plan (:func:`planner.planning.plan_file.read_plan`; a re-planned
        plan is a plan too).
    measured : dict
        Impacter id -> ``natural_frequency_hz`` [Hz] and optionally
        ``quality_factor`` [-], ``damping_ns_per_m`` [N s/m], ``gap_m`` [m]
        (:func:`read_measured`); an impacter not in it keeps its design.
    seed : int, optional
        Drive phases' seed (default: the plan's).
    settings : Settings, optional
        The plan's settings, already resolved (:func:`planner.planning.settings.
        plan_settings`; a yield study resolves them once for every chip); ``seed`` is
        then theirs.
    progress : callable, optional
        ``progress(stage, item=None, total=None)`` as :func:`planner.planning.run_plan`.
    original : tuple, optional
        ``(passed, rows)`` of the original drive already verified on this chip (a yield
        study has just verified it on the chip's true models): recorded as
        ``replan.original_drive`` instead of verifying it again with
        :func:`verify_drive` on the measured models.
    record : bool
        False: skip what only the outputs read (the scene simulation on the measured
        models and the coupling matrix; ``scenes`` is then empty and ``coupling`` an
        empty table).  The drive and its verification are the same.
    remeasure : iterable of str
        Impacter ids whose silent bands and tone windows are measured again on their
        as-built models (a trim's moved impacters: :func:`planner.afterfab.drive.
        remeasured`) instead of taken from the plan's ``manufacturability`` block.

    Returns
    -------
    Plan
        The re-planned drive verified on the as-built models; ``data`` is the plan.json
        contract plus ``as_built`` and ``replan`` (what moved, the original drive's
        verification on this chip, the impacters that can no longer be told apart).
    """
    tick = progress or (lambda stage, item=None, total=None: None)
    t0 = time.perf_counter()
    timings = {}
    if settings is None:
        settings = plan_settings(plan, seed)
    plan_imps = {r.node: r for r in plan.impacters}
    params = as_built_parameters(plan, measured)
    built = measured_models(plan, measured, params)
    models = {n: built[r.id] for n, r in plan_imps.items()}
    devices = sorted({n.device for n in models}, key=device_key)
    sliders = {d: settings.sliders[d] for d in devices}

    # the original drive on this chip
    ts = time.perf_counter()
    tick("original", total=1)
    if original is None:
        orig_passed, orig_rows = verify_drive(plan, measured, settings)
    else:
        orig_passed, orig_rows = bool(original[0]), list(original[1])
    timings["original_drive"] = time.perf_counter() - ts

    # the checks on the measured models keep a margin on the travel (REPLAN_TRAVEL_MARGIN);
    # the record states the spec's own limit
    strict = dataclasses.replace(settings,
                                 max_travel_m=settings.max_travel_m * REPLAN_TRAVEL_MARGIN)
    ts = time.perf_counter()
    drive = rescue(plan, measured_resonances(plan, measured), settings, models, sliders,
                   remeasure=remeasure)
    steps_, waveforms_, gating = regate(settings, drive.steps, drive.waveforms, drive.tones,
                                        models, sliders, plan_phases(plan))
    drive = dataclasses.replace(drive, steps=steps_, waveforms=waveforms_, gating=gating)
    timings["drive"] = time.perf_counter() - ts
    ts = time.perf_counter()
    tick("verify", total=len(drive.steps))
    def check(steps, waveforms, progress=None):
        rows, fails = [], []
        for r, f in check_steps(strict, steps, waveforms, models, sliders,
                                progress=progress):
            rows += r
            fails += f
        return rows, fails

    ver_rows, failures = check(drive.steps, drive.waveforms, lambda k: tick("verify", k))
    # a step the acceleration limit weakened, failing by a slow slider: split it where
    # its sub-steps pass more checks
    drive, ver_rows, failures = split_weak(strict, drive, ver_rows, failures, models,
                                           sliders, check)
    # a step an idle impacter answers on this chip: played weaker, where that passes
    drive, ver_rows, failures = quieten(strict, drive, ver_rows, failures, models,
                                        sliders, check)
    steps, ver_rows, failures, scene_rows, repairs, settle = scenes_and_motion(
        strict, drive.steps, drive.waveforms, models, sliders, ver_rows, failures,
        dwell_floor=drive.dwells)
    timings["verify"] = time.perf_counter() - ts

    ts = time.perf_counter()
    assignment = _assignment(steps, settings, drive.tones, plan.lower_bound)
    designs = {n: _design_like(plan_imps[n], models[n], drive.tones[n], settings)
               for n in plan_imps}
    impacters = {n: d.impacter for n, d in designs.items()}
    coupling = (coupling_matrix(impacters, sorted(set(drive.tones.values())), settings,
                                settings.single_step_s) if record else pd.DataFrame())
    if not record:      # a yield study verifies the drive on the chip's true models itself
        scene_rows = []
    timings["coupling"] = time.perf_counter() - ts
    ver = pd.DataFrame(ver_rows)
    passed = bool(ver["passed"].all()) and not drive.inseparable
    motion = {"sizing": drive.sizing, "drive": drive.notes, "settle_s": settle,
              "repairs": repairs, "design_problems": [], "gating": drive.gating}
    rounds = [{"round": 0, "span": assignment.span,
               "failures": sum(1 for r in ver_rows if not r["passed"])}]
    data, impacter_recs, device_recs, step_recs = build_record(
        settings, steps, assignment, designs, sliders, drive.waveforms, ver_rows, passed,
        rounds, scene_rows, motion,
        # the designs' separations go with the re-plan (the designs are the chip's; a
        # trim or a re-plan of the re-plan reckons from them, as from the plan); the
        # plan's prediction of a yield is not about this chip and stays with the plan
        manufacturability=(None if plan.manufacturability is None else {
            "separation_hz": plan.manufacturability["separation_hz"],
            "note": "the designs' silent bands and tone windows, from the plan this chip "
                    "was made by (its predicted yield is the plan's)"}),
        sections={"as_built": params,
                  "replan": _replan_record(plan, settings, params, drive, orig_passed,
                                           orig_rows)})
    timings["total"] = time.perf_counter() - t0
    return Plan(
        impacters=pd.DataFrame(impacter_recs), devices=pd.DataFrame(device_recs),
        steps=pd.DataFrame(step_recs), verification=ver, coupling=coupling,
        scenes=pd.DataFrame(scene_rows), passed=passed, data=data, timings=timings,
        settings=settings, waveforms=drive.waveforms, designs=designs,
        assignment=assignment, failures=tuple(failures))


def regate(settings, steps, waveforms, tones, models, sliders, phases=None):
    """Gate every ``targets_um`` step again for the chip's models, as the plan gated it
    for its designs (:func:`planner.planning.targets.place_targets`: one tone at a time,
    each playing until its slider has gone its move, found by the scene simulated with
    its state carried).  A slider's speed is the chip's: the plan's gates would put it
    wherever the design's speed would have.

    Returns
    -------
    (steps, waveforms, gating)
        As :func:`~planner.planning.targets.place_targets` returns them; unchanged (and
        ``gating`` empty) when no step asks for positions.  A slider that cannot reach
        its target on this chip keeps the step as synthesised: its verification then
        says by how far it misses.
    """
    from planner.errors import PlanningError
    from planner.planning.drives import synthesize_steps
    from planner.planning.targets import place_targets

    targeted = tuple(st for st in steps if st.targets_m is not None)
    if not targeted:
        return steps, waveforms, {}
    # the tones play one at a time: at their amplitudes as synthesised, not as lowered
    # for the peak of their whole sum, which never plays (as the plan's)
    raw = synthesize_steps(settings, targeted, tones, phases=phases)
    try:
        return place_targets(settings, steps, {**waveforms, **raw}, tones, models, sliders)
    except PlanningError:
        return steps, waveforms, {}


def measured_resonances(plan: PlanRecord, measured: dict) -> dict:
    """Impacter id -> measured resonance [Hz] (the halves' (a, b) where each half was
    measured), for every impacter of the plan (its design where not measured)."""
    out = {}
    for rec in plan.impacters:
        meas = measured.get(rec.id) or {}
        if meas.get("halves_hz"):
            out[rec.id] = tuple(float(x) for x in meas["halves_hz"])
        else:
            out[rec.id] = float(meas.get("natural_frequency_hz") or rec.natural_frequency_hz)
    return out


def _halves_model(plan: PlanRecord, node_id: str, meas: dict):
    """The :class:`model.PairHalves` of a pair measured half by half: each half's
    resonance, and its quality factor and gap where given (else the design's)."""
    qs = meas.get("halves_quality")
    gaps = meas.get("halves_gap_m")
    if gaps is None and meas.get("gap_m"):
        gaps = (meas["gap_m"],) * 2
    return as_built_models(plan, {node_id: tuple(meas["halves_hz"])},
                           quality={node_id: qs} if qs else None,
                           gaps={node_id: gaps} if gaps else None)[node_id]


def measured_models(plan: PlanRecord, measured: dict, params=None) -> dict:
    """Impacter id -> the as-built model of each impacter (:func:`as_built_parameters`;
    a :class:`model.PairHalves` where each half was measured)."""
    params = params or as_built_parameters(plan, measured)
    out = {}
    for rec in plan.impacters:
        meas = measured.get(rec.id) or {}
        if meas.get("halves_hz"):
            out[rec.id] = _halves_model(plan, rec.id, meas)
        else:
            out[rec.id] = _impacter(rec, params[rec.id])
    return out


def _assignment(steps, settings, chosen, lower_bound):
    """An :class:`~planner.assign.Assignment` of the chosen tones (the conflict graph as
    before; each impacter's channel is the grid channel of its tone)."""
    grid = np.asarray(settings.channel_grid_hz)
    graph, groups = conflict_graph(steps, settings.separation_channels, None,
                                   settings.ensemble_separation_channels)
    nodes = {n for g in groups.values() for n in g}
    channels = {n: int(np.argmin(np.abs(grid - chosen[n]))) for n in nodes}
    freqs = {n: float(chosen[n]) for n in nodes}
    lo = min(channels.values())
    coloring = {g: channels[members[0]] - lo for g, members in groups.items()}
    span = max(channels.values()) - lo + 1
    return Assignment(graph, groups, coloring, span, int(lower_bound), False,
                      "as-built", 0.0, 1, lo, channels, freqs,
                      guard_violations(steps, freqs, settings.tone_rules))


def _replan_record(plan, settings, params, drive, orig_passed, orig_rows):
    """plan.json's ``replan`` block: what moved, the original drive on this chip, the
    pairs no drive tells apart, the steps split, the tones beyond the band."""
    moved = []
    for rec in sorted(plan.impacters, key=lambda r: node_key(r.id)):
        n = rec.id
        # the design's resonance (a re-planned plan's impacters are as built already)
        nu0, nu1 = plan.design_natural_frequency_hz[n], params[n]["natural_frequency_hz"]
        f0, f1 = rec.frequency_hz, drive.tones[rec.node]
        moved.append({"id": n, "design_natural_frequency_hz": nu0,
                      "design_frequency_hz": plan.design_frequency_hz[n],
                      "natural_frequency_hz": nu1, "natural_frequency_shift": nu1 / nu0 - 1,
                      "original_frequency_hz": f0, "frequency_hz": f1,
                      "tone_shift": f1 / f0 - 1})
    fails = [r for r in orig_rows if not r["passed"]]
    lo, hi = settings.band_hz
    return {
        "moved": moved,
        "original_drive": {
            "passed": bool(orig_passed), "checks": len(orig_rows),
            "failed_checks": len(fails),
            "failures": [{"step": f"{r['scene']}/{r['step']}", "device": r["device"],
                          "cause": r["cause"]} for r in fails]},
        "inseparable": [{**c, "message": inseparable_message(c)} for c in drive.inseparable],
        "split_steps": drive.splits,
        "outside_band": [m["id"] for m in moved if not lo <= m["frequency_hz"] <= hi],
    }


def inseparable_message(c) -> str:
    """One line on impacters no drive tells apart (:func:`planner.afterfab.drive.rescue`'s
    ``inseparable``: a pair, or one impacter whose window several bands cover)."""
    names = [f"{n} ({hz:.0f} Hz as built)" for n, hz in zip(c["pair"], c["as_built_hz"])]
    if c.get("needs_hz") is None:
        return (f"{names[0]} cannot be told apart from {', '.join(names[1:])}: their silent "
                "bands together cover every tone that drives it; trim one of them "
                "(vibroplan trim)")
    return (f"{names[0]} and {names[1]} cannot be told apart: {c['apart_hz']:.0f} Hz "
            f"apart, they need {c['needs_hz']:.0f} Hz (one's tone window lies inside the "
            "other's silent band); trim one of them (vibroplan trim) or drive them together")


def replan_chip(plan: PlanRecord, as_built: dict, seed=None, *, settings=None, original=None,
                record=True, remeasure=()):
    """Re-plan one chip for a yield study: ``(passed, plan)``.

    Parameters
    ----------
    plan : PlanRecord
        The nominal plan.
    as_built : dict
        Impacter id -> what was measured of it: ``natural_frequency_hz`` [Hz] and
        optionally ``quality_factor`` [-], ``damping_ns_per_m`` [N s/m], ``gap_m`` [m].
    seed : int, optional
        Drive phases' seed (default: the plan's).
    settings : Settings, optional
        The plan's settings, resolved once for every chip (:func:`replan`).
    original, record, remeasure :
        As :func:`replan`: the original drive's ``(passed, rows)`` when already known
        (not verified again), False to skip the scenes and the coupling matrix
        (``vibroplan yield --replan`` passes both), and the impacters whose separations
        are measured again (a trim's).

    Returns
    -------
    passed : bool
        The re-planned drive verifies on the given models and no impacters collide.
    plan : Plan
        The re-plan (``plan.data`` is its plan.json).  To check it on a chip's TRUE
        models when ``as_built`` was a noisy measurement, read ``plan.data`` back
        (:func:`planner.planning.plan_file.plan_record`) and pass it and the true
        parameters to :func:`verify_drive`.
    """
    result = replan(plan, as_built, seed=seed, settings=settings, original=original,
                    record=record, remeasure=remeasure)
    return result.passed, result


# --------------------------------------------------------------------------- outputs

def write_replan_outputs(result: Plan, out_dir, *, figures=True):
    """Write the re-plan as :func:`planner.planning.outputs.write_outputs` does (plan.json
    with ``as_built`` and ``replan``, CSVs, waveforms, figures) and put the re-plan
    section at the top of report.md."""
    from planner.planning.outputs import write_outputs

    out_dir = Path(out_dir)
    write_outputs(result, out_dir, figures=figures)
    report = out_dir / "report.md"
    text = report.read_text()
    text = text.replace("# vibroplan plan:", "# vibroplan replan:", 1)
    head, sep, tail = text.partition("## Frequency assignment")
    report.write_text(head + "\n".join(replan_report_lines(result.data)) + "\n\n" + sep + tail)


def replan_report_lines(data) -> list:
    """The report's re-plan section: as-built against design, tones moved, the original
    drive on this chip, impacters that can no longer be told apart."""
    from planner.planning.report import fmt, md_table

    rp = data["replan"]
    od = rp["original_drive"]
    lines = ["## As-built re-plan", "",
             "Every impacter's as-built model keeps its design's mass (and its damping and gap "
             "unless measured); its stiffness follows from the measured natural frequency, "
             "k = m (2 pi nu_n)^2, and a measured quality factor sets the damping, "
             "b = m 2 pi nu_n / Q.  Only the drive is re-planned; every check above and below "
             "is on the as-built models.", "",
             f"**The original drive on this chip: {'PASSES' if od['passed'] else 'FAILS'}** "
             f"({od['checks'] - od['failed_checks']} of {od['checks']} step x device checks "
             "pass).", ""]
    if od["failures"]:
        lines += ["<details><summary>the original drive's failures on this chip</summary>", ""]
        lines += [f"- {f['step']} {f['device']}: {f['cause']}" for f in od["failures"][:40]]
        if len(od["failures"]) > 40:
            lines.append(f"- ... and {len(od['failures']) - 40} more (plan.json)")
        lines += ["", "</details>", ""]
    rows = []
    for m in rp["moved"]:
        rows.append([m["id"], fmt(m["design_natural_frequency_hz"], ".1f"),
                     fmt(m["natural_frequency_hz"], ".1f"),
                     fmt(100 * m["natural_frequency_shift"], "+.2f"),
                     fmt(m["original_frequency_hz"], ".1f"), fmt(m["frequency_hz"], ".1f"),
                     fmt(100 * m["tone_shift"], "+.2f")])
    lines += ["### What moved", ""]
    lines += md_table(["impacter", "design nu_n [Hz]", "as-built nu_n [Hz]", "shift [%]",
                       "original tone [Hz]", "new tone [Hz]", "tone shift [%]"], rows)
    lines.append("")
    if rp.get("outside_band"):
        lo, hi = data["spec"]["drive"]["band_hz"]
        lines += [f"**Outside the drive band {lo:g}-{hi:g} Hz**: the as-built resonance of "
                  + ", ".join(rp["outside_band"]) + " moved its tone beyond the band; its "
                  "tone is the band edge nearest to it (drive.band_hz limits the piezo's "
                  "drive).", ""]
    if rp.get("split_steps"):
        lines += ["### Steps split", "",
                  "The acceleration limit would have lowered these steps' tones further than "
                  "the plan's verified drive; each plays as sub-steps of neighbouring tones, "
                  "one after the other:", ""]
        lines += [f"- {k} -> {', '.join(v)}" for k, v in rp["split_steps"].items()] + [""]
    if rp["inseparable"]:
        lines += ["### Impacters no drive can tell apart (the re-plan fails)", ""]
        lines += [f"- {c['message']}" for c in rp["inseparable"]] + [""]
    return lines
