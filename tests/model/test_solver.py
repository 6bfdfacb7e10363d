"""The exact solver against independent methods, conservation laws and edge cases."""

import dataclasses
import math
import os
import warnings

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import model
from model import Drive, Impacter, Slider
from model.impacter import impacter_forcing


def scipy_impacts(imp, drive, x0, duration, rtol=1e-12):
    """Independent reference: DOP853 with event location, restarted at each impact."""
    w, a, phi = impacter_forcing(imp, drive)
    wn2 = imp.omega_n**2
    s2 = 2 * imp.sigma

    def rhs(t, y):
        return [y[1], np.sum(a * np.cos(w * t + phi)) - s2 * y[1] - wn2 * y[0]]

    def wall(t, y):
        return y[0] - imp.gap
    wall.terminal = True
    wall.direction = 1
    t, y, times, vels = 0.0, [x0, 0.0], [], []
    while t < duration:
        sol = solve_ivp(rhs, (t, duration), y, method="DOP853", rtol=rtol, atol=1e-22,
                        events=wall)
        if sol.status != 1:
            break
        te, ye = sol.t_events[0][0], sol.y_events[0][0]
        times.append(te)
        vels.append(ye[1])
        t, y = te, [imp.gap, -imp.restitution * ye[1]]
    return np.array(times), np.array(vels)


@pytest.mark.parametrize("freq, x0, damping", [
    (6200.0, 0.0, 0.0), (5200.0, 0.0, 0.0), (5600.0, -2e-6, 0.0), (6200.0, 1e-6, 3e-7),
])
def test_exact_matches_dop853(fig7, freq, x0, damping):
    imp = Impacter(fig7.mass, fig7.stiffness, damping, fig7.gap)
    drive = Drive.tone(freq)
    res = model.simulate(imp, drive, x0=x0, duration=3e-3)
    t_ref, v_ref = scipy_impacts(imp, drive, x0, 3e-3)
    assert res.n_impacts == t_ref.size > 3
    np.testing.assert_allclose(res.times, t_ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(res.velocities, v_ref, rtol=1e-7)


def test_rk4_converges_at_fourth_order(fig7):
    drive = Drive.tone(6200.0)
    exact = model.simulate(fig7, drive)
    errors = []
    steps = [1e-6, 5e-7, 2.5e-7, 1.25e-7]
    for h in steps:
        rk = model.simulate(fig7, drive, method="rk4", step=h)
        assert rk.n_impacts == exact.n_impacts
        errors.append(abs(rk.response - exact.response) / exact.response)
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(orders > 3.5) and np.all(orders < 4.5), orders
    assert errors[-1] < 1e-10


def test_energy_conserved_between_impacts_undamped(fig7):
    # b = 0 and no drive: E = v^2/2 + wn^2 x^2/2 is constant in flight and each impact
    # multiplies the kinetic energy at the wall by e^2
    drive = Drive([5000.0], [0.0])
    x0 = -5e-6
    res = model.simulate(fig7, drive, x0=x0, duration=2e-3, trajectory=4001)
    wn2 = fig7.omega_n**2
    e = fig7.restitution
    # energy from the trajectory (finite differences are not needed: use the impacts)
    energy0 = 0.5 * wn2 * x0**2
    for k, v in enumerate(res.velocities):
        expected_kinetic = energy0 - 0.5 * wn2 * fig7.gap**2
        assert 0.5 * v**2 == pytest.approx(expected_kinetic, rel=1e-10)
        energy0 = 0.5 * (e * v) ** 2 + 0.5 * wn2 * fig7.gap**2
    assert res.n_impacts >= 2
    # between impacts the sampled positions never exceed the amplitude set by the energy
    assert np.max(res.x) <= fig7.gap * (1 + 1e-12)


def test_energy_balance_with_forcing(fig7):
    # b = 0 with forcing: between impacts d/dt (v^2/2 + wn^2 x^2/2) = f(t) v
    imp = fig7
    drive = Drive([4000.0], [0.2e-6])  # too weak to reach the wall from rest
    T = 2e-3
    t = np.linspace(0, T, 200001)
    res = model.simulate(imp, drive, duration=T, trajectory=t)
    assert res.n_impacts == 0
    x = res.x
    v = np.gradient(x, t, edge_order=2)
    w, a, phi = impacter_forcing(imp, drive)
    f = a[0] * np.cos(w[0] * t + phi[0])
    energy = 0.5 * v**2 + 0.5 * imp.omega_n**2 * x**2
    work = np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] * v[1:] + f[:-1] * v[:-1]) * np.diff(t))])
    np.testing.assert_allclose(energy - energy[0], work, atol=1e-6 * np.max(energy))
    assert res.v_end == pytest.approx(v[-1], rel=1e-5)


