"""As-built re-plan: a new drive for a fabricated chip from its measured resonances.

After fabrication an impacter's geometry is fixed, but its drive is not.  Given a plan
(its plan.json) and each impacter's measured natural frequency (and optionally its
quality factor and gap), this module builds the as-built model of every impacter and
re-plans the drive only:

1. **as-built models** (:func:`as_built_parameters`): the design's mass m; stiffness
   k = m (2 pi nu_n)^2 from the measured nu_n; damping b = m 2 pi nu_n / Q when a
   quality factor is given, else the design's; the measured gap when given, else the
   design's;
2. **tones** (:func:`choose_tones`): each impacter's tone is its original tone scaled by
   the measured / designed natural-frequency ratio (the design's operating point
   relative to its resonance is kept), snapped to the spec's channel grid.  The
   candidates are the grid channels within :data:`TONE_WINDOW` of it at which the
   as-built impacter responds from every x0 and every impacter that must be idle while
   it plays (the conflict graph) does not respond from any x0;
3. **local repair**: every step is re-synthesised and re-verified on the as-built
   models (:func:`planner.planning.verify.check_step`); each failure moves one tone to
   its next candidate (an idle impacter that responds: the nearest tone of its step
   moves away from it; a slow slider: its tone moves to the candidate it responds to
   most strongly), and only the steps whose tones changed are simulated again;
4. **inseparable impacters**: an impacter with no candidate because another one
   responds at every tone it responds at can no longer be told apart from it.  When
   only the implicit single-impacter steps (``independent: true``) separate the two,
   they fall back to being driven together (their two single steps become one);
   when a scene step of the spec separates them, or both are on the same device, the
   conflict is reported by name and the plan fails.

The original plan's drive is verified on the as-built models too, so that the report
can say whether the chip needed the re-plan.  :func:`replan_chip` is the per-chip entry
point for a yield study.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd

import model
from model import Drive
from planner.assign import Assignment, conflict_graph, guard_violations
from planner.nodes import Node, device_key, node_key
from planner.planning.drives import limit_acceleration, synthesize_steps
from planner.planning.record import build_record, round_floats
from planner.planning.repair import settle_by_step
from planner.planning.result import Plan
from planner.planning.scenes import simulate_scenes
from planner.planning.plan_file import PlanRecord, drives
from planner.planning.settings import resolve_settings, tone_amplitudes
from planner.planning.verify import (IDLE_MOVES, IDLE_RESPONSE, TOO_SLOW, check_step,
                                     coupling_matrix, x0_grid)
from planner.spec import Step, channel_grid
from planner.units import UM

#: Columns of measured.csv: required, optional, and ignored (calibrate's uncertainties).
MEASURED_REQUIRED = ("impacter", "natural_frequency_hz")
MEASURED_OPTIONAL = ("quality_factor", "gap_um")
#: Relative half-width of the candidate tones around an impacter's scaled tone [-]:
#: wider than any response band of the default plan (~300-1200 Hz at 4-36 kHz).
TONE_WINDOW = 0.05
#: An idle impacter is screened at a candidate tone only when the tone is within this
#: relative distance of its as-built resonance [-] (further off, an impact oscillator
#: in this band does not respond; the full verification checks every step anyway).
SCREEN_WINDOW = 0.15
#: Candidate tones between channels: each channel interval near where an impacter
#: responds is divided in this many (the synthesis snaps every tone to its loop grid
#: anyway; a channel is the nearest one).  1 keeps the tones on the channel grid.
TONE_SUBDIVISION = 4
#: Rounds of verify-and-move after the first verification.
REPAIR_ROUNDS = 6
#: Scene of the implicit single-impacter steps (planner.assign.plan_steps).
INDEPENDENT = "independent"


# --------------------------------------------------------------------------- inputs

def read_measured(path, impacter_ids) -> dict:
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

    Returns
    -------
    dict
        Impacter id -> ``{"natural_frequency_hz": [Hz], "quality_factor": [-] or None,
        "gap_m": [m] or None}``.

    Raises
    ------
    planner.errors.SpecError
        ``FILE: row N, column C: ...`` (N the 1-based line) for a missing or unknown
        column, an unknown or repeated impacter, a value that is not a finite number, or
        a frequency, quality factor or gap <= 0.
    """
    from planner.calibrate import csv_number, read_csv_rows

    known = set(impacter_ids)
    # calibrate writes uncertainties beside the values: accepted and left alone
    header_line, header, rows, fail = read_csv_rows(
        path, MEASURED_REQUIRED, MEASURED_OPTIONAL, what="measured.csv",
        ignore=lambda c: c.endswith("_std") or c.endswith("_std_hz"))
    out, first_line = {}, {}
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
        if name in out:
            raise fail(line, "impacter", f"{name} measured twice (rows {first_line[name]} "
                                         f"and {line})")
        rec = {"natural_frequency_hz": None, "quality_factor": None, "gap_m": None}
        for column in MEASURED_REQUIRED[1:] + MEASURED_OPTIONAL:
            if column not in header:
                continue
            text = values[column]
            if text == "" and column in MEASURED_OPTIONAL:
                continue        # an optional value left blank: the design's
            x = csv_number(text, line, column, fail)
            if x <= 0:
                raise fail(line, column, f"must be > 0, {text} was given")
            if column == "natural_frequency_hz":
                rec["natural_frequency_hz"] = x
            elif column == "quality_factor":
                rec["quality_factor"] = x
            else:
                rec["gap_m"] = x * UM
        out[name] = rec
        first_line[name] = line
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
    return out


