"""Sharing the machine (issue 38 item 3): each stage of a plan alone, and beside a second
plan started at the same moment, for the code at a git revision ("before") and the
working tree ("after").

    python benchmarks/sharing.py [--before REV] [--repeat 3] [--seeds 0 1] [--jobs N]
        [--config default] [--idle-cores 0.25] [--out benchmarks/results/sharing.md]

For each code version and repeat, ``vibroplan plan [CFG] --no-cache --no-figures --quiet
--seed S`` runs as a subprocess (the version's checkout first on PYTHONPATH, its numba
cache warmed by one untimed plan first): seed 0 alone, seed 1 alone, then both at once.
Each run's stage times are the plan's own ``time:`` line (reach, assign, drive, design,
verify, scenes_coupling, manufacturability, total); a job's ratio is its time shared over
its own time alone (medians over the repeats).  Two equal jobs on 2 cores have a fair
share of half the machine each: a stage that used both cores alone may take 2x, one that
used one core about 1x.

Before every measurement the benchmark waits until the other processes on the machine
use less than ``--idle-cores`` cores (sampled over a second), and after it checks how much
CPU time processes other than the plans took during it (the foreign cores, from the
machine's CPU time minus the plans' and their workers'): a measurement disturbed by more
than ``--idle-cores`` is run again (up to ``--retries`` times) and marked when it stays
disturbed.  The 1-minute load average at the start of each measurement is recorded (it
still holds the benchmark's own previous run for a minute or two).

Every plan.json is kept by its SHA-256: the same seed must give the same bytes alone and
shared, and before and after (the thread count changes no result).

No assertion: numbers from a loaded machine are not comparable with an idle one's.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd
import psutil

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
from _timing import machine, plan_stages  # noqa: E402

CONFIGS = {"default": None, "row_assembly": "configs/row_assembly.yaml",
           "array_7x7": "configs/array_7x7.yaml", "tiny_1x2": "configs/tiny_1x2.yaml"}
#: Stages of the table, in the plan's order (a stage a plan does not print is left out).
STAGES = ("reach", "assign", "drive", "design", "verify", "scenes_coupling",
          "manufacturability", "total")
#: Longest wait for an idle machine before a measurement [s]; the measurement then runs
#: and is marked.
IDLE_TIMEOUT_S = 1800.0


def _busy_cpu_s():
    """CPU time every process of the machine has had [s] (all cores)."""
    t = psutil.cpu_times()
    return t.user + t.system + getattr(t, "nice", 0.0) + getattr(t, "irq", 0.0) \
        + getattr(t, "softirq", 0.0)


def _children_cpu_s():
    """CPU time of this process's finished children and their finished children [s]."""
    t = os.times()
    return t.children_user + t.children_system


def wait_idle(idle_cores, timeout_s=IDLE_TIMEOUT_S):
    """Wait until the machine's processes use less than ``idle_cores`` cores over a
    second, three seconds in a row; returns (waited [s], idle: bool)."""
    t0 = time.monotonic()
    calm = 0
    while time.monotonic() - t0 < timeout_s:
        b0, c0 = _busy_cpu_s(), time.monotonic()
        time.sleep(1.0)
        used = (_busy_cpu_s() - b0) / (time.monotonic() - c0)
        calm = calm + 1 if used < idle_cores else 0
        if calm >= 3:
            return time.monotonic() - t0, True
    return time.monotonic() - t0, False


def _command(code, config, out_dir, seed, jobs):
    cmd = [sys.executable, "-m", "planner.cli", "plan"]
    if CONFIGS[config]:
        cmd.append(str(Path(code) / CONFIGS[config]))
    cmd += ["--out", str(out_dir), "--force", "--no-figures", "--quiet", "--seed", str(seed),
            "--no-cache"]
    if jobs:
        cmd += ["--jobs", str(jobs)]
    return cmd


def _digest(path):
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]


