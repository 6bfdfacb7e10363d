"""Designs as a family (issue 43): evaluations, tries and time per design of the default
plan, each design started from the spec's family (the reach probes' designs) or not.

    python benchmarks/design_family.py [--seed 0] [--tasks all|0,5,10]
        [--out benchmarks/results/design_family.md]

The default plan's design tasks are captured as the plan makes them (its reach measured
in this process first, then the stage that dispatches the designs stopped), and each
task is run here serially, one thread, through the planner's own retry policy
(``planning.designs._design_task``): once as the plan runs it (the family of the three
nearest probe designs, ``design.budget``'s ``family_steps`` moves per chain) and once
without the family (the full first round of the budget, as before issue 43).  Every try
is counted: its candidate evaluations, its simulations, its predicted speed.

No assertion; the machine's load is printed with the table.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(HERE))
from _timing import machine  # noqa: E402


class _Captured(Exception):
    pass


def capture_tasks(seed):
    """(min_speed, [task kwargs]) of the default plan's first design round."""
    import planner.planning.designs as designs_mod
    import planner.planning.pipeline as pipeline_mod
    from planner.arrayspec import default_spec_path, load_spec

    real = designs_mod.dispatch
    got = {}

    def capture(func, shared, args_list, **kw):
        if func is designs_mod._design_on_engine:
            got["tasks"] = (shared, [a[0] for a in args_list])
            raise _Captured
        return real(func, shared, args_list, **kw)

    designs_mod.dispatch = capture
    try:
        with tempfile.TemporaryDirectory(prefix="vp-family-") as cache:
            pipeline_mod.run_plan(load_spec(default_spec_path()), seed=seed, jobs=2,
                                  cache_dir=cache)
    except _Captured:
        pass
    finally:
        designs_mod.dispatch = real
    return got["tasks"]


def run(min_speed, tasks, which, family):
    import numba

    import planner.designer as designer
    import planner.planning.designs as designs_mod

    numba.set_num_threads(1)
    real = designer.design_impacter
    tries = []

    def counting(**kw):
        t = time.perf_counter()
        res = real(**kw)
        tries.append((time.perf_counter() - t, res.evaluations, res.simulations,
                      bool(res.feasible), res.predicted_slider_speed_m_s))
        return res

    designer.design_impacter = counting
    rows = []
    try:
        for i in which:
            kw = dict(tasks[i])
            if not family:
                kw.pop("family", None)
            tries.clear()
            t = time.perf_counter()
            res = designs_mod._design_task(kw, min_speed)
            rows.append({"task": i, "tone_hz": round(kw["frequency"]),
                         "seconds": time.perf_counter() - t, "tries": len(tries),
                         "evaluations": sum(x[1] for x in tries),
                         "first_try_evaluations": tries[0][1],
                         "simulations": sum(x[2] for x in tries),
                         "feasible": bool(res.feasible),
                         "speed_mm_s": 1e3 * res.predicted_slider_speed_m_s})
    finally:
        designer.design_impacter = real
    return rows


def main(argv=None):
    import pandas as pd

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--tasks", default="all")
    ap.add_argument("--out", type=Path, default=HERE / "results" / "design_family.md")
    args = ap.parse_args(argv)
    min_speed, tasks = capture_tasks(args.seed)
    which = (range(len(tasks)) if args.tasks == "all" else
             [int(x) for x in args.tasks.split(",")])
    out = []
    for family in (True, False):
        for r in run(min_speed, tasks, which, family):
            out.append({"family": family, **r})
            print(out[-1], flush=True)
    df = pd.DataFrame(out)
    df.to_csv(args.out.with_suffix(".csv"), index=False)
    summary = []
    for family, g in df.groupby("family", sort=False):
        summary.append(
            f"| {'family (as planned)' if family else 'no family (the full first round)'} | {len(g)} | "
            f"{g['seconds'].sum():.1f} | {g['tries'].mean():.2f} | {g['tries'].max()} | "
            f"{(g['tries'] == 1).mean():.0%} | {g['evaluations'].mean():.0f} | "
            f"{g['first_try_evaluations'].median():.0f} | {g['simulations'].mean():.0f} | "
            f"{int(g['feasible'].sum())} | {g['speed_mm_s'].min():.3f}-"
            f"{g['speed_mm_s'].max():.3f} |")
    text = ["# Designs as a family (issue 43)", "",
            f"`python benchmarks/design_family.py --seed {args.seed}` on {machine()} "
            f"(load {os.getloadavg()[0]:.1f}).  The default plan's first-round design tasks, "
            "each run serially on one thread through the planner's retry policy, with the "
            "spec's family (the reach probes' designs: the plan) and without it.", "",
            "| starts | designs | core seconds | tries (mean) | tries (max) | one try | "
            "evaluations per design | evaluations of a first try (median) | simulations "
            "per design | feasible | predicted speed [mm/s] |",
            "|---|---|---|---|---|---|---|---|---|---|---|", *summary, "",
            "Per design: `" + args.out.with_suffix(".csv").name + "`.", ""]
    args.out.write_text("\n".join(text))
    print("\n".join(text))


if __name__ == "__main__":
    main()
