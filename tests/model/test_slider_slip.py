"""The slider kernel's slip phase against an independent integration.

The kernel evaluates a slip in closed form from its start (t_a, z_a, v_a); the terms of
t_a are computed once per slip (issue 43, item 7).  A slip under a two-tone forcing that
never stops, integrated by scipy's DOP853 to 1e-13, must give the kernel's position and
velocity: a start term mixed up (cos for sin) moves the position by the forced part,
a few parts in 10^3 here.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import model
from model import Drive, Slider


def test_a_forced_slip_matches_an_ode_integration():
    mass, beta, fd = 1e-9, 100.0, 1.0          # [kg], B/M [1/s], F_d/M [m/s^2]
    slider = Slider(mass, damping=beta * mass, static_friction=2 * fd * mass,
                    dynamic_friction=fd * mass)
    drive = Drive([5000.0, 7300.0], [6e-8, 3e-8], [0.3, -1.1])
    w = drive.omegas
    a = drive.acceleration_amplitudes()
    phi = np.asarray(drive.phases)
    z0, v0, duration = 1e-6, 0.02, 2e-3        # [m], [m/s] (slips forward throughout), [s]

    def rhs(t, y):
        f = float(np.sum(a * np.cos(w * t + phi)))
        return [y[1], -beta * y[1] + f - fd]

    ref = solve_ivp(rhs, (0.0, duration), [z0, v0], method="DOP853", rtol=1e-13,
                    atol=1e-20)
    assert ref.success and np.all(ref.y[1] > 0), "the reference must slip forward throughout"
    # the forcing's part of the position is what a wrong start term would change
    forced = ref.y[0, -1] - (z0 + v0 * (1 - np.exp(-beta * duration)) / beta)
    assert abs(forced) > 1e-3 * abs(ref.y[0, -1])
    _, _, z, v, status = model.slider_motion(slider, drive, np.empty(0), np.empty(0),
                                             duration, z0, v0)
    assert status == "ok"
    assert z == pytest.approx(ref.y[0, -1], rel=1e-9)
    assert v == pytest.approx(ref.y[1, -1], rel=1e-9)


# --- the forcing's peak bound and the stuck phases it lets the kernel skip (issue 43) ---

def _true_peak(drive, duration):
    """The forcing's peak over [0, duration], found independently: a grid 20x finer than
    the bound's, each local maximum of |f| polished by scipy's bounded scalar search."""
    from scipy.optimize import minimize_scalar

    w, a, phi = drive.omegas, drive.acceleration_amplitudes(), np.asarray(drive.phases)

    def f(t):
        return float(np.sum(a * np.cos(w * t + phi)))

    t = np.linspace(0.0, duration, int(duration * w.max() / (2 * np.pi) * 400) + 2)
    y = np.abs(np.cos(np.outer(t, w) + phi) @ a)
    best = float(y.max())
    for i in np.argsort(y)[-12:]:
        lo, hi = t[max(i - 1, 0)], t[min(i + 1, t.size - 1)]
        res = minimize_scalar(lambda s: -abs(f(s)), bounds=(lo, hi), method="bounded",
                              options={"xatol": 1e-15})
        best = max(best, -float(res.fun))
    return best


@pytest.mark.parametrize("case", ["25 tones", "two close tones (beats)", "one tone",
                                  "two tones far apart", "50 tones, 60 kHz"])
def test_the_forcing_peak_bound_is_never_below_the_peak(case):
    from model.slider import PEAK_BOUND_SLACK, forcing_peak_bound

    rng = np.random.default_rng(abs(hash(case)) % 2**32)
    f, z, duration = {
        "25 tones": (rng.uniform(4e3, 51e3, 25), rng.uniform(1e-9, 3e-8, 25), 10e-3),
        "two close tones (beats)": ([20000.0, 20003.0], [1e-8, 1e-8], 0.4),
        "one tone": ([12000.0], [2e-8], 3e-3),
        "two tones far apart": ([4000.0, 51000.0], [5e-8, 1e-9], 5e-3),
        "50 tones, 60 kHz": (rng.uniform(1e3, 60e3, 50), rng.uniform(1e-9, 1e-8, 50), 2e-3),
    }[case]
    drive = Drive(f, z, rng.uniform(-np.pi, np.pi, len(f)))
    fmax = float(np.sum(np.abs(drive.acceleration_amplitudes())))
    bound = forcing_peak_bound(drive, duration)
    peak = _true_peak(drive, duration)
    if bound == 0.0:                 # too many samples: no bound, the kernel uses fmax
        assert case == "two close tones (beats)"
        return
    assert peak <= bound <= fmax * (1 + 1e-12)
    # and tight: within the grid's slack (plus rounding) above the peak
    assert bound <= peak + PEAK_BOUND_SLACK * fmax * 1.001


@pytest.mark.parametrize("friction", [0.6, 1.5], ids=["drive above friction",
                                                      "drive below friction"])
def test_skipped_stuck_phases_change_no_digit(friction):
    """The kernel with the peak bound (stuck phases between kicks skipped when the drive
    cannot overcome static friction) and without it (every stuck phase stepped through):
    the same position, velocity and samples, bit for bit."""
    from model.kernels.contact import N_COLS, PAPER
    from model.kernels.impacter import MAX_STEPS
    from model.kernels.slider import run_slider
    from model.slider import forcing_peak_bound

    rng = np.random.default_rng(7)
    drive = Drive(rng.uniform(4e3, 51e3, 25), rng.uniform(2e-9, 1e-8, 25),
                  rng.uniform(-np.pi, np.pi, 25))
    w, a, phi = drive.omegas, drive.acceleration_amplitudes(), np.asarray(drive.phases)
    duration = 10e-3
    bound = forcing_peak_bound(drive, duration)
    fmax = float(np.sum(np.abs(a)))
    assert bound < 0.8 * fmax                   # phases at random: the peak is lower
    # per unit mass [m/s^2]: above friction, the drive slips the slider by itself; below
    # it, only the bound knows (fmax, all the kernel knows by itself, is above it)
    fs = 0.6 * bound if friction < 1 else 0.5 * (bound + fmax)
    kick_t = np.sort(rng.uniform(0, duration, 40))
    kick_dv = rng.uniform(0.5e-3, 2e-3, 40)
    sample_t = np.linspace(0, duration, 333)
    out = []
    for f_bound in (bound, 0.0):
        sample_z = np.zeros(sample_t.size)
        res = run_slider(PAPER, 50.0, fs, 0.4 * fs, w, a, phi, kick_t, kick_dv,
                         np.empty((40, N_COLS)), 0.0, duration, 0.0, 0.0, MAX_STEPS,
                         sample_t, sample_z, f_bound)
        out.append((res, sample_z))
    (with_bound, z_with), (without, z_without) = out
    assert with_bound[0] == without[0] == 0
    assert with_bound[1:3] == without[1:3]
    assert np.array_equal(z_with, z_without)
    assert z_with[-1] > 0                       # the kicks moved it
    if friction > 1:
        assert with_bound[3] < without[3] / 3   # and the stuck phases were skipped
    else:
        assert with_bound[3] == without[3]      # the bound decides nothing there
