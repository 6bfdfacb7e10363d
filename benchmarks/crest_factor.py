"""Benchmark of drive synthesis (planner.synthesis): crest factor and speed.

Crest factor (peak / rms, the continuous-time peak) of 25 and of 50 equal tones drawn at
random (fixed seeds, several subsets) from a channel grid of 200 log-spaced channels over
2-20 kHz, with three kinds of phases on the *same* loop and snapped frequencies:

- random: uniform phases, the median over RANDOM_DRAWS draws;
- Schroeder: Schroeder's (1970) phases in frequency order;
- optimised: what ``synthesize`` returns (Schroeder + random starts, L_p continuation,
  minimax polish).

The loop sets what the phases can achieve (a loop of length L has about 2 f_max L extrema
for n phases to hold down), so the crest factors are given for several loop choices:

- ``default``: ``synthesize``'s default, the shortest loop of at most 1 s that holds every
  tone within 0.1 % of a whole number of cycles;
- ``1 s``: ``duration=1.0`` (the loop is the shortest whole fraction of 1 s within 0.1 %);
- ``0.5 Hz``: ``duration=1.0`` with a tolerance of 0.5 Hz, i.e. (nearly) exact
  frequencies and a loop of up to 1 s;
- ``0.5 %`` and ``1 %``: looser tolerances, shorter loops (bigger shifts).

The same on the planner's real band (issue 46 item 5): the channel grid of the default
plan (``configs/array_5x5.yaml``: 227 channels over 4.45-51.1 kHz), with equal tones and
with the power convention's amplitudes (``tones_from_power``, what a plan plays), on

- ``default``: the planner's bound, 0.1 % (``FREQUENCY_TOLERANCE_REL``; a plan's
  multi-tone steps are synthesised with it, plan.json's read-back allows 0.2 %, and a
  re-planned chip's impacters respond within 10-80 Hz of their tone);
- ``default, 10 starts``: the same loop with ``n_starts=10``, how much more phases can do;
- ``0.2 %``, ``0.5 %``, ``1 %``: wider tolerances than the planner allows, to show what
  the target costs in frequency.

Speed: a 1 s, 200 kS/s, 50-tone synthesis (the default 0.1 % tolerance), one warm-up then
the median of REPEATS runs, for several tone sets.

Writes benchmarks/results/crest_factor.csv and crest_factor.md.

    python benchmarks/crest_factor.py [--subsets N] [--repeats N]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

from planner.arrayspec import load_spec
from planner.manufacturability.grid import channel_grid
from planner.synthesis import crest_factor, schroeder_phases, synthesize, tones_from_power

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"

FS = 200e3
GRID = np.geomspace(2e3, 20e3, 200)
#: The default plan's spec, whose channel grid is the planner's real band.
DEFAULT_SPEC = HERE.parent / "configs" / "array_5x5.yaml"
TONE_COUNTS = (25, 50)
RANDOM_DRAWS = 20
TARGET_CREST = 2.0
TARGET_SECONDS = 1.0

#: label -> (duration [s] or None, tolerance, True if the tolerance is relative to f)
LOOPS = {
    "default": (None, 1e-3, True),
    "1 s": (1.0, 1e-3, True),
    "0.5 Hz": (1.0, 0.5, False),
    "0.5 %": (None, 5e-3, True),
    "1 %": (None, 1e-2, True),
}

#: The real band's loops: label -> (LOOPS label, n_starts or None for the default).
BAND_LOOPS = {
    "default": ("default", None),
    "default, 10 starts": ("default", 10),
    "0.2 %": ("0.2 %", None),
    "0.5 %": ("0.5 %", None),
    "1 %": ("1 %", None),
}
LOOPS["0.2 %"] = (None, 2e-3, True)


def subset(n, seed, grid=GRID):
    return np.sort(np.random.default_rng(seed).choice(grid, n, replace=False))


def band_grid():
    """The default plan's channel grid [Hz] (its real band)."""
    return channel_grid(load_spec(DEFAULT_SPEC).spec)


def synth_kwargs(label, f):
    duration, tol, relative = LOOPS[label]
    return {"duration": duration, "frequency_tolerance": tol * f if relative else tol}


def cases(n_subsets):
    """(band, amplitudes, row label, LOOPS label, n_starts, subsets) of every table row."""
    out = []
    for label in ("default", "1 s", "0.5 Hz", "0.5 %", "1 %"):
        # the (nearly) exact-frequency 1 s loops are slow to optimise: fewer subsets
        subsets = range(min(n_subsets, 3) if label == "0.5 Hz" else n_subsets)
        out.append(("2-20 kHz", "equal", label, label, None, subsets))
    for amps in ("equal", "power"):
        for label, (loop, starts) in BAND_LOOPS.items():
            out.append(("array_5x5", amps, label, loop, starts, range(n_subsets)))
    return out


