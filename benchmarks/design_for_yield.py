"""Design for yield (issue 25): predicted collision-free yield and design time, the default
before issue 25 against the default after it.

    python benchmarks/design_for_yield.py [--seeds 0] [--jobs 2] [--out FILE]
        [--before SPEC] [--after SPEC] [--work DIR] [--full-yield-chips N]

For each spec and seed: the grid-level prediction (``vibroplan plan --dry-run``, seconds,
before any design), then a real plan (``vibroplan plan``, an empty design cache, so the
design time is a first run's) and its design-level prediction (plan.json's
``manufacturability``): the collision-free yield with its interval, the die-only and
device-only yields, the closest as-built pair, the line-width sensitivities' range, and
the verification.  With ``--full-yield-chips N`` the plan is also put through
``vibroplan yield --replan`` on N chips (full simulation of every step on every chip,
measured and re-planned), the check of the prediction.

Specs: ``--before`` defaults to benchmarks/data/array_5x5_before_yield.yaml (the previous
default, unmatched designs on a 500 Hz linear grid, with the tolerance model added);
``--after`` to configs/array_5x5.yaml.  Writes benchmarks/results/design_for_yield.md.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from _timing import machine  # noqa: E402


def _run(cmd):
    t = time.perf_counter()
    out = subprocess.run(cmd, capture_output=True, text=True)
    return out, time.perf_counter() - t


def _dry(spec):
    out, secs = _run(["vibroplan", "plan", str(spec), "--dry-run"])
    line = next((x for x in (out.stdout + out.stderr).splitlines()
                 if "collision-free yield" in x), "")
    return line, secs


def _plan(spec, seed, jobs, work):
    out_dir = work / f"{Path(spec).stem}_s{seed}"
    cache = work / f"cache_{Path(spec).stem}_s{seed}"
    shutil.rmtree(cache, ignore_errors=True)
    out, secs = _run(["vibroplan", "plan", str(spec), "--seed", str(seed), "--jobs", str(jobs),
                      "--out", str(out_dir), "--cache-dir", str(cache), "--no-figures",
                      "--quiet"])
    if out.returncode not in (0, 1):
        raise SystemExit(f"plan of {spec} failed: {out.stderr.strip()[-500:]}")
    data = json.loads((out_dir / "plan.json").read_text())
    design_s = None
    for line in out.stdout.splitlines():
        if line.startswith("time:"):
            for part in line[5:].split(","):
                name, value = part.split()[0], part.split()[1]
                if name == "design":
                    design_s = float(value)
    return data, secs, design_s, out_dir


def _full_yield(plan_dir, chips, jobs, work):
    out_dir = work / (plan_dir.name + "_yield")
    out, secs = _run(["vibroplan", "yield", str(plan_dir), "--replan", "--chips", str(chips),
                      "--jobs", str(jobs), "--out", str(out_dir), "--quiet"])
    if not (out_dir / "yield.json").exists():
        return None, secs, out.stderr.strip()[-300:]
    return json.loads((out_dir / "yield.json").read_text()), secs, ""


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", default=str(HERE / "data" / "array_5x5_before_yield.yaml"))
    ap.add_argument("--after", default=str(HERE.parent / "configs" / "array_5x5.yaml"))
    ap.add_argument("--seeds", default="0", help="comma-separated plan seeds")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--full-yield-chips", type=int, default=0)
    ap.add_argument("--work", default=None, help="folder for the plans (default: a temp)")
    ap.add_argument("--out", default=str(HERE / "results" / "design_for_yield.md"))
    args = ap.parse_args()
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="dfy-"))
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    for label, spec in (("before (linear 500 Hz grid, unmatched)", args.before),
                        ("after (tolerance grid, matched)", args.after)):
        grid_line, grid_s = _dry(spec)
        for seed in (int(s) for s in args.seeds.split(",")):
            data, plan_s, design_s, plan_dir = _plan(spec, seed, args.jobs, work)
            m = data.get("manufacturability") or {}
            y = m.get("collision_free_yield") or {}
            lw = m.get("line_width_sensitivity_per_um") or {}
            c = m.get("closest_pair_hz") or {}
            ver = data["verification"]
            checks = sum(1 for rows_ in ver["steps"].values() for r in rows_.values()
                         if r["passed"])
            total = sum(len(r) for r in ver["steps"].values())
            full = ""
            if args.full_yield_chips:
                yj, ys, err = _full_yield(plan_dir, args.full_yield_chips, args.jobs, work)
                full = (f"{yj['replan']['yield']:.3f} ({yj['replan']['passed']}/"
                        f"{args.full_yield_chips}, {ys / 60:.1f} min)" if yj and "replan" in yj
                        else f"n/a {err}")
            rows.append([label, seed, grid_line.split(" from ")[0].replace(
                "predicted collision-free yield ", ""), f"{grid_s:.1f}",
                f"{y.get('value', float('nan')):.3f} [{y.get('ci95', [0, 0])[0]:.3f}, "
                f"{y.get('ci95', [0, 0])[1]:.3f}]" if y else "n/a",
                f"{m.get('die_only_yield', float('nan')):.3f} / "
                f"{m.get('device_only_yield', float('nan')):.3f}",
                f"{c.get('median', float('nan')):.0f} ({c.get('p5', float('nan')):.0f}-"
                f"{c.get('p95', float('nan')):.0f})",
                f"{lw.get('min', float('nan')):.3f}-{lw.get('max', float('nan')):.3f}",
                f"{checks}/{total}", f"{design_s:.0f}" if design_s is not None else "?",
                f"{plan_s:.0f}", full])
            print(" | ".join(str(x) for x in rows[-1]), flush=True)
    header = ["default", "seed", "grid-level prediction (dry run)", "dry run [s]",
              "predicted yield [95 % CI]", "die only / device only",
              "closest pair median (5-95 %) [Hz]", "line-width S [1/um]", "verification",
              "design [s]", "plan [s]", "full-simulation yield with re-plan"]
    mach = machine()
    lines = ["# Design for yield: predicted collision-free yield and design time", "",
             f"Command: `python benchmarks/design_for_yield.py --seeds {args.seeds} --jobs "
             f"{args.jobs}" + (f" --full-yield-chips {args.full_yield_chips}"
                               if args.full_yield_chips else "") + "`", "",
             f"Machine: {mach['cpu']}, {mach['cores']} cores, Python {mach['python']}, load "
             f"average {mach['load'][0]:.1f} at the end.  Tolerances: line width sigma 0.05 um per die, 0.02 um "
             "per device; 10^4 chips per prediction.  Design time is a first run's (empty "
             "design cache).", "",
             "| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    Path(args.out).write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
