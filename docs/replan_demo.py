"""The docs/replan.md experiment: a chip whose every impacter is off its design by a
random +-PCT % (or all by +PCT % with --uniform), re-planned with `vibroplan replan`.

    python docs/replan_demo.py PLAN_DIR OUT_DIR [--pct 3] [--seed 0]

Writes OUT_DIR/measured.csv, runs `vibroplan replan PLAN_DIR --measured ... --out
OUT_DIR/replan` and prints whether the original drive and the re-planned drive pass
on the shifted chip.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("plan")
    ap.add_argument("out")
    ap.add_argument("--pct", type=float, default=3.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--uniform", action="store_true",
                    help="shift every impacter by the same +PCT %% (a die-level bias)")
    args = ap.parse_args()
    plan = json.loads((Path(args.plan) / "plan.json").read_text())
    rng = np.random.default_rng(args.seed)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = ["impacter,natural_frequency_hz"]
    for rec in plan["impacters"]:
        shift = (args.pct if args.uniform else rng.uniform(-args.pct, args.pct)) / 100
        rows.append(f"{rec['id']},{rec['natural_frequency_hz'] * (1 + shift):.6f}")
    (out / "measured.csv").write_text("\n".join(rows) + "\n")
    cmd = [sys.executable, "-m", "planner.cli", "replan", args.plan, "--measured",
           str(out / "measured.csv"), "--out", str(out / "replan"), "--no-figures", "--quiet"]
    print(" ".join(cmd[1:]))
    proc = subprocess.run(cmd, capture_output=True, text=True)
    print(proc.stdout + proc.stderr)
    print(f"exit {proc.returncode}")
    if (out / "replan" / "plan.json").exists():
        d = json.loads((out / "replan" / "plan.json").read_text())
        od = d["replan"]["original_drive"]
        print(f"original drive passes: {od['passed']} ({od['checks'] - od['failed_checks']}/"
              f"{od['checks']}); re-plan passes: {d['verification']['passed']}; "
              f"repair rounds: {d['verification']['repair_rounds']}; inseparable: "
              f"{len(d['replan']['inseparable'])}")


if __name__ == "__main__":
    main()
