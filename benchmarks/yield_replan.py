"""Yield with per-chip re-planning: nominal drive against re-planned drive.

    python benchmarks/yield_replan.py --plan DIR [--chips 10] [--sigma-die 0.05]
        [--sigma-device 0.02] [--spec FILE] [--measure-noise 0] [--jobs 1] [--seed 0]

Tolerance: line width sigma ``--sigma-die`` um per die and ``--sigma-device`` um per
device (issue 17: 0.05 and 0.02), nothing else; or, with ``--spec``, that spec's
``fabrication:`` block.  Every chip is verified with the plan's drive, then measured
(true natural frequencies plus ``--measure-noise`` per cent), re-planned from the
measurement and the re-planned drive verified on the chip's true models
(``vibroplan yield --replan``).  Reports both yields with 95 % Wilson intervals, chips
per minute, the re-plan's failure causes and, to say why a re-plan fails, how close
the chips' as-built resonances come to each other against the design's spacing.
Writes benchmarks/results/yield_replan.md (``--out``).

A re-plan of the default 5 x 5 costs minutes per chip: keep ``--chips`` small.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from planner.fabrication.tolerances import sample_chip  # noqa: E402
from planner.arrayspec import FabricationSpec, Tolerance, load_spec  # noqa: E402
from planner.planfile.reader import read_plan  # noqa: E402
from planner.yield_ import make_payload, run_yield  # noqa: E402

sys.path.insert(0, str(HERE))
from _timing import machine  # noqa: E402

#: Spacing [Hz] below which two as-built resonances count as "close" in the report:
#: about the width over which a design of the default plan responds from every x0
#: (100-200 Hz at 26-34 kHz in air, docs/replan.md).
CLOSE_HZ = 200.0


def _must_differ(data):
    """Pairs of impacters that some step must tell apart (one plays, the other is idle)."""
    ids = [r["id"] for r in data["impacters"]]
    pairs = set()
    for st in data["steps"]:
        active = {f"{d}.forward" for d in st["forward"]} | {f"{d}.backward" for d in st["backward"]}
        for a in active & set(ids):
            for b in set(ids) - active:
                pairs.add(tuple(sorted((a, b))))
    return sorted(pairs)


def _spacing(payload, data, chips, pairs):
    """(design min spacing [Hz], per chip: (min spacing [Hz], pairs closer than CLOSE_HZ))
    over the pairs the plan must tell apart, the chips re-sampled from their seeds."""
    nu0 = {r["id"]: r["natural_frequency_hz"] for r in data["impacters"]}
    design = min(abs(nu0[a] - nu0[b]) for a, b in pairs)
    out = []
    for i in range(chips):
        rng = np.random.default_rng(np.random.SeedSequence([payload.seed, 0, i]))
        chip = sample_chip(payload.design, payload.fabrication, rng, 1.0)
        if chip.unbuildable:
            out.append((float("nan"), -1))
            continue
        nu = {n: imp.natural_frequency for n, imp in chip.impacters.items()}
        d = [abs(nu[a] - nu[b]) for a, b in pairs]
        out.append((min(d), sum(x < CLOSE_HZ for x in d)))
    return design, out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plan", required=True, help="plan folder or plan.json")
    ap.add_argument("--chips", type=int, default=10)
    ap.add_argument("--sigma-die", type=float, default=0.05, help="line width [um]")
    ap.add_argument("--sigma-device", type=float, default=0.02, help="line width [um]")
    ap.add_argument("--spec", default=None,
                    help="take the fabrication: block of this spec instead of the sigmas")
    ap.add_argument("--measure-noise", type=float, default=0.0, help="measurement noise of the resonances [%%]")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(HERE / "results" / "yield_replan.md"))
    ap.add_argument("--json", default=None, help="also write the run's yield.json here")
    args = ap.parse_args(argv)
    if args.spec:
        fab = load_spec(Path(args.spec)).spec.fabrication
        tol_text = f"the `fabrication:` block of `{args.spec}`"
    else:
        if args.sigma_die < 0 or args.sigma_device < 0:
            ap.error("--sigma-die and --sigma-device must be >= 0")
        fab = FabricationSpec(line_width_um=Tolerance(die=args.sigma_die,
                                                      device=args.sigma_device))
        tol_text = (f"line width sigma {args.sigma_die:g} um per die and "
                    f"{args.sigma_device:g} um per device, nothing else")
    record = read_plan(args.plan)
    path = record.path
    data = json.loads(path.read_text())  # the report's numbers
    payload = make_payload(record, args.seed, fab, replan=True,
                           measure_noise_pct=args.measure_noise)
    counter = itertools.count(1)
    t0 = time.perf_counter()

    def tick():
        print(f"  chip {next(counter)}/{args.chips + 1} done at "
              f"{time.perf_counter() - t0:.0f} s (load {os.getloadavg()[0]:.1f})",
              file=sys.stderr, flush=True)

    load0 = os.getloadavg()[0]
    timings = {}
    res = run_yield(payload, args.chips, jobs=args.jobs, progress=tick, timings=timings)
    wall = time.perf_counter() - t0
    load1 = os.getloadavg()[0]
    rp = res["replan"]
    pairs = _must_differ(data)
    design_gap, spacing = _spacing(payload, data, args.chips, pairs)
    ver = data["verification"]["steps"]
    checks = sum(len(v) for v in ver.values())
    ok_checks = sum(r["passed"] for v in ver.values() for r in v.values())
    t_re = np.array(timings["replan_s"]) if timings["replan_s"] else np.array([np.nan])
    t_nom = np.array(timings["nominal_s"])
    cmd = (f"python benchmarks/yield_replan.py --plan {args.plan} --chips {args.chips} "
           + (f"--spec {args.spec} " if args.spec else
              f"--sigma-die {args.sigma_die:g} --sigma-device {args.sigma_device:g} ")
           + f"--measure-noise {args.measure_noise:g} --jobs {args.jobs} --seed {args.seed}")
    lines = [
        "# Yield with per-chip re-planning (`vibroplan yield --replan`)", "",
        f"`{cmd}` on {machine()['cpu']} ({os.cpu_count()} CPUs), Python {platform.python_version()}.",
        "",
        f"Plan: `{data['spec']['name']}` ({len(data['impacters'])} impacters, "
        f"{len(data['steps'])} steps); its own verification: "
        f"{'PASSED' if data['verification']['passed'] else 'FAILED'} "
        f"({ok_checks}/{checks} step x device checks).  Tolerance: {tol_text}.  "
        f"Measurement noise {args.measure_noise:g} %.", "",
        "| drive | yield | 95 % Wilson CI | chips passing |", "|---|---|---|---|",
        f"| nominal (the plan's) | {res['yield']:.3f} | [{res['ci95'][0]:.3f}, "
        f"{res['ci95'][1]:.3f}] | {res['passed']} / {res['chips']} |",
        f"| re-planned per chip | **{rp['yield']:.3f}** | [{rp['ci95'][0]:.3f}, "
        f"{rp['ci95'][1]:.3f}] | {rp['passed']} / {rp['chips']} |", "",
        f"Rescued {rp['rescued']}, lost {rp['lost']}; the re-plan verified on its own "
        f"measured models on {rp['measured_passed']} of {rp['chips']} chips.  Nominal chip "
        f"(no error): plan's drive {'passes' if res['nominal']['passed'] else 'FAILS'} "
        f"({', '.join(f'{k} {v}' for k, v in res['nominal']['failures'].items()) or '-'}); "
        f"re-planned {'passes' if rp['nominal']['replan_passed'] else 'FAILS'}"
        f" ({', '.join(rp['nominal']['causes']) or '-'}).", "",
        "Target (issue 17): re-planned yield >= 0.95.  "
        + ("Met." if rp["ci95"][0] >= 0.95 else
           ("Not shown: the point estimate is >= 0.95 but the interval of so few chips is "
            "wide." if rp["yield"] >= 0.95 else
            f"NOT met: {rp['yield']:.3f}, {0.95 - rp['yield']:.3f} short "
            f"(95 % CI upper end {rp['ci95'][1]:.3f}).")), "",
        "## Cost", "",
        f"{args.chips} chips + the nominal chip in {wall:.0f} s on {args.jobs} worker(s): "
        f"**{60 * (args.chips + 1) / wall:.2f} chips/min**; per chip: nominal checks "
        f"{t_nom.mean():.0f} s, re-plan and its verification on the true models "
        f"{np.nanmean(t_re):.0f} s mean ({np.nanmin(t_re):.0f}-{np.nanmax(t_re):.0f} s).  "
        f"Load average {load0:.1f} -> {load1:.1f} (a shared machine: upper bounds).", "",
        "## Why re-plans fail", "",
        "Causes (chips): " + (", ".join(f"{k} {v}" for k, v in rp["causes"].items())
                              or "none") + ".  Checks the re-planned drive fails on the true "
        "models (chips): " + (", ".join(f"{k} {v}" for k, v in rp["failures"].items())
                              or "none") + ".", "",
        f"Resonance spacing over the {len(pairs)} impacter pairs some step must tell apart: "
        f"design minimum {design_gap:.0f} Hz; a design responds from every x0 over only "
        f"~{CLOSE_HZ:.0f} Hz near 30 kHz, so pairs closer than {CLOSE_HZ:.0f} Hz are at risk.",
        "",
        "| chip | nominal drive | re-planned | causes | min as-built spacing [Hz] | "
        f"pairs < {CLOSE_HZ:.0f} Hz | tones moved | colliding pairs (as built) |",
        "|---:|---|---|---|---:|---:|---:|---|"]
    for c, (gap, close) in zip(rp["per_chip"], spacing):
        pairs_txt = "; ".join(f"{x['driven']} {x['as_built_hz'][0]:.0f} / {x['idle']} "
                              f"{x['as_built_hz'][1]:.0f}" for x in c["collisions"][:3])
        if len(c["collisions"]) > 3:
            pairs_txt += f"; +{len(c['collisions']) - 3}"
        lines.append(f"| {c['chip']} | {'pass' if c['nominal_passed'] else 'fail'} | "
                     f"{'pass' if c['replan_passed'] else 'fail'} | "
                     f"{', '.join(c['causes']) or '-'} | {gap:.0f} | {close} | "
                     f"{c['tones_moved']} | {pairs_txt or '-'} |")
    lines.append("")
    fails = [c for c in rp["per_chip"] if not c["replan_passed"]]
    if fails:
        lines += ["Failing checks of each re-planned chip on its true models:", ""]
        lines += [f"- chip {c['chip']}: " + ", ".join(f"{k} {v}" for k, v in c["failures"].items())
                  + (f"; outside band: {', '.join(c['outside_band'])}" if c["outside_band"] else "")
                  + (f"; merged: {', '.join(c['merged_steps'])}" if c["merged_steps"] else "")
                  for c in fails]
        lines.append("")
    Path(args.out).write_text("\n".join(lines) + "\n")
    if args.json:

        Path(args.json).write_text(json.dumps(res, indent=2) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