def _impacter(rec, params=None):
    """model.Impacter of a plan's impacter record, with as-built ``params``."""
    p = params or {}
    return model.Impacter(rec.mass_kg,
                          float(p.get("stiffness_n_per_m", rec.stiffness_n_per_m)),
                          float(p.get("damping_ns_per_m", rec.damping_ns_per_m)),
                          float(p.get("gap_m", rec.gap_m)),
                          rec.impact_angle_rad, rec.restitution)


# --------------------------------------------------------------------------- records

@dataclass(frozen=True)
class Conflict:
    """Two impacters that can no longer be told apart on this chip.

    Attributes
    ----------
    driven, idle : str
        ``driven`` must play while ``idle`` is silent, and ``idle`` responds at every
        tone near ``driven``'s resonance at which ``driven`` responds.
    driven_hz, idle_hz : float
        Their as-built natural frequencies [Hz].
    steps : tuple of str
        The steps (``scene/name``) that drive one and not the other.
    resolved : bool
        Whether they fell back to being driven together.
    reason : str
    """

    driven: str
    idle: str
    driven_hz: float
    idle_hz: float
    steps: tuple
    resolved: bool
    reason: str

    def __str__(self):
        return (f"{self.driven} (as built {self.driven_hz:.0f} Hz) and {self.idle} "
                f"({self.idle_hz:.0f} Hz) cannot be told apart: {self.reason}")


@dataclass
class _Tones:
    """Candidate tones of every node and the responses already simulated."""

    settings: object
    models: dict
    window: float
    own: dict = field(default_factory=dict)        # (node, tone) -> r over x0 [N]
    idle: dict = field(default_factory=dict)       # (node, tone) -> responds from some x0

    def amplitude(self, t):
        return float(tone_amplitudes(self.settings, [t])[0])

    def r_own(self, n, t):
        key = (n, t)
        if key not in self.own:
            imp = self.models[n]
            self.own[key] = model.responses(imp, Drive([t], [self.amplitude(t)]),
                                            x0_grid(imp, self.settings.x0_points),
                                            duration=self.window)
        return self.own[key]

    def responds(self, n, t):
        key = (n, t)
        if key not in self.idle:
            imp = self.models[n]
            r = model.responses(imp, Drive([t], [self.amplitude(t)]),
                                x0_grid(imp, self.settings.x0_points), duration=self.window,
                                stop_at_first=True)
            self.idle[key] = bool(np.any(r > 0))
        return self.idle[key]


