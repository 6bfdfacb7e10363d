"""A plan's multi-tone steps, every driven device, against independent integrations.

For every step of a plan that plays several tones together (the default plan's
``position_all/position``: 25 tones at 2000 g, and ``release_row_C``: 5), and every
device it drives, the slider's travel from rest over the step's duration, three ways:

- **kernel**: the product's solvers (:func:`model.simulate` for each impacter pair of the
  device, :class:`model.Kicks`, :func:`model.slider_motion`), as the verification runs
  them;
- **DOP853, fine**: :mod:`model.scipy_ref`: each impacter by SciPy's DOP853 with event
  location and its step held to 1/40 of the top tone's period (``max_step``), the
  slider's stick-slip by DOP853 between the kicks;
- **DOP853, as called**: the same with solve_ivp's own step control (no ``max_step``),
  as an ODE user would first call it: event location then misses a grazing impact
  shorter than a step.

The steps play from rest here (the plan's scenes carry the state from step to step and
add the settle dwell, so plan.json's ``travel_m`` differs a little); what is compared is
the same run by different methods.  Writes benchmarks/results/independent_steps.md and
.csv.

    python benchmarks/independent_steps.py --plan PLAN_FOLDER
    # the default plan, seed 0: vibroplan plan --out /tmp/p0
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _timing import machine  # noqa: E402

import model  # noqa: E402
from model import Drive, scipy_ref  # noqa: E402
from planner.afterfab.as_built import as_built  # noqa: E402
from planner.fabrication.tolerances import design_from_plan  # noqa: E402
from planner.planfile.reader import read_plan, step_drive  # noqa: E402

RESULTS = HERE / "results"
#: DOP853's step bound in the fine runs, in periods of the drive's top tone or the
#: impacter's natural frequency, whichever is higher (1/40 of the top tone's missed a
#: graze of release_row_C's C4.backward, 5.7 kHz under 4.5-6.3 kHz tones).
FINE_STEP_PERIODS = 1 / 100


def _kicks_by(method, imps, slider, drive, duration):
    """(Kicks of every impacter pair of a device, impacts, seconds) by ``method``."""
    t0 = time.perf_counter()
    kicks, n = [], 0
    for imp, sign in imps:
        if method == "kernel":
            res = model.simulate(imp, drive, 0.0, 0.0, duration, max_events=1_000_000)
            k = model.Kicks.from_impacts(imp, slider, res, sign)
            n += res.times.size + res.chatter_times.size
        else:
            top = max(float(np.max(drive.frequencies)), imp.natural_frequency)
            max_step = FINE_STEP_PERIODS / top if method == "fine" else np.inf
            t, v = scipy_ref.impacts(imp, drive, duration, max_step=max_step)
            k = _kicks_of(imp, slider, t, v, sign)
            n += t.size
        kicks.append(k)
    return model.Kicks.concatenate(kicks), n, time.perf_counter() - t0


def _kicks_of(imp, slider, times, speeds, sign):
    """A Kicks record of impacts found by the reference (no chatter tails)."""
    k = times.size
    return model.Kicks(times=times, velocities=speeds, chatter=np.zeros(k, dtype=bool),
                       direction=np.full(k, sign),
                       mass_ratio=np.full(k, imp.mass / slider.mass),
                       impact_angle=np.full(k, imp.impact_angle),
                       restitution=np.full(k, imp.restitution),
                       velocity_changes=model.kick(imp, slider, speeds, sign),
                       slider_mass=slider.mass)


def rows(plan_dir):
    plan = read_plan(plan_dir)
    contact = plan.spec.device.contact
    models = as_built(design_from_plan(plan), {})
    out = []
    for st in plan.steps:
        if len(st.tones) < 2 or st.gated:
            continue
        rd = step_drive(st)
        drive = Drive(rd.frequencies, rd.amplitudes, rd.phases)
        duration = float(st.duration_s)
        driven = sorted(set(st.forward) | set(st.backward), key=lambda d: (d[0], int(d[1:])))
        for dev in driven:
            imps = [(models.impacters[r.id], 1.0 if r.direction == "forward" else -1.0)
                    for r in plan.impacters if r.device == dev]
            slider = models.sliders[dev]
            row = {"step": st.key, "device": dev, "tones": len(st.tones),
                   "duration_ms": duration * 1e3}
            for method in ("kernel", "fine", "as_called"):
                kicks, n, secs = _kicks_by(method, imps, slider, drive, duration)
                t0 = time.perf_counter()
                if method == "kernel":
                    z = model.slider_motion(slider, drive, kicks, duration=duration,
                                            contact=contact)[2]
                else:
                    z = scipy_ref.slider_motion(slider, drive, kicks, duration, contact)[0]
                row[f"impacts_{method}"] = n
                row[f"travel_um_{method}"] = z * 1e6
                row[f"seconds_{method}"] = secs + time.perf_counter() - t0
            out.append(row)
            print(f"{st.key} {dev}: kernel {row['travel_um_kernel']:.3f} um "
                  f"({row['impacts_kernel']} impacts, {row['seconds_kernel']:.3f} s); "
                  f"DOP853 fine {row['travel_um_fine']:.3f} um ({row['impacts_fine']}, "
                  f"{row['seconds_fine']:.1f} s); as called {row['travel_um_as_called']:.3f} um "
                  f"({row['impacts_as_called']})", flush=True)
    return pd.DataFrame(out)


def report(df, plan_dir, command):
    rel_fine = (df.travel_um_fine - df.travel_um_kernel).abs() / df.travel_um_kernel.abs()
    rel_called = ((df.travel_um_as_called - df.travel_um_kernel).abs()
                  / df.travel_um_kernel.abs())
    missed = df.impacts_kernel - df.impacts_as_called
    lines = [
        "# A plan's multi-tone steps against independent integrations",
        "",
        f"`{command}` on {machine()}.  Plan: `{plan_dir}`.",
        "",
        "Every device a multi-tone step drives, its slider's travel from rest over the "
        "step's duration: the product's solvers (kernel) against SciPy's DOP853 "
        f"(`model.scipy_ref`), with its step held to {FINE_STEP_PERIODS:g} of the shortest "
        "period of the tones and the impacter (fine) and with solve_ivp's own step "
        "control (as called).",
        "",
        "| step | devices | tones | travel, kernel [um] | impacts, kernel | "
        "largest relative difference, fine | impacts the fine runs differ by | "
        "largest relative difference, as called | impacts missed as called | "
        "seconds per device: kernel / fine |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for step, g in df.groupby("step", sort=False):
        idx = g.index
        lines.append(
            f"| {step} | {len(g)} | {g.tones.iloc[0]} | {g.travel_um_kernel.min():.1f}-"
            f"{g.travel_um_kernel.max():.1f} | {g.impacts_kernel.sum()} | "
            f"{rel_fine[idx].max():.1e} | {int((g.impacts_kernel - g.impacts_fine).abs().sum())} | "
            f"{rel_called[idx].max():.1e} | {int(missed[idx].sum())} "
            f"({int((missed[idx] != 0).sum())} devices) | "
            f"{g.seconds_kernel.median():.3f} / {g.seconds_fine.median():.1f} |")
    worst = df.loc[rel_called.idxmax()]
    lines += [
        "",
        "## Reading",
        "",
        (f"- The fine integration agrees with the kernel on every device: travel within "
         f"{rel_fine.max():.1e} relative, the same impacts one for one."
         if not (df.impacts_kernel != df.impacts_fine).any() else
         f"- The fine integration differs from the kernel in its impacts on "
         f"{int((df.impacts_kernel != df.impacts_fine).sum())} devices (travel within "
         f"{rel_fine.max():.1e} relative): see the csv."),
        f"- Called with its own step control, DOP853 misses {int(missed.sum())} impacts on "
        f"{int((missed != 0).sum())} devices: grazes shorter than its step, which event "
        "location cannot see (tests/model/test_step_against_scipy.py holds one of them, "
        "2.7 nm past a 5.1 um gap); the worst device's travel then differs by "
        f"{rel_called.max():.1%} ({worst.step} {worst.device}: {worst.travel_um_as_called:.2f} "
        f"against {worst.travel_um_kernel:.2f} um).  The kernel's steps are bounded so "
        "that no crossing can be stepped over.",
        f"- Time per device (both impacter pairs and the slider): kernel median "
        f"{df.seconds_kernel.median() * 1e3:.0f} ms, DOP853 fine "
        f"{df.seconds_fine.median():.1f} s.",
    ]
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--plan", required=True, help="a plan folder (vibroplan plan --out)")
    args = ap.parse_args(argv)
    df = rows(args.plan)
    RESULTS.mkdir(exist_ok=True)
    df.to_csv(RESULTS / "independent_steps.csv", index=False, float_format="%.9g")
    text = report(df, args.plan, "python benchmarks/independent_steps.py --plan "
                  + str(args.plan))
    (RESULTS / "independent_steps.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
