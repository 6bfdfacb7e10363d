"""Every output of the planner's commands, written by one checkout, compared with another's.

A restructuring of the code (issue 44: files moved, one plan schema, one after-fabrication
loop) must not change what a user gets.  ``run`` writes, with the checkout it is run from
(its ``planner`` on ``PYTHONPATH``), the outputs of:

- ``plan`` of ``configs/tiny_1x2.yaml`` and, unless ``--no-default``, of the default 5 x 5;
- ``plan`` of a 1 x 2 whose neighbours sit one tolerance spacing apart (``close``), its
  ``replan`` from a measured.csv with one impacter 0.4 % off, and its ``trim`` from one whose
  two neighbours sit 0.05 % apart;
- ``yield --replan --trim`` of the tiny plan on a wafer (6 dies), and the batch ``replan``
  of that wafer's ``wafer_1.csv`` (``--trim``, ``--jobs 1``);

and ``compare`` says, file by file, where two such folders differ, the lines of timings
aside (report.md's "Timings" section, JSON keys ending in ``_s`` under ``timings``)::

    python benchmarks/same_outputs.py run OUT_BEFORE        # with the old checkout
    python benchmarks/same_outputs.py run OUT_AFTER         # with the new one
    python benchmarks/same_outputs.py compare OUT_BEFORE OUT_AFTER

Exit status of ``compare``: 0 when every file is the same, 1 otherwise.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import planner

#: The checkout whose ``planner`` runs (its configs/ are planned).
ROOT = Path(planner.__file__).resolve().parents[1]

CLOSE = """\
name: close
array: {rows: 1, cols: 2}
device:
  slider: {area_um2: 1.6e5}
drive:
  band_hz: [19500, 25500]
  channels: {spacing: tolerance}
  guard: {separation_channels: 1}
design: {guard: 0.019}
verification: {repair_rounds: 1, x0_points: 5, min_speed_mm_s: 0.1}
fabrication:
  line_width_um: {die: 0.05, device: 0.02}
"""

WAFER = """\
fabrication:
  natural_frequency_pct: {die: 4, device: 2}
  line_width_um: {die: 0.02, device: 0.01}
  wafer:
    diameter_mm: 12
    edge_exclusion_mm: 0.5
    line_width_field: {sigma_um: 0.05, correlation_length_mm: 4}
    line_width_gradient_um_per_mm: 0.01
