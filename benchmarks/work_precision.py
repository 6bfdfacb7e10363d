"""Work-precision benchmark of the exact impacter solver against RK4 and solve_ivp.

For each case the response r of eq. (12), the impact times and the impact
velocities of every method are compared with a reference that is itself checked:
the same closed form evaluated in 50 digits by :mod:`model.mpref`, whose impacts
are found by scanning and bracketing (not by the float solver's safe steps).
Time per evaluation is the median of repeated runs after a warm-up
(benchmarks/_timing.py), as timeit / pyperf / asv do.

Cases
    a1  Fig. 7 device at 6.2 kHz (undamped, x0 = 0, 3 ms, 17 impacts)
    a2  Fig. 7 device at 5.2 kHz: exact resonance of the undamped impacter
    b   Table II's forward impacter in air at 6 kHz (damping ratio 0.029), x0 = -2.6 um
    c   Fig. 7 impacter with a 0.3 um gap at 1 kHz: the drive presses it on the wall,
        every approach chatters into sticking, then it is released
Methods
    exact         the event-driven closed-form solver (numba kernel, one r evaluation)
    rk4           the paper's fixed-step RK4 (numba kernel, same impact law), >= 6 steps
    DOP853, RK45  scipy.integrate.solve_ivp with a terminal wall event, restarted at
                  each impact, >= 5 tolerances

Writes work_precision.csv, work_precision.md and work_precision.png into the
output directory (benchmarks/results by default)::

    python benchmarks/work_precision.py [--out DIR] [--quick]
    vibroplan bench [--out DIR] [--quick]
"""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

from _timing import machine, measure  # noqa: E402

import model  # noqa: E402
from model import Drive, Impacter  # noqa: E402
from model.kernels import impacter as kern  # noqa: E402
from model.kernels.rk4 import rk4_response, run_rk4  # noqa: E402
from model.mpref import reference  # noqa: E402
from model.impacter import impacter_forcing  # noqa: E402

#: RK4 steps per shortest period (>= 6 settings) and solve_ivp tolerances (>= 5).
RK4_STEPS_PER_PERIOD = (25, 50, 100, 200, 400, 800, 1600, 3200)
IVP_RTOLS = (1e-4, 1e-6, 1e-8, 1e-10, 1e-12)
IVP_METHODS = ("DOP853", "RK45")
#: --quick: fewer settings and shorter timings (a smoke run, not for the record).
QUICK_RK4 = (50, 200, 800, 3200)
QUICK_RTOLS = (1e-4, 1e-6, 1e-8, 1e-10, 1e-12)
#: Impacts below this fraction of the largest v- are not matched one by one (chatter
#: is resolved to different depths by different methods; r includes all of them).
SIGNIFICANT = 1e-6
#: Error level at which the methods are compared ("at equal error").
EQUAL_ERROR = 1e-6

FIG7 = Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6).with_natural_frequency(5200.0)
TABLE2_AIR = Impacter.from_geometry(13544e-12, 5.6774e-6, 795.74e-6, 5.2046e-6,
                                    viscosity=0.0179e-3).with_natural_frequency(5819.9)
PRESSED = Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 0.3e-6).with_natural_frequency(5200.0)


@dataclass(frozen=True)
class Case:
    key: str
    title: str
    impacter: Impacter
    drive: Drive
    x0: float = 0.0
    duration: float = 3e-3


CASES = (
    Case("a1", "Fig. 7 device, 6.2 kHz", FIG7, Drive.tone(6200.0)),
    Case("a2", "Fig. 7 device, 5.2 kHz (exact resonance, undamped)", FIG7, Drive.tone(5200.0)),
    Case("b", "Table II forward impacter in air, 6 kHz", TABLE2_AIR, Drive.tone(6000.0),
         x0=-2.6e-6),
    Case("c", "chatter into sticking (0.3 um gap, 1 kHz)", PRESSED, Drive.tone(1000.0)),
)


# --------------------------------------------------------------------------- methods

def kernel_args(case):
    imp = case.impacter
    w, a, phi = impacter_forcing(imp, case.drive)
    return imp, w, a, phi


def exact_events(case):
    res = model.simulate(case.impacter, case.drive, x0=case.x0, duration=case.duration)
    keep = res.velocities >= 0
    return res.response, res.times[keep], res.velocities[keep], res.status


