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
import time
from dataclasses import dataclass, field

import numpy as np

from planner.afterfab.separations import Separations
from planner.planfile.reader import PlanRecord
from planner.planfile.schema import through_schema
from planner.planning.result import Plan
from planner.arrayspec import TrimSpec

#: Relative tolerance of "already separable": a move smaller than this is no move [-].
MOVE_TOL = 1e-9
#: Passes of :func:`plan_trim` over the impacters (each pass clears what the previous
#: moves crossed; two suffice on the default plan's chips).
MAX_PASSES = 8
#: Draws of the cuts' errors the odds of a trim are taken over (:func:`trim_odds`), each
#: a check of the re-planned drive by simulation on the trimmed models: 100 put the 95 %
#: interval of odds near 0.95 within about +-0.05 (Wilson) and cost ~0.15 s a draw per
#: device holding a trimmed impacter on the CLOSE test plan.
ODDS_DRAWS = 100
#: The odds' seed stream beside the chip's seed (issue 26's single draw was this stream's
#: first draw, and still is: ``trim.moved[].trimmed_hz``, ``trim.trimmed_models``).
ODDS_STREAM = 26


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


#: trim.csv's columns (pinned by issue 26; ``failed_draws`` added by issue 45: of the
#: odds' draws of the cuts' errors, those on which a failed check implicated the
#: impacter, blank when the chip cannot be trimmed).
TRIM_COLUMNS = ("impacter", "measured_hz", "target_hz", "change_pct", "cut_area_um2",
                "cut_length_um", "failed_draws")


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
    """trim.csv (:data:`TRIM_COLUMNS`), 9 significant digits; a count as an integer,
    blank where a row has none."""
    def cell(r, c):
        v = r.get(c)
        return ("" if v is None else v if c == "impacter" else str(v) if isinstance(v, int)
                else f"{v:.9g}")

    with open(path, "w", encoding="utf-8", newline="") as fh:
        fh.write(",".join(TRIM_COLUMNS) + "\n")
        fh.writelines(",".join(cell(r, c) for c in TRIM_COLUMNS) + "\n" for r in rows)


def trimmed_resonances(tp: TrimPlan, precision_pct: float, rng) -> dict:
    """Impacter id -> its resonance after the trims [Hz]: each moved one lands at its
    target times (1 + precision z / 100), z standard normal from ``rng`` (one draw per
    impacter in id order, moved or not, so the same seed gives the same errors whatever
    moves); the others stay as measured."""
    return landed(tp, precision_pct, rng.standard_normal(len(tp.target)))


def landed(tp: TrimPlan, precision_pct: float, z) -> dict:
    """Impacter id -> its resonance after the trims [Hz] for the standard normal errors
    ``z`` (ndarray, shape (n_impacters,), in id order): each moved one at its target times
    (1 + precision z / 100), the others as measured."""
    ids = sorted(tp.target)
    return {n: (tp.target[n] * (1.0 + precision_pct / 100.0 * float(zi)) if n in tp.moved
                else tp.measured[n]) for n, zi in zip(ids, z)}