def _active(step):
    return {Node(d, r).text for d, r in step.active_nodes()}


def _idle_while(steps, nodes):
    """Node -> {node that must be silent while it plays: step keys}."""
    out = {n: {} for n in nodes}
    for st in steps:
        active = _active(st) & set(nodes)
        for n in active:
            for m in nodes:
                if m not in active:
                    out[n].setdefault(m, []).append(st.key)
    return out


def choose_tones(settings, steps, plan_imps, nu_new, tones: _Tones, grid):
    """Candidate tones of every node, best first, and the blockers of those without one.

    Returns
    -------
    cands : dict
        Node -> list of tones [Hz] at which it responds from every x0 and no impacter
        that must be idle while it plays responds (closest to the scaled tone first).
    fallback : dict
        Node -> the tone to use when it has no candidate (its strongest response).
    blockers : dict
        Node -> {idle node: step keys} for nodes without a candidate.
    """
    nodes = sorted(plan_imps)
    must_idle = _idle_while(steps, nodes)
    cands, fallback, blockers = {}, {}, {}
    for n in nodes:
        rec = plan_imps[n]
        target = rec.frequency_hz * nu_new[n] / rec.natural_frequency_hz
        dist = np.abs(np.log(grid / target))
        near = [float(t) for t in grid[np.argsort(dist, kind="stable")]
                if abs(math.log(t / target)) <= TONE_WINDOW]
        if not near:   # scaled tone beyond the band: the band edge closest to it
            near = [float(grid[int(np.argmin(dist))])]
        responding = [t for t in near if np.min(tones.r_own(n, t)) > 0]
        if TONE_SUBDIVISION > 1:
            # the fixed designs respond from every x0 over only ~1-2 channels (100-200 Hz
            # at 30 kHz in the default plan): refine between channels around where it
            # responds (or around its strongest response) so that there is a choice
            seeds = responding or [max(near, key=lambda t: float(np.max(tones.r_own(n, t))))]
            lo_hz, hi_hz = grid[0], grid[-1]
            fine = set()
            for t in seeds:
                i = int(np.argmin(np.abs(grid - t)))
                width = float(grid[min(i + 1, grid.size - 1)] - grid[max(i - 1, 0)]) / 2
                for k in range(-TONE_SUBDIVISION + 1, TONE_SUBDIVISION):
                    f = round(t + k * width / TONE_SUBDIVISION, 6)
                    if lo_hz <= f <= hi_hz and f not in near:
                        fine.add(f)
            extra = [f for f in fine if np.min(tones.r_own(n, f)) > 0]
            responding = sorted(set(responding) | set(extra),
                                key=lambda t: (abs(math.log(t / target)), t))
        ok, blocked = [], {}
        for t in responding:
            hit = [m for m in must_idle[n]
                   if abs(math.log(t / nu_new[m])) <= SCREEN_WINDOW and tones.responds(m, t)]
            if hit:
                blocked[t] = hit
            else:
                ok.append(t)
        cands[n] = ok
        if responding:
            fallback[n] = max(responding, key=lambda t: float(np.min(tones.r_own(n, t))))
        else:
            fallback[n] = max(near, key=lambda t: float(np.max(tones.r_own(n, t))))
        if not ok:
            if responding:
                common = set.intersection(*(set(v) for v in blocked.values()))
                who = common or set(blocked.get(fallback[n], ()))
            else:
                who = set()
            blockers[n] = {m: tuple(must_idle[n][m]) for m in sorted(who, key=node_key)}
    return cands, fallback, blockers


