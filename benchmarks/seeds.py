"""Seeds and specs (issue 36): does every seed of the default and of every shipped array
config give a verified plan, and what did the planner's loop have to do for it?

    python benchmarks/seeds.py [--configs default array_7x7 ...] [--seeds 0-19]
        [--other-seeds 0-4] [--jobs 2] [--out benchmarks/results/seeds.md] [--resume]

For each config and seed, ``vibroplan plan CFG --seed N --no-figures --quiet`` runs as a
subprocess with an empty design cache of its own (every design and reach probe is
computed, as on a first run) and the table records what its plan.json and its output
say: verified or not (exit 0 / 1 / 2: refused before any design), the checks passed, the
loop's rounds, the channels it moved, the phase draws it made, the designs it made and
kept by a re-check, the designs still infeasible, the stage times (reach, design,
total) and the wall time around the subprocess.

The default is planned for seeds 0-19 (``--seeds``), every other array config in
``configs/`` for seeds 0-4 (``--other-seeds``).  ``--resume`` keeps the rows of the CSV
beside ``--out`` that were measured on the same code (git revision) and runs the rest.

No assertion: the machine's load is printed with the table; timings from a loaded
machine are not comparable with an idle one's.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
from _timing import machine  # noqa: E402

#: The array configs shipped in configs/ (the paper_* files are single devices).
ARRAY_CONFIGS = ("array_5x5", "array_7x7", "array_10x10_rows", "pattern_5x5",
                 "row_assembly", "tiny_1x2")
TIME_LINE = re.compile(r"^time: (.*)$", re.M)


def _seeds(text):
    """'0-19' or '0,3,7' -> list of int."""
    out = []
    for part in text.split(","):
        if "-" in part:
            a, b = part.split("-")
            out += list(range(int(a), int(b) + 1))
        elif part:
            out.append(int(part))
    return out


def _stages(text):
    m = TIME_LINE.search(text)
    out = {}
    if m:
        for part in m.group(1).split(","):
            name, value = part.strip().rsplit(" ", 2)[:2]
            out[name] = float(value)
    return out


def _revision():
    try:
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                             capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               cwd=ROOT, capture_output=True, text=True).stdout.strip()
        return rev + ("+dirty" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def plan_one(config, seed, jobs, work, cache=None):
    """Plan ``config`` (None: the embedded default) with ``seed``; one table row.
    ``cache``: the design cache folder (default: an empty one in ``work``)."""
    out_dir = Path(work) / "out"
    cache = Path(work) / "cache" if cache is None else Path(cache)
    cmd = [sys.executable, "-m", "planner.cli", "plan"]
    if config != "default":
        cmd.append(str(ROOT / "configs" / f"{config}.yaml"))
    cmd += ["--out", str(out_dir), "--force", "--no-figures", "--quiet", "--seed", str(seed),
            "--jobs", str(jobs), "--cache-dir", str(cache)]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    t = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=work)
    wall = time.perf_counter() - t
    row = {"config": config, "seed": seed, "exit": proc.returncode, "wall_s": round(wall, 1)}
    stages = _stages(proc.stdout)
    row.update({"reach_s": stages.get("reach"), "design_s": stages.get("design"),
                "total_s": stages.get("total")})
    plan = out_dir / "plan.json"
    if proc.returncode in (0, 1) and plan.exists():
        d = json.loads(plan.read_text())
        ver = d["verification"]
        checks = [r["passed"] for devs in ver["steps"].values() for r in devs.values()]
        rounds = [r for r in ver["repair_rounds"] if r.get("round") is not None]
        moved = [m["impacter"] for r in rounds for m in r.get("moved", ())]
        recoloured = sum(r.get("recoloured", 0) for r in rounds)
        draws = {}
        for r in rounds:
            draws.update(r.get("phase_draws", {}))
        later = [r for r in rounds if r["round"]]
        designed = sum(r.get("designs", {}).get("designed", 0) for r in later)
        kept = sum(r.get("designs", {}).get("kept", 0) for r in later)
        reach = (d.get("assignment") or {}).get("reach") or {}
        row.update({
            "verified": bool(ver["passed"]), "checks": f"{sum(checks)}/{len(checks)}",
            "rounds": len(rounds), "moved": len(moved) + recoloured,
            "moved_impacters": " ".join(moved), "phase_draws": sum(draws.values()),
            "designed": designed, "kept": kept,
            "infeasible": len(ver.get("design_problems", [])),
            "channels_offered": (f"{reach.get('channels_offered')}/"
                                 f"{reach.get('channels_in_grid')}" if reach else "")})
    else:
        last = (proc.stderr.strip().splitlines() or [""])[-1]
        row.update({"verified": False, "checks": "", "rounds": 0, "why": last[:300]})
    return row


def _table(df):
    cols = ["config", "seed", "exit", "verified", "checks", "rounds", "moved", "phase_draws",
            "designed", "kept", "infeasible", "channels_offered", "reach_s", "design_s",
            "total_s", "wall_s"]
    cols = [c for c in cols if c in df.columns]
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for _, r in df[cols].iterrows():
        lines.append("| " + " | ".join("" if pd.isna(v) else str(v) for v in r) + " |")
    return lines


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--configs", nargs="*", default=["default", *ARRAY_CONFIGS[1:]])
    ap.add_argument("--seeds", default="0-19", help="seeds of the default (e.g. 0-19)")
    ap.add_argument("--other-seeds", default="0-4", help="seeds of every other config")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", default=str(HERE / "results" / "seeds.md"))
    ap.add_argument("--shared-reach", action="store_true",
                    help="one design cache for all seeds of a config: the reach probes "
                         "(the spec's, whatever the seed) are paid by its first seed only; "
                         "designs are keyed by seed and never shared")
    ap.add_argument("--resume", action="store_true",
                    help="keep the CSV's rows measured on this revision; run the rest")
    args = ap.parse_args(argv)
    out = Path(args.out)
    csv = out.with_suffix(".csv")
    rev = _revision()
    rows = []
    if args.resume and csv.exists():
        old = pd.read_csv(csv)
        rows = [r for r in old.to_dict("records") if r.get("revision") == rev]
    done = {(r["config"], int(r["seed"])) for r in rows}
    shared = tempfile.TemporaryDirectory(prefix="vp-seeds-reach-")
    for config in args.configs:
        seeds = _seeds(args.seeds if config in ("default", "array_5x5") else args.other_seeds)
        for seed in seeds:
            if (config, seed) in done:
                continue
            cache = Path(shared.name) / config if args.shared_reach else None
            with tempfile.TemporaryDirectory(prefix="vp-seeds-") as work:
                row = plan_one(config, seed, args.jobs, work, cache)
            row["revision"] = rev
            row["load"] = round(os.getloadavg()[0], 1)
            rows.append(row)
            print(f"{config} seed {seed}: exit {row['exit']}, {row.get('checks', '')}, "
                  f"rounds {row.get('rounds')}, moved {row.get('moved', 0)}, "
                  f"draws {row.get('phase_draws', 0)}, {row['wall_s']} s", flush=True)
            pd.DataFrame(rows).to_csv(csv, index=False)
    df = pd.DataFrame(rows)
    order = {c: i for i, c in enumerate(args.configs)}
    df = df.sort_values(["config", "seed"], key=lambda s: s.map(order) if s.name == "config"
                        else s).reset_index(drop=True)
    df.to_csv(csv, index=False)
    summary = []
    for config, g in df.groupby("config", sort=False):
        summary.append(f"- **{config}**: {int(g['verified'].sum())} of {len(g)} seeds verified "
                       f"(seeds {g['seed'].min()}-{g['seed'].max()}); loop rounds "
                       f"{int(g['rounds'].max())} at most; channels moved in "
                       f"{int((g.get('moved', 0) > 0).sum())}, phases drawn anew in "
                       f"{int((g.get('phase_draws', 0) > 0).sum())}; wall "
                       f"{g['wall_s'].min():.0f}-{g['wall_s'].max():.0f} s")
    for config, g in df.groupby("config", sort=False):
        t = g["total_s"].dropna()
        if len(t) > 1:
            summary.append(f"  - {config}: plan total {t.min():.1f}-{t.max():.1f} s, max/min "
                           f"{t.max() / t.min():.2f}; design stage {g['design_s'].min():.1f}-"
                           f"{g['design_s'].max():.1f} s; reach {g['reach_s'].min():.1f}-"
                           f"{g['reach_s'].max():.1f} s")
    caching = ("one design cache per config shared by its seeds (`--shared-reach`): the "
               "reach probes, the spec's whatever the seed, are computed by the first seed "
               "and read by the others; designs are keyed by seed and never shared"
               if args.shared_reach else
               "each plan with an empty design cache of its own (every design and reach "
               "probe computed)")
    flags = " --shared-reach" if args.shared_reach else ""
    text = ["# Seeds and specs (issues 36, 43)", "",
            f"`python benchmarks/seeds.py --jobs {args.jobs}{flags}` on {machine()}, revision "
            f"{rev}; {caching}.  exit 0: verified, 1: a check failed (plan written), 2: refused "
            "before any design.  `moved`: channels the loop moved (alone or by colouring "
            "again); `phase_draws`: multi-tone steps whose phases it drew anew; `designed` / "
            "`kept`: designs made, and kept by a re-check, in rounds after the first; "
            "`infeasible`: designs still infeasible in the plan kept.", "", *summary, "",
            *_table(df), ""]
    out.write_text("\n".join(text))
    print("\n".join(summary))


if __name__ == "__main__":
    main()
