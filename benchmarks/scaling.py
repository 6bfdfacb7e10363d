"""Plan time against array size, split by stage, on 1 and 2 workers (issue 18).

Cases (every one a real spec, planned end to end without files):

* ``3x3``, ``5x5``, ``7x7``: ``configs/array_7x7.yaml`` (every impacter independent,
  4-60 kHz, 100 Hz channels, no scenes) on 3 x 3, 5 x 5 and 7 x 7 devices;
* ``10x10_rows``: ``configs/array_10x10_rows.yaml`` (a row's devices share a channel;
  200 independent impacters do not fit a realistic band);
* ``default_5x5``: ``configs/array_5x5.yaml``, the default plan (independent, plus a
  scene of two multi-tone steps): the cost model's calibration point.

Each case runs in its own process (``python benchmarks/scaling.py --case NAME --jobs J``
is what the driver calls), so that every run starts with the same warm numba cache and
no design cache.  For each run the table gives ``Plan.timings`` per stage, the work
(designs, steps) and the estimate ``vibroplan plan`` prints after the assignment
(:mod:`planner.planning.estimate`), to judge the cost model.

Usage::

    python benchmarks/scaling.py                      # every case on 1 and 2 workers
    python benchmarks/scaling.py --cases 3x3 10x10_rows --jobs 2

Rows are merged into benchmarks/results/scaling.csv (a re-run replaces its case and
jobs) and the table is rewritten to benchmarks/results/scaling.md.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
RESULTS = HERE / "results"
CONFIGS = ROOT / "configs"
CASES = {
    "3x3": ("array_7x7.yaml", 3),
    "5x5": ("array_7x7.yaml", 5),
    "7x7": ("array_7x7.yaml", 7),
    "10x10_rows": ("array_10x10_rows.yaml", None),
    "default_5x5": ("array_5x5.yaml", None),
}
#: Text below this line of scaling.md is kept when the table is rewritten.
NOTES = "<!-- notes: kept by benchmarks/scaling.py -->"
STAGES = ["assign", "drive", "design", "verify", "scenes_coupling", "total"]


def spec_text(case):
    """The YAML text of a case."""
    name, size = CASES[case]
    text = (CONFIGS / name).read_text()
    if size is not None:
        text = (text.replace("rows: 7", f"rows: {size}").replace("cols: 7", f"cols: {size}")
                .replace("name: array_7x7", f"name: array_{size}x{size}"))
    return text


def run_case(case, jobs):
    """Plan one case in this process; returns one result row (dict)."""
    import numba

    from planner.planning import run_plan
    from planner.planning.estimate import estimate
    from planner.planning.settings import resolve_settings
    from planner.arrayspec import load_spec

    numba.set_num_threads(jobs)
    loaded = load_spec(spec_text(case), source=case)
    settings = resolve_settings(loaded)
    est = {}

    def on_assignment(s, steps, a):
        est["e"] = estimate(s, steps, a, jobs)

    t0 = time.perf_counter()
    plan = run_plan(loaded, jobs=jobs, settings=settings, on_assignment=on_assignment)
    wall = time.perf_counter() - t0
    e = est["e"]
    row = {"case": case, "jobs": jobs, "impacters": e.impacters, "designs": e.designs,
           "steps": e.steps, "passed": bool(plan.passed),
           "rounds": len(plan.data["verification"]["repair_rounds"]),
           "estimate_s": round(e.total_s, 1), "estimate_design_s": round(e.design_s, 1),
           "estimate_verify_s": round(e.verify_s, 1),
           "estimate_coupling_s": round(e.coupling_s, 1), "wall_s": round(wall, 1),
           "load_end": round(os.getloadavg()[0], 2)}
    for k in STAGES:
        row[k] = round(float(plan.timings.get(k, 0.0)), 1)
    return row


def write_results(rows):
    import pandas as pd

    sys.path.insert(0, str(HERE))
    from _timing import machine

    RESULTS.mkdir(exist_ok=True)
    csv = RESULTS / "scaling.csv"
    df = pd.DataFrame(rows)
    if csv.exists():
        old = pd.read_csv(csv)
        keep = ~old.set_index(["case", "jobs"]).index.isin(df.set_index(["case", "jobs"]).index)
        df = pd.concat([old[keep], df], ignore_index=True)
    order = {c: i for i, c in enumerate(CASES)}
    df = df.sort_values(["case", "jobs"], key=lambda s: s.map(order) if s.name == "case"
                        else s).reset_index(drop=True)
    df.to_csv(csv, index=False)
    lines = ["# Plan time against array size", "",
             f"`python benchmarks/scaling.py` on {machine()}.  Wall-clock seconds of "
             "`run_plan` (no files) per stage (`Plan.timings`), numba kernels warm, no "
             "design cache; one process per run.  The machine is shared: `load` is the "
             "1-minute load average when the run ended (2 cores).  `estimate` is what "
             "`vibroplan plan` prints after the assignment (the cost model of "
             "`planner/planning/estimate.py`).", "",
             "| case | jobs | impacters | designs | steps | " + " | ".join(STAGES)
             + " | estimate | passed | rounds | load |",
             "|---|---:|---:|---:|---:|" + "---:|" * len(STAGES) + "---:|---|---:|---:|"]
    for r in df.to_dict("records"):
        lines.append(f"| {r['case']} | {r['jobs']} | {r['impacters']} | {r['designs']} | "
                     f"{r['steps']} | " + " | ".join(f"{r[k]:.1f}" for k in STAGES)
                     + f" | {r['estimate_s']:.0f} | {r['passed']} | {r['rounds']} | "
                     f"{r['load_end']:.1f} |")
    # hand-written notes below the marker (what was not run, other measurements) stay
    md = RESULTS / "scaling.md"
    notes = ""
    if md.exists() and NOTES in md.read_text():
        notes = md.read_text()[md.read_text().index(NOTES):]
    md.write_text("\n".join(lines) + "\n\n" + (notes or NOTES + "\n"))
    return df


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    parser.add_argument("--jobs", nargs="+", type=int, default=[1, 2])
    parser.add_argument("--case", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.case:
        # a single run, in its own process: print its row as JSON
        print(json.dumps(run_case(args.case, args.jobs[0])), flush=True)
        return
    rows = []
    for case in args.cases:
        for jobs in args.jobs:
            print(f"{case} on {jobs} worker(s) ...", file=sys.stderr, flush=True)
            out = subprocess.run([sys.executable, str(Path(__file__)), "--case", case,
                                  "--jobs", str(jobs)], cwd=ROOT, check=True,
                                 capture_output=True, text=True)
            row = json.loads(out.stdout.strip().splitlines()[-1])
            print(row, file=sys.stderr, flush=True)
            rows.append(row)
            write_results([row])
    return rows


if __name__ == "__main__":
    main()
