"""Plan speed (issue 28): design stage, compilation, verification and total of whole plans,
first run and re-run, for the code at a git revision ("before") and the working tree
("after"), side by side on this machine; plus where one design's time goes.

    python benchmarks/plan_speed.py [--before REV] [--configs default row_assembly array_7x7]
        [--jobs 2] [--seed 0] [--profile-tasks 0,25,49] [--out benchmarks/results/plan_speed.md]

For each code version and config, ``vibroplan plan CFG --no-figures --quiet`` runs as a
subprocess (the version's checkout first on PYTHONPATH, the numba cache of that version
warm unless stated):

* **first run**: an empty design cache (``--cache-dir`` a new folder), so every design is
  computed: the stage times are the plan's own ``time:`` line, the wall time is measured
  around the subprocess (interpreter start and imports included);
* **re-run**: the same command again, every design read from that cache;
* **cold compile** (row_assembly only, the smallest plan that compiles every kernel a plan
  uses): the first run again with an empty ``NUMBA_CACHE_DIR``; compilation is its wall
  time minus the warm first run's.

``--before REV`` checks REV out into a temporary git worktree.  The design profile
(``--profile-tasks``, after only) captures the default plan's design tasks (answered from
the first run's design cache, nothing recomputed) and runs the chosen ones serially in this
process, timing each kind of simulation the search makes (one tone or a summed drive, at
the target or forbidden, short or long window) against the Python around them.

No assertion: the machine's load is printed with the table (``os.getloadavg``); numbers
from a loaded machine are not comparable with an idle one's.
"""

from __future__ import annotations

import argparse
import collections
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
from _timing import machine, plan_stages  # noqa: E402

CONFIGS = {"default": None, "row_assembly": "configs/row_assembly.yaml",
           "array_7x7": "configs/array_7x7.yaml"}


def _plan(code, config, work, cache, *, seed, jobs, numba_cache=None):
    """Run one plan; returns (wall seconds, {stage: seconds}, passed)."""
    env = dict(os.environ, PYTHONPATH=str(code))
    if numba_cache is not None:
        env["NUMBA_CACHE_DIR"] = str(numba_cache)
    cmd = [sys.executable, "-m", "planner.cli", "plan"]
    if CONFIGS[config]:
        cmd.append(str(Path(code) / CONFIGS[config]))
    out_dir = Path(work) / f"out_{config}"
    cmd += ["--out", str(out_dir), "--force", "--no-figures", "--quiet", "--seed", str(seed),
            "--jobs", str(jobs), "--cache-dir", str(cache)]
    t = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=work)
    wall = time.perf_counter() - t
    text = proc.stdout + proc.stderr
    if proc.returncode not in (0, 1):
        raise RuntimeError(f"{' '.join(cmd)} exited {proc.returncode}:\n{text[-2000:]}")
    return wall, plan_stages(text), proc.returncode == 0


def measure(code, configs, *, seed, jobs, label):
    """Rows of one code version."""
    rows = []
    with tempfile.TemporaryDirectory(prefix="plan_speed_warm_") as work:
        # numba's cache of this checkout warm (not timed): the smallest plan that
        # compiles every kernel a plan uses
        _plan(code, "row_assembly", work, Path(work) / "designs", seed=seed, jobs=jobs)
    for config in configs:
        with tempfile.TemporaryDirectory(prefix="plan_speed_") as work:
            cache = Path(work) / "designs"
            first = _plan(code, config, work, cache, seed=seed, jobs=jobs)
            again = _plan(code, config, work, cache, seed=seed, jobs=jobs)
            row = {"code": label, "config": config, "first_wall_s": first[0],
                   "design_s": first[1].get("design"), "verify_s": first[1].get("verify"),
                   "manufacturability_s": first[1].get("manufacturability"),
                   "plan_total_s": first[1].get("total"), "passed": first[2],
                   "rerun_wall_s": again[0], "rerun_total_s": again[1].get("total")}
            if config == "row_assembly":
                cold = _plan(code, config, work, Path(work) / "designs_cold", seed=seed,
                             jobs=jobs, numba_cache=Path(work) / "numba_cold")
                row["cold_wall_s"] = cold[0]
                row["compile_s"] = cold[0] - first[0]
            rows.append(row)
            print(label, config, {k: (round(v, 1) if isinstance(v, float) else v)
                                  for k, v in row.items()}, flush=True)
    return rows