def _merge_independent(steps, pairs):
    """Steps with the single-impacter steps of each group of ``pairs`` merged into one
    step driving the group together (re-indexed)."""
    parent = {}

    def find(x):
        parent.setdefault(x, x)
        while parent[x] != x:
            x = parent[x]
        return x

    for a, b in pairs:
        ra, rb = find(a), find(b)
        if ra != rb:
            parent[max(ra, rb, key=node_key)] = min(ra, rb, key=node_key)
    groups = {}
    for x in list(parent):
        groups.setdefault(find(x), []).append(x)
    merged_into = {m: sorted(g, key=node_key) for g in groups.values() for m in g}
    out, done = [], set()
    for st in steps:
        if st.scene == INDEPENDENT and st.name in merged_into:
            group = merged_into[st.name]
            if group[0] in done:
                continue
            done.add(group[0])
            nodes = [Node.parse(n) for n in group]
            name = "+".join(group) if len(group) <= 3 else f"{group[0]}+{len(group) - 1}more"
            st = Step(INDEPENDENT, name, 0, st.duration_s,
                      tuple(n.device for n in nodes if n.direction == "forward"),
                      tuple(n.device for n in nodes if n.direction == "backward"))
        out.append(st)
    return tuple(Step(s.scene, s.name, i, s.duration_s, tuple(s.forward), tuple(s.backward))
                 for i, s in enumerate(out))


#: Why a pair found by the verification (not the screening) cannot be told apart.
_VERIFIED = ("{m} responds in a step that drives {n} alone, and {n} has no candidate tone "
             "left further from {m}'s resonance (found by the verification)")
_SCREENED = ("{m} responds at every tone within {w:.0%} of {n}'s scaled tone at which {n} "
             "responds from every x0")


def _resolve_conflicts(steps, blockers, nu_new, why=_SCREENED):
    """(pairs to drive together, Conflict records); a pair is reported once."""
    pairs, conflicts, seen = [], [], set()
    for n, who in sorted(blockers.items()):
        for m, keys in who.items():
            if frozenset((n, m)) in seen:
                continue
            seen.add(frozenset((n, m)))
            scene_steps = [k for k in keys if not k.startswith(INDEPENDENT + "/")]
            same_device = Node.parse(n).device == Node.parse(m).device
            if same_device:
                reason = ("they are the two impacters of one device, which are never driven "
                          "together")
            elif scene_steps:
                many = len(scene_steps) > 1
                reason = (f"the spec's step{'s' if many else ''} {', '.join(scene_steps[:5])} "
                          f"drive{'' if many else 's'} {n} with {m} idle")
            else:
                reason = ("only the single-impacter steps separate them: they are driven "
                          "together instead (one step drives both)")
            reason = why.format(n=n, m=m, w=TONE_WINDOW) + "; " + reason
            ok = not same_device and not scene_steps
            if ok:
                pairs.append((n, m))
            conflicts.append(Conflict(n, m, nu_new[n], nu_new[m], tuple(keys), ok, reason))
    return pairs, conflicts


def _share_tones(steps, cands, chosen):
    """Impacters driven together after a collision share one tone where every one of
    them responds (one tone, no beating of two close ones that stirs idle impacters)."""
    for st in steps:
        if st.scene != INDEPENDENT:
            continue
        group = sorted(_active(st) & set(chosen), key=node_key)
        if len(group) < 2:
            continue
        common = [t for t in cands.get(group[0], ())
                  if all(t in cands.get(m, ()) for m in group[1:])]
        if common:
            for m in group:
                chosen[m] = common[0]


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
        settings = resolve_settings(plan.loaded, plan.seed)
    params = as_built_parameters(plan, as_built)
    models = {r.id: _impacter(r, params[r.id]) for r in plan.impacters}
    devices = sorted({Node.parse(n).device for n in models}, key=device_key)
    sliders = {d: settings.sliders[d] for d in devices}
    waves = drives(plan)
    rows = []
    for st in plan.steps:
        rows += check_step(settings, st.step, waves[st.key], models, sliders)[0]
    return bool(rows) and all(r["passed"] for r in rows), rows


# --------------------------------------------------------------------------- the re-plan

