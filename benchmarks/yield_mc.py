"""Yield Monte Carlo benchmark: the default 5 x 5 plan under line-width variation.

    python benchmarks/yield_mc.py [--plan DIR] [--chips 200] [--jobs 1,2] [--seed 0]

Tolerance: line width sigma 0.05 um per die and 0.02 um per device (issue 16), nothing
else.  Runs the same Monte Carlo (same seed) once per entry of ``--jobs`` (1: in
process; n > 1: a local Dask cluster of n single-threaded processes), checks that the
numbers agree, and reports the yield with its 95 % Wilson interval, the checks that
fail and chips verified per minute, with the machine's load average (the machine is
shared).  Without ``--plan`` the default 5 x 5 spec is planned first (minutes).
Writes benchmarks/results/yield.md.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from planner.arrayspec import FabricationSpec, Tolerance  # noqa: E402
from planner.planfile.reader import read_plan  # noqa: E402
from planner.yield_ import make_payload, run_yield  # noqa: E402

sys.path.insert(0, str(HERE))
from _timing import machine  # noqa: E402

TOLERANCE = FabricationSpec(line_width_um=Tolerance(die=0.05, device=0.02))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plan", help="plan folder or plan.json (default: plan the 5x5 default)")
    ap.add_argument("--chips", type=int, default=200)
    ap.add_argument("--jobs", default="1,2")
    ap.add_argument("--chips-per-run", default=None,
                    help="chips for each --jobs entry, e.g. 40,200 (default: --chips each)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(HERE / "results" / "yield.md"))
    args = ap.parse_args(argv)
    if args.plan is None:
        from planner.planning import plan

        folder = Path(tempfile.mkdtemp()) / "plan"
        t = time.perf_counter()
        plan(None, out_dir=folder, figures=False)
        print(f"planned the default 5x5 in {time.perf_counter() - t:.0f} s", file=sys.stderr)
        args.plan = str(folder)
    record = read_plan(args.plan)
    path = record.path
    data = json.loads(path.read_text())  # the report's numbers
    payload = make_payload(record, args.seed, TOLERANCE)
    runs = []
    jobs_list = [int(j) for j in args.jobs.split(",")]
    counts = ([int(c) for c in args.chips_per_run.split(",")] if args.chips_per_run
              else [args.chips] * len(jobs_list))
    for jobs, chips in zip(jobs_list, counts):
        load0 = os.getloadavg()[0]
        t = time.perf_counter()
        res = run_yield(payload, chips, jobs=jobs)
        dt = time.perf_counter() - t
        load1 = os.getloadavg()[0]
        runs.append({"jobs": jobs, "chips": chips, "seconds": dt,
                     "chips_per_min": (chips + 1) / dt * 60,
                     "load": (load0, load1), "result": res})
        print(f"jobs {jobs}: {dt:.0f} s, yield {res['yield']:.3f} {res['ci95']}, "
              f"failures {res['failures']}", file=sys.stderr)
    # chip i is the same chip in every run: compare the failing chips of the common prefix
    common = min(r["chips"] for r in runs)
    same = all([c for c in r["result"]["failed_chips"] if c < common]
               == [c for c in runs[0]["result"]["failed_chips"] if c < common] for r in runs)
    res = max(runs, key=lambda r: r["chips"])["result"]
    lo, hi = res["ci95"]
    lines = [
        "# Yield Monte Carlo benchmark", "",
        f"`python benchmarks/yield_mc.py --chips {args.chips} --jobs {args.jobs} "
        + (f"--chips-per-run {args.chips_per_run} " if args.chips_per_run else "")
        + f"--seed {args.seed}` on {machine()['cpu']} ({os.cpu_count()} CPUs), Python "
        f"{platform.python_version()}; plan: the default 5 x 5 "
        f"(`{data['spec']['name']}`, {len(data['impacters'])} impacters, "
        f"{len(data['steps'])} steps). Wall-clock; the machine was shared (load averages "
        "below: other people's jobs ran at the same time, so the times are upper bounds).",
        "", "Tolerance: line width sigma 0.05 um per die, 0.02 um per device; nothing else.", "",
        f"**Yield {res['yield']:.3f}** ({res['passed']} of {res['chips']} chips), 95 % Wilson "
        f"interval [{lo:.3f}, {hi:.3f}]; nominal chip "
        f"{'passes' if res['nominal']['passed'] else 'FAILS'}.", "",
        "Checks failing (chips): " + (", ".join(f"{k} {v}" for k, v in res["failures"].items())
                                      or "none") + ".", "",
        "Impacters failing most: " + ", ".join(
            f"{n} {r:.2f}" for n, r in sorted(res["impacters"].items(), key=lambda kv: -kv[1])[:6]
            if r > 0) + ".", "",
        "| workers | chips (+ nominal) | wall [s] | chips / min | load avg before -> after |",
        "|---:|---:|---:|---:|---|",
    ]
    for r in runs:
        lines.append(f"| {r['jobs']} | {r['chips']} + 1 | {r['seconds']:.0f} | "
                     f"{r['chips_per_min']:.1f} | {r['load'][0]:.1f} -> {r['load'][1]:.1f} |")
    lines += ["", f"Same failing chips (indices < {common}) on every worker count: "
              f"{'yes' if same else 'NO'}.", ""]
    Path(args.out).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
