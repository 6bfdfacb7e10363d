"""The exact solver against the same closed form evaluated in 50 digits (model.mpref).

Property: the float solver's r of eq. (12), its impact times and its impact
velocities agree with an arbitrary-precision evaluation of the same closed form,
whose impacts are found by an independent method (scan and bracket), to 1e-12.
"""

import math
from dataclasses import replace

import numpy as np
import pytest

import model
from model import Drive, Impacter
from model.mpref import reference

# Fig. 7 of the paper: A = 1.5e4 um^2, w = 4 um, l = 1242 um, c = 3 um, nu_n = 5.2 kHz
FIG7 = Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6).with_natural_frequency(5200.0)
# Table II's forward impacter in air (nu_n = 5819.9 Hz as the table gives it)
TABLE2_AIR = Impacter.from_geometry(13544e-12, 5.6774e-6, 795.74e-6, 5.2046e-6,
                                    viscosity=0.0179e-3).with_natural_frequency(5819.9)
# The Fig. 7 impacter with a 0.3 um gap under a 1 kHz drive (Z0^2 w^3 = 50, Z0 = 14 um):
# the drive presses it on the wall for about a fifth of each cycle, so every approach
# chatters into sticking, then the drive pulls it off again.
CHATTER = Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 0.3e-6).with_natural_frequency(5200.0)


def agreement(imp, drive, x0=0.0, duration=3e-3):
    """(relative error of r, max |dt| [s], max |dv| / max v-) of the float solver."""
    res = model.simulate(imp, drive, x0=x0, duration=duration)
    ref = reference(imp, drive, x0=x0, duration=duration)
    assert res.status == "ok" and ref.status == "ok"
    r_ref = float(ref.response)
    rel_r = abs(res.response - r_ref) / r_ref
    # compare the impacts that matter: the float solver resolves chatter down to the
    # wall series' limit and sums the rest in closed form, the reference further
    t_ref, v_ref = ref.impact_arrays()
    vmax = v_ref.max()
    keep_ref = v_ref > 1e-6 * vmax
    keep = res.velocities > 1e-6 * vmax
    assert np.count_nonzero(keep) == np.count_nonzero(keep_ref)
    dt = np.max(np.abs(res.times[keep] - t_ref[keep_ref]))
    dv = np.max(np.abs(res.velocities[keep] - v_ref[keep_ref])) / vmax
    return rel_r, dt, dv


@pytest.mark.parametrize("freq", [6200.0, 5200.0])
def test_fig7_agrees_with_50_digits(freq):
    # case (a): at 5.2 kHz the drive is at exact resonance of the undamped impacter
    rel_r, dt, dv = agreement(FIG7, Drive.tone(freq))
    assert rel_r <= 1e-12
    assert dt <= 1e-15      # [s], against 3 ms
    assert dv <= 1e-12


def test_table2_in_air_agrees_with_50_digits():
    # case (b): damped (damping ratio 0.029), x0 = -2.6 um, 6 kHz
    rel_r, dt, dv = agreement(TABLE2_AIR, Drive.tone(6000.0), x0=-2.6e-6)
    assert rel_r <= 1e-12 and dt <= 1e-15 and dv <= 1e-12


def test_chatter_to_sticking_agrees_with_50_digits():
    # case (c); regression: the solver used to lose the tail of every chatter sequence
    # (r off by 1.3e-7) once the bounces fell below the closed form's resolution
    res = model.simulate(CHATTER, Drive.tone(1000.0))
    assert res.chatter_times.size >= 2  # two sequences summed in closed form
    rel_r, dt, dv = agreement(CHATTER, Drive.tone(1000.0))
    assert rel_r <= 1e-12 and dt <= 1e-15 and dv <= 1e-12


def test_light_damping_at_resonance_agrees_with_50_digits():
    # regression: with damping ratio 1e-9 at resonance the regular particular solution
    # (amplitude a / (2 sigma w), 1e8 times the motion) cost 9 digits and 1.35 million
    # steps; at 1e-12 the run hit the step cap.  The damped beat form fixes both.
    for zeta in (1e-12, 1e-9):
        imp = Impacter(FIG7.mass, FIG7.stiffness,
                       zeta * 2.0 * math.sqrt(FIG7.stiffness * FIG7.mass), FIG7.gap)
        res = model.simulate(imp, Drive.tone(5200.0))
        assert res.status == "ok" and res.n_steps < 2000
        rel_r, dt, dv = agreement(imp, Drive.tone(5200.0))
        assert rel_r <= 1e-12 and dv <= 1e-12


