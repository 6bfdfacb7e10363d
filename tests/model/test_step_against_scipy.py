"""A plan's 25-tone positioning step, impacter and slider, against independent integrations.

The case is a real one (``tests/data/position_step_d1.json``): the default plan's
(``configs/array_5x5.yaml``, seed 0) first step, which plays all 25 forward tones together
at 2000 g for 10 ms, and the device that travels furthest in it (D1: 90 um, 9 mm/s, where
one tone alone moves a slider 2-3 mm/s).  Two questions a reader of that number asks:

- is the slider's stick-slip under a 25-tone base acceleration (kicked by 42 impacts)
  what an ODE integrator gives?  The reference (:func:`model.scipy_ref.slider_motion`)
  integrates the slip phases with scipy's DOP853 (rtol 1e-12), finds each stop (v = 0)
  by event location and each release from stick (|f| = F_s/M) by a fine grid and
  Brent's method, and applies the two-body contact law restated from docs/contact.md;
- are the kicks the impacts?  DOP853 with event location, restarted at each impact
  (:func:`model.scipy_ref.impacts`), must
  find the same impacts, except where its event location cannot see one: a grazing impact
  whose excursion past the wall is shorter than the integrator's step.  This step has one
  (2.7 nm past a 5.1 um gap for under a microsecond); the kernel's bounds find it, and a
  dense search of the same ODE confirms it, as does DOP853 held to steps of 0.5 us.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import model
from model import Drive, Impacter, Slider
from model.impacter import impacter_forcing
from model.scipy_ref import impacts as scipy_impacts
from model.scipy_ref import slider_motion as reference_slider

CASE = Path(__file__).resolve().parents[1] / "data" / "position_step_d1.json"


@pytest.fixture(scope="module")
def case():
    data = json.loads(CASE.read_text())
    tones = data["tones"]
    drive = Drive(tones["frequency_hz"], tones["amplitude_m"], tones["phase_rad"])
    return (Impacter(**data["impacter"]), Slider(**data["slider"]), drive,
            data["duration_s"])


# ------------------------------------------------------------------------ the tests

@pytest.mark.parametrize("contact", ["two_body", "paper"])
@pytest.mark.parametrize("friction", ["as designed", "below the drive's peak"])
def test_the_step_moves_the_slider_as_an_ode_integration_does(case, contact, friction):
    imp, slider, drive, duration = case
    if friction != "as designed":
        # static friction under the 25-tone drive's peak (19 600 m/s^2): the drive slips
        # the stuck slider by itself, every release from stick is exercised
        slider = Slider(slider.mass, slider.damping, 0.5 * slider.static_friction,
                        0.5 * slider.dynamic_friction)
    res = model.simulate(imp, drive, 0.0, 0.0, duration, max_events=1_000_000)
    assert res.times.size >= 40
    kicks = model.Kicks.from_impacts(imp, slider, res, 1.0)
    _, _, z, v, status = model.slider_motion(slider, drive, kicks, duration=duration,
                                             contact=contact)
    assert status == "ok"
    z_ref, v_ref = reference_slider(slider, drive, kicks, duration, contact)
    assert z > 20e-6                                    # it travels tens of um
    assert z == pytest.approx(z_ref, rel=1e-9)
    assert v == pytest.approx(v_ref, rel=1e-7, abs=1e-12)


def test_the_shaking_itself_adds_to_the_travel(case):
    """Part of the 9 mm/s is the die's shaking under the slider: after a kick, a base
    acceleration up to 19 600 m/s^2 against a kinetic friction of 6 700 m/s^2 lengthens
    the slip.  With the same kicks and no base acceleration the slider travels less, but
    the kicks still carry most of it (42 impacts in 10 ms)."""
    imp, slider, drive, duration = case
    res = model.simulate(imp, drive, 0.0, 0.0, duration, max_events=1_000_000)
    kicks = model.Kicks.from_impacts(imp, slider, res, 1.0)
    z = model.slider_motion(slider, drive, kicks, duration=duration, contact="two_body")[2]
    still = Drive(drive.frequencies, np.zeros(len(drive.frequencies)))
    z_still = model.slider_motion(slider, still, kicks, duration=duration,
                                  contact="two_body")[2]
    assert z_still == pytest.approx(reference_slider(slider, still, kicks, duration,
                                                     "two_body")[0], rel=1e-9)
    assert 0.6 * z < z_still < 0.95 * z


def test_the_kernel_finds_a_grazing_impact_event_location_misses(case):
    imp, _, drive, duration = case
    res = model.simulate(imp, drive, 0.0, 0.0, duration, max_events=1_000_000)
    t_ref, v_ref = scipy_impacts(imp, drive, duration)
    assert res.chatter_times.size == 0
    # the impacts agree one for one until the graze, which only the kernel has
    n = int(np.argmax(np.abs(res.times[:t_ref.size] - t_ref) > 1e-9))
    assert n > 20
    np.testing.assert_allclose(res.times[:n], t_ref[:n], rtol=0, atol=1e-12)
    np.testing.assert_allclose(res.velocities[:n], v_ref[:n], rtol=1e-7)
    graze_t, graze_v = res.times[n], res.velocities[n]
    assert graze_v < 0.1 * np.median(res.velocities)       # a slow, grazing impact
    # a dense search of the same ODE from the impact before it: x does pass the wall
    w, a, phi = impacter_forcing(imp, drive)
    wn2, s2 = imp.omega_n ** 2, 2 * imp.sigma
    sol = solve_ivp(lambda t, y: [y[1], np.sum(a * np.cos(w * t + phi)) - s2 * y[1] - wn2 * y[0]],
                    (res.times[n - 1], graze_t + 2e-5),
                    [imp.gap, -imp.restitution * res.velocities[n - 1]], method="DOP853",
                    rtol=1e-13, atol=1e-22, max_step=2e-7, dense_output=True)
    ts = np.linspace(graze_t - 1e-5, graze_t + 1e-5, 20001)
    over = ts[sol.sol(ts)[0] > imp.gap]
    assert over.size and abs(over[0] - graze_t) < 2e-9
    assert over[-1] - over[0] < 1e-6                       # past the wall < 1 us
    # after it the two runs part: the reference follows a different trajectory
    assert res.times.size == t_ref.size + 1
    # with its step held to 1/40 of the top tone's period, DOP853 sees the graze too, and
    # then every impact is the kernel's
    t_fine, v_fine = scipy_impacts(imp, drive, duration, max_step=5e-7)
    assert t_fine.size == res.times.size
    np.testing.assert_allclose(t_fine, res.times, rtol=0, atol=1e-12)
    np.testing.assert_allclose(v_fine, res.velocities, rtol=1e-7)
