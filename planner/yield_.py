"""Yield of a plan under fabrication variation: the Monte Carlo behind ``vibroplan yield``.

Every chip is a sample of the spec's ``fabrication:`` tolerance model
(:mod:`planner.fabrication`) built from the plan's designs.  On each chip every step
of the plan is re-verified with the plan's own checks
(:func:`planner.planning.verify.check_step`, from the same initial-state grid, with the
drive rebuilt exactly from ``plan.json``'s tones) and every scene is simulated with the
state carried across steps and the plan's settle dwells
(:func:`planner.planning.scenes.simulate_scenes`,
:func:`planner.planning.scenes.scene_failures`).  A chip passes when every step passes
the plan's own checks AND the carried-state check passes -- the criterion
``vibroplan plan`` calls PASSED since the carried-state check became part of
``verification.passed`` (issue 15).  The yield is the fraction of chips that pass, with
a 95 % Wilson score interval.  ``carried_state`` (chips passing the carried-state check
too) is kept for compatibility: it now equals the yield.

Check kinds counted in ``failures`` (chips on which that check failed at least once):

- ``idle responds``: an impacter that must be idle hits its slider (r > 0, eq. (14));
- ``too slow``: a driven slider is slower than ``verification.min_speed_mm_s`` from
  some initial state;
- ``idle slider moves``: an idle slider moves more than ``verification.idle_tolerance_um``;
- ``travel over limit``, ``still moving``: a step's travel beyond
  ``verification.max_travel_um``, or motion left at the end of the longest dwell;
- ``idle slider moves (carried state)``: the same when each scene runs in order with
  the state the previous step left (``travel over limit (carried state)`` and
  ``still moving (carried state)`` likewise);
- ``unbuildable``: the sampled errors closed a gap or removed a beam (no simulation).

With ``replan=True`` (``vibroplan yield --replan``) every chip is also *measured* --
its true natural frequencies (of the sampled impacters) times ``1 + noise z / 100``,
z standard normal from the chip's own seed -- re-planned from the measurement with
:func:`planner.planning.replan.replan_chip` (only the drive changes), and the re-planned
drive is verified with the same checks on the chip's TRUE models (the sampled impacters
and sliders, not the re-plan's as-built models built from the measurement).

Chip ``i`` at sigma scale ``s`` draws from :func:`chip_seed` ``(seed, s, i)``: a
``numpy.random.SeedSequence`` of the seed, the 64 bits of the scale's value and the
chip's index (its measurement noise from that sequence's first spawned child).  The
numbers depend on the seed, the scale's value and the chip only: never on the number of
workers, the order they finish in, or where the scale stands in ``--sigma-scale``
(and scales 1.0000001 and 1.0000002 are two scales).
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass

import numpy as np

from planner._random import chip_seed
from model import halves
from planner.fabrication import ChipDesign, design_from_plan, sample_chip
from planner.planning.plan_file import PlanRecord, drives, plan_record
from planner.spec import FabricationSpec, LoadedSpec, TrimSpec

#: z of the two-sided 95 % normal quantile.
Z95 = 1.959963984540054
#: Check kinds, in the order reports list them.
KINDS = ("idle responds", "too slow", "idle slider moves",
         "idle slider moves (carried state)", "unbuildable", "travel over limit",
         "still moving", "travel over limit (carried state)",
         "still moving (carried state)")
#: The carried-state check's idle-motion kind (part of a chip's pass, as in
#: ``vibroplan plan``).
CARRIED = "idle slider moves (carried state)"
#: Every kind of the carried-state check.
CARRIED_KINDS = (CARRIED, "travel over limit (carried state)", "still moving (carried state)")
#: Why a re-plan failed, in the order reports list them (a chip may have several):
#: two impacters the spec must tell apart can no longer be (the re-plan's unresolved
#: conflict: the idle one responds at every candidate tone of the other -- close
#: resonances, or response bands that overlap although the resonances do not); a
#: scaled tone fell beyond ``drive.band_hz``; the re-plan does not verify even on the
#: measured models it was made for; it verifies there but not on the chip's true
#: models (measurement noise, or what the re-plan's model does not know: the as-built
#: mass, damping, gap and sliders); its steps pass on the true models but the
#: carried-state check fails (the re-plan does not simulate the scenes); the chip
#: cannot be built.
REPLAN_CAUSES = ("cannot be told apart", "outside band", "fails on the measured models",
                 "fails only on the true models", "carried state", "unbuildable")
#: Memory one chip's task and result hold until the end of a run [bytes]: its result
#: (a few hundred bytes, a few KB with --replan) and, on Dask, the scheduler's and the
#: client's bookkeeping of its task (~10 KB); an upper estimate.
CHIP_BYTES = 16 * 1024
#: Scale index of the nominal chip's task (scale 0: its draws are multiplied by 0).
NOMINAL_INDEX = 2**31 - 1


def scale_key(scale: float) -> str:
    """yield.json's key of a sigma scale: its short form (``"1"``, ``"0.5"``) when that
    reads back as the same number, else its full one (``"1.0000001"``)."""
    short = f"{scale:g}"
    return short if float(short) == scale else repr(float(scale))


def wilson_interval(passed: int, n: int, z: float = Z95) -> list[float]:
    """Wilson score interval [low, high] of a binomial proportion ``passed / n``.

    >>> [round(x, 4) for x in wilson_interval(10, 10)]
    [0.7225, 1.0]
    """
    if n <= 0:
        return [0.0, 1.0]
    p = passed / n
    den = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    # exact ends at 0 and n passes (the formula leaves round-off there)
    return [0.0 if passed == 0 else max(0.0, centre - half),
            1.0 if passed == n else min(1.0, centre + half)]


@dataclass(frozen=True)
class Payload:
    """Everything a worker needs to verify chips; sent to each worker once."""

    design: ChipDesign
    loaded: LoadedSpec
    waveforms: dict
    fabrication: FabricationSpec
    seed: int
    #: Numba threads per chip (None: numba's default); :func:`run_yield` sets 1.
    threads: int | None = None
    #: Settle dwell [s] of every step key (plan.json's ``settle_s``, the dwell the
    #: plan's own carried-state check used).
    dwells: dict = dataclasses.field(default_factory=dict)
    #: Measure, re-plan and re-verify every chip (``--replan``).
    replan: bool = False
    #: One sigma of the relative measurement noise of a natural frequency [%].
    measure_noise_pct: float = 0.0
    #: The plan the re-plan starts from (only with ``replan``).
    record: "PlanRecord | None" = None
    #: Trim the chips the re-plan cannot rescue (``--trim``, needs ``replan``).
    trim: bool = False
    #: One sigma of a trim's error [%] (``--trim-precision``; None: the spec's
    #: ``trim.precision_pct``).
    trim_precision_pct: float | None = None


def _drive_of(record: PlanRecord):
    """(steps, step key -> recorded drive, step key -> settle dwell [s]) of a plan."""
    return tuple(st.step for st in record.steps), drives(record), dict(record.dwells)


def check_noise(pct, option: str = "--measure-noise") -> float:
    """``pct`` as a relative sigma [%] (a measurement noise, a trim's precision): a finite
    number >= 0.

    Raises
    ------
    ValueError
        Naming ``option``.
    """
    try:
        x = float(pct)
    except (TypeError, ValueError):
        raise ValueError(f"{option}: {pct!r} is not a number") from None
    if not (math.isfinite(x) and x >= 0):
        raise ValueError(f"{option}: must be a finite number >= 0 [%], {pct} was given")
    return x


def make_payload(record: PlanRecord, seed: int, fabrication: FabricationSpec | None = None, *,
                 replan: bool = False, measure_noise_pct: float = 0.0,
                 allow_zero: bool = False, trim: bool = False,
                 trim_precision_pct: float | None = None) -> Payload:
    """The worker payload of a plan (:func:`planner.planning.plan_file.read_plan`);
    ``fabrication`` overrides the plan's.

    ``replan``: measure, re-plan and re-verify every chip; ``measure_noise_pct``: one
    sigma of the relative noise of each measured natural frequency [%] (>= 0).
    ``allow_zero``: accept a tolerance model whose every sigma is 0 (every chip is then
    the nominal one: the yield is 1 or 0 by construction, not a measurement).

    Raises
    ------
    ValueError
        A zero tolerance model without ``allow_zero``; noise without ``replan``.
    """
    noise = check_noise(measure_noise_pct)
    if noise and not replan:
        raise ValueError("--measure-noise needs --replan (only a re-plan measures the chip)")
    if trim and not replan:
        raise ValueError("--trim needs --replan (a trimmed chip's drive is re-planned)")
    if trim_precision_pct is not None:
        trim_precision_pct = check_noise(trim_precision_pct, "--trim-precision")
        if not trim:
            raise ValueError("--trim-precision needs --trim")
    fab = fabrication if fabrication is not None else record.spec.fabrication
    if fab.zero and not allow_zero:
        raise ValueError("every fabrication tolerance is 0 (the spec has no fabrication: "
                         "section, or only zero sigmas): every chip would be the nominal one "
                         "and the yield 1 or 0 by construction. Give the tolerances with "
                         "--spec FILE (its fabrication: section), or pass --allow-zero to "
                         "check the nominal chip alone")
    steps, waveforms, dwells = _drive_of(record)
    loaded = LoadedSpec(record.spec, steps, str(record.path or "plan.json"))
    return Payload(design_from_plan(record), loaded, waveforms, fab, int(seed),
                   dwells=dwells, replan=bool(replan), measure_noise_pct=noise,
                   record=record if replan else None, trim=bool(trim),
                   trim_precision_pct=trim_precision_pct)


def _kind(cause: str) -> str:
    if "responds" in cause:
        return "idle responds"
    if cause.startswith("too slow"):
        return "too slow"
    if cause.startswith("idle slider moves"):
        return "idle slider moves"
    if cause.startswith("travel") and "over the limit" in cause:
        return "travel over limit"
    if cause.startswith("still moving"):
        return "still moving"
    return cause.split(":")[0].strip() or "other"


def _settings(loaded: LoadedSpec):
    from planner.planning.settings import resolve_settings

    return resolve_settings(loaded)


def check_drive(settings, steps, waveforms, dwells, impacters, sliders, *,
                first_failure=False) -> dict:
    """Every check of a drive on one chip's models: the per-step checks and the
    carried-state check, as ``vibroplan plan`` runs them.

    With ``first_failure`` the checks stop at the first step that fails (its kinds are
    then the only ones counted, ``stopped`` says so): whether a drive passes is all a
    re-planning yield needs of the drive the chip is about to be re-planned away from.

    Parameters
    ----------
    settings : planner.planning.settings.Settings
        The plan's settings (checks, x0 grid, contact laws, dwell caps).
    steps : sequence of Step
        The drive's steps (plan.json's, or a re-plan's).
    waveforms : dict
        Step key -> the step's tones (``frequencies`` [Hz], ``amplitudes`` [m],
        ``phases`` [rad]).
    dwells : dict
        Step key -> settle dwell [s] after the step in the scene simulation.
    impacters, sliders : dict
        The chip's models: node id -> :class:`model.Impacter`, device -> :class:`model.Slider`.

    Returns
    -------
    dict
        ``passed`` (every check), ``steps_passed`` (the per-step checks only),
        ``failures`` (kind -> failing rows), ``nodes`` (impacter pairs implicated),
        ``rows`` (the per-step verification rows).
    """
    from planner.nodes import Node
    from planner.planning.scenes import scene_failures, simulate_scenes
    from planner.planning.verify import CARRIED_IDLE, TRAVEL_OVER, check_step

    by_device = {}
    for n in impacters:
        by_device.setdefault(Node.parse(n).device, []).append(n)
    failures, nodes, rows = {}, set(), []
    for st in steps:
        active = {f"{d}.{r}" for d, r in st.active_nodes()}
        step_rows = check_step(settings, st, waveforms[st.key], impacters, sliders)[0]
        rows += step_rows
        for row in step_rows:
            if row["passed"]:
                continue
            for cause in row["cause"].split("; "):
                kind = _kind(cause)
                failures[kind] = failures.get(kind, 0) + 1
                own = by_device.get(row["device"], [])
                named = [n for n in own if cause.startswith(n + " ")]
                if kind == "too slow":
                    named = [n for n in own if n in active]
                elif not named:  # an idle slider moved: its idle impacters did it
                    named = [n for n in own if n not in active]
                nodes |= set(named)
        if first_failure and failures:
            return {"passed": False, "steps_passed": False, "failures": failures,
                    "nodes": nodes, "rows": rows, "stopped": st.key}
    steps_passed = not failures
    if settings.scenes:
        by_index = {st.index: st for st in steps}
        scene_rows = simulate_scenes(settings, steps, waveforms, impacters, sliders, dwells)
        for f in scene_failures(settings, steps, scene_rows):
            kind = {CARRIED_IDLE: CARRIED,
                    TRAVEL_OVER: "travel over limit (carried state)"}.get(
                        f.kind, "still moving (carried state)")
            failures[kind] = failures.get(kind, 0) + 1
            st = by_index.get(f.step)
            if f.kind == CARRIED_IDLE and st is not None:
                active = {f"{d}.{r}" for d, r in st.active_nodes()}
                nodes |= {n for n in by_device.get(f.device, []) if n not in active}
    return {"passed": not failures, "steps_passed": steps_passed, "failures": failures,
            "nodes": nodes, "rows": rows}


def verify_chip(payload: Payload, scale_index: int, chip_index: int, scale: float) -> dict:
    """Sample chip ``chip_index`` at sigma scale ``scale`` and run every check on it.

    Returns
    -------
    dict
        ``passed``, ``carried_passed`` (equal to ``passed``: the carried-state check is
        part of the pass), ``failures`` (kind -> failing rows), ``nodes`` (ids of the
        impacter pairs implicated in a failure), ``scale_index``, ``chip``; with
        ``payload.replan`` also ``replan`` (see :func:`replan_chip_on`) and
        ``seconds`` (wall time of the nominal checks and of the re-plan [s]).
    """
    import time

    from planner.assign import split_node

    if payload.threads:
        import numba

        # per thread: every task sets it in the worker thread that runs it
        numba.set_num_threads(min(payload.threads, numba.config.NUMBA_NUM_THREADS))
    t0 = time.perf_counter()
    rng = np.random.default_rng(chip_seed(payload.seed, scale, chip_index))
    chip = sample_chip(payload.design, payload.fabrication, rng, scale)
    out = {"scale_index": scale_index, "chip": chip_index}
    if chip.unbuildable:
        nodes = set()
        for x in chip.unbuildable:
            nodes |= {n for n in payload.design.node_ids if n == x or split_node(n)[0] == x}
        out.update(passed=False, carried_passed=False,
                   failures={"unbuildable": len(chip.unbuildable)}, nodes=sorted(nodes))
        if payload.replan:
            out["replan"] = {"passed": False, "measured_passed": False,
                             "causes": ["unbuildable"], "failures": {"unbuildable": 1},
                             "collisions": [], "outside_band": []}
            if payload.trim:
                out["trim"] = {"passed": False, "trimmed": [], "causes": ["unbuildable"],
                               "failures": {"unbuildable": 1}}
            out["seconds"] = {"nominal": time.perf_counter() - t0, "replan": 0.0}
        return out
    settings = _settings(payload.loaded)
    # re-planning, the plan's own drive is only a reference: its checks stop at the
    # first failing step (a chip the die moved fails the first one it plays)
    got = check_drive(settings, payload.loaded.steps, payload.waveforms, payload.dwells,
                      chip.impacters, chip.sliders, first_failure=payload.replan)
    out.update(passed=got["passed"], carried_passed=got["passed"],
               failures=got["failures"], nodes=sorted(got["nodes"]))
    if payload.replan:
        t1 = time.perf_counter()
        out["replan"] = replan_chip_on(payload, settings, scale, chip_index, chip, got)
        out["seconds"] = {"nominal": t1 - t0, "replan": time.perf_counter() - t1}
        if payload.trim:
            t2 = time.perf_counter()
            out["trim"] = trim_chip_on(payload, settings, scale, chip_index, chip, got,
                                       out["replan"])
            out["seconds"]["trim"] = time.perf_counter() - t2
    return out


def trim_chip_on(payload: Payload, settings, scale: float, chip_index: int, chip,
                 nominal: dict, replanned: dict) -> dict:
    """Trim a chip the re-plan could not rescue because two of its impacters cannot be
    told apart, re-measure it, re-plan it and verify the drive on its trimmed true models.

    A chip the re-plan rescued needs no trim (its result is the re-plan's); a chip the
    re-plan lost for another reason is not helped by one.  The trims are chosen from the
    chip's measurement (:func:`planner.trim.plan_trim`); each lands on its target times
    (1 + precision z / 100) of the true resonance's move, z from the chip's seed
    (:func:`planner.trim.trimmed_resonances`); the trimmed chip is measured again (the
    same noise level, new draws) and re-planned.

    Returns
    -------
    dict
        ``passed``, ``trimmed`` (impacters trimmed), ``causes`` (``cannot be trimmed``
        naming the moves beyond the range, or the re-plan's causes after the trim),
        ``failures`` (kind -> rows on the trimmed true models).
    """
    from planner.planning.replan import measured_resonances
    from planner.planning.rescue import must_differ, separations_of
    from planner.spec import TrimSpec
    from planner.trim import plan_trim, trim_models, trimmed_resonances

    if replanned["passed"] or not replanned["collisions"]:
        return {**{k: replanned[k] for k in ("passed", "causes", "failures")}, "trimmed": []}
    spec = payload.record.spec.trim or TrimSpec()
    precision = (spec.precision_pct if payload.trim_precision_pct is None
                 else payload.trim_precision_pct)
    freqs = measured_frequencies(payload, scale, chip_index, chip)
    measured = measured_resonances(payload.record, _as_measured(freqs))
    mean = {n: float(np.mean(v)) if isinstance(v, tuple) else v for n, v in measured.items()}
    tp = plan_trim(separations_of(payload.record, settings), mean, must_differ(settings.steps),
                   range_pct=spec.range_pct, direction=spec.direction,
                   precision_pct=precision)
    if not tp.ok:
        return {"passed": False, "trimmed": [], "failures": {},
                "causes": ["cannot be trimmed"],
                "beyond_range": [f["impacter"] for f in tp.failures]}
    seq = chip_seed(payload.seed, scale, chip_index).spawn(3)
    actual = trimmed_resonances(tp, precision, np.random.default_rng(seq[1]))
    ratios = {n: actual[n] / tp.measured[n] for n in tp.moved}
    true = trim_models(chip.impacters, ratios, spec.direction)
    # the trimmed chip measured again
    z = np.random.default_rng(seq[2]).standard_normal((len(payload.design.nodes), 2))
    again = {}
    for node, zi in zip(payload.design.nodes, z):
        parts = halves(true[node.id])
        meas = [float(h.natural_frequency) * max(1.0 + payload.measure_noise_pct / 100.0
                                                 * float(zk), 0.1)
                for (h, _), zk in zip(parts, zi)]
        again[node.id] = ({"natural_frequency_hz": meas[0]} if len(parts) == 1 else
                          {"natural_frequency_hz": float(np.mean(meas)),
                           "halves_hz": tuple(meas)})
    got = _replan_and_check(payload, settings, again, true, chip.sliders,
                            (nominal["steps_passed"], nominal["rows"]))
    return {"passed": got["passed"], "trimmed": list(tp.moved), "causes": got["causes"],
            "failures": got["failures"]}


def measured_frequencies(payload: Payload, scale: float, chip_index: int, chip) -> dict:
    """Node id -> (true, measured) natural frequency [Hz] of a sampled chip; for a pair
    of unequal halves each is a tuple (half a, half b).

    measured = true (1 + pct z / 100), z standard normal from the first child of the
    chip's SeedSequence (two draws per node in the design's order, the second for its
    second half, whatever pct, so the same chip gets the same normals at every noise
    level), floored at a tenth of the true frequency (a measurement never finds a
    resonance at or below 0 Hz; only a noise of tens of per cent reaches the floor).
    """
    seq = chip_seed(payload.seed, scale, chip_index).spawn(1)[0]
    z = np.random.default_rng(seq).standard_normal((len(payload.design.nodes), 2))
    out = {}
    for node, zi in zip(payload.design.nodes, z):
        parts = halves(chip.impacters[node.id])
        true = [float(h.natural_frequency) for h, _ in parts]
        meas = [nu * max(1.0 + payload.measure_noise_pct / 100.0 * float(zk), 0.1)
                for nu, zk in zip(true, zi)]
        out[node.id] = ((true[0], meas[0]) if len(parts) == 1 else
                        (tuple(true), tuple(meas)))
    return out


def _as_measured(freqs: dict) -> dict:
    """The re-plan's ``measured`` of :func:`measured_frequencies`' pairs."""
    out = {}
    for n, (_, m) in freqs.items():
        if isinstance(m, tuple):
            out[n] = {"natural_frequency_hz": float(np.mean(m)), "halves_hz": m}
        else:
            out[n] = {"natural_frequency_hz": m}
    return out


def replan_chip_on(payload: Payload, settings, scale: float, chip_index: int, chip,
                   nominal: dict) -> dict:
    """Measure a sampled chip, re-plan its drive, verify it on the chip's true models.

    Parameters
    ----------
    payload : Payload
        With ``record`` and ``measure_noise_pct``.
    settings : Settings
        The plan's settings (the checks).
    scale : float
        The chip's sigma scale.
    chip_index : int
        The chip's index (its measurement noise is seeded from both, :func:`chip_seed`).
    chip : planner.fabrication.Chip
        The sampled chip (its impacters and sliders are the truth).
    nominal : dict
        :func:`check_drive` of the original drive on this chip: passed on as the
        re-plan's ``original`` so that it is not verified a second time.

    Returns
    -------
    dict
        ``passed`` (the re-planned drive passes every check on the true models),
        ``measured_passed`` (the re-plan verified on the models it was made from),
        ``causes`` (:data:`REPLAN_CAUSES` that apply when it fails), ``failures``
        (kind -> rows on the true models), ``collisions`` (pairs no drive tells apart:
        ``pair``, their measured resonances ``as_built_hz``, ``apart_hz`` and the
        ``needs_hz`` they would need), ``outside_band`` (impacters whose tone fell
        beyond the band), ``split_steps`` (steps played as sub-steps),
        ``tones_moved``.
    """
    freqs = measured_frequencies(payload, scale, chip_index, chip)
    return _replan_and_check(payload, settings, _as_measured(freqs), chip.impacters,
                             chip.sliders, (nominal["steps_passed"], nominal["rows"]))


def _replan_and_check(payload, settings, measured, impacters, sliders, original):
    """Re-plan from ``measured`` and verify the drive on the true models (a yield's
    re-plan and its trim's)."""
    from planner.planning.replan import replan_chip

    ok, plan = replan_chip(payload.record, measured, original=original, record=False)
    data = plan.data
    rp = data["replan"]
    collisions = [{k: c[k] for k in ("pair", "as_built_hz", "apart_hz", "needs_hz")}
                  for c in rp["inseparable"]]
    if collisions:      # no drive can pass: not simulated on the true models
        return {"passed": False, "measured_passed": False,
                "causes": ["cannot be told apart"], "failures": {}, "collisions": collisions,
                "outside_band": list(rp["outside_band"]),
                "split_steps": sorted(rp["split_steps"]), "tones_moved": len(rp["moved"])}
    # the re-plan's plan.json, read back as any plan is
    steps, waveforms, dwells = _drive_of(plan_record(data, source="the chip's re-plan"))
    got = check_drive(settings, steps, waveforms, dwells, impacters, sliders)
    causes = []
    if not got["passed"]:
        if rp["outside_band"]:
            causes.append("outside band")
        if not ok:
            causes.append("fails on the measured models")
        elif got["steps_passed"]:
            causes.append("carried state")
        else:
            causes.append("fails only on the true models")
    return {"passed": got["passed"], "measured_passed": bool(ok), "causes": causes,
            "failures": got["failures"], "collisions": collisions,
            "outside_band": list(rp["outside_band"]),
            "split_steps": sorted(rp["split_steps"]),
            "tones_moved": sum(1 for m in rp["moved"]
                               if m["frequency_hz"] != m["original_frequency_hz"])}


def _ordered(counts: dict, order) -> dict:
    rank = {k: i for i, k in enumerate(order)}
    return dict(sorted(counts.items(), key=lambda kv: (-kv[1], rank.get(kv[0], 99), kv[0])))


def _tally(lists, order) -> dict:
    """How many of ``lists`` (each a chip's causes or failing checks) name each item,
    most frequent first (:func:`_ordered`)."""
    counts = {}
    for items in lists:
        for k in items:
            counts[k] = counts.get(k, 0) + 1
    return _ordered(counts, order)


def _summary(results, chips):
    passed = sum(r["passed"] for r in results)
    failures = _tally((r["failures"] for r in results), KINDS)
    both = sum(r.get("carried_passed", r["passed"]) for r in results)
    out = {"chips": chips, "passed": passed, "yield": passed / chips,
           "ci95": wilson_interval(passed, chips), "failures": failures,
           "carried_state": {"passed": both, "yield": both / chips,
                             "ci95": wilson_interval(both, chips)}}
    if results and "replan" in results[0]:
        out["replan"] = _replan_summary(results, chips)
    if results and "trim" in results[0]:
        out["trim"] = _trim_summary(results, chips)
    return out


def _trim_summary(results, chips):
    """The yield with trims: chips the re-plan passed, or that a trim and a re-plan of
    the trimmed chip rescued."""
    ok = sum(r["trim"]["passed"] for r in results)
    failed = [r["trim"] for r in results if not r["trim"]["passed"]]
    return {"chips": chips, "passed": ok, "yield": ok / chips,
            "ci95": wilson_interval(ok, chips),
            "trimmed": sum(1 for r in results if r["trim"]["trimmed"]),
            "rescued": sum(1 for r in results
                           if r["trim"]["passed"] and not r["replan"]["passed"]),
            "causes": _tally((t["causes"] for t in failed),
                             REPLAN_CAUSES + ("cannot be trimmed",)),
            "failures": _tally((t["failures"] for t in failed), KINDS)}


def _replan_summary(results, chips):
    """The re-plan's yield, its failure causes and the chips it rescued or lost."""
    ok = sum(r["replan"]["passed"] for r in results)
    return {"chips": chips, "passed": ok, "yield": ok / chips,
            "ci95": wilson_interval(ok, chips),
            "rescued": sum(1 for r in results if r["replan"]["passed"] and not r["passed"]),
            "lost": sum(1 for r in results if r["passed"] and not r["replan"]["passed"]),
            "measured_passed": sum(r["replan"]["measured_passed"] for r in results),
            "causes": _tally((r["replan"]["causes"] for r in results), REPLAN_CAUSES),
            "failures": _tally((r["replan"]["failures"] for r in results), KINDS)}


def _chip_record(r) -> dict:
    """One chip's line of yield.json's ``replan.per_chip``."""
    rp = r["replan"]
    return {"chip": r["chip"], "nominal_passed": r["passed"], "replan_passed": rp["passed"],
            "measured_passed": rp["measured_passed"], "causes": rp["causes"],
            "failures": _ordered(rp["failures"], KINDS), "collisions": rp["collisions"],
            "outside_band": rp["outside_band"], "split_steps": rp.get("split_steps", []),
            "tones_moved": rp.get("tones_moved", 0),
            **({"trim_passed": r["trim"]["passed"], "trimmed": r["trim"]["trimmed"],
                "trim_causes": r["trim"]["causes"]} if "trim" in r else {})}


def parse_scales(text: str | None) -> list[float]:
    """``"0.5,1,2"`` -> [0.5, 1.0, 2.0]; None -> [1.0].

    Raises
    ------
    ValueError
        An entry is not a finite number >= 0, or an entry repeats.
    """
    if text is None or str(text).strip() == "":
        return [1.0]
    out = []
    for part in str(text).split(","):
        try:
            x = float(part)
        except ValueError:
            raise ValueError(f"--sigma-scale: {part.strip()!r} is not a number") from None
        if not (math.isfinite(x) and x >= 0):
            raise ValueError(f"--sigma-scale: {part.strip()} must be a finite number >= 0")
        if x in out:
            raise ValueError(f"--sigma-scale: {part.strip()} is given twice")
        out.append(x)
    return out


def check_chip_count(chips: int, n_scales: int = 1) -> None:
    """Refuse, before any work, a Monte Carlo whose chips the memory cannot hold.

    Raises
    ------
    ValueError
        ``chips`` < 1; :class:`planner.errors.LimitError` with the figures when
        ``chips`` x ``n_scales`` chips (plus the nominal one) need more memory than the
        machine has (:data:`CHIP_BYTES` each).
    """
    from planner._limits import check_memory

    if int(chips) < 1:
        raise ValueError(f"chips must be >= 1, {chips} was given")
    n = int(chips) * int(n_scales) + 1
    check_memory(n * CHIP_BYTES, f"--chips {chips} x {n_scales} sigma scale"
                                 f"{'s' if n_scales != 1 else ''} ({n} chips in all)")


def run_yield(payload: Payload, chips: int, *, scales=(1.0,), jobs: int = 1,
              scheduler: str | None = None, progress=None, timings: dict | None = None
              ) -> dict:
    """The Monte Carlo: ``chips`` chips at every sigma scale, plus the nominal chip.

    ``timings``: when given a dict, it receives ``nominal_s`` and ``replan_s`` (lists of
    the wall times [s] of each chip's nominal checks and re-plan, with
    ``payload.replan``) and ``wall_s``; kept out of the returned dict so that
    ``yield.json`` depends on the seed only.

    Returns
    -------
    dict
        The content of ``yield.json`` (see :func:`write_outputs` and docs/yield.md).
    """
    import time

    t_start = time.perf_counter()
    from planner.engine import run_tasks

    chips = int(chips)
    scales = [float(s) for s in scales]
    check_chip_count(chips, len(scales))
    # the nominal chip (scale 0: every error 0) is task 0; it must reproduce the plan
    tasks = [(NOMINAL_INDEX, 0, 0.0)] + [(j, i, s) for j, s in enumerate(scales) for i in range(chips)]
    # one numba thread per chip everywhere: the chips are the parallelism, and the
    # kernels' own threads over a 5-9 point x0 grid cost more than they bring (on a
    # loaded 2-core machine a chip of the 5x5 plan took ~50 s threaded, ~5 s not)
    import numba

    before = numba.get_num_threads()
    payload = dataclasses.replace(payload, threads=1)
    try:
        results = run_tasks(verify_chip, payload, tasks, jobs=jobs, scheduler=scheduler,
                            progress=progress)
    finally:
        numba.set_num_threads(before)
    if timings is not None:
        timings["wall_s"] = time.perf_counter() - t_start
        timings["nominal_s"] = [r["seconds"]["nominal"] for r in results if "seconds" in r]
        timings["replan_s"] = [r["seconds"]["replan"] for r in results
                               if "seconds" in r and "unbuildable" not in r["failures"]]
    nominal, results = results[0], results[1:]
    main = scales.index(1.0) if 1.0 in scales else 0
    out_scale = {}
    for j, s in enumerate(scales):
        mine = [r for r in results if r["scale_index"] == j]
        out_scale[j] = (_summary(mine, chips), mine)
    summary, mine = out_scale[main]
    ids = payload.design.node_ids
    counts = dict.fromkeys(ids, 0)
    for r in mine:
        for n in r["nodes"]:
            counts[n] += 1
    data = {
        "chips": chips, "passed": summary["passed"], "yield": summary["yield"],
        "ci95": summary["ci95"], "ci95_method": "wilson", "seed": payload.seed,
        "sigma_scale": scales[main],
        "tolerance": json.loads(payload.fabrication.model_dump_json()),
        "failures": summary["failures"],
        "impacters": {n: counts[n] / chips for n in ids},
        "carried_state": summary["carried_state"],
        "nominal": {"passed": nominal["passed"], "failures": nominal["failures"],
                    "carried_passed": nominal["carried_passed"]},
        "failed_chips": [r["chip"] for r in mine if not r["passed"]],
    }
    if payload.replan:
        rp = summary["replan"]
        data["replan"] = {
            "measure_noise_pct": payload.measure_noise_pct,
            "chips": chips, "passed": rp["passed"], "yield": rp["yield"], "ci95": rp["ci95"],
            "nominal_drive": {"passed": summary["passed"], "yield": summary["yield"],
                              "ci95": summary["ci95"]},
            "rescued": rp["rescued"], "lost": rp["lost"],
            "measured_passed": rp["measured_passed"],
            "causes": rp["causes"], "failures": rp["failures"],
            "nominal": _chip_record(nominal),
            "failed_chips": [r["chip"] for r in mine if not r["replan"]["passed"]],
            "per_chip": [_chip_record(r) for r in mine],
        }
    if payload.trim:
        tr = summary["trim"]
        spec_trim = payload.record.spec.trim
        data["trim"] = {
            "precision_pct": (payload.trim_precision_pct if payload.trim_precision_pct
                              is not None else (spec_trim.precision_pct if spec_trim
                                                else TrimSpec().precision_pct)),
            **{k: tr[k] for k in ("chips", "passed", "yield", "ci95", "trimmed", "rescued",
                                  "causes", "failures")},
            "failed_chips": [r["chip"] for r in mine if not r["trim"]["passed"]],
        }
    if len(scales) > 1 or scales != [1.0]:
        keys = ("yield", "ci95", "passed", "failures", "carried_state")
        data["by_sigma_scale"] = {}
        for j, s in enumerate(scales):
            entry = {k: out_scale[j][0][k] for k in keys}
            if payload.replan:
                entry["replan"] = {k: out_scale[j][0]["replan"][k]
                                   for k in ("yield", "ci95", "passed", "rescued", "causes")}
            if payload.trim:
                entry["trim"] = {k: out_scale[j][0]["trim"][k]
                                 for k in ("yield", "ci95", "passed", "rescued", "causes")}
            data["by_sigma_scale"][scale_key(s)] = entry
    return data


# ----------------------------------------------------------------------------------
# outputs