def _design_like(rec, imp, tone, r_own):
    """A DesignResult standing for the as-built impacter (the record, figures and the
    coupling read it like a design)."""
    from planner.designer.result import DesignResult

    g = rec.geometry
    geometry = model.Geometry(g.area_m2, g.width_m, g.length_m, imp.gap)
    imp = model.Impacter(imp.mass, imp.stiffness, imp.damping, imp.gap, imp.impact_angle,
                         imp.restitution, geometry)
    x0s = x0_grid(imp, len(r_own))
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


def replan(plan: PlanRecord, measured, *, seed=None, progress=None, original=None,
           record=True):
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
    seed = plan.seed if seed is None else int(seed)
    loaded = plan.loaded
    settings = resolve_settings(loaded, seed)
    plan_imps = {r.id: r for r in plan.impacters}
    params = as_built_parameters(plan, measured)
    models = {n: _impacter(plan_imps[n], params[n]) for n in plan_imps}
    nu_new = {n: params[n]["natural_frequency_hz"] for n in plan_imps}
    devices = sorted({Node.parse(n).device for n in models}, key=device_key)
    sliders = {d: settings.sliders[d] for d in devices}

    # the original drive on this chip
    ts = time.perf_counter()
    tick("original", total=1)
    if original is None:
        orig_passed, orig_rows = verify_drive(plan, measured, settings)
    else:
        orig_passed, orig_rows = bool(original[0]), list(original[1])
    timings["original_drive"] = time.perf_counter() - ts

    # tones: candidates per impacter; inseparable pairs fall back or fail
    ts = time.perf_counter()
    grid = channel_grid(loaded.spec)
    tones = _Tones(settings, models, settings.window_s)
    # the plan's bursts as it sized and repaired them: a travel_um step's duration in
    # the spec is only its cap (60 ms for the default 5 x 5's position step, where the
    # plan runs 5.2 ms: with the cap every slider travels beyond max_travel_um)
    recorded = {st.key: st.duration_s for st in plan.steps}
    base_steps = tuple(replace(st, duration_s=recorded.get(st.key, st.duration_s))
                       for st in settings.steps)
    steps = base_steps
    cands, fallback, blockers = choose_tones(settings, steps, plan_imps, nu_new, tones, grid)
    pairs, conflicts = _resolve_conflicts(steps, blockers, nu_new)
    if pairs:
        steps = _merge_independent(base_steps, pairs)
        cands, fallback, blockers = choose_tones(settings, steps, plan_imps, nu_new, tones,
                                                 grid)
        _, more = _resolve_conflicts(steps, blockers, nu_new)
        conflicts += [c for c in more if not c.resolved]
    timings["tones"] = time.perf_counter() - ts

    chosen = {n: (cands[n][0] if cands[n] else fallback[n]) for n in plan_imps}
    _share_tones(steps, cands, chosen)
    tried = {n: {chosen[n]} for n in plan_imps}
    verified = {}          # (step key, index, tones) -> (rows, failures)
    rounds = []
    ts = time.perf_counter()
    for round_ in range(REPAIR_ROUNDS + 1):
        assignment = _assignment(loaded, steps, settings, chosen, grid, plan.lower_bound)
        # drive.max_acceleration_g holds for the re-planned drive as for the plan's
        waveforms, drive_notes = limit_acceleration(settings, synthesize_steps(settings, steps,
                                                                               assignment))
        ver_rows, failures = [], []
        tick("verify", total=len(steps))
        for st in steps:
            key = (st.key, st.index, tuple(np.round(waveforms[st.key].frequencies, 6)))
            if key not in verified:
                verified[key] = check_step(settings, st, waveforms[st.key], models, sliders)
            ver_rows += verified[key][0]
            failures += verified[key][1]
            tick("verify", st.key)
        failed = sum(1 for r in ver_rows if not r["passed"])
        rounds.append({"round": round_, "span": assignment.span, "failures": failed})
        if not failed or round_ == REPAIR_ROUNDS:
            break
        stuck = []
        moved = _move_tones(failures, steps, chosen, cands, tried, nu_new, tones, stuck,
                            speed=lambda n, st, t: _worst_speed(settings, st, chosen, n, t,
                                                                models, sliders))
        # an idle impacter that still responds to a tone that cannot move further from
        # it: the verification found a pair the single-tone screening did not
        must_idle = _idle_while(steps, sorted(plan_imps))
        found = {}
        for a, m in stuck:
            if m in must_idle[a] and not any({c.driven, c.idle} == {a, m} for c in conflicts):
                found.setdefault(a, {})[m] = tuple(must_idle[a][m])
        new_pairs, new_conf = _resolve_conflicts(steps, found, nu_new, _VERIFIED)
        # these merge only two impacters neither of which is driven with another yet:
        # chains of merges would leave whole rows not addressable one by one
        merged = {x for pr in pairs for x in pr}
        keep = []
        for c in new_conf:
            if c.resolved and ({c.driven, c.idle} & merged):
                c = Conflict(c.driven, c.idle, c.driven_hz, c.idle_hz, c.steps, False,
                             c.reason.split("; ")[0] + "; one of them is already driven "
                             "together with another impacter")
            elif c.resolved:
                merged |= {c.driven, c.idle}
            keep.append(c)
        new_pairs = [(c.driven, c.idle) for c in keep if c.resolved]
        conflicts += keep
        if new_pairs:
            pairs += new_pairs
            steps = _merge_independent(base_steps, pairs)
            cands, fallback, _ = choose_tones(settings, steps, plan_imps, nu_new, tones, grid)
            for n in {x for pr in new_pairs for x in pr}:
                chosen[n] = cands[n][0] if cands[n] else fallback[n]
                tried[n].add(chosen[n])
            _share_tones(steps, cands, chosen)
            moved = True
        if not moved:
            break
    timings["verify"] = time.perf_counter() - ts

    ts = time.perf_counter()
    designs = {n: _design_like(plan_imps[n], models[n], chosen[n],
                               tones.r_own(n, chosen[n])) for n in plan_imps}
    impacters = {n: d.impacter for n, d in designs.items()}
    if record:
        scene_rows = simulate_scenes(settings, steps, waveforms, impacters, sliders)
        coupling = coupling_matrix(impacters, sorted(set(assignment.frequencies.values())),
                                   settings, settings.single_step_s)
    else:   # a yield study verifies the drive on the chip's true models itself
        scene_rows, coupling = [], pd.DataFrame()
    timings["scenes_coupling"] = time.perf_counter() - ts
    ver = pd.DataFrame(ver_rows)
    passed = bool(ver["passed"].all()) and not any(not c.resolved for c in conflicts)
    # the plan.json contract's per-step motion keys: drive peaks (after the
    # acceleration limit), settle dwells and travels as verified on the as-built models
    motion = {"sizing": {}, "drive": drive_notes, "settle_s": settle_by_step(ver_rows),
              "repairs": [], "design_problems": []}
    data, impacter_recs, device_recs, step_recs = build_record(
        settings, steps, assignment, designs, sliders, waveforms, ver_rows, passed, rounds,
        scene_rows, motion)
    data["as_built"] = round_floats(params)
    data["replan"] = round_floats(_replan_record(plan, plan_imps, params, assignment,
                                                 orig_passed, orig_rows, conflicts, steps))
    lo, hi = settings.band_hz
    data["replan"]["outside_band"] = [
        n for n in sorted(plan_imps, key=node_key)
        if not lo <= plan_imps[n].frequency_hz * nu_new[n]
        / plan_imps[n].natural_frequency_hz <= hi]
    timings["total"] = time.perf_counter() - t0
    return Plan(
        impacters=pd.DataFrame(impacter_recs), devices=pd.DataFrame(device_recs),
        steps=pd.DataFrame(step_recs), verification=ver, coupling=coupling,
        scenes=pd.DataFrame(scene_rows), passed=passed, data=data, timings=timings,
        settings=settings, waveforms=waveforms, designs=designs, assignment=assignment,
        failures=tuple(failures))


