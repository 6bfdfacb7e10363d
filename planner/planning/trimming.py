"""Trim a measured chip and re-plan its drive for the trimmed resonances (``vibroplan trim``).

:func:`trim_chip` chooses the trims (:func:`planner.trim.plan_trim`: the fewest and smallest
one-way moves within ``trim.range_pct`` that make every pair the steps must tell apart
separable), says what to cut (trim.csv), re-plans the drive for the trimmed chip
(:func:`planner.planning.replan.replan`, from the targets), and verifies that drive on the
*trimmed models*: every trimmed resonance where the cut really put it, its target off by
``trim.precision_pct`` (one normal draw per trim, seeded).  A pair of halves is trimmed as a
pair (both cantilevers by the same fraction).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from planner.planning.plan_file import PlanRecord
from planner.planning.result import Plan
from planner.spec import TrimSpec
from planner.trim import TrimPlan, plan_trim, trim_rows, trimmed_resonances


@dataclass(frozen=True)
class TrimResult:
    """A chip's trims and the drive re-planned for it.

    Attributes
    ----------
    trims : TrimPlan
        Targets, the impacters to trim and why a chip cannot be trimmed.
    rows : list of dict
        trim.csv's rows (:func:`planner.trim.trim_rows`).
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


def _targets(measured: dict, tp: TrimPlan, resonances: dict) -> dict:
    """measured.csv's dict for the trimmed chip: each impacter at ``resonances`` (its
    halves moved by the same fraction)."""
    out = {}
    for n, meas in measured.items():
        hz = resonances[n]
        entry = {**meas, "natural_frequency_hz": hz}
        if meas.get("halves_hz"):
            ratio = hz / meas["natural_frequency_hz"]
            entry["halves_hz"] = tuple(h * ratio for h in meas["halves_hz"])
        out[n] = entry
    return out


def trim_chip(plan: PlanRecord, measured: dict, *, seed: int | None = None,
              spec: TrimSpec | None = None, progress=None) -> TrimResult:
    """Trims for a measured chip, and its drive re-planned and verified.

    Parameters
    ----------
    plan : PlanRecord
        The plan the chip was made by.
    measured : dict
        :func:`planner.planning.replan.read_measured`'s dict: every impacter of the plan
        (a :class:`~planner.errors.SpecError` names those without a measurement).
    seed : int, optional
        Seeds the trims' errors and the drive's phases (default: the plan's).
    spec : TrimSpec, optional
        Default: the plan's ``trim:`` section, else :class:`planner.spec.TrimSpec`'s
        defaults.
    """
    from planner.planning.replan import measured_models, measured_resonances, replan
    from planner.planning.rescue import must_differ, separations_of
    from planner.planning.settings import plan_settings
    from planner.yield_ import check_drive
    from planner.yield_.inputs import _drive_of

    missing = [r.id for r in plan.impacters if not measured.get(r.id)]
    if missing:
        # a design value is no measurement of this chip: trim.csv would state it as
        # measured_hz and the trims would be chosen against a resonance nobody measured
        from planner.errors import SpecError

        raise SpecError(f"no measured resonance for {', '.join(missing)}: a trim is chosen "
                        "from every impacter's measured resonance; measure them (vibroplan "
                        "calibrate) and give each a row", path="measured.csv")
    seed = plan.seed if seed is None else int(seed)
    settings = plan_settings(plan, seed)
    spec = spec or settings.trim
    full = {r.id: measured.get(r.id) or {"natural_frequency_hz": r.natural_frequency_hz}
            for r in plan.impacters}
    resonances = measured_resonances(plan, full)
    mean = {n: float(np.mean(v)) if isinstance(v, tuple) else v for n, v in resonances.items()}
    seps = separations_of(plan, settings)
    tp = plan_trim(seps, mean, must_differ(settings.steps), range_pct=spec.range_pct,
                   direction=spec.direction, precision_pct=spec.precision_pct)
    rows = trim_rows(plan, tp, spec.direction)
    if not tp.ok:
        return TrimResult(tp, rows, spec, None, False)
    result = replan(plan, _targets(full, tp, tp.target), settings=settings,
                    progress=progress, remeasure=tp.moved)
    # where the cuts really put the resonances: the targets, off by the trim precision
    rng = np.random.default_rng(np.random.SeedSequence([seed, 26]))
    actual = trimmed_resonances(tp, spec.precision_pct, rng)
    true = _targets(full, tp, actual)
    models = measured_models(plan, true)
    sliders = {d: settings.sliders[d] for d in sorted({r.device for r in plan.impacters})}
    from planner.planning.plan_file import plan_record

    steps, waveforms, dwells = _drive_of(plan_record(result.data, source="the trim's re-plan"))
    got = check_drive(settings, steps, waveforms, dwells, models, sliders)
    trim = {
        "direction": spec.direction, "range_pct": spec.range_pct,
        "precision_pct": spec.precision_pct, "seed": seed,
        "moved": [{k: r[k] for k in ("impacter", "measured_hz", "target_hz", "change_pct")}
                  | {"trimmed_hz": actual[r["impacter"]]}
                  for r in rows if r["impacter"] in tp.moved],
        "trimmed_models": {"passed": bool(got["passed"]), "failures": got["failures"]}}
    result = dataclasses.replace(result, data={**result.data, "trim": trim})
    return TrimResult(tp, rows, spec, result, bool(result.passed and got["passed"]))
