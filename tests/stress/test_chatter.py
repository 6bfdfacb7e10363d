"""Chattering into sticking, and release, for every restitution.

Under a drive that presses the impacter on the wall, its bounces shrink
geometrically (v-_{k+1} = e v-_k) and accumulate in finite time; the solver
resolves them, sums the tail in closed form, sticks, and leaves the wall when the
net force pulls it off.  Properties: the run terminates with status "ok", and the
sum of v- (hence r) converges to the 50-digit value of the same model.
"""

import math
from dataclasses import replace

import numpy as np
import pytest

import model
from model import Drive, Impacter
from model.mpref import reference

# Fig. 7's impacter with a 0.3 um gap: a 1 kHz tone at Z0^2 w^3 = 50 presses it on
# the wall for a fifth of each cycle (the benchmark's case (c))
PRESSED = Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 0.3e-6).with_natural_frequency(5200.0)
FAST_DRIVE = Drive.tone(1000.0)


def slow_press(imp, zeta=0.2):
    """A damped impacter and a 100 Hz drive pressing it on the wall for a third of each
    cycle: the approach is slow enough for even e = 0.99 to chatter into sticking."""
    imp = replace(imp, damping=zeta * 2 * math.sqrt(imp.stiffness * imp.mass))
    a = 2.0 * imp.omega_n**2 * imp.gap
    z = a / (math.cos(imp.impact_angle) * (2 * math.pi * 100.0) ** 2)
    return imp, Drive([100.0], [z])


def check_sequences(res, e):
    """Each summed chatter sequence: shrinking bounces before it, a release after it."""
    for tc in res.chatter_times:
        before = res.velocities[(res.times < tc) & (res.times > tc - 1e-3)]
        ratios = before[1:][-3:] / before[:-1][-3:]
        # the bounces shrink by e, to first order in the flight time, which shrinks too
        np.testing.assert_allclose(ratios, e, rtol=2e-2)
        assert ratios[-1] == pytest.approx(e, rel=1e-3)
    if res.chatter_times.size >= 2:
        # released after each sequence but the last: impacts follow it
        assert np.any(res.times > res.chatter_times[0])


@pytest.mark.parametrize("e", [0.0, 0.01, 0.5, 1.0])
def test_chatter_converges_to_50_digit_sum(e):
    imp = replace(PRESSED, restitution=e)
    res = model.simulate(imp, FAST_DRIVE, duration=3e-3)
    assert res.status == "ok"
    if 0 < e < 1:
        assert res.chatter_times.size >= 2
        check_sequences(res, e)
    ref = reference(imp, FAST_DRIVE, duration=3e-3)
    assert abs(res.response - float(ref.response)) <= 1e-12 * float(ref.response)


def test_nearly_elastic_chatter_terminates():
    # e = 0.99: thousands of bounces per sequence, taken from the wall series
    imp, drive = slow_press(replace(PRESSED, restitution=0.99))
    res = model.simulate(imp, drive, duration=0.02)
    assert res.status == "ok"
    assert res.chatter_times.size == 3 and res.n_steps < 20_000
    check_sequences(res, 0.99)
    # the summed tail is the geometric remainder of the last resolved bounce
    last = res.velocities[res.times < res.chatter_times[0]][-1]
    assert res.chatter_sums[0] == pytest.approx(last * 0.99 / 0.01, rel=1e-6)


def test_plastic_impact_sticks_at_once_then_releases():
    imp = replace(PRESSED, restitution=0.0)
    res = model.simulate(imp, FAST_DRIVE, duration=3e-3, trajectory=3001)
    assert res.status == "ok" and res.chatter_times.size == 0
    # stuck at the wall after each impact for a while, then free again
    at_wall = res.x == imp.gap
    assert at_wall.any() and not at_wall.all()
    assert np.all(res.x <= imp.gap)


def test_elastic_damped_pressing_ends_on_a_status():
    # e = 1 with damping under a sustained pressing force: the bounces shrink only as
    # 1/k, so they never accumulate and never stop (infinitely many in the pressing
    # phase).  The model has no sticking for e = 1; the run must end on the event cap
    # with a status, not hang.
    imp, drive = slow_press(replace(PRESSED, restitution=1.0))
    with pytest.warns(model.SolverWarning, match="event cap"):
        res = model.simulate(imp, drive, duration=0.02, max_events=2000)
    assert res.status == "event cap reached"


@pytest.mark.slow
@pytest.mark.parametrize("e", [0.0, 0.01, 0.5, 0.99])
def test_slow_press_converges_to_50_digit_sum(e):
    imp, drive = slow_press(replace(PRESSED, restitution=e))
    res = model.simulate(imp, drive, duration=0.01)   # two chatter sequences
    assert res.status == "ok"
    ref = reference(imp, drive, duration=0.01)
    assert abs(res.response - float(ref.response)) <= 1e-12 * float(ref.response)


@pytest.mark.slow
def test_elastic_undamped_slow_press_against_50_digits():
    imp, drive = slow_press(replace(PRESSED, restitution=1.0), zeta=0.0)
    res = model.simulate(imp, drive, duration=0.02)
    ref = reference(imp, drive, duration=0.02)
    assert res.status == "ok" and res.n_impacts == ref.n_impacts
    assert abs(res.response - float(ref.response)) <= 1e-12 * float(ref.response)
