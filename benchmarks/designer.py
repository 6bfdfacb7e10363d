"""Designer benchmark: Table II's pair with default settings, and the fast budget.

1. Table II (nu_f = 6 kHz, nu_b = 3 kHz, air, ``configs/paper_table2.yaml``): wall-clock
   time of ``design_pair`` with the config's (default, "full") settings, numba kernels
   already loaded; median of ``--repeat`` runs with seed 0, then one run per further
   seed.  Every design is re-checked independently: r_min over 2049 + 5 x0 in [-c, c]
   (both ends exactly), silence at the other frequency on that grid over 3 ms and
   over 30 ms.  The paper's own Table II designs (with their stated natural
   frequencies) are evaluated on the same grid for comparison.
2. The "fast" budget the array planner uses: one impacter per target frequency with
   every tone of a 50-tone grid (2-16 kHz, geometric) at least 25% away forbidden.

Writes designer.md and designer.csv into the output directory (benchmarks/results)::

    python benchmarks/designer.py [--out DIR] [--repeat N] [--seeds N] [--quick]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
RESULTS = HERE / "results"
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

from _timing import machine  # noqa: E402

from model import Drive, Impacter, responses  # noqa: E402
from model import devices as _d  # noqa: E402
from planner.config import EnvironmentConfig  # noqa: E402
from planner.designer.config import load_design_config  # noqa: E402
from planner.designer import design_impacter, design_pair, x0_grid  # noqa: E402

UM = 1e-6
TABLE2 = ROOT / "configs" / "paper_table2.yaml"
#: Table II: (A [um^2], w, l, c [um], nu_n [Hz]).
PAPER = {"forward": (13544, 5.6774, 795.74, 5.2046, 5819.9),
         "backward": (45446, 4.0354, 795.27, 2.6676, 2038.5)}
CHECK_POINTS = 2049
FAST_TARGETS = (3000.0, 4000.0, 5500.0, 7000.0, 10000.0, 13000.0)


def dense(gap):
    return np.unique(np.concatenate([np.linspace(-gap, gap, CHECK_POINTS), x0_grid(gap, 5)]))


def recheck(imp, own, other, window=3e-3):
    """(r_min [N], worst x0 [m], r_max at other over 3 ms [N], responds within 30 ms)."""
    x0s = dense(imp.gap)
    r = responses(imp, Drive.tone(own), x0s, duration=window)
    r_other = responses(imp, Drive.tone(other), x0s, duration=window)
    r_long = responses(imp, Drive.tone(other), x0s, duration=10 * window, stop_at_first=True)
    i = int(np.argmin(r))
    return float(r[i]), float(x0s[i]), float(r_other.max()), bool(np.any(r_long > 0))


def table2(repeat, seeds):
    cfg = load_design_config(TABLE2)
    kw = cfg.design_kwargs()
    rows = []
    times = []
    for k in range(repeat + seeds - 1):
        seed = 0 if k < repeat else k - repeat + 1
        t0 = time.perf_counter()
        pair = design_pair(6000.0, 3000.0, seed=seed, **kw)
        elapsed = time.perf_counter() - t0
        if seed == 0:
            times.append(elapsed)
            if k > 0:
                continue
        for name, d, own, other in (("forward", pair.forward, 6000.0, 3000.0),
                                    ("backward", pair.backward, 3000.0, 6000.0)):
            r_min, worst, r_other, late = recheck(d.impacter, own, other)
            g = d.geometry
            rows.append({
                "case": "table2", "who": "vibroplan", "seed": seed, "pair": name,
                "pair_time_s": elapsed, "design_time_s": d.seconds,
                "evaluations": d.evaluations, "simulations": d.simulations,
                "area_um2": g.area / UM**2, "width_um": g.width / UM,
                "length_um": g.length / UM, "gap_um": g.gap / UM,
                "nu_n_hz": d.natural_frequency_hz, "r_min_n": d.r_min_n,
                "recheck_r_min_n": r_min, "worst_x0_um": worst / UM,
                "r_max_other_n": r_other, "responds_30ms": late, "margin_hz": d.margins_hz[0],
                "slider_mm_s": d.predicted_slider_speed_m_s * 1e3, "feasible": d.feasible,
                "coarse_only": d.checks["coarse_only_designs"]})
    for name, (a, w, l, c, nu) in PAPER.items():
        own, other = (6000.0, 3000.0) if name == "forward" else (3000.0, 6000.0)
        imp = Impacter.from_geometry(a * UM**2, w * UM, l * UM, c * UM,
                                     viscosity=_d.VISCOSITY_AIR).with_natural_frequency(nu)
        r_min, worst, r_other, late = recheck(imp, own, other)
        rows.append({"case": "table2", "who": "paper", "seed": None, "pair": name,
                     "area_um2": a, "width_um": w, "length_um": l, "gap_um": c, "nu_n_hz": nu,
                     "recheck_r_min_n": r_min, "worst_x0_um": worst / UM,
                     "r_max_other_n": r_other, "responds_30ms": late})
    return rows, times


def fast_budget():
    env = EnvironmentConfig(viscosity_mpa_s=0.0179)
    grid = np.geomspace(2000.0, 16000.0, 50)
    rows = []
    for target in FAST_TARGETS:
        forbidden = [f for f in grid if abs(math.log(f / target)) > 0.25]
        t0 = time.perf_counter()
        d = design_impacter(target, forbidden, environment=env, budget="fast", seed=0)
        elapsed = time.perf_counter() - t0
        rows.append({"case": "fast", "target_hz": target, "forbidden": len(forbidden),
                     "time_s": elapsed, "feasible": d.feasible, "r_min_n": d.r_min_n,
                     "nu_n_hz": d.natural_frequency_hz, "min_margin_hz": min(d.margins_hz),
                     "evaluations": d.evaluations, "simulations": d.simulations})
    return rows


def write(rows, times, fast_rows, out):
    import pandas as pd

    out.mkdir(parents=True, exist_ok=True)
    pd.DataFrame(rows + fast_rows).to_csv(out / "designer.csv", index=False, float_format="%.6g")
    m = machine()
    ours = [r for r in rows if r["who"] == "vibroplan"]
    paper = {r["pair"]: r for r in rows if r["who"] == "paper"}
    med = float(np.median(times))
    lines = [
        "# Designer benchmark",
        "",
        f"`python benchmarks/designer.py` on {m['cpu']} ({m['cores']} CPUs), Python "
        f"{m['python']}, load average {m['load'][0]:.2f} at the end.  Numba kernels loaded "
        "before timing; wall-clock seconds.",
        "",
        "## Table II: nu_f = 6 kHz, nu_b = 3 kHz, air (`configs/paper_table2.yaml`, defaults)",
        "",
        f"`design_pair` (forward + backward, full budget, seed 0): median **{med:.1f} s** over "
        f"{len(times)} runs (min {min(times):.1f} s, max {max(times):.1f} s); target <= 60 s.",
        "",
        "Re-check, independent of the designer: r_min over 2049 uniform x0 in [-c, c] plus "
        "both ends and the designer's near-wall points; r_max at the other frequency on that "
        "grid over 3 ms; whether any of them responds there within 30 ms (10x window).",
        "",
        "| who | seed | pair | A [um^2] | w [um] | l [um] | c [um] | nu_n [Hz] | r_min [N] "
        "| vs paper | worst x0 [um] | r_max other [N] | 30 ms | margin [Hz] | slider [mm/s] "
        "| evals | coarse-only |",
        "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|",
    ]
    for r in ours + list(paper.values()):
        ref = paper[r["pair"]]["recheck_r_min_n"]
        mine = r["who"] == "vibroplan"
        lines.append(
            f"| {r['who']} | {'' if r['seed'] is None else r['seed']} | {r['pair']} | "
            f"{r['area_um2']:.0f} | {r['width_um']:.3f} | {r['length_um']:.1f} | "
            f"{r['gap_um']:.3f} | {r['nu_n_hz']:.0f} | {r['recheck_r_min_n']:.4g} | "
            f"{r['recheck_r_min_n'] / ref:.2f}x | {r['worst_x0_um']:.3f} | "
            f"{r['r_max_other_n']:.3g} | {'responds' if r['responds_30ms'] else 'silent'} | "
            + (f"{r['margin_hz']:.0f} | {r['slider_mm_s']:.2f} | {r['evaluations']} | "
               f"{r['coarse_only']} |" if mine else "— | — | — | — |"))
    lines += [
        "",
        "- The paper's designs are evaluated with its stated natural frequencies (eq. (4) as "
        "printed gives 16.1 and 6.0 kHz for them); ours use eqs. (2)-(4) as printed.",
        "- The paper's backward design responds at 6 kHz in our model from x0 just inside the "
        "wall (the drive presses it on the wall at t0 and it chatters): (14) fails there by "
        "a response of 0.4% of its r_min.",
        "- margin: distance from the other pair's frequency to the nearest frequency where "
        "the design responds from some x0 (129-point x0 grid).  The designer keeps each "
        "design silent at 5 frequencies across +-2% of the other frequency (guard band), so "
        "margins are about 2% or more; the responses just outside are small (Fig. 10).",
        "- The worst-case response peaks just below its collapse (the forward designs lose it "
        "about 2% above 6 kHz): (13) rewards sitting at the bifurcation edge, as in the paper's "
        "Fig. 10.",
        "- coarse-only: archived designs that passed on the optimiser's grid and failed the "
        "designer's own 1025-point re-check (rejected; their failing x0 join the grid).",
        "",
        "## Fast budget (array planner): one impacter, ~40 forbidden frequencies",
        "",
        "Every tone of a 50-tone geometric grid 2-16 kHz at least 25% from the target is "
        "forbidden; air; seed 0.",
        "",
        "| target [Hz] | forbidden | time [s] | feasible | r_min [N] | nu_n [Hz] "
        "| min margin [Hz] | evaluations |",
        "|---:|---:|---:|---|---:|---:|---:|---:|",
    ]
    for r in fast_rows:
        lines.append(f"| {r['target_hz']:.0f} | {r['forbidden']} | {r['time_s']:.2f} | "
                     f"{r['feasible']} | {r['r_min_n']:.3g} | {r['nu_n_hz']:.0f} | "
                     f"{r['min_margin_hz']:.0f} | {r['evaluations']} |")
    lines.append("")
    (out / "designer.md").write_text("\n".join(lines), encoding="utf-8")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--repeat", type=int, default=3, help="timed Table II runs (seed 0)")
    parser.add_argument("--seeds", type=int, default=4, help="seeds 0..N-1 for the designs")
    parser.add_argument("--quick", action="store_true", help="one run, one seed")
    args = parser.parse_args(argv)
    repeat, seeds = (1, 1) if args.quick else (args.repeat, args.seeds)
    # load the numba kernels (compile or read the cache) before timing
    design_impacter(6000.0, (3000.0,), environment=EnvironmentConfig(viscosity_mpa_s=0.0179),
                    budget="fast")
    rows, times = table2(repeat, seeds)
    fast_rows = fast_budget()
    write(rows, times, fast_rows, args.out)
    print((args.out / "designer.md").read_text())


if __name__ == "__main__":
    main()