def profile_designs(code, tasks, *, seed):
    """Per-kind simulation time of chosen design tasks of the default plan (after only)."""
    sys.path.insert(0, str(code))
    import numba

    import planner.designer.problem as problem_mod
    import planner.planning.designs as designs_mod
    import planner.planning.pipeline as pipeline_mod
    from planner.designer import design_impacter
    from planner.designer.runs import Ensemble
    from planner.planning.design_store import DesignStore, task_digest
    from planner.arrayspec import default_spec_path, load_spec

    with tempfile.TemporaryDirectory(prefix="plan_speed_prof_") as work:
        cache = Path(work) / "designs"
        _plan(code, "default", work, cache, seed=seed, jobs=2)
        store = DesignStore(cache)
        captured = []

        def from_store(kwargs, min_speed):
            captured.append((kwargs, min_speed))
            return store.get(task_digest(kwargs, min_speed, designs_mod.DESIGN_RETRIES,
                                         designs_mod.INFEASIBLE_TRIES,
                                         designs_mod.SPEED_MARGIN))

        real_task, real_all = designs_mod._design_task, pipeline_mod.design_all
        designs_mod._design_task = from_store
        pipeline_mod.design_all = lambda *a, **k: real_all(
            *a, **{**k, "jobs": 1, "store": None, "scheduler": None})
        try:
            pipeline_mod.run_plan(load_spec(default_spec_path()), seed=seed, jobs=1)
        finally:
            designs_mod._design_task, pipeline_mod.design_all = real_task, real_all
    numba.set_num_threads(1)
    acc = collections.defaultdict(lambda: [0.0, 0])
    real_runs = problem_mod._Problem.runs_of

    def runs_of(self, geometry, frequency, u, window, stop):
        key = (geometry, problem_mod._freq_key(frequency), float(window), bool(stop),
               u.tobytes())
        if key in self.runs:
            return self.runs[key]
        ens = isinstance(frequency, Ensemble)
        target = (any(frequency is e for e in self.target_ensembles)
                  or (not ens and problem_mod._freq_key(frequency)
                      == problem_mod._freq_key(self.frequency)))
        kind = (("summed drive" if ens else "one tone") + (", target" if target else
                                                         ", forbidden")
                + (", long window" if window > 1.5 * self.window else ""))
        t = time.perf_counter()
        out = real_runs(self, geometry, frequency, u, window, stop)
        acc[kind][0] += time.perf_counter() - t
        acc[kind][1] += u.size
        return out

    problem_mod._Problem.runs_of = runs_of
    lines = []
    try:
        design_impacter(**{k: v for k, v in captured[0][0].items() if k != "_stream"})  # warm
        for i in tasks:
            kw = {k: v for k, v in captured[i][0].items() if k != "_stream"}
            acc.clear()
            t = time.perf_counter()
            res = design_impacter(**kw)
            total = time.perf_counter() - t
            sims = sum(a[0] for a in acc.values())
            lines.append(f"- task {i}, {kw['frequency']:.0f} Hz, {len(kw['forbidden'])} "
                         f"forbidden tones, {len(kw['forbidden_drives'])} forbidden and "
                         f"{len(kw['target_drives'])} target summed drives: one try "
                         f"{total:.2f} s, {res.evaluations} evaluations, "
                         f"{res.simulations} runs; simulations {sims:.2f} s, the rest "
                         f"(geometry solves, search, margins, slider speed) "
                         f"{total - sims:.2f} s")
            for kind, (secs, runs) in sorted(acc.items(), key=lambda x: -x[1][0]):
                lines.append(f"  - {kind}: {secs:.3f} s, {runs} runs, "
                             f"{1e6 * secs / max(runs, 1):.1f} us per run")
    finally:
        problem_mod._Problem.runs_of = real_runs
    return lines


def _table(rows):
    cols = ["code", "config", "passed", "first_wall_s", "design_s", "verify_s",
            "manufacturability_s", "plan_total_s", "rerun_wall_s", "cold_wall_s", "compile_s"]
    out = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        out.append("| " + " | ".join(
            f"{r[c]:.1f}" if isinstance(r.get(c), float) else str(r.get(c, ""))
            for c in cols) + " |")
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", help="git revision to compare against (a temporary worktree)")
    ap.add_argument("--configs", nargs="+", default=list(CONFIGS), choices=list(CONFIGS))
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--profile-tasks", default="0,25,49",
                    help="indices of the default plan's design tasks to profile ('' for none)")
    ap.add_argument("--out", type=Path, default=HERE / "results" / "plan_speed.md")
    ap.add_argument("--skip-after", action="store_true",
                    help="measure only --before (for a later run's --include)")
    ap.add_argument("--include", type=Path, action="append", default=[],
                    help="rows of an earlier run (its .csv) to put in this table first")
    args = ap.parse_args(argv)
    rows, lines = [], []
    for csv in args.include:
        rows += pd.read_csv(csv).to_dict("records")
    load0 = os.getloadavg()
    if args.before:
        tmp = Path(tempfile.mkdtemp(prefix="plan_speed_before_"))
        wt = tmp / "code"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(wt),
                        args.before], check=True, capture_output=True)
        try:
            rows += measure(wt, args.configs, seed=args.seed, jobs=args.jobs,
                            label=f"before ({args.before})")
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(wt)],
                           capture_output=True)
            shutil.rmtree(tmp, ignore_errors=True)
    if not args.skip_after:
        rows += measure(ROOT, args.configs, seed=args.seed, jobs=args.jobs, label="after")
    if args.profile_tasks and not args.skip_after:
        lines = profile_designs(ROOT, [int(i) for i in args.profile_tasks.split(",")],
                                seed=args.seed)
    load1 = os.getloadavg()
    text = ["# Plan speed: whole plans, first run and re-run, before and after", "",
            f"`python benchmarks/plan_speed.py {' '.join(argv or sys.argv[1:])}`", "",
            f"Machine: {machine()}; load average at start {load0[0]:.1f}, at end "
            f"{load1[0]:.1f} (2 cores: above ~2 the numbers are inflated).", "",
            "Seconds. first_wall_s: the whole command, empty design cache, warm numba cache; "
            "design/verify/manufacturability/plan_total: the plan's own stage times of that "
            "run; rerun_wall_s: the same command again, designs from the cache; "
            "cold_wall_s: the first run with an empty numba cache; compile_s = cold - warm "
            "first run.", ""] + _table(rows)
    if lines:
        text += ["", "## Where one design's time goes (after; serial, one thread)", ""] + lines
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(text) + "\n")
    pd.DataFrame(rows).to_csv(args.out.with_suffix(".csv"), index=False,
                              float_format="%.2f")
    print("\n".join(text))


if __name__ == "__main__":
    main()