def exact_timer(case):
    imp, w, a, phi = kernel_args(case)
    args = (imp.omega_n, imp.sigma, imp.gap, imp.restitution, w, a, phi, case.duration,
            case.x0, 0.0, 0, kern.MAX_EVENTS, kern.MAX_STEPS)
    return lambda: kern.response_single(*args)


def rk4_step(case, per_period):
    fmax = max(float(case.drive.frequencies.max()), case.impacter.natural_frequency)
    return 1.0 / (per_period * fmax)


def rk4_events(case, h):
    imp, w, a, phi = kernel_args(case)
    cap = 200_000
    t = np.zeros(cap)
    v = np.zeros(cap)
    status, n, sum_v, _, _, _ = run_rk4(imp.omega_n, imp.sigma, imp.gap, imp.restitution,
                                        w, a, phi, 0.0, case.duration, case.x0, 0.0, h, cap,
                                        t, v)
    n = min(n, cap)
    return imp.mass * sum_v / case.duration, t[:n], v[:n], "ok" if status == 0 else "cap"


def rk4_timer(case, h):
    imp, w, a, phi = kernel_args(case)
    args = (imp.omega_n, imp.sigma, imp.gap, imp.restitution, w, a, phi, case.duration,
            case.x0, 0.0, h, 200_000)
    return lambda: rk4_response(*args)


def ivp_run(case, method, rtol, max_events=5000):
    """solve_ivp with a terminal wall event, restarted at each impact (v+ = -e v-).

    A rebound slower than the method's velocity tolerance under a force pressing on
    the wall ends a chatter sequence by sticking (the remaining bounces are lost, as
    with any fixed tolerance), and an event on the net force releases it.
    """
    from scipy.integrate import solve_ivp

    imp = case.impacter
    w, a, phi = impacter_forcing(imp, case.drive)
    wn2, s2, gap, e = imp.omega_n**2, 2 * imp.sigma, imp.gap, imp.restitution
    w0, a0, p0 = float(w[0]), float(a[0]), float(phi[0])
    one = w.size == 1

    def force(t):
        if one:
            return a0 * math.cos(w0 * t + p0)
        return float(np.dot(a, np.cos(w * t + phi)))

    def rhs(t, y):
        return [y[1], force(t) - s2 * y[1] - wn2 * y[0]]

    def wall(t, y):
        return y[0] - gap
    wall.terminal = True
    wall.direction = 1

    def release(t, y):
        return force(t) - wn2 * gap
    release.terminal = True
    release.direction = -1

    vscale = gap * imp.omega_n
    atol = [rtol * gap, rtol * vscale]
    period = 2 * math.pi / max(float(w.max()), imp.omega_n)
    accel_max = float(np.sum(np.abs(a))) + wn2 * 2 * gap + s2 * vscale
    t, y = 0.0, [case.x0, 0.0]
    stuck = case.x0 == gap and force(0.0) - wn2 * gap > 0
    times, vels, sum_v = [], [], 0.0
    restarts = 0
    while t < case.duration and len(times) < max_events and restarts < 20 * max_events:
        restarts += 1
        if stuck:
            sol = solve_ivp(lambda t, y: [0.0, 0.0], (t, case.duration), [gap, 0.0],
                            rtol=rtol, atol=atol, events=release, max_step=period / 16)
            if sol.status != 1:
                break
            t, stuck = float(sol.t_events[0][0]), False
            # leave the wall by a short Taylor step (1e-4 period) of the motion from
            # rest, x = gap + F s^2 / 2 + F' s^3 / 6, so that the wall event does not
            # fire at the start
            s0 = 1e-4 * period
            f1 = -a0 * w0 * math.sin(w0 * t + p0) if one else \
                float(np.dot(-a * w, np.sin(w * t + phi)))
            f0 = force(t) - wn2 * gap
            y = [gap + f0 * s0**2 / 2 + f1 * s0**3 / 6, f0 * s0 + f1 * s0**2 / 2]
            t += s0
            continue
        # from the wall (after an impact or a release) the first step must end below
        # it, or the wall event fires at the start: within |v+| / max|x''| it does
        first = None
        if y[0] == gap:
            first = min(period / 100, max(abs(y[1]), 1e-300) / accel_max)
            first = max(first, 4 * math.ulp(max(t, 1e-300)))
        sol = solve_ivp(rhs, (t, case.duration), y, method=method, rtol=rtol, atol=atol,
                        events=wall, first_step=first)
        if sol.status != 1:
            break
        te, ye = float(sol.t_events[0][0]), sol.y_events[0][0]
        if ye[1] <= 0 or te <= t:
            # the event fired at the start: the integrator cannot resolve a flight this
            # short; end it by sticking if the force presses, else give up the run
            if force(te) - wn2 * gap > 0:
                t, stuck = te, True
                continue
            break
        times.append(te)
        vels.append(float(ye[1]))
        if len(times) >= 2:
            sum_v += float(ye[1])
        vplus = -e * float(ye[1])
        t, y = te, [gap, vplus]
        if force(te) - wn2 * gap - s2 * vplus > 0 and abs(vplus) < rtol * vscale:
            stuck = True
    status = "ok" if len(times) < max_events else "cap"
    return imp.mass * sum_v / case.duration, np.array(times), np.array(vels), status