def _assignment(loaded, steps, settings, chosen, grid, lower_bound):
    """An :class:`~planner.assign.Assignment` of the chosen tones (the conflict graph as
    before; each impacter's channel is the grid channel of its tone)."""
    graph, groups = conflict_graph(steps, settings.separation_channels, None,
                                   loaded.spec.drive.guard.ensemble_separation_channels)
    nodes = {n for g in groups.values() for n in g}
    channels = {n: int(np.argmin(np.abs(grid - chosen[n]))) for n in nodes}
    freqs = {n: float(chosen[n]) for n in nodes}
    lo = min(channels.values())
    coloring = {g: channels[members[0]] - lo for g, members in groups.items()}
    span = max(channels.values()) - lo + 1
    return Assignment(graph, groups, coloring, span, int(lower_bound), False,
                      "as-built", 0.0, 1, lo, channels, freqs,
                      guard_violations(steps, freqs, loaded.spec.drive.guard))


def _move_tones(failures, steps, chosen, cands, tried, nu_new, tones, stuck, speed=None):
    """Move one tone per failure to its next candidate; returns whether any moved.

    ``stuck`` collects (playing node, idle node) of every idle response that no tone
    could be moved away from.  ``speed(node, step, tone)``: the worst slider speed
    [m/s] of the node's device in that step with the node at that tone.
    """
    by_index = {st.index: st for st in steps}
    moved = set()

    def strength(n, t):
        return float(np.min(tones.r_own(n, t)))

    for fail in failures:
        st = by_index[fail.step]
        active = sorted(_active(st) & set(chosen))
        if not active:
            continue
        if fail.kind == TOO_SLOW:
            # a slow slider: its impacter's tone moves to the untried candidate that
            # moves the slider fastest from its worst x0 (this step's drive, this
            # device alone; the next round verifies everything)
            for n in (n for n in active if Node.parse(n).device == fail.device):
                opts = [t for t in cands.get(n, ()) if t not in tried[n]]
                if not opts or n in moved:
                    continue
                if speed is not None:
                    best = max(opts, key=lambda t, n=n: speed(n, st, t))
                else:
                    best = max(opts, key=lambda t, n=n: strength(n, t))
                chosen[n] = best
                tried[n].add(best)
                moved.add(n)
            continue
        # an idle impacter responds, or an idle slider moves: the playing tone nearest
        # to the idle impacter's resonance moves away from it (the next nearest if it
        # cannot)
        if fail.kind == IDLE_RESPONSE and fail.impacter in nu_new:
            idle = [fail.impacter]
        elif fail.kind == IDLE_MOVES:
            idle = [n for n in nu_new if Node.parse(n).device == fail.device]
        else:
            continue
        if not idle:
            continue
        ranked = sorted(((a, m) for a in active for m in idle),
                        key=lambda am: abs(math.log(chosen[am[0]] / nu_new[am[1]])))
        for a, m in ranked:
            if a in moved:
                break
            d0 = abs(math.log(chosen[a] / nu_new[m]))
            options = [t for t in cands.get(a, ())
                       if t not in tried[a] and abs(math.log(t / nu_new[m])) > d0]
            if options:
                chosen[a] = options[0]
                tried[a].add(options[0])
                moved.add(a)
                break
        else:
            if st.scene == INDEPENDENT and len(active) == 1:
                stuck.append(ranked[0])
    return bool(moved)