def test_momentum_bookkeeping_eq9(fig7, fig7_slider):
    # eq. (9): 2 m v+ cos(theta) + M V+ = 2 m v- cos(theta) + M V-, with v+ = -e v-
    m, M, th, e = fig7.mass, fig7_slider.mass, fig7.impact_angle, fig7.restitution
    vminus = np.array([0.01, 0.05, 0.2])
    dV = model.kick(fig7, fig7_slider, vminus)
    lhs = 2 * m * (-e * vminus) * math.cos(th) + M * dV
    rhs = 2 * m * vminus * math.cos(th)
    np.testing.assert_allclose(lhs, rhs, rtol=1e-14)


def test_slider_single_kick_closed_form(fig7_slider):
    # after one kick V0 with no forcing, Coulomb friction stops the slider after V0^2/(2 F_d/M)
    quiet = Drive([5000.0], [0.0])
    V0 = 0.05
    _, _, z, v, status = model.slider_motion(fig7_slider, quiet, [1e-4], [V0], 1e-3)
    a = fig7_slider.dynamic_friction / fig7_slider.mass
    assert status == "ok" and v == 0.0
    assert z == pytest.approx(V0**2 / (2 * a), rel=1e-12)


def test_slider_viscous_and_coulomb_closed_form():
    # V' = -beta V - fd: stops at T = ln(1 + beta V0 / fd) / beta, travelling (V0 - fd T) / beta
    sl = Slider(mass=1e-9, damping=2e-5, static_friction=20e-6, dynamic_friction=5e-6)
    beta, fd, V0 = 2e-5 / 1e-9, 5e-6 / 1e-9, 0.05
    T = math.log(1 + beta * V0 / fd) / beta
    dist = (V0 - fd * T) / beta
    _, _, z, v, status = model.slider_motion(sl, Drive([5000.0], [0.0]), [0.0], [V0], 1e-3)
    assert z == pytest.approx(dist, rel=1e-10)


def test_slider_backward_pair_moves_negative(fig7, fig7_slider):
    res = model.simulate_slider(fig7, fig7_slider, Drive.tone(6200.0), direction=-1.0)
    assert res.displacement < 0


def test_start_exactly_at_wall(fig7):
    drive = Drive.tone(6200.0)
    res = model.simulate(fig7, drive, x0=fig7.gap)
    assert res.status == "ok" and res.n_impacts > 5
    # the first run from the wall (v0 = 0) leaves it and returns: no impact at t = 0
    assert res.times[0] > 0


def test_start_at_wall_pressed_sticks_then_releases():
    # a static force pressing on the wall keeps the mass stuck until the drive pulls it away
    imp = Impacter(mass=1e-10, stiffness=1e-10 * (2 * math.pi * 1000) ** 2, damping=0.0, gap=1e-9)
    res = model.simulate(imp, Drive.tone(5000.0, power=50.0), x0=1e-9, duration=1e-3)
    assert res.status == "ok"


def test_event_cap_gives_status_not_silence(fig7):
    with pytest.warns(model.SolverWarning, match="event cap"):
        res = model.simulate(fig7, Drive.tone(6200.0), max_events=3)
    assert res.status == "event cap reached" and not res.success


def test_response_excludes_first_impact(fig7):
    drive = Drive.tone(6200.0)
    res = model.simulate(fig7, drive)
    expected = fig7.mass * res.velocities[1:].sum() / 3e-3
    assert model.response(fig7, drive) == pytest.approx(expected, rel=1e-14)
    assert res.response == pytest.approx(expected, rel=1e-14)


