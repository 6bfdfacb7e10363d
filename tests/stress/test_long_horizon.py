"""Long horizons: 1e5 periods without drift, and work linear in the horizon.

Properties: an elastic, undamped, unforced impacter keeps its energy through 1e5
impacts (every v- equals the one the energy balance gives); a driven impacter on a
periodic impacting orbit stays on it after 1e5 drive periods; the closed form keeps
its phase over 1e5 periods (against 50 digits); and the number of steps (the
solver's work) grows linearly with the horizon.
"""

import math

import mpmath
import numpy as np
import pytest

import model
from model import Drive, Impacter
from model.kernels import impacter as kernel
from model.kernels.closed_form import tone_coefficients
from model.mpref import _ClosedForm, _Segment
from model.impacter import impacter_forcing

FIG7 = Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6).with_natural_frequency(5200.0)


def run(imp, drive, x0, duration, capacity):
    """The raw kernel with a large event list: (status, times, v-, n_steps)."""
    w, a, phi = impacter_forcing(imp, drive)
    coef = tone_coefficients(imp.omega_n, imp.sigma, w, a, phi)
    imp_t = np.zeros(capacity)
    imp_v = np.zeros(capacity)
    kinds = np.zeros(capacity, dtype=np.int64)
    status, n, _, _, _, _, _, steps = kernel.run_impacter(
        imp.omega_n, imp.sigma, imp.gap, imp.restitution, w, a, phi, coef, 0.0, duration,
        x0, 0.0, False, 0, 10 * capacity, kernel.MAX_STEPS, imp_t, imp_v, kinds,
        np.empty(0), np.empty(0))
    return status, imp_t[:n], imp_v[:n], steps


def test_elastic_free_oscillation_keeps_its_energy_for_1e5_periods():
    # E = v^2 / 2 + wn^2 x^2 / 2 is conserved in flight and by e = 1 impacts, so every
    # impact has v- = wn sqrt(A^2 - c^2) (A the amplitude from x0 = -A at rest)
    amp = 2 * FIG7.gap
    imp = Impacter(FIG7.mass, FIG7.stiffness, 0.0, FIG7.gap, restitution=1.0)
    quiet = Drive([5000.0], [0.0])
    wn = imp.omega_n
    periods = 1e5
    status, t, v, steps = run(imp, quiet, -amp, periods * 2 * math.pi / wn, 200_000)
    assert status == kernel.OK
    v_exact = wn * math.sqrt((amp - imp.gap) * (amp + imp.gap))
    # between impacts the motion covers the arc below the wall: 2 (pi - acos(c / A)) / wn
    dt_exact = 2 * (math.pi - math.acos(imp.gap / amp)) / wn
    assert t.size == pytest.approx(periods * 2 * math.pi / wn / dt_exact, abs=1.5)
    # regression: beyond t = 8 s (where a step of one ulp of t moves x by 1e-16 m, and
    # a rounded t + h lands just past the wall) every impact lost 4e-11 of its speed;
    # v- is now taken at the wall from the energy, v^2 + 2 x'' (gap - x)
    np.testing.assert_allclose(v, v_exact, rtol=1e-12)
    np.testing.assert_allclose(np.diff(t), dt_exact, rtol=1e-9)
    # no drift of the impact times: the last one is where the first one predicts it
    assert abs(t[-1] - (t[0] + (t.size - 1) * dt_exact)) <= 1e-9


def test_periodic_impact_orbit_after_1e5_drive_periods():
    # Fig. 7 at 6.2 kHz settles on an orbit with one impact per drive period
    drive = Drive.tone(6200.0)
    period = 1 / 6200.0
    status, t, v, steps = run(FIG7, drive, 0.0, 1e5 * period, 200_000)
    assert status == kernel.OK
    assert t.size == pytest.approx(1e5, rel=1e-3)
    tail_v = v[-1000:]
    phase = np.mod(t[-1000:], period) / period
    # at t ~ 16 s, t itself is resolved to 3.6e-15 s: x'' times that moves v- by ~1e-10
    assert np.ptp(tail_v) <= 1e-9 * tail_v.mean()
    assert np.ptp(phase) <= 1e-9


def test_closed_form_keeps_its_phase_for_1e5_periods():
    # no wall in reach: the end state after 1e5 drive periods is the closed form at T,
    # whose phase w T ~ 4e6 rad the float solver must not lose
    imp = Impacter(FIG7.mass, FIG7.stiffness, 0.0, 1.0)
    drive = Drive.tone(6200.0)
    duration = 1e5 / 6200.0
    res = model.simulate(imp, drive, x0=-1e-6, duration=duration)
    assert res.n_impacts == 0
    w, a, phi = impacter_forcing(imp, drive)
    with mpmath.workdps(50):
        seg = _Segment(_ClosedForm(imp.omega_n, imp.sigma, w, a, phi), mpmath.mpf(0),
                       mpmath.mpf(-1e-6), mpmath.mpf(0))
        x_ref, v_ref, _ = seg.state(mpmath.mpf(duration))
    amp = 2e-6
    assert abs(res.x_end - float(x_ref)) <= 1e-9 * amp
    assert abs(res.v_end - float(v_ref)) <= 1e-9 * amp * imp.omega_n


@pytest.mark.parametrize("drive, x0", [(Drive.tone(6200.0), 0.0),     # impacting orbit
                                       (Drive.tone(7500.0), -3e-6)])  # grazing beats
def test_steps_grow_linearly_with_the_horizon(drive, x0):
    period = 1 / drive.frequencies[0]
    steps = {}
    for n in (1e3, 1e4, 1e5):
        status, _, _, steps[n] = run(FIG7, drive, x0, n * period, 200_000)
        assert status == kernel.OK
    # work per period is the same over 1e3, 1e4 and 1e5 periods (within 10%)
    per_period = np.array([steps[n] / n for n in steps])
    assert np.ptp(per_period) <= 0.1 * per_period.mean()