def _worst_speed(settings, step, chosen, node, tone, models, sliders):
    """Worst signed slider speed [m/s] over the x0 grid of ``node``'s device in ``step``
    with ``node`` at ``tone`` (the other tones as chosen)."""
    from planner.planning.verify import device_motion

    freqs = {**chosen, node: tone}
    waves, _ = limit_acceleration(
        settings, synthesize_steps(settings, [step], SimpleNamespace(frequencies=freqs)))
    wave = waves[step.key]
    drive = Drive(wave.frequencies, wave.amplitudes, wave.phases)
    dev = Node.parse(node).device
    own = {n: imp for n, imp in models.items() if Node.parse(n).device == dev}
    sign = Node.parse(node).sign
    speeds = [sign * device_motion(own, sliders[dev], drive, step.duration_s,
                                   {node: (x0, 0.0, False)})[0] / step.duration_s
              for x0 in x0_grid(models[node], settings.x0_points)]
    return float(min(speeds))


def _replan_record(plan, plan_imps, params, assignment, orig_passed, orig_rows,
                   conflicts, steps):
    moved = []
    for n in sorted(plan_imps, key=node_key):
        rec = plan_imps[n]
        # the design's resonance (a re-planned plan's impacters are as built already)
        nu0, nu1 = plan.design_natural_frequency_hz[n], params[n]["natural_frequency_hz"]
        f0, f1 = rec.frequency_hz, assignment.frequencies[n]
        moved.append({"id": n, "design_natural_frequency_hz": nu0,
                      "natural_frequency_hz": nu1, "natural_frequency_shift": nu1 / nu0 - 1,
                      "original_frequency_hz": f0, "frequency_hz": f1,
                      "original_channel": rec.channel,
                      "channel": assignment.channels[n], "tone_shift": f1 / f0 - 1})
    fails = [r for r in orig_rows if not r["passed"]]
    return {
        "moved": moved,
        "original_drive": {
            "passed": bool(orig_passed), "checks": len(orig_rows),
            "failed_checks": len(fails),
            "failures": [{"step": f"{r['scene']}/{r['step']}", "device": r["device"],
                          "cause": r["cause"]} for r in fails]},
        "inseparable": [{**asdict(c), "steps": list(c.steps), "message": str(c)}
                        for c in conflicts],
        "merged_steps": [st.key for st in steps
                         if st.scene == INDEPENDENT and "+" in st.name],
    }