def test_stop_at_first_counted_impact(fig7):
    drive = Drive.tone(6200.0)
    quick = model.response(fig7, drive, stop_at_first=True)
    assert quick > 0
    assert model.response(fig7, Drive.tone(3000.0), stop_at_first=True) == 0.0


def test_batch_and_sweep_agree_with_single_runs(fig7):
    x0s = np.linspace(-fig7.gap, fig7.gap, 7)
    drive = Drive.tone(6000.0)
    batch = model.responses(fig7, drive, x0s)
    singles = [model.response(fig7, drive, x0=x) for x in x0s]
    np.testing.assert_allclose(batch, singles, rtol=1e-14)
    grid = model.sweep(fig7, [6000.0, 7000.0], x0s)
    np.testing.assert_allclose(grid[0], batch, rtol=1e-14)


def test_unchecked_batch_equals_checked(fig7):
    # check_input=False only skips validation: same kernel, same numbers, even when the
    # duration is given as an int (it is still converted to one float specialisation)
    x0s = np.linspace(-fig7.gap, fig7.gap, 9)
    drive = Drive.tone(6200.0) + Drive([7100.0], [0.3e-6], [0.4])
    for stop in (False, True):
        r, st = model.responses(fig7, drive, x0s, duration=3e-3, stop_at_first=stop,
                                return_status=True)
        r2, st2 = model.responses(fig7, drive, x0s, duration=3e-3, stop_at_first=stop,
                                  return_status=True, check_input=False)
        np.testing.assert_array_equal(r2, r)
        np.testing.assert_array_equal(st2, st)
    assert np.all(model.responses(fig7, drive, x0s, duration=1, check_input=False) > 0)
    with pytest.raises(ValueError, match="x0s must be <= the gap"):
        model.responses(fig7, drive, [2 * fig7.gap])


def test_multitone_drive_superposes(fig7):
    """The wall-free motion is linear: with a gap no tone reaches, the trajectory under
    two tones (from rest at x0 = 0) is the sum of the one-tone trajectories; and a
    zero-amplitude second tone changes nothing: impacts, their velocities, the response,
    the final state and the trajectory equal the one-tone run's to rounding."""
    one = model.simulate(fig7, Drive.tone(6200.0), trajectory=True)
    two = model.simulate(fig7, Drive.tone(6200.0) + Drive([9000.0], [0.0]), trajectory=True)
    assert two.n_impacts == one.n_impacts > 0
    np.testing.assert_allclose(two.times, one.times, rtol=1e-14)
    np.testing.assert_allclose(two.velocities, one.velocities, rtol=1e-14)
    assert two.response == pytest.approx(one.response, rel=1e-14)
    np.testing.assert_allclose(two.x, one.x, rtol=0, atol=1e-14 * fig7.gap)
    assert (two.x_end, two.v_end) == pytest.approx((one.x_end, one.v_end), rel=1e-12)
    # 100 um: neither tone (~5 um swing) nor their sum reaches the wall
    far = dataclasses.replace(fig7, gap=100e-6)
    a, b = Drive.tone(6200.0), Drive([9000.0], [0.4e-6], [0.7])
    ra, rb, rab = (model.simulate(far, d, trajectory=True) for d in (a, b, a + b))
    assert rab.n_impacts == 0
    peak = np.abs(rab.x).max()
    assert np.abs(rb.x).max() > 0.1 * peak   # the second tone counts in the sum
    np.testing.assert_allclose(rab.x, ra.x + rb.x, rtol=0, atol=1e-12 * peak)


def test_multitone_against_dop853(fig7):
    drive = Drive([6200.0, 9100.0, 4300.0], [0.9e-6, 0.3e-6, 0.2e-6], [0.0, 1.0, -2.0])
    res = model.simulate(fig7, drive, x0=-1e-6)
    t_ref, v_ref = scipy_impacts(fig7, drive, -1e-6, 3e-3)
    assert res.n_impacts == t_ref.size
    np.testing.assert_allclose(res.times, t_ref, atol=1e-12)


