"""A wafer at a time (issue 39): frequency neighbours placed near each other, and a
wafer sampled by the yield, re-planned in batch.

    python benchmarks/wafer.py [--work DIR] [--jobs 2] [--dies 101] [--seed 0]
        [--gradient 0.003] [--out benchmarks/results/wafer.md]

1. **Placement.**  The default spec (``configs/array_5x5.yaml``) with a
   ``fabrication.wafer`` section (:data:`WAFER`: a 135 mm wafer of 101 dies, an
   across-wafer line-width field and a within-die gradient) is planned twice, seed 0:
   with today's channel order (``drive.channels.placement: coloring``) and with
   ``placement: neighbours``.  Each plan's predicted collision-free yield (plan.json's
   ``manufacturability``, the within-die gradient included) is compared, and then
   re-evaluated for the same designs at other gradients
   (:func:`planner.manufacturability.collision_free_yield` on the plan's recorded
   sensitivities and separations).
2. **A wafer in batch.**  ``vibroplan yield PLAN --chips DIES --replan --trim`` samples
   one wafer of today's-order plan (its dies' outcomes on their true models, the wafer
   map, wafer_1.csv and wafer_1.stdf as a prober measures them); ``vibroplan replan PLAN
   --measured wafer_1.csv --trim --jobs J`` re-plans the dies in batch (timed), and the
   STDF file is read back and re-planned likewise; the per-die outcomes are compared
   with the yield's.

Writes benchmarks/results/wafer.md and wafer.csv (the per-die comparison), and copies
the wafer maps to benchmarks/results/wafer_map_yield.png and wafer_map_replan.png.
Steps whose outputs exist in ``--work`` are not run again.
"""

from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(ROOT))
from _timing import machine  # noqa: E402

#: The wafer of the benchmark: 135 mm, 3 mm edge exclusion (101 dies of 10 x 10 mm), a
#: smooth line-width field of 0.03 um over 30 mm (MKID arrays: ~1.5 % smooth across
#: the wafer, McKenney et al. 2019; 0.24/um x 0.03 um is 0.7 %) and a within-die gradient
#: (set by --gradient).
WAFER = {"diameter_mm": 135, "edge_exclusion_mm": 3,
         "line_width_field": {"sigma_um": 0.03, "correlation_length_mm": 30}}
#: Gradients the placements' predictions are compared at [um/mm].
GRADIENTS = (0.0, 0.001, 0.002, 0.003, 0.005, 0.008)


def spec_text(gradient: float, placement: str) -> str:
    """The default spec with the wafer section and the placement."""
    import yaml

    data = yaml.safe_load((ROOT / "configs" / "array_5x5.yaml").read_text())
    data["name"] = f"array_5x5_{placement}"
    data["fabrication"]["wafer"] = {**WAFER, "line_width_gradient_um_per_mm": gradient}
    data["drive"]["channels"]["placement"] = placement
    return yaml.safe_dump(data, sort_keys=False)


def run(cmd, **kw):
    t0 = time.perf_counter()
    proc = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, **kw)
    return proc, time.perf_counter() - t0