def crest_rows(n_subsets):
    rows = []
    grids = {"2-20 kHz": GRID, "array_5x5": band_grid()}
    for band, amps, row_label, label, starts, subsets in cases(n_subsets):
        for n in TONE_COUNTS:
            for s in subsets:
                f = subset(n, s, grids[band])
                a = np.full(n, 1e-6) if amps == "equal" else tones_from_power(f)
                extra = {} if starts is None else {"n_starts": starts}
                t0 = time.perf_counter()
                wf = synthesize(f, a, FS, seed=s, **synth_kwargs(label, f), **extra)
                seconds = time.perf_counter() - t0
                cycles = np.rint(wf.frequencies * wf.loop_length).astype(int)
                rng = np.random.default_rng(1000 + s)
                rand = np.median([crest_factor(cycles, a, rng.uniform(0, 2 * np.pi, n))
                                  for _ in range(RANDOM_DRAWS)])
                rows.append({
                    "band": band, "amplitudes": amps, "loop": row_label, "tones": n,
                    "subset": s,
                    "loop_length_s": wf.loop_length,
                    "max_shift_rel": float(np.max(np.abs(wf.frequency_shift) / f)),
                    "crest_random": rand,
                    "crest_schroeder": crest_factor(cycles, a, schroeder_phases(a)),
                    "crest_optimised": wf.crest_factor,
                    "seconds": seconds,
                })
                print(f"{band} {amps} {row_label:>18} n={n} subset {s}: L={wf.loop_length * 1e3:.4g} ms  random "
                      f"{rand:.2f}  Schroeder {rows[-1]['crest_schroeder']:.2f}  optimised "
                      f"{wf.crest_factor:.3f}  ({seconds:.2f} s)", flush=True)
    return pd.DataFrame(rows)


def timing_rows(n_sets, repeats):
    rows = []
    for s in range(n_sets):
        f = subset(50, s)
        synthesize(f, 1e-6, FS, duration=1.0, seed=s)          # warm-up
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            wf = synthesize(f, 1e-6, FS, duration=1.0, seed=s)
            times.append(time.perf_counter() - t0)
        rows.append({"subset": s, "points": len(wf.samples), "loop_length_s": wf.loop_length,
                     "median_s": float(np.median(times)), "min_s": float(np.min(times)),
                     "max_s": float(np.max(times))})
        print(f"timing subset {s}: median {rows[-1]['median_s']:.3f} s "
              f"(min {rows[-1]['min_s']:.3f}, max {rows[-1]['max_s']:.3f})", flush=True)
    return pd.DataFrame(rows)


def _met(opt):
    if opt.max() <= TARGET_CREST:
        return "met on every subset"
    if opt.mean() <= TARGET_CREST:
        return f"mean met; worst subset {opt.max():.2f}"
    return f"missed by {opt.mean() / TARGET_CREST - 1:.0%}; worst subset {opt.max():.2f}"