@pytest.mark.parametrize("bad, match", [
    (dict(x0=5e-6), "x0"), (dict(x0=float("nan")), "x0"), (dict(duration=-1.0), "duration"),
    (dict(method="euler"), "method"),
])
def test_invalid_simulation_arguments(fig7, bad, match):
    with pytest.raises(ValueError, match=match):
        model.simulate(fig7, Drive.tone(6000.0), **bad)


def test_release_from_wall_does_not_loop_on_noise_velocity():
    # regression: started at the wall (x0 = gap, v0 = 0) under a four-tone drive, the
    # impacter is released after 1.18 us; the closed form then evaluated v = 3.5e-18 m/s
    # (rounding noise) at the wall and the solver recorded 100000 "impacts" at that instant
    # until the event cap.  Noise-level velocities at the wall are not impacts.
    imp = Impacter(mass=1.6862675999999998e-10, stiffness=0.02867260144575654, damping=3.58e-07,
                   gap=1.0717616509007002e-05)
    drive = Drive([2914.97975708502, 5398.110661268556, 9986.504723346829, 18515.519568151147],
                  [2.8569348163396596e-06, 1.1329916038468874e-06, 4.493172077451155e-07,
                   1.781883930034403e-07],
                  [-2.50052163619395, 1.5013782463205816, -0.7910867647368707, 0.48407696468598704])
    with warnings.catch_warnings():
        warnings.simplefilter("error", model.SolverWarning)
        res = model.simulate(imp, drive, x0=imp.gap, duration=0.01)
    assert res.status == "ok"
    assert np.all(np.diff(res.times) > 0)
    assert np.all(res.velocities > 1e-9)


@pytest.mark.skipif(os.environ.get("NUMBA_DISABLE_JIT") == "1", reason="counts numba's "
                    "compiled specialisations")
def test_one_kernel_specialisation_serves_responses_sweeps_and_simulations():
    """responses(), sweep() and simulate() (a frozen Drive's read-only phases included)
    reach one specialisation of the parallel response kernel and one of the exact
    kernel: numba re-optimises the impacter kernel inside each entry point and for each
    argument type, ~8-16 s apiece on a cold cache (model.warmup).  In a fresh
    interpreter, where each argument type loads (or compiles) one specialisation."""
    import subprocess
    import sys

    code = (
        "import numpy as np\n"
        "from model import Impacter, Drive, responses, sweep, simulate\n"
        "from model.kernels import impacter as k\n"
        "from model.warmup import compile_kernels\n"
        "compile_kernels()\n"
        "imp = Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6).with_natural_frequency(5200)\n"
        "d = Drive([5100.0, 6100.0], [2e-8, 1e-8], [0.3, 1.0])\n"
        "assert not d.phases.flags.writeable\n"
        "responses(imp, d, [0.0, 1e-6], duration=2e-4)\n"
        "responses(imp, d, np.array([0.0, 1e-6])[::2], v0s=1e-3, duration=2e-4)\n"
        "sweep(imp, [5000.0, 5200.0], [0.0], duration=2e-4)\n"
        "simulate(imp, d, duration=2e-4, trajectory=5)\n"
        "print(len(k.response_grid.signatures), len(k.run_impacter.signatures))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.split() == ["1", "1"]


def test_a_sweep_is_the_responses_of_its_tones():
    """sweep() (one tone per frequency through the grid kernel) gives the responses of
    each tone alone, to the rounding of the tone's amplitude (sweep computes it from the
    power, the Drive from its amplitude)."""
    from model import Drive, responses, sweep

    imp = Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6).with_natural_frequency(5200)
    f = np.array([4800.0, 5150.0, 5600.0, 6200.0])
    x0s = np.linspace(-imp.gap, imp.gap, 7)
    r = sweep(imp, f, x0s, duration=1e-3)
    for i, fi in enumerate(f):
        assert r[i] == pytest.approx(responses(imp, Drive.tone(fi), x0s, duration=1e-3),
                                     rel=1e-12, abs=0.0)