def predicted(plan_json: Path, gradient: float, chips=10_000) -> dict:
    """The plan's collision-free yield re-evaluated at ``gradient`` [um/mm]."""
    import numpy as np

    from planner.assignment.assign import node_order
    from planner.fabrication.tolerances import ERRORS, Tolerances
    from planner.manufacturability import BAND_MARGIN, collision_free_yield
    from planner.core.nodes import Node
    from planner.planfile.reader import read_plan
    from planner.fabrication.wafer import device_positions

    rec = read_plan(plan_json)
    d = json.loads(plan_json.read_text())
    m = d["manufacturability"]
    nodes = sorted((Node.parse(r["id"]) for r in d["impacters"]), key=node_order)
    by = {r["id"]: r for r in d["impacters"]}
    # the pairs told apart: every pair of a step-distinguished node (all of them on
    # the default, every impacter being independent)
    from planner.afterfab.drive import must_differ
    from planner.planning.settings import plan_settings

    settings = plan_settings(rec)
    index = {n.text: k for k, n in enumerate(nodes)}
    pairs = sorted({tuple(sorted((index[str(a)], index[str(b)])))
                    for a, b in must_differ(settings.steps)})
    fab = rec.spec.fabrication
    tol = Tolerances.from_spec(fab)
    sep = m["separation_hz"]
    pos = device_positions(rec.spec.array)
    pred = collision_free_yield(
        [n.text for n in nodes], [by[n.text]["natural_frequency_hz"] for n in nodes],
        [by[n.text]["frequency_hz"] for n in nodes],
        [[m["sensitivity"][n.text][e] for e in ERRORS] for n in nodes],
        tol.die, tol.device,
        np.array(pairs), silent_below=[(1 + BAND_MARGIN) * sep[n.text]["silent_below"]
                                       for n in nodes],
        silent_above=[(1 + BAND_MARGIN) * sep[n.text]["silent_above"] for n in nodes],
        responds_below=[sep[n.text]["responds_below"] for n in nodes],
        responds_above=[sep[n.text]["responds_above"] for n in nodes],
        chips=chips, seed=rec.seed, sigma_pair=tol.pair,
        sigma_field_line_width=fab.wafer.line_width_field.sigma_um,
        sigma_gradient=gradient * 1e3,
        positions=np.array([pos[n.device] for n in nodes]))
    return {"value": pred.value, "ci95": pred.ci95, "die_only": pred.die_only,
            "limiting": pred.limiting_pairs[:3]}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", default="/tmp/vibroplan-wafer-bench")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--dies", type=int, default=101)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--gradient", type=float, default=0.003)
    ap.add_argument("--out", default=str(HERE / "results" / "wafer.md"))
    args = ap.parse_args()
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    exe = Path(sys.executable).with_name("vibroplan")
    times, plans = {}, {}
    for placement in ("coloring", "neighbours"):
        spec = work / f"spec_{placement}.yaml"
        spec.write_text(spec_text(args.gradient, placement))
        out = work / f"plan_{placement}"
        if not (out / "plan.json").exists():
            proc, t = run([exe, "plan", spec, "--out", out, "--seed", args.seed, "--jobs",
                           args.jobs, "--no-figures", "--quiet", "--force"])
            times[f"plan {placement}"] = t
            if not (out / "plan.json").exists():
                raise SystemExit(f"plan {placement} failed: {proc.stderr[-800:]}")
        plans[placement] = json.loads((out / "plan.json").read_text())
    curve = {p: {g: predicted(work / f"plan_{p}" / "plan.json", g) for g in GRADIENTS}
             for p in plans}

    # the wafer: sampled by the yield, re-planned in batch
    plan_dir = work / "plan_coloring"
    ydir = work / "yield"
    if not (ydir / "yield.json").exists():
        proc, t = run([exe, "yield", plan_dir, "--chips", args.dies, "--seed", args.seed,
                       "--jobs", args.jobs, "--replan", "--trim", "--out", ydir, "--quiet",
                       "--force"])
        times["yield"] = t
        if not (ydir / "yield.json").exists():
            raise SystemExit(f"yield failed: {proc.stderr[-800:]}")
    y = json.loads((ydir / "yield.json").read_text())
    batch = {}
    for kind, src in (("csv", ydir / "wafer_1.csv"), ("stdf", ydir / "wafer_1.stdf")):
        rdir = work / f"replan_{kind}"
        if not (rdir / "summary.csv").exists():
            proc, t = run([exe, "replan", plan_dir, "--measured", src, "--trim", "--jobs",
                           args.jobs, "--out", rdir, "--quiet", "--force"])
            times[f"replan {kind}"] = t
            if not (rdir / "summary.csv").exists():
                raise SystemExit(f"replan {kind} failed: {proc.stderr[-800:]}")
        batch[kind] = {(int(r["die_x"]), int(r["die_y"])): r
                       for r in csv.DictReader((rdir / "summary.csv").open())}
    # the times of the steps run now, beside those of earlier runs of the same work folder
    stamp = work / "times.json"
    times = {**(json.loads(stamp.read_text()) if stamp.exists() else {}), **times}
    stamp.write_text(json.dumps(times, indent=2))
    write(args, work, plans, curve, y, batch, times)


def _same(mc: str, lab: str) -> bool:
    return mc == lab or (mc == "fails" and lab == "scrapped")