def trim_models(impacters: dict, ratios: dict, direction: str) -> dict:
    """The models after trims: node -> model, each trimmed one's natural frequency times
    its ratio [-] (both halves of a pair alike).  ``up`` removes plate mass (m / r^2,
    k kept: the kick each impact gives falls with the mass), ``down`` frees beam from the
    anchor (k r^2 to first order, m kept)."""
    import model

    from planner.afterfab.as_built import resonance_times

    def trimmed(imp, r):
        if direction == "down":
            return resonance_times(imp, r)
        parts = [model.Impacter(h.mass / (r * r), h.stiffness, h.damping, h.gap,
                                h.impact_angle, h.restitution, h.geometry)
                 for h, _ in model.halves(imp)]
        return parts[0] if len(parts) == 1 else model.pair_of(*parts)

    out = dict(impacters)
    for n, r in ratios.items():
        out[n] = trimmed(impacters[n], r)
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
        The chip can be trimmed, the re-planned drive verifies on the targets' models,
        and its odds on the trimmed models (:class:`TrimOdds`) reach
        ``fabrication.target_yield``.
    odds : TrimOdds or None
        The share of the cuts' error draws on which the drive works (None when the chip
        cannot be trimmed).
    alternatives : tuple of dict
        Cuts that raise the odds where they fall short (:func:`trim_chip`), each with
        ``cut``, ``why``, ``moved``, ``targets_verify`` and ``odds`` (a
        :meth:`TrimOdds.as_record`).
    """

    trims: TrimPlan
    rows: list
    spec: TrimSpec
    plan: Plan | None
    passed: bool
    odds: TrimOdds | None = None
    alternatives: tuple = ()


def scaled_measurements(measured: dict, resonances: dict) -> dict:
    """Id -> :class:`~planner.afterfab.measurement.Measurement` of ``measured`` with
    each pair's resonance at ``resonances[id]`` [Hz] (both halves moved by the same
    fraction), unchanged where ``resonances`` has none."""
    return {n: (m.scaled(resonances[n] / m.natural_frequency_hz) if n in resonances else m)
            for n, m in measured.items()}


@dataclass(frozen=True)
class TrimPasses:
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
    refused : TrimPlan or None
        The pass that could not be made (its targets, its ``failures``: ``scrapped``);
        None when the chip can be trimmed.
    """

    passes: list
    measured: dict
    ratios: dict
    moved: list
    scrapped: list
    refused: TrimPlan | None = None

    @property
    def separable(self) -> bool:
        """The last measurement has every pair separable (no pass needed more)."""
        return not self.scrapped and (not self.passes or not self.passes[-1].moved)

    @property
    def last(self) -> TrimPlan | None:
        """The last pass chosen: the refused one, else the last made (None: no pass)."""
        return self.refused or (self.passes[-1] if self.passes else None)