# --------------------------------------------------------------------------- errors

def errors(r, t, v, ref):
    """(relative error of r, max |dt| [s], max |dv| / max v-) against the reference.

    Impacts are matched one by one above SIGNIFICANT of the largest v-; a method
    that misses or adds one gets inf for dt and dv.
    """
    r_ref, t_ref, v_ref = ref
    err_r = abs(r - r_ref) / r_ref
    vmax = v_ref.max()
    keep_ref = v_ref >= SIGNIFICANT * vmax
    keep = v >= SIGNIFICANT * vmax
    if np.count_nonzero(keep) != np.count_nonzero(keep_ref):
        return err_r, math.inf, math.inf
    dt = float(np.max(np.abs(t[keep] - t_ref[keep_ref]))) if keep.any() else 0.0
    dv = float(np.max(np.abs(v[keep] - v_ref[keep_ref]))) / vmax if keep.any() else 0.0
    return err_r, dt, dv


def reference_of(case):
    ref = reference(case.impacter, case.drive, x0=case.x0, duration=case.duration)
    if ref.status != "ok":
        raise RuntimeError(f"reference of case {case.key}: {ref.status}")
    t, v = ref.impact_arrays()
    return float(ref.response), t, v, ref.n_impacts


# --------------------------------------------------------------------------- runs

def work_precision(case, quick, echo):
    """Rows of (case, method, setting, errors, time) for one case."""
    t0 = time.perf_counter()
    r_ref, t_ref, v_ref, n_ref = reference_of(case)
    echo(f"  {case.key}: 50-digit reference, {n_ref} impacts, r = {r_ref:.12e} N "
         f"({time.perf_counter() - t0:.1f} s)")
    ref = (r_ref, t_ref, v_ref)
    rows = []
    fast = dict(min_time=0.05 if quick else 0.2, repeat=3 if quick else 7)
    slow = dict(min_time=0.0, repeat=1 if quick else 3)

    r, t, v, status = exact_events(case)
    timing = measure(exact_timer(case), **fast)
    rows.append(_row(case, "exact", "-", errors(r, t, v, ref), timing, t.size, status))
    for per_period in (QUICK_RK4 if quick else RK4_STEPS_PER_PERIOD):
        h = rk4_step(case, per_period)
        r, t, v, status = rk4_events(case, h)
        timing = measure(rk4_timer(case, h), **fast)
        rows.append(_row(case, "rk4", f"{per_period}/period", errors(r, t, v, ref), timing,
                         t.size, status))
    for method in IVP_METHODS:
        for rtol in (QUICK_RTOLS if quick else IVP_RTOLS):
            if quick and method == "RK45" and rtol < 1e-10:
                continue
            r, t, v, status = ivp_run(case, method, rtol)
            timing = measure(lambda: ivp_run(case, method, rtol), **slow)
            rows.append(_row(case, method, f"rtol={rtol:g}", errors(r, t, v, ref), timing,
                             t.size, status))
    for row in rows:
        echo(f"    {row['method']:7s} {row['setting']:14s} err_r {row['err_r']:9.2e}  "
             f"err_t {row['err_t']:9.2e}  err_v {row['err_v']:9.2e}  "
             f"{row['time_s'] * 1e6:12.1f} us")
    return rows


