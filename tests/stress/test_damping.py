"""Every damping regime, and the undamped exact resonance, against 50 digits.

Property: for damping ratios 0, 1e-9, 0.3, 0.99, 1 (exactly critical, and within
1e-12 of it) and 2, and for a drive exactly at the natural frequency of an undamped
impacter (the secular solution), r agrees with the 50-digit evaluation of the same
model to 1e-12.
"""

import math

import numpy as np
import pytest

import model
from model import Drive, Impacter
from model.kernels.closed_form import BEAT, tone_coefficients
from model.mpref import reference

WN = 2 * math.pi * 5200.0
GAP = 1e-6


def impacting_drive(zeta, ratio=0.9):
    """A tone at ratio * wn whose steady amplitude, without the wall, is 2.5 gaps."""
    w = ratio * WN
    a = 2.5 * GAP * abs(complex(WN**2 - w**2, 2 * zeta * WN * w))
    return Drive([w / (2 * math.pi)], [a / (math.cos(0.0) * w**2)])


def agree(imp, drive, x0=0.0, duration=2e-3):
    res = model.simulate(imp, drive, x0=x0, duration=duration)
    ref = reference(imp, drive, x0=x0, duration=duration)
    assert res.status == "ok" and res.n_impacts > 3
    return abs(res.response - float(ref.response)) / float(ref.response)


@pytest.mark.parametrize("zeta, ratio", [(0.0, 0.9), (1e-9, 0.9), (0.3, 0.9), (0.99, 0.9),
                                         (2.0, 2.0)])
def test_damping_ratios(zeta, ratio):
    imp = Impacter(1.0, WN**2, 2 * zeta * WN, GAP, impact_angle=0.0)
    assert agree(imp, impacting_drive(zeta, ratio), x0=-GAP) <= 1e-12


@pytest.mark.parametrize("rel", [0.0, 1e-12, -1e-12])
def test_critical_damping_and_its_neighbours(rel):
    # sigma == wn exactly (m = 1, b = 2 wn), and within 1e-12 of it on both sides:
    # the over- and under-damped forms must not cancel there
    imp = Impacter(1.0, WN**2, 2 * WN * (1 + rel), GAP, impact_angle=0.0)
    assert (imp.sigma == imp.omega_n) == (rel == 0.0)
    assert agree(imp, impacting_drive(1.0), x0=-GAP) <= 1e-12


def test_undamped_exact_resonance_is_secular():
    # m = 1 and k = w^2: sqrt(k / m) == w exactly, so the particular solution is the
    # secular a t sin(w t + phi) / (2 w); the beat form must reproduce it
    w = 2.0 * np.pi * 5200.0
    imp = Impacter(1.0, w * w, 0.0, GAP, impact_angle=0.0)
    assert imp.omega_n == w
    drive = Drive([5200.0], [0.05 * GAP])
    coef = tone_coefficients(imp.omega_n, 0.0, drive.omegas, w**2 * drive.amplitudes,
                             drive.phases)
    assert coef[0, 3] == BEAT and coef[0, 5] == 0.0  # wd - w = 0: E1(t) = t
    # the amplitude grows as a t / (2 w) until the impacter reaches the wall
    assert agree(imp, drive, duration=3e-3) <= 1e-12


@pytest.mark.parametrize("zeta", [1e-12, 1e-9, 1e-6])
def test_light_damping_at_resonance_steps(zeta):
    # regression (with test_reference.py): at resonance, damping ratio 1e-9 took
    # 1.35 million steps and 1e-12 hit the step cap with the regular particular form
    imp = Impacter(1.0, WN**2, 2 * zeta * WN, GAP, impact_angle=0.0)
    drive = Drive([5200.0], [0.05 * GAP])
    res = model.simulate(imp, drive, duration=3e-3)
    assert res.status == "ok" and res.n_steps < 5000