def write_markdown(crest, timing, path, command, load_before):
    lines = [
        "# Drive synthesis: crest factor and speed",
        "",
        f"`{command}` on {platform.platform()}, Python {platform.python_version()}, "
        f"{os.cpu_count()} CPUs (load average {load_before}; the machine was shared, so the "
        "times are pessimistic).",
        "",
        "Random subsets (fixed seeds) of a channel grid: 200 log-spaced channels over "
        "2-20 kHz, or the planner's real band, the default plan's channel grid "
        "(`configs/array_5x5.yaml`, 227 channels over 4.45-51.1 kHz). Amplitudes equal, or "
        "by the power convention (Z^2 w^3 = 50 m^2/s^3, what a plan plays: the lowest tone "
        "38 times the highest). Crest factor = continuous-time peak / rms. Random: median "
        f"of {RANDOM_DRAWS} draws; all three on the same loop and snapped frequencies. "
        "Largest shift: the largest |snapped - requested| / requested.",
        "",
        "## Crest factor (mean over subsets, [min - max] for the optimised phases)",
        "",
        "| band | amplitudes | loop | tones | subsets | loop length [ms] | largest shift | "
        "random | Schroeder | optimised | target 2.0 | s per synthesis |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for (band, amps, label, n), g in crest.groupby(["band", "amplitudes", "loop", "tones"],
                                                    sort=False):
        opt = g["crest_optimised"]
        lines.append(
            f"| {band} | {amps} | {label} | {n} | {len(g)} | "
            f"{g['loop_length_s'].min() * 1e3:.4g}-{g['loop_length_s'].max() * 1e3:.4g} | "
            f"{g['max_shift_rel'].max():.2%} | {g['crest_random'].mean():.2f} | "
            f"{g['crest_schroeder'].mean():.2f} | "
            f"{opt.mean():.2f} [{opt.min():.2f} - {opt.max():.2f}] | {_met(opt)} | "
            f"{g['seconds'].median():.2f} |")
    t = timing["median_s"]

    def mean_of(band, amps, loop, n):
        sel = crest[(crest["band"] == band) & (crest["amplitudes"] == amps)
                    & (crest["loop"] == loop) & (crest["tones"] == n)]["crest_optimised"]
        return sel.mean(), sel.max()

    planner = {(amps, n): mean_of("array_5x5", amps, "default", n)
               for amps in ("equal", "power") for n in TONE_COUNTS}
    starts = {n: mean_of("array_5x5", "equal", "default, 10 starts", n) for n in TONE_COUNTS}
    lines += [
        "",
        "## Speed: 1 s, 200 kS/s, 50 tones (`synthesize(f, 1e-6, 200e3, duration=1.0)`)",
        "",
        f"Median over tone sets of the per-set median: **{t.median():.3f} s** "
        f"(sets: {', '.join(f'{v:.3f}' for v in t)} s; target <= {TARGET_SECONDS:g} s: "
        f"{'met' if t.median() <= TARGET_SECONDS else 'missed'}). Includes the loop search, "
        "the phase optimisation and the exact sum of cosines over 200 000 samples.",
        "",
        "## Reading",
        "",
        "- **Within the planner's bound (0.1 %) the target of 2.0 is not met in the real "
        "band**: equal tones "
        + ", ".join(f"{n}: {planner[('equal', n)][0]:.2f} (worst {planner[('equal', n)][1]:.2f})"
                    for n in TONE_COUNTS)
        + "; the power convention's amplitudes "
        + ", ".join(f"{n}: {planner[('power', n)][0]:.2f} (worst {planner[('power', n)][1]:.2f})"
                    for n in TONE_COUNTS) + ".",
        "- The phases are not what limits it: ten starts instead of two give "
        + ", ".join(f"{starts[n][0]:.2f}" for n in TONE_COUNTS)
        + " (equal tones), and in exploratory runs the minimax polish ends on a local "
        "minimax optimum (25 tones: 25 extrema equal to 1e-4, the linear programme finding "
        "no descent at any trust radius), other loops within the tolerance gain under "
        "1.5 %, and L_p continuation to p = 4096 or iterative clipping gain nothing.",
        "- What limits it is the loop: a loop of length L holds about 2 f_max L extrema "
        "that n phases must hold down, and the tolerance sets L (the lowest tones, whose "
        "0.1 % is 4.5 Hz, need loops of 26-55 ms, i.e. 1300-2700 cycles of the highest "
        "tone). The target is met where the loop is a few ms: the rows with wider "
        "tolerances show what it costs in frequency (shifts of 0.5-1 % are 25-500 Hz, "
        "beyond the 10-80 Hz window in which a re-planned chip's impacter responds and "
        "beyond plan.json's 0.2 % read-back check).",
        "- The optimised phases beat random and Schroeder phases everywhere (Schroeder's "
        "formula assumes consecutive harmonics; on a sparse log-spaced set it is no better "
        "than random). Exact frequencies (a 1 s loop, shifts below 0.5 Hz) cost the most.",
        "",
    ]
    path.write_text("\n".join(lines))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--subsets", type=int, default=6, help="tone subsets per case")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per tone set")
    parser.add_argument("--timing-sets", type=int, default=5, help="tone sets timed")
    args = parser.parse_args(argv)
    command = "python benchmarks/crest_factor.py " + " ".join(argv or sys.argv[1:])
    load_before = ", ".join(f"{v:.1f}" for v in os.getloadavg())
    RESULTS.mkdir(exist_ok=True)
    timing = timing_rows(args.timing_sets, args.repeats)
    crest = crest_rows(args.subsets)
    table = pd.concat([crest.assign(kind="crest_factor"), timing.assign(kind="timing_1s_50_tones")])
    table.to_csv(RESULTS / "crest_factor.csv", index=False, float_format="%.6g")
    write_markdown(crest, timing, RESULTS / "crest_factor.md", command.strip(), load_before)
    print((RESULTS / "crest_factor.md").read_text())


if __name__ == "__main__":
    main()