def _row(case, method, setting, errs, timing, n_impacts, status):
    return {"case": case.key, "method": method, "setting": setting, "err_r": errs[0],
            "err_t": errs[1], "err_v": errs[2], "time_s": timing.median,
            "time_min_s": timing.minimum, "calls_per_run": timing.calls_per_run,
            "runs": timing.runs, "n_impacts": int(n_impacts), "status": status}


def time_at_error(rows, method, level=EQUAL_ERROR):
    """Time per evaluation of ``method`` at relative error ``level`` of r (log-log
    interpolation between the two settings that bracket it), or None."""
    pts = sorted((row["err_r"], row["time_s"]) for row in rows
                 if row["method"] == method and row["err_r"] > 0 and math.isfinite(row["err_r"]))
    for (e1, t1), (e2, t2) in zip(pts, pts[1:]):
        if e1 <= level <= e2:
            if e1 == e2:
                return t1
            f = math.log(level / e1) / math.log(e2 / e1)
            return math.exp(math.log(t1) + f * math.log(t2 / t1))
    return None


# --------------------------------------------------------------------------- speed targets

def sweep_time(quick):
    """model.sweep of 1001 frequencies x 21 initial positions on the Fig. 7 device."""
    freqs = np.linspace(4000.0, 9000.0, 1001)
    x0s = np.linspace(-FIG7.gap, FIG7.gap, 21)
    return measure(lambda: model.sweep(FIG7, freqs, x0s), min_time=0.05 if quick else 0.5,
                   repeat=3 if quick else 7)


def in_sweep_time(quick):
    """One r evaluation of case a1 inside a parallel batch: 2000 identical runs."""
    freqs = np.full(2000, 6200.0)
    timing = measure(lambda: model.sweep(FIG7, freqs, [0.0]), min_time=0.05 if quick else 0.5,
                     repeat=3 if quick else 7)
    return timing.median / freqs.size, timing.minimum / freqs.size


def fresh_process_time():
    """Wall time of a fresh interpreter that imports model and calls model.response once
    (numba's on-disk cache warm: run once before), and the part after the imports."""
    code = ("import time; t0 = time.perf_counter(); import model; "
            "imp = model.Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6)"
            ".with_natural_frequency(5200.0); t1 = time.perf_counter(); "
            "model.response(imp, model.Drive.tone(6200.0)); t2 = time.perf_counter(); "
            "print(t1 - t0, t2 - t1)")
    cmd = [sys.executable, "-c", code]
    subprocess.run(cmd, check=True, capture_output=True)  # warm the cache
    walls, imports, calls = [], [], []
    for _ in range(3):
        t0 = time.perf_counter()
        out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout.split()
        walls.append(time.perf_counter() - t0)
        imports.append(float(out[0]))
        calls.append(float(out[1]))
    return float(np.median(walls)), float(np.median(imports)), float(np.median(calls))


# ------------------------------------------------------------ skip what is not needed

def _no_reuse_sweep_kernel():
    """A sweep that recomputes every per-frequency constant for each run (parallel),
    the baseline for sweep_batch's reuse of them."""
    from numba import njit, prange

    @njit(parallel=True)
    def no_reuse(wn, sigma, gap, e, w_list, a_list, x0s, t_end, max_events, max_steps):
        nf = w_list.shape[0]
        nx = x0s.shape[0]
        out = np.zeros((nf, nx))
        phi = np.zeros(1)
        for k in prange(nf * nx):
            i = k // nx
            j = k % nx
            res = kern.response_single(wn, sigma, gap, e, w_list[i:i + 1], a_list[i:i + 1],
                                       phi, t_end, x0s[j], 0.0, 0, max_events, max_steps)
            out[i, j] = res[2]
        return out

    return no_reuse