def run_plans(code, config, work, seeds, *, jobs, tag, env=None):
    """Plans of ``seeds`` started at once (one seed: alone); returns one row per plan
    (stage times, wall time, plan.json's digest) and the foreign cores of the run.
    ``env``: variables set for the plans (a threading layer, an OpenMP wait policy)."""
    env = dict(os.environ, **(env or {}), PYTHONPATH=str(code))
    busy0, kids0, own0 = _busy_cpu_s(), _children_cpu_s(), time.process_time()
    t0 = time.perf_counter()
    procs = []
    for seed in seeds:
        out_dir = Path(work) / f"{tag}_seed{seed}"
        procs.append((seed, out_dir, time.perf_counter(), subprocess.Popen(
            _command(code, config, out_dir, seed, jobs), stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT, text=True, env=env, cwd=work)))
    rows = []
    for seed, out_dir, start, proc in procs:
        text, _ = proc.communicate()
        wall = time.perf_counter() - start
        if proc.returncode not in (0, 1):
            raise RuntimeError(f"plan seed {seed} exited {proc.returncode}:\n{text[-2000:]}")
        rows.append({"seed": seed, "wall_s": wall, **plan_stages(text),
                     "passed": proc.returncode == 0,
                     "plan_sha256": _digest(out_dir / "plan.json")})
    elapsed = time.perf_counter() - t0
    # what the machine ran besides the plans (their worker processes are waited for by
    # the plans, so their CPU time is in this process's children's)
    foreign = ((_busy_cpu_s() - busy0) - (_children_cpu_s() - kids0)
               - (time.process_time() - own0)) / elapsed
    return rows, foreign


def measure(code, config, seeds, *, repeat, jobs, label, idle_cores, retries, env=None):
    """Rows of one code version: every seed alone, then all of them at once, ``repeat``
    times."""
    rows = []
    with tempfile.TemporaryDirectory(prefix="sharing_") as work:
        # numba's cache of this checkout warm (not timed)
        run_plans(code, "row_assembly", work, [seeds[0]], jobs=jobs, tag="warm", env=env)
        for r in range(repeat):
            for mode, group in [*(("alone", [s]) for s in seeds), ("shared", list(seeds))]:
                for attempt in range(retries + 1):
                    waited, idle = wait_idle(idle_cores)
                    load = os.getloadavg()[0]
                    got, foreign = run_plans(code, config, work, group, jobs=jobs,
                                             tag=f"{mode}{r}", env=env)
                    disturbed = not idle or foreign > idle_cores
                    if not disturbed or attempt == retries:
                        break
                    print(f"{label} repeat {r} {mode} {group}: {foreign:.2f} foreign cores, "
                          "again", flush=True)
                for row in got:
                    row.update(code=label, repeat=r, mode=mode, load_1min=load,
                               foreign_cores=foreign, waited_s=waited,
                               disturbed=disturbed)
                    rows.append(row)
                    print(label, r, mode, {k: (round(v, 2) if isinstance(v, float) else v)
                                           for k, v in row.items()}, flush=True)
    return rows


def stage_table(rows):
    """Per code version, seed and stage: median alone, median shared, and their ratio."""
    df = pd.DataFrame(rows)
    df = df[~df["disturbed"]] if df["disturbed"].any() and not df["disturbed"].all() else df
    out = []
    for (code, seed), g in df.groupby(["code", "seed"], sort=False):
        alone, shared = g[g["mode"] == "alone"], g[g["mode"] == "shared"]
        for stage in [s for s in STAGES if s in g.columns] + ["wall_s"]:
            a, s = alone[stage].median(), shared[stage].median()
            out.append({"code": code, "seed": seed, "stage": stage, "alone_s": a,
                        "shared_s": s, "ratio": s / a if a > 0 else float("nan"),
                        "load_alone": alone["load_1min"].median(),
                        "load_shared": shared["load_1min"].median()})
    return pd.DataFrame(out)