def replan_chip(plan: PlanRecord, as_built: dict, seed=None, *, original=None, record=True):
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
    original, record :
        As :func:`replan`: the original drive's ``(passed, rows)`` when already known
        (not verified again), and False to skip the scenes and the coupling matrix
        (``vibroplan yield --replan`` passes both).

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
    result = replan(plan, as_built, seed=seed, original=original, record=record)
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
    from planner.planning.outputs import _fmt, _md_table

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
        rows.append([m["id"], _fmt(m["design_natural_frequency_hz"], ".1f"),
                     _fmt(m["natural_frequency_hz"], ".1f"),
                     _fmt(100 * m["natural_frequency_shift"], "+.2f"),
                     _fmt(m["original_frequency_hz"], ".1f"), _fmt(m["frequency_hz"], ".1f"),
                     _fmt(100 * m["tone_shift"], "+.2f"),
                     f"{m['original_channel']} -> {m['channel']}"])
    lines += ["### What moved", ""]
    lines += _md_table(["impacter", "design nu_n [Hz]", "as-built nu_n [Hz]", "shift [%]",
                        "original tone [Hz]", "new tone [Hz]", "tone shift [%]", "channel"],
                       rows)
    lines.append("")
    if rp.get("outside_band"):
        lo, hi = data["spec"]["drive"]["band_hz"]
        lines += [f"**Outside the drive band {lo:g}-{hi:g} Hz**: the as-built resonance of "
                  + ", ".join(rp["outside_band"]) + " moved its tone beyond the band; its "
                  "tone is the band edge nearest to it (drive.band_hz limits the piezo's "
                  "drive).", ""]
    if rp["inseparable"]:
        lines += ["### Impacters that can no longer be told apart", ""]
        for c in rp["inseparable"]:
            what = ("driven together" if c["resolved"] else "**unresolved: the plan fails**")
            lines.append(f"- {c['message']} ({what})")
        if rp["merged_steps"]:
            lines += ["", "Single-impacter steps merged (these impacters are now driven "
                      "together): " + ", ".join(rp["merged_steps"])]
        lines.append("")
    return lines
