"""Trimming a fabricated chip: one-way moves of its resonances that make every pair separable.

After fabrication a lab measures every impacter's resonance (``vibroplan calibrate``).
Where two that must be told apart came too close, a cut can still move one of them -- one
way only: removing plate mass raises a resonance (``trim.direction: up``), cutting a beam
free of its anchor over a length lowers it (``down``) -- by at most ``trim.range_pct``.
:func:`plan_trim` chooses the targets with the fewest and smallest moves; :func:`cut_for`
says what to cut, through eqs. (2)-(4); the drive is then re-planned for the trimmed chip.
(:mod:`planner.afterfab.separations` says when two resonances can be told apart).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from planner.afterfab.separations import Separations
from planner.planfile.reader import PlanRecord
from planner.planning.result import Plan
from planner.arrayspec import TrimSpec

#: Relative tolerance of "already separable": a move smaller than this is no move [-].
MOVE_TOL = 1e-9
#: Passes of :func:`plan_trim` over the impacters (each pass clears what the previous
#: moves crossed; two suffice on the default plan's chips).
MAX_PASSES = 8


@dataclass
class TrimPlan:
    """Targets for one chip.

    Attributes
    ----------
    measured, target : dict
        Impacter id -> resonance measured / to trim to [Hz].
    moved : list of str
        The impacters to trim, in id order.
    failures : list of dict
        Why the chip cannot be made separable within the range: ``impacter``, ``why``,
        and the ``needed_pct`` move.
    """

    measured: dict
    target: dict
    moved: list = field(default_factory=list)
    failures: list = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.failures

    def change_pct(self, n: str) -> float:
        return 100.0 * (self.target[n] / self.measured[n] - 1.0)


def plan_trim(seps: Separations, measured: dict, pairs, *, range_pct=1.0, direction="up",
              precision_pct=0.1, used_pct=None) -> TrimPlan:
    """The fewest and smallest one-way moves that make every pair in ``pairs`` separable.

    Parameters
    ----------
    seps : Separations
        The plan's designs (:meth:`Separations.from_plan`).
    measured : dict
        Impacter id -> measured resonance [Hz].
    pairs : iterable of (str, str)
        Impacters that must be told apart (the plan's conflict graph).
    range_pct, direction, precision_pct
        ``trim:`` of the spec.
    used_pct : dict, optional
        Impacter id -> how far earlier passes already moved it [%]: the range left to it
        is ``range_pct`` less that.

    Returns
    -------
    TrimPlan

    Notes
    -----
    ``up``: the impacters are taken in rising order of resonance; each one that sits
    too close above a lower one it must be told apart from (at that one's target) is
    raised just enough.  Raising only the upper member of a pair is the smallest move
    that keeps the order, and each move is the least that clears every lower
    neighbour, so the total is minimal for that order; a move that would exceed the
    range is a failure naming the impacter and the move it needed.  ``down`` is the
    mirror image (falling order, the lower member lowered).
    """
    if direction not in ("up", "down"):
        raise ValueError(f"direction must be 'up' or 'down', {direction!r} was given")
    index = {n: k for k, n in enumerate(seps.ids)}
    missing = sorted(set(seps.ids) - set(measured))
    if missing:
        raise ValueError(f"no measured resonance for {', '.join(missing)}")
    used = used_pct or {}
    prec = precision_pct / 100.0
    partners = {n: set() for n in seps.ids}
    for a, b in pairs:
        partners[a].add(b)
        partners[b].add(a)
    target = {n: float(measured[n]) for n in seps.ids}
    up = direction == "up"
    failed = {}
    # passes until nothing moves: a raised impacter can pass one above it, which the
    # next pass then clears (every move is one way, so the passes end)
    for _ in range(MAX_PASSES):
        changed = False
        order = sorted(seps.ids, key=lambda n: target[n], reverse=not up)
        for k, n in enumerate(order):
            j = index[n]
            need = target[n]
            for m in order[:k]:
                if m not in partners[n]:
                    continue
                i = index[m]
                if up:
                    # n above m: at least m's target plus the separation
                    need = max(need, seps.needed(i, j, target[m], prec))
                else:
                    # mirror: n below m, at most the highest that keeps m far enough above
                    need = min(need, _highest_below(seps, j, i, target[m], prec))
            move = need / measured[n] - 1.0
            if (need - target[n]) * (1 if up else -1) > MOVE_TOL * target[n]:
                # what earlier passes moved it counts against the range
                if abs(move) > (range_pct - abs(used.get(n, 0.0))) / 100.0:
                    failed[n] = move
                    continue
                target[n] = need
                changed = True
        if not changed:
            break
    failures = [{"impacter": n, "needed_pct": 100.0 * mv,
                 "why": f"needs a {100 * mv:+.2f} % move to clear its neighbours, beyond "
                        f"trim.range_pct {range_pct:g}"
                        + (f" (earlier passes moved it {used[n]:+.2f} %)" if used.get(n) else "")}
                for n, mv in sorted(failed.items())]
    # the outcome, checked pair by pair (without the trim margin)
    for a, b in sorted({tuple(sorted(p)) for p in pairs}):
        if a in failed or b in failed:
            continue
        if not seps.separable(index[a], index[b], target[a], target[b]):
            failures.append({"impacter": a, "needed_pct": None,
                             "why": f"{a} and {b} stay too close ({target[a]:.0f} and "
                                    f"{target[b]:.0f} Hz) after every move the range allows"})
    moved = sorted(n for n in seps.ids if abs(target[n] / measured[n] - 1.0) > MOVE_TOL)
    return TrimPlan({n: float(measured[n]) for n in seps.ids}, target, moved, failures)


def _highest_below(seps, j, i, nu_i, prec):
    """The highest resonance [Hz] ``j`` may have below ``i`` at ``nu_i`` (bisection on
    :meth:`Separations.needed`, which rises with its argument)."""
    lo, hi = 0.5 * nu_i, nu_i
    if seps.needed(j, i, lo, prec) > nu_i:
        return lo
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        if seps.needed(j, i, mid, prec) <= nu_i:
            lo = mid
        else:
            hi = mid
    return lo


def cut_for(record: dict, measured_hz: float, target_hz: float, process, direction: str):
    """What to cut from one impacter to move its resonance from ``measured_hz`` to
    ``target_hz`` [Hz]: (plate area [m^2], beam length [m]), the other one 0.

    ``up``: nu ~ sqrt(k/m), so m' = m (measured / target)^2 and the plate loses
    (m - m') / (rho t) of its area (eq. (2)).  ``down``: the beams are freed from the
    anchor over a length dl, k ~ (w / (l + dl))^3 (eq. (4)) while the freed beam still
    moves (m grows by 2 rho h w dl): dl solves nu(l + dl) / nu(l) = target / measured
    on the design geometry.

    Parameters
    ----------
    record : dict
        The impacter's plan.json record (``mass_kg``, ``geometry``).
    process : planner.config.ProcessConfig
        The spec's process (density, mass thickness, beam height).
    """
    from scipy import optimize

    ratio = target_hz / measured_hz
    g = record["geometry"]
    m = record["mass_kg"]
    rho = process.density_kg_m3
    t = process.mass_thickness_um * 1e-6
    h = process.beam_height_um * 1e-6
    if direction == "up":
        if ratio < 1.0:
            raise ValueError("a trim up cannot lower a resonance")
        dm = m * (1.0 - 1.0 / ratio ** 2)
        return dm / (rho * t), 0.0
    if ratio > 1.0:
        raise ValueError("a trim down cannot raise a resonance")
    w, l, area = g["width_m"], g["length_m"], g["area_m2"]
    c_wl = 2.0 * rho * h

    def nu_rel(dl):
        # k ~ 1/l^3 at fixed w; m = rho t A + 2 rho h w l
        m0 = rho * t * area + c_wl * w * l
        m1 = rho * t * area + c_wl * w * (l + dl)
        return math.sqrt((l / (l + dl)) ** 3 * m0 / m1)

    if ratio == 1.0:
        return 0.0, 0.0
    dl = optimize.brentq(lambda x: nu_rel(x) - ratio, 0.0, l, xtol=1e-15)
    return 0.0, dl


#: trim.csv's columns (pinned by issue 26).
TRIM_COLUMNS = ("impacter", "measured_hz", "target_hz", "change_pct", "cut_area_um2",
                "cut_length_um")


def trim_rows(plan, tp: TrimPlan, direction: str) -> list:
    """trim.csv's rows, one per impacter in the plan's order: what to cut to move its
    measured resonance to its target (zeros where it stays)."""
    process = plan.spec.process
    rows = []
    for rec in plan.impacters:
        n = rec.id
        meas, target = tp.measured[n], tp.target[n]
        area = length = 0.0
        if n in tp.moved:
            record = {"mass_kg": rec.mass_kg,
                      "geometry": {"area_m2": rec.geometry.area_m2,
                                   "width_m": rec.geometry.width_m,
                                   "length_m": rec.geometry.length_m}}
            area, length = cut_for(record, meas, target, process, direction)
        rows.append({"impacter": n, "measured_hz": meas, "target_hz": target,
                     "change_pct": tp.change_pct(n), "cut_area_um2": area * 1e12,
                     "cut_length_um": length * 1e6})
    return rows


def write_trim_csv(rows, path) -> None:
    """trim.csv (:data:`TRIM_COLUMNS`), 9 significant digits."""
    with open(path, "w", encoding="utf-8", newline="") as fh:
        fh.write(",".join(TRIM_COLUMNS) + "\n")
        for r in rows:
            fh.write(",".join(r["impacter"] if c == "impacter" else f"{r[c]:.9g}"
                              for c in TRIM_COLUMNS) + "\n")


def trimmed_resonances(tp: TrimPlan, precision_pct: float, rng) -> dict:
    """Impacter id -> its resonance after the trims [Hz]: each moved one lands at its
    target times (1 + precision z / 100), z standard normal from ``rng`` (one draw per
    impacter in id order, moved or not, so the same seed gives the same errors whatever
    moves); the others stay as measured."""
    ids = sorted(tp.target)
    z = rng.standard_normal(len(ids))
    return {n: (tp.target[n] * (1.0 + precision_pct / 100.0 * float(zi)) if n in tp.moved
                else tp.measured[n]) for n, zi in zip(ids, z)}


def trim_models(impacters: dict, ratios: dict, direction: str) -> dict:
    """The models after trims: node -> model, each trimmed one's natural frequency times
    its ratio [-] (both halves of a pair alike).  ``up`` removes plate mass (m / r^2,
    k kept: the kick each impact gives falls with the mass), ``down`` frees beam from the
    anchor (k r^2 to first order, m kept)."""
    import model

    def trimmed(imp, r):
        if direction == "up":
            return model.Impacter(imp.mass / (r * r), imp.stiffness, imp.damping, imp.gap,
                                  imp.impact_angle, imp.restitution, imp.geometry)
        return model.Impacter(imp.mass, imp.stiffness * r * r, imp.damping, imp.gap,
                              imp.impact_angle, imp.restitution, imp.geometry)

    out = dict(impacters)
    for n, r in ratios.items():
        parts = model.halves(impacters[n])
        new = [trimmed(h, r) for h, _ in parts]
        out[n] = new[0] if len(new) == 1 else model.pair_of(*new)
    return out


@dataclass(frozen=True)
class TrimResult:
    """A chip's trims and the drive re-planned for it.

    Attributes
    ----------
    trims : TrimPlan
        Targets, the impacters to trim and why a chip cannot be trimmed.
    rows : list of dict
        trim.csv's rows (:func:`planner.afterfab.trim.trim_rows`).
    spec : TrimSpec
        The trim settings used.
    plan : Plan or None
        The re-plan of the trimmed chip (None when it cannot be trimmed); its ``data``
        carries a ``trim`` block.
    passed : bool
        The chip can be trimmed and the re-planned drive verifies on the trimmed models
        (and on the targets' models).
    """

    trims: TrimPlan
    rows: list
    spec: TrimSpec
    plan: Plan | None
    passed: bool


def scaled_measurements(measured: dict, resonances: dict) -> dict:
    """Id -> :class:`~planner.afterfab.measurement.Measurement` of ``measured`` with
    each pair's resonance at ``resonances[id]`` [Hz] (both halves moved by the same
    fraction), unchanged where ``resonances`` has none."""
    return {n: (m.scaled(resonances[n] / m.natural_frequency_hz) if n in resonances else m)
            for n, m in measured.items()}


@dataclass(frozen=True)
class TrimOutcome:
    """The passes of a trim sequence (:func:`trim_sequence`).

    Attributes
    ----------
    passes : list of TrimPlan
        Each pass's targets (from the measurement it started with).
    measured : dict
        Id -> the last measurement (:class:`~planner.afterfab.measurement.Measurement`).
    ratios : dict
        Id -> how far the trims moved each trimmed resonance in all, as the measurements
        say (last / first) [-].
    moved : list of str
        Every impacter trimmed in some pass.
    scrapped : list of dict
        Why the chip cannot be trimmed (a pass whose moves exceed what is left of the
        range): ``impacter``, ``why``, ``needed_pct``; empty when it can be.
    """

    passes: list
    measured: dict
    ratios: dict
    moved: list
    scrapped: list

    @property
    def separable(self) -> bool:
        """The last measurement has every pair separable (no pass needed more)."""
        return not self.scrapped and (not self.passes or not self.passes[-1].moved)


def trim_sequence(seps: Separations, measured: dict, pairs, spec: TrimSpec, *, cut,
                  measure_again, precision_pct=None, passes=None) -> TrimOutcome:
    """Measure, trim, measure again: the loop a lab runs on a chip whose pairs collide,
    used by ``vibroplan yield --trim`` (a simulated chip) and, for one pass, by
    :func:`trim_chip`.

    Each pass chooses the trims from the last measurement (:func:`plan_trim`, within
    what earlier passes left of ``trim.range_pct``), cuts them (``cut``), and measures
    the chip again (``measure_again``); the sequence ends when a measurement has every
    pair separable, when ``passes`` (``trim.passes``) are used, or when a pass needs more
    than the range allows (the chip is scrapped, with why).

    Parameters
    ----------
    seps : Separations
        The designs' silent bands and tone windows.
    measured : dict
        Id -> :class:`~planner.afterfab.measurement.Measurement`, the chip as first
        measured.
    pairs : iterable of (str, str)
        The impacters the steps must tell apart.
    spec : TrimSpec
        ``trim:`` of the spec.
    cut : callable(TrimPlan, k) -> None
        Cuts pass ``k``'s trims on the chip (each lands off its target by the trim's
        precision: the chip's business).
    measure_again : callable(k) -> dict
        The chip measured after pass ``k``: id -> Measurement.
    precision_pct, passes : optional
        Override ``spec.precision_pct`` and ``spec.passes``.

    Returns
    -------
    TrimOutcome
    """
    precision = spec.precision_pct if precision_pct is None else precision_pct
    passes = spec.passes if passes is None else int(passes)
    first = measured
    done, used, moved = [], {}, []
    for k in range(passes):
        mean = {n: m.natural_frequency_hz for n, m in measured.items()}
        tp = plan_trim(seps, mean, pairs, range_pct=spec.range_pct, direction=spec.direction,
                       precision_pct=precision, used_pct=used)
        if not tp.ok:
            return TrimOutcome(done, measured, _ratios(first, measured, moved), moved,
                               tp.failures)
        done.append(tp)
        if not tp.moved:
            break
        cut(tp, k)
        measured = measure_again(k)
        for n in tp.moved:
            if n not in moved:
                moved.append(n)
            used[n] = 100.0 * (measured[n].natural_frequency_hz
                               / first[n].natural_frequency_hz - 1.0)
    return TrimOutcome(done, measured, _ratios(first, measured, moved), sorted(moved), [])


def _ratios(first, last, moved):
    return {n: last[n].natural_frequency_hz / first[n].natural_frequency_hz for n in moved}


def trim_chip(plan: PlanRecord, measured: dict, *, seed: int | None = None,
              spec: TrimSpec | None = None, progress=None) -> TrimResult:
    """Trims for a measured chip, and its drive re-planned and verified.

    One pass of the trim sequence (:func:`trim_sequence`): the trims are chosen from the
    measurement, the drive re-planned for the targets on the chip's as-built models with
    the trims applied (:func:`trim_models`), and that drive verified, in memory, on the
    *trimmed models*: every trimmed resonance where a cut really puts it, its target off
    by ``trim.precision_pct`` (one normal draw per trim, seeded).  After cutting, a lab
    measures the chip again and runs ``vibroplan trim`` again if a pair still collides
    (``trim.passes`` is what ``yield --trim`` simulates).

    Parameters
    ----------
    plan : PlanRecord
        The plan the chip was made by.
    measured : dict
        Id -> :class:`~planner.afterfab.measurement.Measurement`
        (:func:`~planner.afterfab.measurement.read_measured`): every impacter of the plan
        (a :class:`~planner.core.errors.SpecError` names those without a measurement).
    seed : int, optional
        Seeds the trims' errors and the drive's phases (default: the plan's).
    spec : TrimSpec, optional
        Default: the plan's ``trim:`` section, else :class:`planner.arrayspec.TrimSpec`'s
        defaults.
    """
    from planner.afterfab.checks import check_drive
    from planner.afterfab.drive import must_differ
    from planner.afterfab.replan import chip_models, replan
    from planner.afterfab.separations import separations_of
    from planner.planning.settings import plan_settings

    missing = [r.id for r in plan.impacters if r.id not in measured]
    if missing:
        # a design value is no measurement of this chip: trim.csv would state it as
        # measured_hz and the trims would be chosen against a resonance nobody measured
        from planner.core.errors import SpecError

        raise SpecError(f"no measured resonance for {', '.join(missing)}: a trim is chosen "
                        "from every impacter's measured resonance; measure them (vibroplan "
                        "calibrate) and give each a row", path="measured.csv")
    seed = plan.seed if seed is None else int(seed)
    settings = plan_settings(plan, seed)
    spec = spec or settings.trim
    models = chip_models(plan, measured)
    seps = separations_of(plan, settings)
    mean = {n: m.natural_frequency_hz for n, m in measured.items()}
    tp = plan_trim(seps, mean, must_differ(settings.steps), range_pct=spec.range_pct,
                   direction=spec.direction, precision_pct=spec.precision_pct)
    rows = trim_rows(plan, tp, spec.direction)
    if not tp.ok:
        return TrimResult(tp, rows, spec, None, False)
    aimed = trim_models(models.impacters, {n: tp.target[n] / tp.measured[n] for n in tp.moved},
                        spec.direction)
    result = replan(plan, scaled_measurements(measured, tp.target), settings=settings,
                    progress=progress, remeasure=tp.moved,
                    models=dataclasses.replace(models, impacters=aimed))
    # where the cuts really put the resonances: the targets, off by the trim precision
    rng = np.random.default_rng(np.random.SeedSequence([seed, 26]))
    actual = trimmed_resonances(tp, spec.precision_pct, rng)
    true = trim_models(models.impacters, {n: actual[n] / tp.measured[n] for n in tp.moved},
                       spec.direction)
    got = check_drive(settings, result.run_steps, result.waveforms, result.dwells,
                      {r.node: true[r.id] for r in plan.impacters}, models.sliders)
    trim = {
        "direction": spec.direction, "range_pct": spec.range_pct,
        "precision_pct": spec.precision_pct, "seed": seed,
        "moved": [{k: r[k] for k in ("impacter", "measured_hz", "target_hz", "change_pct")}
                  | {"trimmed_hz": actual[r["impacter"]]}
                  for r in rows if r["impacter"] in tp.moved],
        "trimmed_models": {"passed": bool(got["passed"]), "failures": got["failures"]}}
    result = dataclasses.replace(result, data={**result.data, "trim": trim})
    return TrimResult(tp, rows, spec, result, bool(result.passed and got["passed"]))
