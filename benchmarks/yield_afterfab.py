"""After fabrication (issues 26, 37): the plan's drive, a re-plan per chip, tuned on the
chip, and trimmed where needed, at one or more measurement noise levels.

    python benchmarks/yield_afterfab.py --plan DIR [--chips 200] [--jobs 2]
        [--measure-noise 0.05,0.01,0.1] [--trim-precision 0.1] [--seed 0]
        [--no-tune] [--spec FILE] [--out FILE] [--work DIR]

Runs ``vibroplan yield PLAN --replan --tune --trim --measure-noise PCT`` once per noise
level (its tolerance model the plan's own ``fabrication:`` section, or ``--spec``'s) and
writes one table per level -- the yields with their Wilson intervals against issue 37's
targets (re-planned >= 0.95, tuned >= 0.98, trimmed >= 0.99, judged on the Wilson lower
bound), what made chips fail (cause and check kind), and the time per chip -- to
benchmarks/results/yield_afterfab.md.  The plan's predicted collision-free yield
(plan.json's ``manufacturability``) is printed beside them.
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

#: Issue 37's targets on the default plan: block -> yield asked.
TARGETS = {"replan": 0.95, "tune": 0.98, "trim": 0.99}
#: The study's time budget for 200 chips on a 2-core machine [min].
BUDGET_MIN = 15.0


def run_level(args, noise: str, work: Path):
    """One ``vibroplan yield`` at measurement noise ``noise`` [%]: (command, yield.json,
    wall time [s])."""
    out_dir = work / f"yield_{noise.replace('.', 'p')}"
    cmd = ["vibroplan", "yield", args.plan, "--chips", str(args.chips), "--seed",
           str(args.seed), "--jobs", str(args.jobs), "--replan"]
    cmd += [] if args.no_tune else ["--tune"]
    cmd += ["--trim", "--measure-noise", noise, "--trim-precision", args.trim_precision]
    if args.spec:
        cmd += ["--spec", args.spec]
    shown = list(cmd)
    cmd += ["--out", str(out_dir), "--quiet", "--force"]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if not (out_dir / "yield.json").exists():
        raise SystemExit(f"vibroplan yield failed ({proc.returncode}): {proc.stderr[-800:]}")
    (out_dir / "wall_s.txt").write_text(f"{wall:.1f}\n")
    return shown, json.loads((out_dir / "yield.json").read_text()), wall


def reused_level(args, noise: str, work: Path):
    """A level already run into ``work`` (``--reuse``): its command as it would be run,
    yield.json and the wall time in its ``wall_s.txt``."""
    out_dir = work / f"yield_{noise.replace('.', 'p')}"
    cmd = ["vibroplan", "yield", args.plan, "--chips", str(args.chips), "--seed",
           str(args.seed), "--jobs", str(args.jobs), "--replan"]
    cmd += [] if args.no_tune else ["--tune"]
    cmd += ["--trim", "--measure-noise", noise, "--trim-precision", args.trim_precision]
    wall = float((out_dir / "wall_s.txt").read_text())
    return cmd, json.loads((out_dir / "yield.json").read_text()), wall


def level_lines(noise, shown, y, wall, chips):
    def row(name, block, key=None):
        lo, hi = block["ci95"]
        target = TARGETS.get(key)
        verdict = ("-" if target is None else
                   f">= {target:g}: {'met' if lo >= target else 'missed'}"
                   + ("" if lo >= target else f" by {target - lo:.3f} (lower bound)"))
        return (f"| {name} | {block['yield']:.3f} | [{lo:.3f}, {hi:.3f}] | "
                f"{block['passed']} / {block.get('chips', y['chips'])} | {verdict} |")

    lines = [f"## Measurement noise {noise} %", "", f"`{' '.join(shown)}`", "",
             "| drive | yield | 95 % Wilson CI | chips | target (Wilson lower bound) |",
             "|---|---|---|---|---|",
             row("the plan's drive", y), row("re-planned per chip", y["replan"], "replan")]
    told = y["replan"]["chips"] - y["replan"]["causes"].get("cannot be told apart", 0)
    if "tune" in y:
        lines.append(row("re-planned and tuned on the chip", y["tune"], "tune"))
    lines += [row("trimmed where needed, re-planned" + (" and tuned" if "tune" in y else ""),
                  y["trim"], "trim"), ""]
    lines += [f"Of the {told} chips the re-plan can tell apart, re-planned: "
              f"{y['replan']['passed']} = {y['replan']['passed'] / max(told, 1):.3f} (issue 45 "
              "asks >= 0.95)"
              + (f"; tuned: {y['tune']['passed']} = {y['tune']['passed'] / max(told, 1):.3f}"
                 if "tune" in y else "") + ".", ""]
    tu = y.get("tune") or {}
    if "kept_replan" in tu:
        raised = tu.get("repaired_chips", {}).get("amplitude_raised", 0)
        timed = tu.get("repaired_chips", {}).get("gates_timed_on_chip", 0)
        lines += [f"Played on the chip (the tune stage): the re-plan kept where the tuned drive "
                  f"failed on the chip and it worked: {tu['kept_replan']} chips; a slider too "
                  f"slow on the chip, its tone raised: {raised} chips "
                  f"({tu.get('repairs', {}).get('amplitude_raised', 0)} steps); a slider off "
                  f"its target, the step's gates timed on the chip: {timed} chips.", ""]
    lines += [f"Wall time {wall / 60:.1f} min for {chips} chips ({wall / max(chips, 1):.1f} s "
              f"per chip; budget {BUDGET_MIN:g} min for 200: "
              f"{'met' if wall * 200 / max(chips, 1) <= 60 * BUDGET_MIN else 'missed'}).", ""]
    for name, key in (("re-plan", "replan"), ("tune", "tune"), ("trim", "trim")):
        block = y.get(key)
        if block and block.get("causes"):
            lines += [f"Why chips fail after the {name}: "
                      + ", ".join(f"{k} ({v})" for k, v in block["causes"].items())
                      + ("; checks failing on the true models: "
                         + ", ".join(f"{k} ({v})" for k, v in block["failures"].items())
                         if block.get("failures") else "") + ".", ""]
    return lines


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plan", required=True, help="a plan folder (vibroplan plan --out)")
    ap.add_argument("--chips", type=int, default=200)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--measure-noise", default="0.05,0.01,0.1",
                    help="comma-separated noise levels [%%], one run each")
    ap.add_argument("--trim-precision", default="0.1")
    ap.add_argument("--no-tune", action="store_true", help="leave out --tune")
    ap.add_argument("--spec", default=None)
    ap.add_argument("--work", default=None)
    ap.add_argument("--out", default=str(HERE / "results" / "yield_afterfab.md"))
    ap.add_argument("--reuse", action="store_true",
                    help="read each level's yield.json and wall_s.txt from --work instead "
                         "of running it (a run of this script, or the same command by hand)")
    args = ap.parse_args()
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="afterfab-"))
    work.mkdir(parents=True, exist_ok=True)
    plan = json.loads((Path(args.plan) / "plan.json").read_text())
    m = plan.get("manufacturability") or {}
    pred = m.get("collision_free_yield")
    levels = [x.strip() for x in args.measure_noise.split(",") if x.strip()]
    body, tolerance = [], None
    for noise in levels:
        shown, y, wall = (reused_level if args.reuse else run_level)(args, noise, work)
        tolerance = y["tolerance"]
        body += level_lines(noise, shown, y, wall, args.chips)
        print("\n".join(body[-12:]), flush=True)
    mach = machine()
    lines = ["# After fabrication: the plan's drive, re-planned per chip, tuned, trimmed",
             "", f"Via `python benchmarks/yield_afterfab.py --plan {args.plan} --chips "
             f"{args.chips} --measure-noise {','.join(levels)}`.", "",
             f"Machine: {mach['cpu']}, {mach['cores']} cores, Python {mach['python']}; load "
             f"average {mach['load'][0]:.1f} at the end.  Plan: `{args.plan}` "
             f"(seed {plan['seed']}, {len(plan['impacters'])} impacters).  Tolerance: "
             + ", ".join(f"{k} die {v['die']:g} device {v['device']:g}"
                         + (f" pair {v['pair']:g}" if v.get("pair") else "")
                         for k, v in tolerance.items()
                         if isinstance(v, dict) and any(v.values()))
             + f"; trim precision {args.trim_precision} %; chip seed {args.seed}.", ""]
    if pred:
        lines += [f"Predicted collision-free yield (plan.json, issue 25): {pred['value']:.3f} "
                  f"[{pred['ci95'][0]:.3f}, {pred['ci95'][1]:.3f}] ({pred['chips']} chips, "
                  "first order, no simulation); the yields below are the full simulation of "
                  "every step on every chip's true models.", ""]
    told = m.get("told_apart_yield")
    if told:
        lines += [f"Predicted share told apart as measured (plan.json `told_apart_yield`, "
                  f"{told['measurement_noise_pct']:g} % noise): {told['value']:.3f} "
                  f"[{told['ci95'][0]:.3f}, {told['ci95'][1]:.3f}]; held against 10 000 "
                  "sampled chips in collision_calibration.md.", ""]
    Path(args.out).write_text("\n".join(lines + body) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