def gains(quick):
    """Time saved by each shortcut of the response path (rows of dicts)."""
    opt = dict(min_time=0.05 if quick else 0.2, repeat=3 if quick else 7)
    imp, drive = FIG7, Drive.tone(6200.0)
    slider = model.Slider.from_geometry(8.0e-8)
    rows = []

    def add(what, full_label, full, fast_label, fast):
        rows.append({"shortcut": what, "baseline": full_label,
                     "baseline_s": full.median, "shortcut_path": fast_label,
                     "shortcut_s": fast.median, "gain": full.median / fast.median})

    resp = measure(lambda: model.response(imp, drive), **opt)
    add("response only: no slider, no event list, no trajectory",
        "simulate_slider (impacts + slider, 2001-sample trajectory)",
        measure(lambda: model.simulate_slider(imp, slider, drive, trajectory=True), **opt),
        "model.response", resp)
    add("response only: no event list",
        "model.simulate (event list, no trajectory)",
        measure(lambda: model.simulate(imp, drive), **opt), "model.response", resp)
    add("'does it respond?': stop at the first counted impact (case a1)",
        "model.response", resp, "model.response(stop_at_first=True)",
        measure(lambda: model.response(imp, drive, stop_at_first=True), **opt))
    x0s = np.linspace(-imp.gap, imp.gap, 21)
    freqs = np.linspace(4000.0, 9000.0, 201)
    add("'does it respond?' over a 201 x 21 sweep", "model.sweep",
        measure(lambda: model.sweep(imp, freqs, x0s), **opt),
        "model.sweep(stop_at_first=True)",
        measure(lambda: model.sweep(imp, freqs, x0s, stop_at_first=True), **opt))
    # per-frequency constants shared by all x0 of a frequency, against recomputing them
    w = 2 * np.pi * freqs
    a = math.cos(imp.impact_angle) * w**2 * model.amplitude_from_power(freqs)
    no_reuse = _no_reuse_sweep_kernel()
    args = (imp.omega_n, imp.sigma, imp.gap, imp.restitution, w, a, x0s, 3e-3,
            kern.MAX_EVENTS, kern.MAX_STEPS)
    add("sweep: per-frequency constants computed once",
        "every run recomputes them (same parallel loop)",
        measure(lambda: no_reuse(*args), **opt),
        "sweep_batch",
        measure(lambda: kern.sweep_batch(imp.omega_n, imp.sigma, imp.gap, imp.restitution,
                                         w, a, x0s, 3e-3, 0, kern.MAX_EVENTS, kern.MAX_STEPS),
                **opt))
    return rows


# --------------------------------------------------------------------------- outputs

