"""The closed-form silence bound (model.bounds) held against the exact simulator.

The bound may only ever say "silent" where the simulator, from every start in D and
every phasing tried, finds no counted impact (eq. 12 > 0); where it says no impact at
all (``impacts == 0``) the simulator must find none.  Its envelope must be exact for the
wall-free motion: never below it, and reached at the worst start and phase.
"""

import math
import os

import numpy as np
import pytest

from model import Drive, Impacter, responses, simulate
from model.bounds import linear_envelope, silence_bound

AIR = 1.79e-5
#: The simulator-heavy checks need the compiled kernels (.ci/run also runs tests/model
#: with NUMBA_DISABLE_JIT=1, where the bound's own code still runs in the other tests)
compiled = pytest.mark.skipif(os.environ.get("NUMBA_DISABLE_JIT") == "1",
                              reason="thousands of simulations: too slow without the JIT")


def _impacter(nu_n, gap, viscosity=AIR, area=1.5e-8, restitution=0.5):
    imp = Impacter.from_geometry(area, 4e-6, 1242e-6, gap, viscosity=viscosity,
                                 restitution=restitution)
    return imp.with_natural_frequency(nu_n)


def _starts(imp):
    """The designer's starts: a grid over [-c, c] with the edge just inside the wall."""
    u = np.concatenate([np.linspace(-1.0, 1.0, 41), [1 - 1e-2, 1 - 1e-4, 1 - 1e-6, 1 - 1e-9]])
    return np.unique(np.clip(u, -1.0, 1.0 - 1e-9)) * imp.gap


def _phased(drive, phases):
    return Drive(drive.frequencies, drive.amplitudes, phases)


def _simulated_response(imp, drive, duration, n_phases=8, seed=0):
    """The largest r from every start and ``n_phases`` phasings (the first all zero)."""
    rng = np.random.default_rng(seed)
    worst = 0.0
    for k in range(n_phases):
        phases = np.zeros(drive.frequencies.size) if k == 0 else rng.uniform(
            0, 2 * np.pi, drive.frequencies.size)
        r = responses(imp, _phased(drive, phases), _starts(imp), duration=duration)
        worst = max(worst, float(np.max(r)))
    return worst


def _duration(imp, periods=400):
    """Long enough for the free part to decay far below the margin."""
    return max(periods / (imp.omega_n / (2 * np.pi)), 12.0 / imp.sigma)


@compiled
def test_envelope_bounds_the_wall_free_motion_and_is_reached():
    # a gap far beyond the motion: the simulator's trajectory is the wall-free one
    imp = _impacter(1e4, 50e-6)
    drive = Drive([7e3, 13e3], [0.4e-6, 0.2e-6], [0.3, 1.9])
    c = 2e-6                                      # the starts' range, inside the gap
    t = np.linspace(0, 2e-3, 4001)
    W = linear_envelope(imp, drive, t, x0_max=c)
    rng = np.random.default_rng(1)
    for _ in range(12):
        x0 = rng.uniform(-c, c)
        d = _phased(drive, rng.uniform(0, 2 * np.pi, 2))
        res = simulate(imp, d, x0=x0, duration=2e-3, trajectory=t)
        assert res.n_impacts == 0
        assert np.all(np.abs(res.x) <= W + 1e-12 * c)
    # exact: at a chosen t* the worst start and phasing reach W(t*)
    k = 1234
    ts = t[k]
    wn, sg = imp.omega_n, imp.sigma
    wd = math.sqrt(wn * wn - sg * sg)
    g1 = math.exp(-sg * ts) * (math.cos(wd * ts) + sg / wd * math.sin(wd * ts))
    # each tone's response from rest at t* as a complex number: phase it onto the real axis
    w = 2 * np.pi * drive.frequencies
    a = math.cos(imp.impact_angle) * w * w * drive.amplitudes
    X = a / (wn * wn - w * w + 2j * sg * w)
    A, B = -X, -(sg + 1j * w) * X / wd
    Z = X * np.exp(1j * w * ts) + math.exp(-sg * ts) * (A * math.cos(wd * ts)
                                                          + B * math.sin(wd * ts))
    worst = Drive(drive.frequencies, drive.amplitudes, -np.angle(Z))
    res = simulate(imp, worst, x0=c * np.sign(g1), duration=ts * 1.0001, trajectory=t[:k + 1])
    assert res.x[k] == pytest.approx(W[k], rel=1e-9)


def _random_case(case):
    rng = np.random.default_rng(1000 + case)
    nu_n = float(rng.uniform(3e3, 50e3))
    # damping from near-vacuum to heavy, gaps from a fraction to twice the resonant swing
    viscosity = AIR * float(10 ** rng.uniform(-1.5, 1.0))
    imp = _impacter(nu_n, 1e-6, viscosity=viscosity)
    n_tones = int(rng.integers(1, 4))
    ratios = np.exp(rng.uniform(np.log(0.25), np.log(4.0), n_tones))
    drive = Drive.tone(nu_n)
    x_res = drive.amplitudes[0] * math.cos(imp.impact_angle) * imp.omega_n / (2 * imp.sigma)
    gap = float(np.clip(x_res * 10 ** rng.uniform(-1.0, 0.3), 0.3e-6, 40e-6))
    imp = _impacter(nu_n, gap, viscosity=viscosity)
    freqs = nu_n * ratios
    drive = Drive(freqs, Drive.tone(freqs[0]).amplitudes[0] * (freqs[0] / freqs) ** 1.5)
    return imp, drive