def _release_case():
    """Critically damped, three tones: chatters into sticking, then is released."""
    imp = Impacter(1.0, 26055.2109568764**2, 2 * 26055.2109568764, 3.4647633036412696e-07,
                   impact_angle=0.0, restitution=0.5)
    w = np.array([38286.51421228, 27664.82779133, 22895.37317039])
    a = np.array([994.23171887, 523.82001188, 2006.6146716])
    drive = Drive(w / (2 * math.pi), a / w**2, [5.10405384, 4.1964729, 6.02189045])
    return imp, drive, 2.950000489915352e-07, 0.004822977881529184


def test_release_from_wall_regression():
    # regression: at each release from sticking the solver evaluated v = 1.7e-18 m/s
    # (the rounding noise of p1 + vp) at the wall and recorded 100000 zero-time
    # "impacts" until the event cap
    imp, drive, x0, duration = _release_case()
    res = model.simulate(imp, drive, x0=x0, duration=duration)
    assert res.status == "ok" and res.n_impacts < 1000
    assert np.all(np.diff(res.times) > 0)


@pytest.mark.slow
def test_release_from_wall_regression_agrees_with_50_digits():
    imp, drive, x0, duration = _release_case()
    res = model.simulate(imp, drive, x0=x0, duration=duration)
    ref = reference(imp, drive, x0=x0, duration=duration)
    assert abs(res.response - float(ref.response)) <= 1e-12 * float(ref.response)


def _random_case(rng):
    fn = 10 ** rng.uniform(3, 5)
    wn = 2 * math.pi * fn
    zeta = rng.choice([0.0, 0.0, 1e-9, 1e-3, 0.05, 0.3, 1.0, 2.0])
    gap = 10 ** rng.uniform(-7, -5)
    e = rng.choice([0.0, 0.3, 0.5, 0.9, 1.0])
    nt = rng.choice([1, 1, 2, 3])
    w = wn * rng.uniform(0.5, 1.6, nt)
    if rng.random() < 0.2:
        w[0] = wn * (1 + rng.choice([0.0, 1e-9, 1e-4, 5e-3]))
    z = np.sqrt(50 / w**3) * rng.uniform(0.1, 3, nt)
    phi = rng.uniform(0, 2 * math.pi, nt)
    imp = Impacter(1.0, wn**2, 2 * zeta * wn, gap, impact_angle=0.0, restitution=e)
    x0 = rng.choice([-gap, 0.0, gap, rng.uniform(-gap, gap)])
    return imp, Drive(w / (2 * math.pi), z, phi), x0, 20 / fn


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(60))
def test_random_parameters_agree_with_50_digits(seed):
    # random stiffness, damping (every regime), gap, restitution, 1-3 tones, start.
    # Some of these runs are chaotic (undamped, elastic) or graze: there a change of
    # 1e-13 in the data changes r by far more than 1e-12, and no double-precision
    # solver can do better.  So the float solver's error is measured against the
    # problem's own sensitivity: the spread of the 50-digit r over perturbations of
    # the gap and the stiffness by 1e-13.
    imp, drive, x0, duration = _random_case(np.random.default_rng(seed))
    res = model.simulate(imp, drive, x0=x0, duration=duration)
    assert res.status == "ok"

    def exact(device, max_events):
        ref = reference(device, drive, x0=x0, duration=duration, max_events=max_events)
        return float(ref.sum_v) if ref.status == "ok" else math.nan

    r0 = exact(imp, 20000)
    assert math.isfinite(r0)
    err = abs(res.response * duration - r0)
    if err <= 1e-12 * max(abs(r0), 1e-300):
        return
    spread = max(abs(exact(replace(imp, gap=imp.gap * (1 + 1e-13)), 2000) - r0),
                 abs(exact(replace(imp, stiffness=imp.stiffness * (1 + 1e-13)), 2000) - r0))
    if math.isnan(spread):
        # a perturbed problem bounces without end (e = 1 against a pressing force
        # after a near graze): the sensitivity is unbounded, nothing to compare
        pytest.skip("perturbing the data by 1e-13 changes the run qualitatively")
    assert err <= 10 * spread + 1e-12 * abs(r0)