"""


def _cli(out: Path, *args) -> int:
    """Run ``python -m planner.cli ARGS`` in ``out``; its exit status (logged)."""
    cmd = [sys.executable, "-m", "planner.cli", *map(str, args)]
    proc = subprocess.run(cmd, cwd=out, capture_output=True, text=True)
    shown = " ".join(str(a).replace(str(out) + "/", "").replace(str(ROOT), "CHECKOUT")
                     for a in args)
    with (out / "commands.log").open("a") as log:
        log.write(f"$ vibroplan {shown}\n-> exit {proc.returncode}\n")
    if proc.returncode not in (0, 1):
        sys.exit(f"vibroplan {' '.join(map(str, args))}: exit {proc.returncode}\n{proc.stderr}")
    return proc.returncode


def _impacters(plan_dir: Path) -> dict[str, float]:
    data = json.loads((plan_dir / "plan.json").read_text())
    return {r["id"]: float(r["natural_frequency_hz"]) for r in data["impacters"]}


def _measured(path: Path, freqs: dict[str, float]) -> Path:
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["impacter", "natural_frequency_hz"])
        w.writerows([k, repr(v)] for k, v in freqs.items())
    return path


def run(out: Path, default: bool) -> None:
    out.mkdir(parents=True)
    out = out.resolve()
    os.environ["VIBROPLAN_CACHE_DIR"] = str(out / "cache")
    quiet = ("--quiet",)
    _cli(out, "plan", ROOT / "configs" / "tiny_1x2.yaml", "--out", "tiny", *quiet)
    if default:
        _cli(out, "plan", "--out", "default", *quiet)
    (out / "close.yaml").write_text(CLOSE)
    _cli(out, "plan", "close.yaml", "--out", "close", "--no-figures", *quiet)
    freqs = _impacters(out / "close")
    first = next(iter(freqs))
    _cli(out, "replan", "close", "--measured",
         _measured(out / "replan.csv", {**freqs, first: freqs[first] * 1.004}),
         "--out", "replan", "--no-figures", *quiet)
    lo, hi = sorted(freqs, key=freqs.get)[:2]
    _cli(out, "trim", "close", "--measured",
         _measured(out / "trim.csv", {**freqs, hi: freqs[lo] * 1.0005}),
         "--out", "trim", "--no-figures", *quiet)
    (out / "wafer.yaml").write_text(WAFER)
    _cli(out, "yield", "tiny", "--chips", 6, "--seed", 3, "--spec", "wafer.yaml",
         "--replan", "--trim", "--out", "yield", *quiet)
    _cli(out, "replan", "tiny", "--measured", "yield/wafer_1.csv", "--trim", "--jobs", 1,
         "--out", "batch", *quiet)


#: Lines that hold a time: report.md's timings table rows and "... in 12.3 s" phrases.
_TIME = re.compile(r"\d+(\.\d+)?(-\d+(\.\d+)?)? ?(s|min|ms|chips/min)\b")


def _normalised(path: Path) -> bytes:
    data = path.read_bytes()
    if path.name == ".vibroplan-output":
        # the folder's marker: the digests of its files, a report's with its timings
        doc = json.loads(data)

        def hide(node):
            if isinstance(node, dict):
                return {k: ("<digest>" if k.endswith(".md") else hide(v))
                        for k, v in node.items()}
            return node
        return json.dumps(hide(doc), sort_keys=True).encode()
    if path.suffix == ".json":
        doc = json.loads(data)

        def strip(node):
            if isinstance(node, dict):
                return {k: ("<time>" if k in ("timings", "seconds", "elapsed_s", "wall_s")
                            or k.endswith("_seconds") else strip(v)) for k, v in node.items()}
            if isinstance(node, list):
                return [strip(v) for v in node]
            return node
        return json.dumps(strip(doc), sort_keys=True).encode()
    if path.suffix in (".md", ".log", ".txt"):
        text = data.decode(errors="replace")
        # a command's paths in the log: the folder and the checkout it ran from
        text = re.sub(r"/\S*/(configs/|replan\.csv|trim\.csv)", r"\1", text)
        text = text.split("## Timings")[0]
        return _TIME.sub("<time>", text).encode()
    return data


def compare(a: Path, b: Path) -> int:
    def files(root):
        return {p.relative_to(root).as_posix() for p in root.rglob("*")
                if p.is_file() and "cache" not in p.relative_to(root).parts}
    fa, fb = files(a), files(b)
    bad = 0
    for name in sorted(fa ^ fb):
        print(f"only in {'first' if name in fa else 'second'}: {name}")
        bad += 1
    for name in sorted(fa & fb):
        if _normalised(a / name) != _normalised(b / name):
            print(f"differs: {name}")
            bad += 1
    print(f"{len(fa & fb)} files compared, {bad} differ or are missing")
    return 1 if bad else 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="write every command's outputs into OUT (must not exist)")
    r.add_argument("out", type=Path)
    r.add_argument("--no-default", action="store_true", help="skip the default 5 x 5 plan")
    c = sub.add_parser("compare", help="compare two folders written by run")
    c.add_argument("a", type=Path)
    c.add_argument("b", type=Path)
    args = parser.parse_args(argv)
    if args.cmd == "run":
        run(args.out, default=not args.no_default)
        return 0
    return compare(args.a, args.b)


if __name__ == "__main__":
    sys.exit(main())