@compiled
def test_silent_by_the_bound_is_silent_in_the_simulator():
    """300 random impacters and drives (1-3 tones, Q ~ 2-1000, gaps 0.1-2x the resonant
    swing): every proof holds in the simulator, and the proofs are not rare."""
    proven = {0: 0, 1: 0}
    for case in range(300):
        imp, drive = _random_case(case)
        bound = silence_bound(imp, drive)
        if not bound.silent:
            continue
        proven[bound.impacts] += 1
        r = _simulated_response(imp, drive, _duration(imp))
        assert r == 0.0, (case, bound)
        if bound.impacts == 0:
            for x0 in _starts(imp)[[0, -1]]:
                assert simulate(imp, drive, x0=x0, duration=_duration(imp)).n_impacts == 0
    assert proven[0] >= 25 and proven[1] >= 8, proven


def test_the_bound_is_not_vacuous_on_a_designed_impacter():
    """An impacter designed like the default plan's (Q ~ 50, gap ~ 0.6 of its resonant
    swing): the tones an octave or more away are proven, the near ones are left to the
    simulator."""
    imp = _impacter(21e3, 4.3e-6, area=3.4e-8)
    far = [silence_bound(imp, Drive.tone(21e3 * k)).silent for k in (0.25, 0.3, 2.0, 3.0, 4.0)]
    near = [silence_bound(imp, Drive.tone(21e3 * k)).silent for k in (0.9, 1.0, 1.05, 1.2)]
    assert all(far) and not any(near)


@compiled
def test_resonance_is_never_proven_silent_and_does_respond():
    imp = _impacter(1e4, 3e-6)
    assert not silence_bound(imp, Drive.tone(1e4)).silent
    assert _simulated_response(imp, Drive.tone(1e4), 10e-3, n_phases=1) > 0


@compiled
def test_grazing_gap_just_above_the_proof():
    """Shrink the gap until the proof stops: at the smallest proven gap the simulator
    must still find no counted impact (grazing is where a loose bound would slip)."""
    nu_n, f = 15e3, 30e3
    lo, hi = 0.05e-6, 5e-6
    assert silence_bound(_impacter(nu_n, hi), Drive.tone(f)).silent
    assert not silence_bound(_impacter(nu_n, lo), Drive.tone(f)).silent
    for _ in range(30):
        mid = math.sqrt(lo * hi)
        if silence_bound(_impacter(nu_n, mid), Drive.tone(f)).silent:
            hi = mid
        else:
            lo = mid
    imp = _impacter(nu_n, hi)
    assert _simulated_response(imp, Drive.tone(f), _duration(imp), n_phases=16) == 0.0


def test_no_proof_undamped_or_overdamped_or_pressing():
    assert not silence_bound(_impacter(1e4, 3e-6, viscosity=0.0), Drive.tone(3e4)).silent
    over = _impacter(1e4, 3e-6, viscosity=AIR * 1e3)
    assert over.sigma >= over.omega_n
    assert not silence_bound(over, Drive.tone(3e4)).silent
    # a tone whose peak force alone pushes the impacter through the gap
    pressing = _impacter(1e4, 0.01e-6)
    assert not silence_bound(pressing, Drive.tone(5e3)).silent


@compiled
def test_extreme_q_and_many_tones():
    """A 20-tone summed drive on Q ~ 70 is proven and silent; at Q ~ 1000 (near vacuum)
    the free swing from x0 = -c comes back within 0.2 % of the wall and nothing is
    proven: the simulator decides."""
    freqs = np.geomspace(30e3, 60e3, 20)
    drive = Drive(freqs, 0.2 * Drive.tone(30e3).amplitudes[0] * (30e3 / freqs) ** 1.5)
    imp = _impacter(12e3, 8e-6, viscosity=AIR / 2)
    assert 50 < imp.omega_n / (2 * imp.sigma) < 200
    assert silence_bound(imp, drive).silent
    assert _simulated_response(imp, drive, 30e-3, n_phases=4) == 0.0
    high_q = _impacter(12e3, 8e-6, viscosity=AIR / 30)
    assert not silence_bound(high_q, drive).silent


def test_margin_is_checked():
    with pytest.raises(ValueError, match="margin"):
        silence_bound(_impacter(1e4, 3e-6), Drive.tone(3e4), margin=0.5)


def test_envelope_matches_the_closed_form_written_out():
    """The kernel's W(t) against the closed form written out here in numpy (an
    independent transcription; runs without the JIT too)."""
    imp = _impacter(8e3, 3e-6)
    drive = Drive([5e3, 11e3, 19e3], [0.5e-6, 0.3e-6, 0.1e-6])
    t = np.linspace(0.0, 3e-3, 301)
    wn, sg, c = imp.omega_n, imp.sigma, imp.gap
    wd = math.sqrt(wn * wn - sg * sg)
    w = 2 * np.pi * drive.frequencies
    a = math.cos(imp.impact_angle) * w * w * drive.amplitudes
    # response from rest to a e^{i w t}: the forced part and the free part that cancels it
    X = a / (wn * wn - w * w + 2j * sg * w)
    z = (X[None, :] * np.exp(1j * w[None, :] * t[:, None])
         + np.exp(-sg * t)[:, None] * (-X[None, :] * np.cos(wd * t)[:, None]
                                      - ((sg + 1j * w) * X / wd)[None, :]
                                      * np.sin(wd * t)[:, None]))
    g1 = np.exp(-sg * t) * (np.cos(wd * t) + sg / wd * np.sin(wd * t))
    expected = c * np.abs(g1) + np.abs(z).sum(axis=1)
    np.testing.assert_allclose(linear_envelope(imp, drive, t), expected, rtol=1e-12,
                               atol=1e-12 * c)