def plot(rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    styles = {"exact": dict(marker="*", ms=14, color="k", ls="none"),
              "rk4": dict(marker="o", color="tab:blue"),
              "DOP853": dict(marker="s", color="tab:orange"),
              "RK45": dict(marker="^", color="tab:green")}
    fig, axes = plt.subplots(2, 2, figsize=(11, 8.5), sharey=True)
    for ax, case in zip(axes.flat, CASES):
        for method, style in styles.items():
            pts = [(max(row["err_r"], 1e-17), row["time_s"]) for row in rows
                   if row["case"] == case.key and row["method"] == method]
            if pts:
                x, y = zip(*pts)
                label = "exact (closed form)" if method == "exact" else (
                    "RK4 (paper, numba)" if method == "rk4" else f"solve_ivp {method}")
                ax.loglog(x, y, label=label, **style)
        ax.axvline(EQUAL_ERROR, color="0.7", lw=0.8, ls=":")
        ax.set_title(f"({case.key}) {case.title}", fontsize=10)
        ax.set_xlabel("relative error of r (eq. 12)")
        ax.grid(True, which="major", alpha=0.3)
        ax.set_xlim(1e-17, 10)
    for ax in axes[:, 0]:
        ax.set_ylabel("time per evaluation [s]")
    axes[0, 0].legend(fontsize=8, loc="upper right")
    fig.suptitle("Work-precision: response r of a 3 ms run (errors against 50 digits)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _fmt_err(x):
    return "missed/extra impact" if not math.isfinite(x) else f"{x:.1e}"


def markdown(rows, refcheck, targets, gain_rows, info, quick):
    lines = ["# Work-precision benchmark of the exact impacter solver", "",
             "Generated by `python benchmarks/work_precision.py` (or `vibroplan bench`)"
             + (" with `--quick` (a smoke run: fewer settings, short timings)" if quick
                else "") + ".",
             f"Machine: {info['cpu']}, {info['cores']} cores, Python {info['python']}; "
             f"load average {info['load'][0]:.2f} at the start, "
             f"{info['load_end'][0]:.2f} at the end (the machine is shared: wall-clock "
             "figures include other users' load).", "",
             "Times are medians of repeated runs after a warm-up "
             "(benchmarks/_timing.py). Errors are against the 50-digit evaluation of the "
             "same closed form (`model.mpref`), whose impacts are found by scanning and "
             "bracketing, independently of the float solver's safe steps. err_t is the "
             "largest impact-time error [s], err_v the largest impact-velocity error over "
             "the largest v-, both over the impacts above 1e-6 of the largest v-.", "",
             "![work-precision](work_precision.png)", "",
             "## Targets", "", "| target | measured | met |", "|---|---|---|"]
    for t in targets:
        lines.append(f"| {t[0]} | {t[1]} | {t[2]} |")
    lines += ["", "**What bounds the misses.** The exact solver advances by rigorous safe steps: "
              "about seven per impact (leave the wall, two or three far-field steps limited by "
              "the bound on |x''|, three converging on the wall), each a closed-form "
              "evaluation (two sine/cosine pairs) whose cost is latency-bound at about 70 ns, "
              "so a 17-impact run costs ~10 us on one core (~5 us per run in a sweep on two). "
              "The paper's RK4, compiled, reaches an r error of 1e-6 at about 50 steps per "
              "period (~1000 steps, ~100 us): beating it 100x would need ~1 us, about one "
              "step per impact, which no rigorous crossing test achieves. In the chattering "
              "case RK4's stick-by-step-size rule loses each sequence's tail, so its error "
              "falls only as h and never reaches 1e-6 (0.04% at 3200 steps per period).",
              "", "## The reference checked: exact solver against 50 digits", "",
              "| case | impacts | rel. error of r | max impact-time error [s] | "
              "max impact-velocity error / max v- |", "|---|---|---|---|---|"]
    for case in CASES:
        rc = refcheck[case.key]
        lines.append(f"| ({case.key}) {case.title} | {rc['n']} | {rc['err_r']:.1e} | "
                     f"{rc['err_t']:.1e} | {rc['err_v']:.1e} |")
    lines += ["", "## Shortcuts of the response path", "",
              "| shortcut | baseline | time | with the shortcut | time | gain |",
              "|---|---|---|---|---|---|"]
    for g in gain_rows:
        lines.append(f"| {g['shortcut']} | {g['baseline']} | {_fmt_time(g['baseline_s'])} | "
                     f"{g['shortcut_path']} | {_fmt_time(g['shortcut_s'])} | "
                     f"{g['gain']:.1f}x |")
    lines += ["", "A sweep's per-frequency constants (the particular solution's coefficients, "
              "two sines and a complex division) cost about 0.1 us against the ~10 us of a "
              "run, so sharing them between the initial positions of a frequency gains "
              "little; the shortcuts that matter are not building what r does not need and "
              "stopping at the first counted impact.", "", "## All runs", "",
              "| case | method | setting | impacts | err r | err t [s] | err v | "
              "time / evaluation |", "|---|---|---|---|---|---|---|---|"]
    for row in rows:
        lines.append(f"| {row['case']} | {row['method']} | {row['setting']} | "
                     f"{row['n_impacts']} | {_fmt_err(row['err_r'])} | "
                     f"{_fmt_err(row['err_t'])} | {_fmt_err(row['err_v'])} | "
                     f"{_fmt_time(row['time_s'])} |")
    return "\n".join(lines) + "\n"


def _fmt_time(s):
    if s < 1e-3:
        return f"{s * 1e6:.2f} us"
    if s < 1:
        return f"{s * 1e3:.2f} ms"
    return f"{s:.2f} s"


def run(out_dir=RESULTS, quick=False, echo=print):
    """Run the benchmark and write its CSV, PNG and Markdown into ``out_dir``."""
    import pandas as pd

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    info = machine()
    echo(f"work-precision benchmark{' (quick)' if quick else ''}: {info['cpu']}, "
         f"{info['cores']} cores, load {info['load'][0]:.2f}")
    rows = []
    refcheck = {}
    for case in CASES:
        case_rows = work_precision(case, quick, echo)
        rows += case_rows
        ex = case_rows[0]
        refcheck[case.key] = dict(n=ex["n_impacts"], err_r=ex["err_r"], err_t=ex["err_t"],
                                  err_v=ex["err_v"])
    echo("speed targets ...")
    sw = sweep_time(quick)
    per_eval, per_eval_min = in_sweep_time(quick)
    single = measure(exact_timer(CASES[0]), min_time=0.2, repeat=7)
    tone = Drive.tone(6200.0)
    api = measure(lambda: model.response(FIG7, tone), min_time=0.2, repeat=7)
    fresh_wall, fresh_import, fresh_call = fresh_process_time()
    echo("shortcuts ...")
    gain_rows = gains(quick)
    info["load_end"] = machine()["load"]

    def ok(flag):
        return "yes" if flag else "**no**"

    targets = []
    worst = max(refcheck[c.key]["err_r"] for c in CASES)
    targets.append(("exact solver: relative error of r <= 1e-12 on every case",
                    ", ".join(f"{c.key}: {refcheck[c.key]['err_r']:.1e}" for c in CASES),
                    ok(worst <= 1e-12)))
    targets.append(("one r evaluation of case a1 (3 ms, 17 impacts) <= 5 us inside a sweep",
                    f"{per_eval * 1e6:.2f} us per evaluation in a 2000-run parallel sweep "
                    f"(both cores); {single.median * 1e6:.2f} us on one core (kernel)",
                    ok(per_eval <= 5e-6) + ("" if single.median <= 5e-6 else
                                            " (one core: **no**)")))
    targets.append(("a single model.response call from Python <= 50 us",
                    f"{api.median * 1e6:.1f} us", ok(api.median <= 50e-6)))
    for case in CASES:
        case_rows = [r for r in rows if r["case"] == case.key]
        t_exact = case_rows[0]["time_s"]
        t_rk4 = time_at_error(case_rows, "rk4")
        msg = ("RK4 never reaches 1e-6" if t_rk4 is None else
               f"{t_rk4 / t_exact:.0f}x ({_fmt_time(t_rk4)} vs {_fmt_time(t_exact)})")
        targets.append((f"({case.key}) at error 1e-6, >= 100x faster than RK4 (numba)", msg,
                        ok(t_rk4 is not None and t_rk4 / t_exact >= 100)))
        for method in IVP_METHODS:
            ivp = [r for r in case_rows
                   if r["method"] == method and r["setting"] == "rtol=1e-10"]
            if ivp:
                ratio = ivp[0]["time_s"] / t_exact
                targets.append((f"({case.key}) >= 1000x faster than solve_ivp {method} at "
                                "rtol 1e-10", f"{ratio:.0f}x ({_fmt_time(ivp[0]['time_s'])}, "
                                f"its r error {_fmt_err(ivp[0]['err_r'])})", ok(ratio >= 1000)))
    targets.append(("model.sweep 1001 x 21 on the Fig. 7 device <= 0.2 s warm, both cores",
                    f"{sw.median:.3f} s (min {sw.minimum:.3f} s)", ok(sw.median <= 0.2)))
    targets.append(("first call in a fresh process (numba cache warm) <= 3 s",
                    f"{fresh_wall:.2f} s wall for the whole process (import model "
                    f"{fresh_import:.2f} s, first model.response {fresh_call * 1e3:.0f} ms)",
                    ok(fresh_wall <= 3.0)))

    frame = pd.DataFrame(rows)
    frame.to_csv(out_dir / "work_precision.csv", index=False, float_format="%.6g")
    plot(rows, out_dir / "work_precision.png")
    (out_dir / "work_precision.md").write_text(
        markdown(rows, refcheck, targets, gain_rows, info, quick))
    echo("targets:")
    for t in targets:
        echo(f"  [{t[2]:>6s}] {t[0]}: {t[1]}")
    echo(f"wrote {out_dir / 'work_precision.csv'}, work_precision.md, work_precision.png")
    return rows, targets


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(RESULTS), help="output directory")
    parser.add_argument("--quick", action="store_true",
                        help="fewer settings and short timings (a smoke run)")
    args = parser.parse_args(argv)
    run(args.out, args.quick)


if __name__ == "__main__":
    main()
