"""The plan's collision prediction held against sampled chips (issue 45, item 1).

A plan predicts, from its designs' first-order sensitivities and silent bands, the share of
fabricated chips on which no two impacters that must be told apart collide
(``manufacturability.collision_free_yield``) and, with the measurement's own error on each
resonance, the share a re-plan can tell apart (``told_apart_yield``).  This samples chips
through the full equations (:func:`planner.fabrication.tolerances.sample_chip`, as
``vibroplan yield`` does, seed for seed), measures them as the loop does
(:meth:`planner.afterfab.loop.Truth.measure`) and applies the re-plan's own rule
(:func:`planner.afterfab.drive.inseparable`) to the true and to the measured resonances;
a chip the rule finds inseparable is then trimmed on paper
(:func:`planner.afterfab.trim.plan_trim`, one pass within the spec's range): the share no
trim separates is what the loop loses to collisions.  No step is simulated.

    python benchmarks/collision_calibration.py PLAN_DIR [PLAN_DIR ...] --chips 2000

Writes ``benchmarks/results/collision_calibration.md`` (``--out`` to change).
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np

from planner.afterfab.drive import inseparable, must_differ
from planner.afterfab.measurement import true_resonances
from planner.afterfab.separations import separations_of
from planner.afterfab.trim import plan_trim
from planner.core.intervals import wilson_interval
from planner.core.rng import chip_seed
from planner.fabrication.tolerances import sample_chip
from planner.fabrication.wafer import line_width_offsets
from planner.planfile.reader import read_plan
from planner.yield_.chip import truth_of
from planner.yield_.inputs import make_payload

RESULTS = Path(__file__).resolve().parent / "results"


def calibrate(plan_dir, chips, seed=0, noise_pct=None):
    """One plan's predicted and sampled collision rates (a dict of the table's row)."""
    rec = read_plan(plan_dir)
    noise = (rec.spec.fabrication.measurement_noise_pct if noise_pct is None
             else float(noise_pct))
    p = make_payload(rec, seed, replan=True, measure_noise_pct=noise)
    seps = separations_of(rec, p.settings)
    pairs = must_differ(p.settings.steps)
    ids = [r.id for r in rec.impacters]
    trim = p.settings.trim
    true_hits = meas_hits = untrimmable = 0
    t0 = time.perf_counter()
    for c in range(chips):
        rng = np.random.default_rng(chip_seed(p.seed, 1.0, c))
        chip = sample_chip(p.design, p.fabrication, rng, 1.0,
                           line_width_offsets(p.design.spec, p.fabrication, p.seed, 1.0, c))
        truth = truth_of(p, 1.0, c, chip)
        measured = {k: v.resonance for k, v in truth.measure(ids, noise).items()}
        true_hits += bool(inseparable(seps, true_resonances(chip.impacters), pairs))
        if inseparable(seps, measured, pairs):
            meas_hits += 1
            tp = plan_trim(seps, measured, pairs, range_pct=trim.range_pct,
                           direction=trim.direction, precision_pct=trim.precision_pct)
            untrimmable += not tp.ok
    m = json.loads((Path(plan_dir) / "plan.json").read_text())["manufacturability"]
    pred = m["collision_free_yield"]["value"]
    told = (m.get("told_apart_yield") or {}).get("value")
    return {"plan": str(plan_dir), "spec": rec.spec.name, "impacters": len(ids),
            "pairs": len(pairs), "chips": chips, "noise_pct": noise,
            "predicted_collisions": 1.0 - pred,
            "sampled_collisions": true_hits / chips,
            "sampled_ci": wilson_interval(true_hits, chips),
            "predicted_inseparable": None if told is None else 1.0 - told,
            "sampled_inseparable": meas_hits / chips,
            "sampled_inseparable_ci": wilson_interval(meas_hits, chips),
            "untrimmable": untrimmable / chips,
            "untrimmable_ci": wilson_interval(untrimmable, chips),
            "seconds": time.perf_counter() - t0}


def _pct(x):
    return "-" if x is None else f"{100 * x:.2f} %"


def _ci(ci):
    return f"[{100 * ci[0]:.2f}, {100 * ci[1]:.2f}] %"


def _ratio(pred, sim):
    return "-" if pred is None or not sim else f"{pred / sim:.2f}"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("plans", nargs="+", help="plan folders (vibroplan plan --out)")
    ap.add_argument("--chips", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=RESULTS / "collision_calibration.md")
    args = ap.parse_args(argv)
    rows = [calibrate(p, args.chips, args.seed) for p in args.plans]
    lines = [
        "# The collision prediction against sampled chips (issue 45, item 1)", "",
        f"`python benchmarks/collision_calibration.py {' '.join(args.plans)} --chips "
        f"{args.chips}` ({platform.python_version()}, {platform.machine()}).", "",
        "Collisions: a chip on which some pair that must be told apart cannot be "
        "(`planner.afterfab.drive.inseparable`, the re-plan's rule).  Predicted: the plan's "
        "first-order Monte Carlo (10 000 chips, plan.json `manufacturability`); sampled: "
        "chips through the full equations, seed for seed as `vibroplan yield --seed "
        f"{args.seed}`, on their true resonances and as measured (the spec's "
        "measurement noise); untrimmable: measured inseparable and no one-way trim within "
        "`trim.range_pct` separates them (`plan_trim`, on paper).  Ratio: predicted / "
        "sampled (the issue asks 0.8-1.2).", "",
        "| spec | impacters | chips | noise | collisions predicted | sampled (true) | 95 % CI "
        "| ratio | inseparable predicted (measured) | sampled (measured) | 95 % CI | ratio "
        "| untrimmable | 95 % CI | s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {r['spec']} | {r['impacters']} | {r['chips']} | {r['noise_pct']:g} % "
            f"| {_pct(r['predicted_collisions'])} | {_pct(r['sampled_collisions'])} "
            f"| {_ci(r['sampled_ci'])} | {_ratio(r['predicted_collisions'], r['sampled_collisions'])} "
            f"| {_pct(r['predicted_inseparable'])} | {_pct(r['sampled_inseparable'])} "
            f"| {_ci(r['sampled_inseparable_ci'])} "
            f"| {_ratio(r['predicted_inseparable'], r['sampled_inseparable'])} "
            f"| {_pct(r['untrimmable'])} | {_ci(r['untrimmable_ci'])} | {r['seconds']:.0f} |")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
