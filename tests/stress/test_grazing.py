"""Grazing: an impact is found exactly when the closed form reaches the wall.

Trajectories are built to touch x = c tangentially (the wall at the height of a
maximum of the free motion, found to 50 digits) and to pass within 1e-12 m of it,
above or below.  Property: a crossing by 1e-12 m is always found, with the impact
time and velocity of the closed form; a miss by 1e-12 m never gives an impact; a
tangential touch gives at most an impact at the noise level of x.
"""

import math

import numpy as np
import pytest

import model
from model import Drive, Impacter
from model.mpref import free_maximum, reference

WN = 2 * math.pi * 5200.0   # Fig. 7's natural frequency [rad/s]
HAIR = 1e-12                # [m]


def noise_velocity(imp, drive, height):
    """Impact speed of a parabola that rises NOISE * EPS * height above the wall [m/s]:
    the largest v- a touch within the rounding noise of x can produce."""
    accel = imp.omega_n**2 * height + float(np.sum(drive.acceleration_amplitudes()))
    return math.sqrt(2 * accel * 32 * 2.2e-16 * height) * 4


def free_oscillation_cases():
    # x(t) = -A e^{-sigma t} (cos wd t + sigma/wd sin wd t) from rest at -A: the first
    # maximum is at t = pi / wd, at A exp(-sigma pi / wd) (closed form, no drive)
    for zeta in (0.0, 0.01):
        amp = 3e-6
        sigma = zeta * WN
        wd = WN * math.sqrt(1 - zeta**2)
        top = amp * math.exp(-sigma * math.pi / wd)
        yield zeta, amp, top, math.pi / wd


@pytest.mark.parametrize("zeta, amp, top, t_top", list(free_oscillation_cases()))
def test_free_oscillation_grazing(zeta, amp, top, t_top):
    quiet = Drive([5000.0], [0.0])
    duration = 0.9 * 2 * math.pi / WN * 1.5  # one maximum only
    for offset, expect in ((HAIR, 0), (-HAIR, 1), (0.0, None)):
        imp = Impacter(1.0, WN**2, 2 * zeta * WN, top + offset)
        res = model.simulate(imp, quiet, x0=-amp, duration=duration)
        assert res.status == "ok"
        if expect == 0:
            assert res.n_impacts == 0, "impact invented 1e-12 m below a maximum"
        elif expect == 1:
            assert res.n_impacts == 1, "impact missed 1e-12 m above the wall"
            # the crossing of the closed form: v- = sqrt(2 |x''| delta) to first order
            curv = WN**2 * top
            v_exact = math.sqrt(2 * curv * HAIR)
            assert res.velocities[0] == pytest.approx(v_exact, rel=1e-3)
            assert abs(res.times[0] - t_top) <= 1.01 * math.sqrt(2 * HAIR / curv)
        else:
            # tangential touch: at most a touch at the rounding noise of x
            assert res.n_impacts <= 1
            assert np.all(res.velocities <= noise_velocity(imp, quiet, amp))


FORCED = [
    # (natural frequency [Hz], damping ratio, drive [Hz], Z [m], x0 [m], duration [s])
    (5200.0, 0.0, 6200.0, 1.0e-6, 0.0, 1e-3),
    (5200.0, 0.0, 5200.0, 0.3e-6, -1e-6, 1e-3),    # exact resonance (beat form)
    (5819.9, 0.029, 6000.0, 1.2e-6, -2.6e-6, 1e-3),  # Table II in air
]


@pytest.mark.parametrize("fn, zeta, f, z, x0, duration", FORCED)
def test_forced_grazing_against_50_digits(fn, zeta, f, z, x0, duration):
    wn = 2 * math.pi * fn
    drive = Drive([f], [z])
    far = Impacter(1.0, wn**2, 2 * zeta * wn, 1.0)
    t_top, top = free_maximum(far, drive, x0=x0, duration=duration)
    top = float(top)
    assert top > abs(x0)
    for offset in (HAIR, -HAIR):
        imp = Impacter(1.0, wn**2, 2 * zeta * wn, top + offset)
        res = model.simulate(imp, drive, x0=x0, duration=duration)
        ref = reference(imp, drive, x0=x0, duration=duration)
        t_ref, v_ref = ref.impact_arrays()
        assert res.n_impacts == ref.n_impacts == (0 if offset > 0 else 1)
        if offset < 0:
            # grazing impacts are ill-conditioned (d v- / d x ~ 1 / sqrt(height)): the
            # rounding noise of x (~1e-20 m) moves v- by ~1e-8 of itself
            assert res.velocities[0] == pytest.approx(v_ref[0], rel=1e-6)
            assert res.times[0] == pytest.approx(t_ref[0], abs=1e-14)
    # the tangential touch
    imp = Impacter(1.0, wn**2, 2 * zeta * wn, top)
    res = model.simulate(imp, drive, x0=x0, duration=duration)
    assert res.n_impacts <= 1
    assert np.all(res.velocities <= noise_velocity(imp, drive, top))


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(20))
def test_random_forced_grazing(seed):
    rng = np.random.default_rng(1000 + seed)
    fn = 10 ** rng.uniform(2, 5)
    wn = 2 * math.pi * fn
    zeta = rng.choice([0.0, 1e-6, 0.01, 0.2])
    nt = rng.integers(1, 4)
    f = fn * rng.uniform(0.6, 1.5, nt)
    z = np.sqrt(50 / (2 * math.pi * f) ** 3) * rng.uniform(0.2, 2, nt)
    drive = Drive(f, z, rng.uniform(0, 2 * math.pi, nt))
    duration = 10 / fn
    x0 = 0.0
    far = Impacter(1.0, wn**2, 2 * zeta * wn, 1.0)
    t_top, top = free_maximum(far, drive, x0=x0, duration=duration)
    if top is None or float(top) <= 0:
        pytest.skip("no positive maximum")
    top = float(top)
    for offset in (10 * HAIR * top / 1e-6, -10 * HAIR * top / 1e-6):
        imp = Impacter(1.0, wn**2, 2 * zeta * wn, top + offset)
        res = model.simulate(imp, drive, x0=x0, duration=duration)
        ref = reference(imp, drive, x0=x0, duration=duration)
        assert res.n_impacts == ref.n_impacts
        if ref.n_impacts:
            t_ref, v_ref = ref.impact_arrays()
            assert res.velocities[0] == pytest.approx(v_ref[0], rel=1e-5)
