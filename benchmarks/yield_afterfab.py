"""After fabrication (issue 26): the plan's drive, a re-plan per chip, and trims where needed.

    python benchmarks/yield_afterfab.py --plan DIR [--chips 200] [--jobs 2]
        [--sigma-scale 1] [--measure-noise 0.05] [--trim-precision 0.1] [--seed 0]
        [--spec FILE] [--out FILE] [--work DIR]

Runs ``vibroplan yield PLAN --replan --trim --measure-noise PCT --trim-precision PCT`` (its
tolerance model the plan's own ``fabrication:`` section, or ``--spec``'s) and writes the
three yields with their Wilson intervals, what made chips fail, and the time per chip to
benchmarks/results/yield_afterfab.md.  Also prints the plan's predicted collision-free
yield (plan.json's ``manufacturability``) beside them: the prediction of issue 25 against
the full simulation.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from _timing import machine  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plan", required=True, help="a plan folder (vibroplan plan --out)")
    ap.add_argument("--chips", type=int, default=200)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--sigma-scale", default="1")
    ap.add_argument("--measure-noise", default="0.05")
    ap.add_argument("--trim-precision", default="0.1")
    ap.add_argument("--spec", default=None)
    ap.add_argument("--work", default=None)
    ap.add_argument("--out", default=str(HERE / "results" / "yield_afterfab.md"))
    args = ap.parse_args()
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="afterfab-"))
    work.mkdir(parents=True, exist_ok=True)
    out_dir = work / "yield"
    cmd = ["vibroplan", "yield", args.plan, "--chips", str(args.chips), "--seed",
           str(args.seed), "--jobs", str(args.jobs), "--sigma-scale", args.sigma_scale,
           "--replan", "--trim", "--measure-noise", args.measure_noise, "--trim-precision",
           args.trim_precision, "--out", str(out_dir), "--quiet", "--force"]
    if args.spec:
        cmd += ["--spec", args.spec]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if not (out_dir / "yield.json").exists():
        raise SystemExit(f"vibroplan yield failed ({proc.returncode}): {proc.stderr[-800:]}")
    y = json.loads((out_dir / "yield.json").read_text())
    plan = json.loads((Path(args.plan) / "plan.json").read_text())
    m = plan.get("manufacturability") or {}
    pred = m.get("collision_free_yield")

    def row(name, block):
        lo, hi = block["ci95"]
        return (f"| {name} | {block['yield']:.3f} | [{lo:.3f}, {hi:.3f}] | "
                f"{block['passed']} / {block['chips'] if 'chips' in block else y['chips']} |")

    mach = machine()
    lines = ["# After fabrication: the plan's drive, re-planned per chip, trimmed where needed",
             "", f"Command: `{' '.join(cmd[:-4] if cmd[-4] == '--quiet' else cmd)}` "
             f"(via `python benchmarks/yield_afterfab.py --plan {args.plan} --chips "
             f"{args.chips}`)", "",
             f"Machine: {mach['cpu']}, {mach['cores']} cores, Python {mach['python']}; load "
             f"average {mach['load'][0]:.1f} at the end.  Plan: `{args.plan}` "
             f"(seed {plan['seed']}, {len(plan['impacters'])} impacters).  Tolerance: "
             + ", ".join(f"{k} die {v['die']:g} device {v['device']:g}"
                         + (f" pair {v['pair']:g}" if v.get("pair") else "")
                         for k, v in y["tolerance"].items()
                         if isinstance(v, dict) and any(v.values()))
             + f"; measurement noise {args.measure_noise} %, trim precision "
             f"{args.trim_precision} %.", "",
             "| drive | yield | 95 % Wilson CI | chips |", "|---|---|---|---|",
             row("the plan's drive", y), row("re-planned per chip", y["replan"]),
             row("trimmed where needed, re-planned", y["trim"]), ""]
    if pred:
        lines += [f"Predicted collision-free yield (plan.json, issue 25): {pred['value']:.3f} "
                  f"[{pred['ci95'][0]:.3f}, {pred['ci95'][1]:.3f}] ({pred['chips']} chips, "
                  "first order, no simulation); the re-planned yield above is the full "
                  "simulation of every step on every chip.", ""]
    lines += [f"Wall time {wall / 60:.1f} min for {args.chips} chips "
              f"({wall / max(args.chips, 1):.1f} s per chip, {args.jobs} jobs).", ""]
    for name, block in (("re-plan", y["replan"]), ("trim", y["trim"])):
        if block.get("causes"):
            lines += [f"Why chips fail after the {name}: "
                      + ", ".join(f"{k} ({v})" for k, v in block["causes"].items())
                      + ("; checks failing on the true models: "
                         + ", ".join(f"{k} ({v})" for k, v in block["failures"].items())
                         if block.get("failures") else "") + ".", ""]
    Path(args.out).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
