"""Robust design (``design.robust``) against nominal design: cost and yield.

    python benchmarks/robust_design.py [--spec configs/row_assembly.yaml] [--chips 100]
                                       [--jobs 2] [--seed 0] [--device-only]

Plans the spec twice, nominal and with ``design.robust: true`` (k = ``design.robust_k``,
default 2), under the tolerance of issue 16 (line width sigma 0.05 um per die and
0.02 um per device; ``--device-only`` drops the per-die part), then runs the same
yield Monte Carlo (same seed, same chips) on both plans.  Reports per plan: whether it
verifies, span, design time, the smallest r_min, and the yield with
its 95 % Wilson interval.  Writes benchmarks/results/robust_design.md.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import yaml

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from planner.planning import plan  # noqa: E402
from planner.arrayspec import load_spec  # noqa: E402
from planner.planfile.reader import read_plan  # noqa: E402
from planner.yield_ import make_payload, run_yield  # noqa: E402


def _spec_text(path, robust, device_only):
    data = yaml.safe_load(Path(path).read_text())
    data["fabrication"] = {"line_width_um": {"die": 0.0 if device_only else 0.05,
                                             "device": 0.02}}
    data.setdefault("design", {})["robust"] = bool(robust)
    return yaml.safe_dump(data, sort_keys=False) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spec", default=str(HERE.parent / "configs" / "row_assembly.yaml"))
    ap.add_argument("--chips", type=int, default=100)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--device-only", action="store_true")
    ap.add_argument("--out", default=str(HERE / "results" / "robust_design.md"))
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for robust in (False, True):
            text = _spec_text(args.spec, robust, args.device_only)
            out = Path(tmp) / ("robust" if robust else "nominal")
            t0 = time.perf_counter()
            result = plan(load_spec(text), out_dir=out, figures=False, jobs=args.jobs)
            wall = time.perf_counter() - t0
            record = read_plan(out)
            data = json.loads(record.path.read_text())  # the report's numbers
            imps = data["impacters"]
            t1 = time.perf_counter()
            y = run_yield(make_payload(record, args.seed), args.chips, jobs=args.jobs)
            ymc = time.perf_counter() - t1
            rows.append({
                "design": "robust (k = 2)" if robust else "nominal",
                "verifies": result.passed,
                "span": data["assignment"]["span"],
                "design_s": result.timings.get("design", float("nan")),
                "plan_s": wall,
                "r_min_nN": 1e9 * min(r.get("r_min_n") or 0.0 for r in imps),
                "feasible": sum(1 for r in imps if r.get("feasible", True)),
                "n": len(imps),
                "yield": y["yield"], "ci95": y["ci95"], "chips": y["chips"],
                "passed": y["passed"], "yield_s": ymc,
            })
            print(rows[-1], flush=True)
    tol = ("line width sigma 0.02 um per device (no per-die part)" if args.device_only else
           "line width sigma 0.05 um per die and 0.02 um per device")
    lines = [f"# Robust design against nominal design: {Path(args.spec).name}", "",
             f"Tolerance: {tol}. {args.chips} chips, seed {args.seed}, --jobs {args.jobs}; "
             f"load average at the end {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores "
             "(shared machine: times are a rough guide).", "",
             f"    python benchmarks/robust_design.py --spec {args.spec} --chips {args.chips} "
             f"--jobs {args.jobs} --seed {args.seed}" + (" --device-only" if args.device_only
                                                          else ""), "",
             "| design | verifies | span [channels] | feasible designs | design [s] | "
             "plan [s] | min r_min [nN] | yield | 95 % CI | Monte Carlo [s] |",
             "|---|---|---:|---:|---:|---:|---:|---:|---|---:|"]
    for r in rows:
        lines.append(f"| {r['design']} | {'yes' if r['verifies'] else 'no'} | {r['span']} | "
                     f"{r['feasible']}/{r['n']} | {r['design_s']:.1f} | {r['plan_s']:.1f} | "
                     f"{r['r_min_nN']:.1f} | {r['yield']:.3f} ({r['passed']}/{r['chips']}) | "
                     f"[{r['ci95'][0]:.3f}, {r['ci95'][1]:.3f}] | {r['yield_s']:.0f} |")
    Path(args.out).write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