def trim_sequence(seps: Separations, measured: dict, pairs, spec: TrimSpec, *, cut,
                  measure_again, precision_pct=None, passes=None) -> TrimPasses:
    """Measure, trim, measure again: the loop a lab runs on a chip whose pairs collide,
    used by the after-fabrication loop on a simulated chip (``vibroplan yield --trim``,
    its cuts made on the chip's truth) and, for one pass, by :func:`trim_chip` (the
    test floor, where the lab cuts afterwards).

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
    TrimPasses
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
            return TrimPasses(done, measured, _ratios(first, measured, moved), moved,
                              tp.failures, tp)
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
    return TrimPasses(done, measured, _ratios(first, measured, moved), sorted(moved), [])


def _ratios(first, last, moved):
    return {n: last[n].natural_frequency_hz / first[n].natural_frequency_hz for n in moved}


@dataclass(frozen=True)
class TrimOdds:
    """The odds that a trim's cuts leave a chip its re-planned drive works on
    (:func:`trim_odds`).

    Attributes
    ----------
    draws, passed : int
        Draws of the cuts' errors, and those on which every check of the drive passed on
        the trimmed models.
    target_yield : float
        ``fabrication.target_yield`` [-], what :attr:`share` must reach.
    failures : dict
        Check kind (:data:`planner.afterfab.checks.KINDS`) -> draws failing by it (the
        first draw counts every failed check's kind, the others the first failing
        step's: they stop there).
    implicated : dict
        Impacter id -> draws on which a failed check implicated it.
    separable, second_pass : int
        Draws on which every pair the steps must tell apart can still be told apart at
        the resonances the cuts gave (a re-plan after measuring again can place every
        tone), and on which it can be after a second trim pass within the range left
        (those draws included).
    first : dict
        The first draw's check: ``passed``, ``failures`` (kind -> failed checks) and
        ``resonances`` (id -> trimmed resonance [Hz]); issue 26's single draw.
    """

    draws: int
    passed: int
    target_yield: float
    failures: dict
    implicated: dict
    separable: int
    second_pass: int
    first: dict

    @property
    def share(self) -> float:
        return self.passed / self.draws if self.draws else 0.0

    @property
    def ci95(self) -> list:
        from planner.core.intervals import wilson_interval

        return wilson_interval(self.passed, self.draws)

    @property
    def meets_target(self) -> bool:
        return self.draws > 0 and self.share >= self.target_yield

    def as_record(self) -> dict:
        """plan.json's ``trim.odds``."""
        return {"draws": self.draws, "passed": self.passed, "share": self.share,
                "ci95": self.ci95, "target_yield": self.target_yield,
                "meets_target": self.meets_target, "failures": dict(self.failures),
                "implicated": dict(self.implicated),
                "after_measuring_again": {"separable": self.separable,
                                          "separable_after_second_pass": self.second_pass}}


def trim_odds(settings, plan: PlanRecord, drive, models, tp: TrimPlan, spec: TrimSpec,
              seps: Separations, pairs, seed: int, draws: int = ODDS_DRAWS) -> TrimOdds:
    """The share of the cuts' error draws on which a drive works on the trimmed chip.

    Each draw puts every trimmed resonance at its target off by ``spec.precision_pct``
    (standard normal errors, one per impacter in id order, seeded by ``seed``: the same
    inputs and seed give the same draws) and checks the drive on the trimmed models as
    ``vibroplan plan`` verifies one (:func:`planner.afterfab.checks.check_drive`).  No
    re-plan per draw: a lab cuts for one drive.  The devices that hold no trimmed
    impacter are the same on every draw: their per-step checks run once; each draw
    re-runs those of the devices that do, and the scenes (their dwells settle the whole
    chip).  When a device no trim touches fails, no draw can pass: the trimmed devices
    are then checked on the first draw only, and every draw counts the others'
    failures.

    Parameters
    ----------
    settings : Settings
        The plan's settings.
    plan : PlanRecord
        The plan the chip was made by (its impacters' nodes).
    drive : Plan
        The drive re-planned for the targets (``run_steps``, ``waveforms``, ``dwells``).
    models : AsBuilt
        The chip's as-built models from its measurement, before the trims.
    tp : TrimPlan
        The trims.
    spec : TrimSpec
        ``trim:`` of the spec (``direction``, ``precision_pct``, ``range_pct``).
    seps : Separations
        The designs' silent bands and tone windows (for the separability after the cut).
    pairs : iterable of (str, str)
        The impacters the steps must tell apart.
    seed : int
        The chip's seed.
    draws : int
        How many draws (:data:`ODDS_DRAWS`).

    Returns
    -------
    TrimOdds
    """
    from planner.afterfab.checks import KINDS, check_drive

    pairs = sorted({tuple(sorted(p)) for p in pairs})
    index = {n: k for k, n in enumerate(seps.ids)}
    nodes = {r.id: r.node for r in plan.impacters}
    sliders = models.sliders
    # nothing trimmed: every draw is the chip as measured, checked once on every device
    trimmed = sorted({nodes[n].device for n in tp.moved}) if tp.moved else list(sliders)
    others = [d for d in sliders if d not in trimmed]
    steps, waves, dwells = drive.run_steps, drive.waveforms, drive.dwells
    static = (check_drive(settings, steps, waves, dwells,
                          {nodes[n]: m for n, m in models.impacters.items() if n in nodes},
                          sliders, devices=others, scenes=False)
              if others else None)
    rng = np.random.default_rng(np.random.SeedSequence([seed, ODDS_STREAM]))
    # draw k is the k-th run of len(ids) normals: draw 0 is issue 26's single draw
    z = rng.standard_normal((draws, len(tp.target)))
    passed, failures, implicated = 0, {}, {}
    separable = second = 0
    first = None
    # a device no trim touches that fails, fails on every draw: no draw can pass, and
    # the trimmed devices are simulated on the first draw only (what it records)
    hopeless = static is not None and not static["passed"]
    for k in range(draws):
        actual = landed(tp, spec.precision_pct, z[k])
        true = trim_models(models.impacters,
                           {n: actual[n] / tp.measured[n] for n in tp.moved}, spec.direction)
        if k == 0 or (tp.moved and not hopeless):
            got = check_drive(settings, steps, waves, dwells,
                              {nodes[n]: true[n] for n in nodes}, sliders,
                              devices=trimmed, first_failure=k > 0)
        kinds = dict(got["failures"])
        implied = {n.text for n in got["nodes"]}
        if hopeless and k > 0:
            kinds, implied = {}, set()
        if static is not None:
            for kind, c in static["failures"].items():
                kinds[kind] = kinds.get(kind, 0) + c
            implied |= {n.text for n in static["nodes"]}
        ok = not kinds
        if k == 0:
            first = {"passed": ok, "failures": {q: kinds[q] for q in KINDS if q in kinds}
                     | {q: c for q, c in kinds.items() if q not in KINDS},
                     "resonances": actual}
        passed += ok
        for kind in kinds:
            failures[kind] = failures.get(kind, 0) + 1
        for n in implied:
            implicated[n] = implicated.get(n, 0) + 1
        # the lab's next step: measure again and re-plan; the re-plan can tell every pair
        # apart where the cuts left them separable, or after a second pass that makes them
        if all(seps.separable(index[a], index[b], actual[a], actual[b]) for a, b in pairs):
            separable += 1
            second += 1
        else:
            used = {n: 100.0 * (actual[n] / tp.measured[n] - 1.0) for n in tp.moved}
            again = plan_trim(seps, actual, pairs, range_pct=spec.range_pct,
                              direction=spec.direction, precision_pct=spec.precision_pct,
                              used_pct=used)
            second += again.ok
    return TrimOdds(draws, passed, float(settings.target_yield),
                    {q: failures[q] for q in KINDS if q in failures}
                    | {q: c for q, c in failures.items() if q not in KINDS},
                    {n: implicated[n] for n in sorted(implicated)}, separable, second,
                    first or {"passed": True, "failures": {}, "resonances": {}})


#: What the lab does after cutting, whatever the odds (the report's and stdout's words).
NEXT_STEP = ("cut as trim.csv says, then measure every resonance again (vibroplan "
             "calibrate) and run `vibroplan replan PLAN --measured <the new measured.csv>`: "
             "the re-plan puts the tones where the cuts really left the resonances, so a "
             "cut's error no longer decides; if the re-plan names a pair it cannot tell "
             "apart, run `vibroplan trim` on the new measurement (a second pass, within the "
             "range the first left)")


def trimmed_chip(models, ratios: dict, direction: str):
    """A chip's as-built models (:class:`~planner.afterfab.as_built.AsBuilt`) with trims
    applied: each trimmed impacter's resonance times its ratio [-] (:func:`trim_models`),
    the rest as built.  What a trimmed chip is re-planned on: the targets' ratios on the
    test floor (the cuts as aimed), the measured ones where the chip was cut and measured
    again."""
    return dataclasses.replace(models, impacters=trim_models(models.impacters, ratios,
                                                             direction))


def _replan_for(plan, measured, tp, models, settings, spec, progress, *, written=True):
    """The drive re-planned for a trim's targets, on the chip's as-built models with the
    trims applied as aimed.  ``written=False``: a drive only weighed, never written (an
    alternative cut's), skips what only the outputs read (the original drive on this
    chip, the scenes on the measured models, the coupling matrix); its drive and its
    verification are the same."""
    from planner.afterfab.replan import replan

    aimed = {n: tp.target[n] / tp.measured[n] for n in tp.moved}
    return replan(plan, scaled_measurements(measured, tp.target), settings=settings,
                  progress=progress, remeasure=tp.moved,
                  models=trimmed_chip(models, aimed, spec.direction),
                  **({} if written else {"original": (True, []), "record": False}))


def trim_chip(plan: PlanRecord, measured: dict, *, seed: int | None = None,
              spec: TrimSpec | None = None, progress=None, draws: int = ODDS_DRAWS,
              settings=None, models=None) -> TrimResult:
    """Trims for a measured chip, its drive re-planned and verified, and the odds that
    the cuts leave a chip that drive works on: ``vibroplan trim``, and the trim stage of
    the after-fabrication loop on the test floor (:mod:`planner.afterfab.loop`).

    One pass of the trim sequence (:func:`trim_sequence`, the chip taken at its targets
    after the cuts: the lab cuts after this, and measures again): the trims are chosen
    from the measurement, the drive re-planned for the targets on the chip's as-built
    models with the trims applied (:func:`trimmed_chip`), and that drive checked, in
    memory, on the *trimmed models* of ``draws`` draws of the cuts' errors
    (:func:`trim_odds`: every trimmed resonance off its target by
    ``trim.precision_pct``, seeded).  The chip passes when the drive verifies on the
    targets and the share of draws it works on reaches ``fabrication.target_yield``.
    Where the drive verifies but its odds fall short, a smaller move (the targets'
    margin halved to :data:`~planner.afterfab.separations.MARGIN_SIGMAS` / 2 sigmas of
    the precision) is re-planned once and its odds taken on the same draws; it is
    offered when they are higher.  After cutting, a lab measures the chip again and
    re-plans (:data:`NEXT_STEP`; ``trim.passes`` is what ``yield --trim`` simulates).

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
    draws : int
        Draws of the cuts' errors (:data:`ODDS_DRAWS`); 1 is issue 26's single draw.
    settings : Settings, optional
        The plan's settings already resolved for ``seed``
        (:func:`planner.planning.settings.plan_settings`; the loop's).
    models : AsBuilt, optional
        The chip's as-built models from ``measured`` (default
        :func:`planner.afterfab.replan.chip_models`; the loop's).
    """
    from planner.afterfab.drive import must_differ
    from planner.afterfab.replan import chip_models
    from planner.afterfab.separations import MARGIN_SIGMAS, separations_of
    from planner.planning.settings import plan_settings

    missing = [r.id for r in plan.impacters if r.id not in measured]
    if missing:
        # a design value is no measurement of this chip: trim.csv would state it as
        # measured_hz and the trims would be chosen against a resonance nobody measured
        from planner.core.errors import SpecError

        raise SpecError(f"no measured resonance for {', '.join(missing)}: a trim is chosen "
                        "from every impacter's measured resonance; measure them (vibroplan "
                        "calibrate) and give each a row", path="measured.csv")
    if int(draws) < 1:
        raise ValueError(f"draws must be at least 1, {draws!r} was given")
    seed = plan.seed if seed is None else int(seed)
    if settings is None:
        settings = plan_settings(plan, seed)
    spec = spec or settings.trim
    if models is None:
        models = chip_models(plan, measured)
    seps = separations_of(plan, settings)
    mean = {n: m.natural_frequency_hz for n, m in measured.items()}
    pairs = must_differ(settings.steps)
    aimed = []

    def cut(tp, k):
        aimed.append(tp)        # the lab cuts after this command

    def measure_again(k):
        # measured again, the chip is taken at its targets
        return scaled_measurements(measured, aimed[k].target)

    tp = trim_sequence(seps, measured, pairs, spec, cut=cut, measure_again=measure_again,
                       passes=1).last
    if not tp.ok:
        return TrimResult(tp, trim_rows(plan, tp, spec.direction), spec, None, False)
    result = _replan_for(plan, measured, tp, models, settings, spec, progress)
    ts = time.perf_counter()
    odds = trim_odds(settings, plan, result, models, tp, spec, seps, pairs, seed, draws)
    # report.md's timings (plan.json holds none: its bytes depend on the inputs only)
    timings = {**result.timings, "trim_odds": time.perf_counter() - ts}
    alternatives = []
    if result.passed and not odds.meets_target and tp.moved:
        # a smaller move: the targets' margin halved; on the same draws of the errors
        smaller = plan_trim(seps, mean, pairs, range_pct=spec.range_pct,
                            direction=spec.direction, precision_pct=spec.precision_pct / 2.0)
        if smaller.ok and smaller.moved and smaller.target != tp.target:
            ts = time.perf_counter()
            alt = _replan_for(plan, measured, smaller, models, settings, spec, progress,
                              written=False)
            alt_odds = trim_odds(settings, plan, alt, models, smaller, spec, seps, pairs,
                                 seed, draws)
            if alt.passed and alt_odds.share > odds.share:
                alternatives.append({
                    "cut": "smaller move",
                    "why": f"targets with a margin of {MARGIN_SIGMAS / 2:g} sigmas of the "
                           f"precision instead of {MARGIN_SIGMAS:g}",
                    "moved": [{"impacter": n, "target_hz": smaller.target[n],
                               "change_pct": smaller.change_pct(n)} for n in smaller.moved],
                    "targets_verify": bool(alt.passed), "odds": alt_odds.as_record()})
            timings["trim_smaller_move"] = time.perf_counter() - ts
    rows = trim_rows(plan, tp, spec.direction)
    for r in rows:
        r["failed_draws"] = odds.implicated.get(r["impacter"], 0)
    first = odds.first
    trim = {
        "direction": spec.direction, "range_pct": spec.range_pct,
        "precision_pct": spec.precision_pct, "seed": seed,
        "moved": [{k: r[k] for k in ("impacter", "measured_hz", "target_hz", "change_pct")}
                  | {"trimmed_hz": first["resonances"][r["impacter"]]}
                  for r in rows if r["impacter"] in tp.moved],
        # the first draw of the cuts' errors, as issue 26 checked one
        "trimmed_models": {"passed": bool(first["passed"]), "failures": first["failures"]},
        "odds": odds.as_record(),
        "raise_odds": alternatives,
        "next_step": NEXT_STEP}
    # plan.json's trim block, through the schema as the rest of the file
    plan_file, data = through_schema({**result.data, "trim": trim})
    result = dataclasses.replace(result, data=data, plan_file=plan_file, timings=timings)
    return TrimResult(tp, rows, spec, result, bool(result.passed and odds.meets_target),
                      odds, tuple(alternatives))
