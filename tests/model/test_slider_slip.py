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
