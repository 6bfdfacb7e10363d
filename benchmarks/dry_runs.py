"""Know early (issue 43): how long ``vibroplan plan --dry-run`` and a refusal take, for
every array spec in configs/ and for the refusals of docs/loop.md.

    python benchmarks/dry_runs.py [--jobs 2] [--out benchmarks/results/dry_runs.md]

Each spec's dry run is timed as a whole process (interpreter start and imports
included) twice with one design cache of its own: first empty (the reach probes are
designed), then again (the probes are the spec's, whatever the seed, and come from the
cache; a second seed is timed, so that nothing but the reach can be shared).  The
refusals are the real command ``vibroplan plan`` on the specs docs/loop.md names (a band
no design can serve, an undamped array in vacuum) and on an array the band cannot hold,
each from an empty cache.  numba's cache is warm (a tiny plan runs first, untimed).

No assertion; the machine's load is printed with the table.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
from _timing import machine  # noqa: E402

ARRAY_CONFIGS = ("array_5x5", "array_7x7", "array_10x10_rows", "pattern_5x5",
                 "row_assembly", "tiny_1x2")

LOW_BAND = """\
name: below
array: {rows: 1, cols: 2}
independent: false
drive:
  band_hz: [1500, 3200]
  channels: {count: 30}
verification: {x0_points: 5}
scenes:
  s:
    - {name: push, duration_ms: 5, forward: [A1]}
    - {name: pull, duration_ms: 5, backward: [A2]}
"""
VACUUM = ("name: vac\narray: {rows: 2, cols: 2}\nenvironment: {viscosity_mpa_s: 0}\n"
          "independent: true\ndrive:\n  band_hz: [5000, 30000]\n")
HUGE = "name: huge\narray: {rows: 26, cols: 99}\nindependent: true\n"


def _run(args, cwd, cache):
    cmd = [sys.executable, "-m", "planner.cli", "plan", *map(str, args), "--cache-dir",
           str(cache)]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    t = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=cwd)
    wall = time.perf_counter() - t
    reach = next((line for line in (proc.stdout + proc.stderr).splitlines()
                  if line.startswith("reach (measured in")), "")
    return wall, proc.returncode, reach.split(":")[0]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", type=Path, default=HERE / "results" / "dry_runs.md")
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory(prefix="vp-dry-") as work:
        work = Path(work)
        _run([ROOT / "configs" / "tiny_1x2.yaml", "--out", work / "warm", "--quiet",
              "--no-figures"], work, work / "warm-cache")
        for name in ARRAY_CONFIGS:
            cache = work / f"cache-{name}"
            spec = ROOT / "configs" / f"{name}.yaml"
            first = _run([spec, "--dry-run", "--quiet", "--jobs", args.jobs], work, cache)
            again = _run([spec, "--dry-run", "--quiet", "--jobs", args.jobs, "--seed", 7],
                         work, cache)
            rows.append((f"`configs/{name}.yaml` --dry-run", *first, *again))
            print(rows[-1], flush=True)
        for label, text in (("a band no design can serve (1.5-3.2 kHz, docs/loop.md)", LOW_BAND),
                            ("vacuum, 2 x 2 (docs/loop.md)", VACUUM),
                            ("26 x 99 independent (the band cannot hold it)", HUGE),
                            ("a 3 x 3 in a 5 um process (refused by its probes, issue 43)",
                             (HERE / "data" / "issue43_thick_3x3.yaml").read_text())):
            spec = work / f"{label.split()[0]}-{len(rows)}.yaml"
            spec.write_text(text)
            got = _run([spec, "--out", work / "never", "--quiet", "--jobs", args.jobs], work,
                       work / f"cache-{len(rows)}")
            rows.append((label, *got, None, None, ""))
            print(rows[-1], flush=True)
    lines = ["# Dry runs and refusals (issue 43)", "",
             f"`python benchmarks/dry_runs.py --jobs {args.jobs}` on {machine()} (load at the "
             f"end {os.getloadavg()[0]:.1f}).  Whole-process wall times [s], numba's cache warm. "
             "First: an empty design cache (the reach probes are designed); again: the same "
             "spec with another seed and the same cache (the probes are the spec's).", "",
             "| command | first [s] | exit | reach | again, seed 7 [s] | exit | reach |",
             "|---|---|---|---|---|---|---|"]
    for label, w1, e1, r1, w2, e2, r2 in rows:
        lines.append(f"| {label} | {w1:.1f} | {e1} | {r1} | "
                     f"{'' if w2 is None else f'{w2:.1f}'} | {'' if e2 is None else e2} | "
                     f"{r2} |")
    args.out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