def write(args, work, plans, curve, y, batch, times):
    mach = machine()
    out = Path(args.out)
    rows = []
    for d in y["wafer"]["dies"]:
        key = (d["die_x"], d["die_y"])
        c, s = batch["csv"].get(key), batch["stdf"].get(key)
        rows.append({"die_x": key[0], "die_y": key[1], "radius_mm": d["radius_mm"],
                     "yield_outcome": d["outcome"], "yield_causes": "; ".join(d["causes"]),
                     "replan_outcome": c["outcome"] if c else "not measured",
                     "replan_causes": c["causes"] if c else "",
                     "stdf_outcome": s["outcome"] if s else "not measured"})
    with out.with_suffix(".csv").open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    agree = sum(_same(r["yield_outcome"], r["replan_outcome"]) for r in rows)
    agree_stdf = sum(r["stdf_outcome"] == r["replan_outcome"] for r in rows)
    differ = [r for r in rows if not _same(r["yield_outcome"], r["replan_outcome"])]
    # the two maps drawn again from the files (the batch's: from its summary.csv)
    from planner.figures.wafer_map import plot_wafer_map

    w = y["wafer"]
    plot_wafer_map(w["dies"], w["die_size_mm"], out.parent / "wafer_map_yield.png",
                   diameter_mm=w["diameter_mm"], edge_exclusion_mm=w["edge_exclusion_mm"],
                   title=f"vibroplan yield: {len(w['dies'])} dies of the default plan "
                         "on their true models")
    plot_wafer_map([{"die_x": k[0], "die_y": k[1], "outcome": r["outcome"],
                     "causes": [c for c in r["causes"].split("; ") if c]}
                    for k, r in batch["csv"].items()], w["die_size_mm"],
                   out.parent / "wafer_map_replan.png", diameter_mm=w["diameter_mm"],
                   edge_exclusion_mm=w["edge_exclusion_mm"],
                   title="vibroplan replan --measured wafer_1.csv --trim: the same dies "
                         "from their measurement")
    c0, c1 = plans["coloring"]["manufacturability"], plans["neighbours"]["manufacturability"]
    lines = ["# A wafer at a time (issue 39)", "",
             f"`python benchmarks/wafer.py --work {args.work} --jobs {args.jobs} --dies "
             f"{args.dies} --seed {args.seed} --gradient {args.gradient}`", "",
             f"Machine: {mach['cpu']}, {mach['cores']} cores, Python {mach['python']}; load "
             f"average {mach['load'][0]:.1f} at the end.", "",
             "The default spec (`configs/array_5x5.yaml`: line width 0.05 um per die, 0.02 um "
             "per device) on a wafer: " + json.dumps(WAFER) + f", within-die gradient "
             f"{args.gradient:g} um/mm (one sigma of each of its x and y components).", "",
             "## Frequency neighbours placed near each other", "",
             "Seed 0, planned twice: today's channel order (`drive.channels.placement: "
             "coloring`: the colouring gives the channels in reading order, A1 to E5, so each "
             "row's last device and the next row's first, 8 mm apart, are tone neighbours) "
             "and `placement: neighbours` (a serpentine walk: tone neighbours on neighbouring "
             "devices, 2 mm apart).", "",
             "| placement | verifies | predicted collision-free yield (95 % CI) | die errors "
             "alone | most often colliding | plan time [s] |", "|---|---|---|---|---|---|"]
    for name, m in (("coloring", c0), ("neighbours", c1)):
        p = plans[name]
        y_ = m["collision_free_yield"]
        checks = [c for st in p["verification"]["steps"].values() for c in st.values()]
        ok = sum(1 for c in checks if c["passed"])
        lines.append(f"| {name} | {ok}/{len(checks)} | {y_['value']:.4f} "
                     f"({y_['ci95'][0]:.4f}-{y_['ci95'][1]:.4f}) | {m['die_only_yield']:.4f} | "
                     + ", ".join(f"{'/'.join(q['pair'])} {100 * q['collision_fraction']:.1f} %"
                                 for q in m["limiting_pairs"][:2])
                     + f" | {times.get(f'plan {name}', float('nan')):.0f} |")
    lines += ["", "The same designs' prediction at other gradients (10^4 chips, same seed, "
              "the plans' recorded sensitivities and separations):", "",
              "| gradient [um/mm] | coloring | neighbours | gain |", "|---|---|---|---|"]
    for g in GRADIENTS:
        a, b = curve["coloring"][g]["value"], curve["neighbours"][g]["value"]
        lines.append(f"| {g:g} | {a:.4f} | {b:.4f} | {b - a:+.4f} |")
    n = len(rows)
    oc = y["wafer"]["outcomes"]
    lines += ["", "## A wafer sampled by the yield, re-planned in batch", "",
              f"`vibroplan yield plan_coloring --chips {args.dies} --replan --trim --jobs "
              f"{args.jobs}`: {n} dies of one wafer, on their true models: "
              + ", ".join(f"{k} {v}" for k, v in oc.items())
              + f" ({times.get('yield', float('nan')):.0f} s).  Then `vibroplan replan "
              f"plan_coloring --measured wafer_1.csv --trim --jobs {args.jobs}`: "
              f"**{times.get('replan csv', float('nan')):.0f} s for {len(batch['csv'])} dies** "
              f"({times.get('replan csv', float('nan')) / max(len(batch['csv']), 1):.1f} s per "
              f"die on {args.jobs} workers), and the same wafer from wafer_1.stdf in "
              f"{times.get('replan stdf', float('nan')):.0f} s.", "",
              f"Per-die outcomes, the batch (what the lab can know: the measured models) "
              f"against the yield (the true models): **{agree} of {n} agree**; the STDF "
              f"file's re-plan agrees with the CSV's on {agree_stdf} of {n} (its resonances "
              "are 4-byte floats).", ""]
    if differ:
        lines += ["| die | yield (true models) | causes | batch (measured models) | causes |",
                  "|---|---|---|---|---|"]
        lines += [f"| ({r['die_x']}, {r['die_y']}) | {r['yield_outcome']} | "
                  f"{r['yield_causes'] or '-'} | {r['replan_outcome']} | "
                  f"{r['replan_causes'] or '-'} |" for r in differ]
        lines.append("")
    lines += ["![the yield's wafer map](wafer_map_yield.png)", "",
              "![the batch re-plan's wafer map](wafer_map_replan.png)", "",
              "Per die: wafer.csv.  Times: " + json.dumps(
                  {k: round(v, 1) for k, v in times.items()}), ""]
    out.write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