def _markdown(df, cols, fmt):
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for _, r in df.iterrows():
        lines.append("| " + " | ".join(fmt.get(c, "{}").format(r[c]) for c in cols) + " |")
    return lines


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", help="git revision to compare against (a temporary worktree)")
    ap.add_argument("--config", default="default", choices=list(CONFIGS))
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--jobs", type=int, help="the plans' --jobs (default theirs: every core)")
    ap.add_argument("--env", action="append", default=[], metavar="NAME=VALUE",
                    help="set for the plans, named in the label (e.g. "
                         "NUMBA_THREADING_LAYER=workqueue, OMP_WAIT_POLICY=PASSIVE)")
    ap.add_argument("--idle-cores", type=float, default=0.25,
                    help="other processes' use under which the machine counts as idle")
    ap.add_argument("--retries", type=int, default=2,
                    help="runs again of a measurement disturbed by other processes")
    ap.add_argument("--out", type=Path, default=HERE / "results" / "sharing.md")
    ap.add_argument("--skip-after", action="store_true",
                    help="measure only --before (for a later run's --include)")
    ap.add_argument("--include", type=Path, action="append", default=[],
                    help="rows of an earlier run (its _runs.csv) to put in this table first")
    args = ap.parse_args(argv)
    rows = []
    for csv in args.include:
        rows += pd.read_csv(csv).to_dict("records")
    env = dict(e.split("=", 1) for e in args.env)
    kw = dict(repeat=args.repeat, jobs=args.jobs, idle_cores=args.idle_cores,
              retries=args.retries, env=env)
    with_env = "".join(f" {k}={v}" for k, v in env.items())
    load0 = os.getloadavg()
    if args.before:
        tmp = Path(tempfile.mkdtemp(prefix="sharing_before_"))
        wt = tmp / "code"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(wt),
                        args.before], check=True, capture_output=True)
        try:
            rows += measure(wt, args.config, args.seeds,
                            label=f"before ({args.before}){with_env}", **kw)
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(wt)],
                           capture_output=True)
            shutil.rmtree(tmp, ignore_errors=True)
    if not args.skip_after:
        rows += measure(ROOT, args.config, args.seeds, label=f"after{with_env}", **kw)
    load1 = os.getloadavg()
    runs = pd.DataFrame(rows)
    table = stage_table(rows)
    digests = runs.groupby("seed")["plan_sha256"].unique()
    same = all(len(v) == 1 for v in digests)
    text = [
        "# Sharing the machine: each stage alone and beside a second plan", "",
        f"`python benchmarks/sharing.py {' '.join(argv if argv is not None else sys.argv[1:])}`",
        "",
        f"Machine: {machine()}; load average at start {load0[0]:.2f}, at end "
        f"{load1[0]:.2f}.", "",
        f"Each plan: `vibroplan plan{' ' + CONFIGS[args.config] if CONFIGS[args.config] else ''}"
        f" --no-cache --no-figures --quiet --seed S"
        f"{' --jobs ' + str(args.jobs) if args.jobs else ''}` (its checkout first on "
        f"PYTHONPATH, numba's cache warm); alone: one plan on the machine; shared: seeds "
        f"{', '.join(map(str, args.seeds))} started at the same moment.  Seconds, medians "
        f"over {args.repeat} repeats; ratio = shared / alone for the same job (fair share of "
        f"two equal jobs on 2 cores: about 2 for a stage that keeps both cores busy alone, "
        f"about 1 for a stage that keeps one).  load_alone, load_shared: the 1-minute "
        "load average when the measurement started (it still holds the benchmark's "
        "previous run: the machine was idle by its CPU use, < "
        f"{args.idle_cores} core of other processes, before each measurement).", "",
    ]
    fmt = {"alone_s": "{:.2f}", "shared_s": "{:.2f}", "ratio": "{:.2f}",
           "load_alone": "{:.2f}", "load_shared": "{:.2f}"}
    text += _markdown(table, ["code", "seed", "stage", "alone_s", "shared_s", "ratio",
                              "load_alone", "load_shared"], fmt)
    worst = (table[table["stage"].isin(STAGES[:-1])].groupby("code")["ratio"].max())
    text += ["", "Largest ratio of any stage: " + "; ".join(
        f"{code} {value:.2f}" for code, value in worst.items()) + ".", ""]
    text += ["## plan.json", "",
             "SHA-256 (first 16 hex digits) of every run's plan.json, by seed: "
             + ("**one digest per seed** over alone, shared, repeats and code versions"
                if same else "**digests differ**") + ".", ""]
    text += [f"- seed {seed}: {', '.join(v)}" for seed, v in digests.items()]
    disturbed = runs[runs["disturbed"]]
    if len(disturbed):
        text += ["", f"{len(disturbed)} run(s) disturbed by other processes (kept out of "
                 "the medians where undisturbed runs exist): "
                 + ", ".join(f"{r['code']} repeat {r['repeat']} {r['mode']} seed {r['seed']} "
                             f"({r['foreign_cores']:.2f} cores)"
                             for _, r in disturbed.iterrows())]
    text += ["", "## Every run", ""]
    cols = ["code", "repeat", "mode", "seed"] + [s for s in STAGES if s in runs.columns] + [
        "wall_s", "load_1min", "foreign_cores", "passed"]
    text += _markdown(runs, cols, {c: "{:.2f}" for c in cols[4:-1]})
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(text) + "\n")
    table.to_csv(args.out.with_suffix(".csv"), index=False, float_format="%.3f")
    runs.to_csv(args.out.with_name(args.out.stem + "_runs.csv"), index=False,
                float_format="%.3f")
    print("\n".join(text))


if __name__ == "__main__":
    main()
