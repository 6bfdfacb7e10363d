"""Contact laws (docs/contact.md): eq. (10) as printed ("paper") and the two-body law.

Property tests of the two-body collision (energy, restitution, momentum, no kick
without approach, the limit m/M -> 0), sequences of kicks through the real slider
kernel, and the paper path reproducing the numbers it gave before contact laws
existed, bit for bit.
"""

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import model
from model import Drive, Impacter, Kicks, Slider
from model.kernels.contact import two_body_impact

# m/M, e, theta, v- > 0 and V- as the brief asks; velocities in m/s over the range devices reach
ratios = st.floats(1e-3, 10.0)
restitutions = st.floats(0.0, 1.0)
angles = st.floats(1e-3, math.pi / 2 - 1e-3)
speeds = st.floats(1e-6, 10.0)
slider_speeds = st.floats(-10.0, 10.0)
signs = st.sampled_from([1.0, -1.0])


def collide(ratio, e, theta, v, V, s=1.0):
    """(dV, v+) of one two-body impact with M = 1 kg, m = ratio kg (one impacter of the pair)."""
    c = math.cos(theta)
    return two_body_impact(V, v, s, 2.0 * ratio * c, c, e)


def energy(ratio, v, V):
    """Kinetic energy of the pair along its axis plus the slider's, M = 1 kg [J]."""
    return ratio * v * v + 0.5 * V * V


@settings(max_examples=500, deadline=None)
@given(ratios, restitutions, angles, speeds, slider_speeds, signs)
def test_two_body_never_creates_energy(ratio, e, theta, v, V, s):
    dV, v_plus = collide(ratio, e, theta, v, V, s)
    before = energy(ratio, v, V)
    after = energy(ratio, v_plus, V + dV)
    assert after <= before * (1.0 + 1e-12)
    # and it dissipates exactly (1 - e^2)/2 m_eff u^2, m_eff = 2m / (1 + q)
    c = math.cos(theta)
    u = max(v - s * V * c, 0.0)
    loss = 0.5 * (1 - e * e) * 2 * ratio / (1 + 2 * ratio * c * c) * u * u
    assert before - after == pytest.approx(loss, rel=1e-9, abs=1e-12 * before)


@settings(max_examples=500, deadline=None)
@given(ratios, restitutions, angles, speeds, slider_speeds, signs)
def test_two_body_separates_at_e_times_approach(ratio, e, theta, v, V, s):
    c = math.cos(theta)
    approach = v - s * V * c          # along the impacter axis, the line of the impulse
    dV, v_plus = collide(ratio, e, theta, v, V, s)
    if approach > 0:
        separation = s * (V + dV) * c - v_plus
        assert separation == pytest.approx(e * approach, rel=1e-9, abs=1e-12 * (v + abs(V)))
        # eq. (9): momentum along the slider axis is conserved (pair 2m, slider M = 1)
        p_before = s * 2 * ratio * v * c + V
        p_after = s * 2 * ratio * v_plus * c + V + dV
        assert p_after == pytest.approx(p_before, rel=1e-12, abs=1e-12 * (ratio * v + abs(V)))
        assert s * dV > 0


@settings(max_examples=300, deadline=None)
@given(ratios, restitutions, angles, speeds, st.floats(1.0, 100.0), signs)
def test_two_body_no_kick_without_approach(ratio, e, theta, v, factor, s):
    # the slider recedes along the impacter axis at least as fast as the tip approaches
    # (1 + 1e-15): V cos(theta) rounds to at least v
    V = s * factor * v / math.cos(theta) * (1 + 1e-15)
    dV, v_plus = collide(ratio, e, theta, v, V, s)
    assert dV == 0.0 and v_plus == v


@settings(max_examples=300, deadline=None)
@given(ratios, restitutions, angles, speeds, signs)
def test_two_body_tends_to_eq10(ratio, e, theta, v, s):
    # relative difference from eq. (10) for a slider at rest: q / (1 + q), q = 2 (m/M) cos^2
    c = math.cos(theta)
    dV, _ = collide(ratio, e, theta, v, 0.0, s)
    eq10 = s * 2 * ratio * (1 + e) * v * c
    q = 2 * ratio * c * c
    assert abs(dV - eq10) == pytest.approx(abs(eq10) * q / (1 + q), rel=1e-9)
    assert abs(dV - eq10) <= 2 * ratio * abs(eq10)
    # and the limit itself: eq. (10) to 1e-6 at m/M = 1e-6
    dV_small, v_plus = collide(1e-6, e, theta, v, 0.0, s)
    assert dV_small == pytest.approx(s * 2e-6 * (1 + e) * v * c, rel=2e-6)
    assert v_plus == pytest.approx(-e * v, rel=1e-5, abs=1e-5 * v)   # eq. (8)


@pytest.mark.parametrize("ratio", [0.1, 0.3, 0.452, 1.0, 5.0])
def test_paper_energy_balance_and_two_body_kick_ratio(fig7, fig7_slider, ratio):
    # kick() with both laws against the closed forms of docs/contact.md: per kick from rest the
    # paper law gives the slider (1+e)^2 q of the pair's incoming energy m v^2 and keeps e^2 in
    # the pair (total e^2 + (1+e)^2 q, > 1 when q > (1-e)/(1+e)); two_body gives (e^2+q)/(1+q)
    imp = replace(fig7, mass=ratio * fig7_slider.mass)
    e, c = imp.restitution, math.cos(imp.impact_angle)
    q = 2 * ratio * c * c
    v = np.array([0.05, 0.2])
    incoming = imp.mass * v**2
    paper = model.kick(imp, fig7_slider, v)
    two = model.kick(imp, fig7_slider, v, contact="two_body")
    np.testing.assert_allclose(two / paper, 1 / (1 + q), rtol=1e-13)
    paper_total = (e * e * incoming + 0.5 * fig7_slider.mass * paper**2) / incoming
    np.testing.assert_allclose(paper_total, e * e + (1 + e) ** 2 * q, rtol=1e-12)
    assert (paper_total > 1).all() == (q > (1 - e) / (1 + e))
    v_plus = v - (1 + e) * v / (1 + q)
    two_total = (imp.mass * v_plus**2 + 0.5 * fig7_slider.mass * two**2) / incoming
    np.testing.assert_allclose(two_total, (e * e + q) / (1 + q), rtol=1e-12)
    assert (two_total <= 1).all()


def test_kick_two_body_reads_slider_velocity(fig7, fig7_slider):
    c = math.cos(fig7.impact_angle)
    v = 0.1
    dv = model.kick(fig7, fig7_slider, v, contact="two_body", slider_velocity=[0.0, v / c, -0.1])
    assert dv[1] == 0.0                          # slider receding as fast as the tip: no kick
    assert dv[2] > dv[0] > 0                     # slider coming at the tip: harder kick
    back = model.kick(fig7, fig7_slider, v, -1.0, contact="two_body", slider_velocity=-v / c)
    assert back == 0.0


def test_contact_is_validated(fig7, fig7_slider):
    drive = Drive.tone(6200.0)
    for call in (lambda: model.kick(fig7, fig7_slider, 0.1, contact="elastic"),
                 lambda: model.simulate_slider(fig7, fig7_slider, drive, contact="Paper"),
                 lambda: model.slider_motion(fig7_slider, drive, [0.0], [0.1], 1e-3,
                                             contact=None)):
        with pytest.raises(ValueError, match=r"contact must be one of \['paper', 'two_body'\]"):
            call()
    # two_body needs v- per kick, not velocity changes
    with pytest.raises(ValueError, match="Kicks"):
        model.slider_motion(fig7_slider, drive, [0.0], [0.1], 1e-3, contact="two_body")
    with pytest.raises(ValueError, match="direction"):
        model.simulate_slider(fig7, fig7_slider, drive, direction=0.5, contact="two_body")
    kicks = Kicks.from_impacts(fig7, fig7_slider, model.simulate(fig7, drive))
    with pytest.raises(ValueError, match="mass"):
        model.slider_motion(Slider.from_geometry(9e-8), drive, kicks, duration=3e-3)
    with pytest.raises(ValueError, match="kick_dv"):
        model.slider_motion(fig7_slider, drive, kicks, [0.1], 3e-3)
    with pytest.raises(ValueError, match="duration"):
        model.slider_motion(fig7_slider, drive, kicks)


# ---------------------------------------------------------------------------------------
# sequences of kicks through the real slider kernel


def speed_after_each_kick(slider, drive, kicks, contact):
    """Slider velocity just after each distinct kick time [m/s], each from its own run."""
    out = []
    for t in np.unique(kicks.times):
        _, _, _, v, status = model.slider_motion(slider, drive, kicks, duration=t * (1 + 1e-12),
                                                 contact=contact)
        assert status == "ok"
        out.append(v)
    return np.array(out)


def test_heavy_impacter_slider_speed_bound_fig7(fig7, fig7_slider):
    # Fig. 7's device at 6.2 kHz with the impacter's mass (and k, so nu_n and every impact stay)
    # scaled to m/M = 5.  Two-body bound: the slider's velocity along the impacter axis, V cos(theta),
    # never exceeds (1 + e) times the tip's fastest v- (docs/contact.md).  The paper law breaks it.
    drive = Drive.tone(6200.0)
    m = 5.0 * fig7_slider.mass
    heavy = replace(fig7, mass=m, stiffness=fig7.stiffness * m / fig7.mass)
    res = model.simulate_slider(heavy, fig7_slider, drive, contact="two_body")
    assert res.status == "ok" and res.impacts.n_impacts == 17
    kicks = Kicks.from_impacts(heavy, fig7_slider, res.impacts)
    e, c = heavy.restitution, math.cos(heavy.impact_angle)
    bound = (1 + e) * res.impacts.velocities.max()
    along_axis = speed_after_each_kick(fig7_slider, drive, kicks, "two_body") * c
    assert along_axis.max() <= bound
    assert along_axis.max() > 0.5 * bound          # and it is not vacuous: kicks reach 83 % of it
    paper = speed_after_each_kick(fig7_slider, drive, kicks, "paper") * c
    assert paper.max() > 3 * bound
    # the same simulation, end to end: two_body moves the slider less than the paper law
    assert 0 < res.mean_velocity < model.simulate_slider(heavy, fig7_slider, drive).mean_velocity


def frictionless_kicks(ratio, e, theta, speeds, signs, times):
    slider = Slider(mass=1e-9, damping=0.0, static_friction=0.0, dynamic_friction=0.0)
    m = ratio * slider.mass
    imp = Impacter(mass=m, stiffness=m * (2 * math.pi * 5e3) ** 2, damping=0.0, gap=3e-6,
                   impact_angle=theta, restitution=e)
    n = len(speeds)
    kicks = [Kicks(times=np.array([t]), velocities=np.array([v]), chatter=np.zeros(1, bool),
                   direction=np.array([s]), mass_ratio=np.array([ratio]),
                   impact_angle=np.array([theta]), restitution=np.array([e]),
                   velocity_changes=model.kick(imp, slider, [v], s), slider_mass=slider.mass)
             for t, v, s in zip(times, speeds, signs)]
    assert n == len(kicks)
    return slider, imp, Kicks.concatenate(kicks)


@settings(max_examples=60, deadline=None)
@given(ratios, restitutions, angles,
       st.lists(st.floats(1e-3, 2.0), min_size=1, max_size=25))
def test_no_kick_sequence_beats_the_bound(ratio, e, theta, tip_speeds):
    # the worst case for the bound: no friction and no drive, so the slider keeps every kick;
    # one pair pushing, the slider starting at rest
    n = len(tip_speeds)
    times = 1e-4 * (1 + np.arange(n))
    slider, imp, kicks = frictionless_kicks(ratio, e, theta, tip_speeds, [1.0] * n, times)
    quiet = Drive([5000.0], [0.0])
    _, _, _, V, status = model.slider_motion(slider, quiet, kicks, duration=1.0,
                                             contact="two_body")
    c = math.cos(theta)
    assert status == "ok"
    assert 0 <= V * c <= (1 + e) * max(tip_speeds) * (1 + 1e-12)
    # and the kernel applied the law with the velocity at each kick: replay it by hand
    W = 0.0
    for v in tip_speeds:
        W += collide(ratio, e, theta, v, W)[0]
    assert V == pytest.approx(W, rel=1e-12, abs=1e-300)


@settings(max_examples=60, deadline=None)
@given(ratios, restitutions.filter(lambda e: 0.05 < e < 0.95), angles, speeds)
def test_chatter_tail_is_its_impacts_one_by_one(ratio, e, theta, first):
    # a chatter tail (sum S of v-_k = v-_1 e^(k-1)) kicks as its impacts would, applied in turn
    slider, imp, single = frictionless_kicks(ratio, e, theta, [first], [1.0], [1e-4])
    S = first * e / (1 - e)
    tail = replace(single, velocities=np.array([S]), chatter=np.array([True]),
                   velocity_changes=model.kick(imp, slider, [S]))
    both = Kicks.concatenate([single, tail])
    quiet = Drive([5000.0], [0.0])
    _, _, _, V, _ = model.slider_motion(slider, quiet, both, duration=1e-3, contact="two_body")
    W, vk = 0.0, first
    while vk > 1e-17 * first:
        W += collide(ratio, e, theta, vk, W)[0]
        vk *= e
    assert V == pytest.approx(W, rel=1e-12)
    # the paper path applies the tail as its sum, as before
    _, _, _, Vp, _ = model.slider_motion(slider, quiet, both, duration=1e-3)
    assert Vp == pytest.approx(model.kick(imp, slider, first / (1 - e)), rel=1e-13)


# ---------------------------------------------------------------------------------------
# the paper path is unchanged


@pytest.mark.parametrize("frequency,direction", [(6200.0, 1.0), (5200.0, -1.0)])
def test_paper_contact_reproduces_the_old_path_bit_for_bit(fig7, fig7_slider, frequency,
                                                           direction):
    drive = Drive.tone(frequency)
    default = model.simulate_slider(fig7, fig7_slider, drive, direction=direction,
                                    trajectory=True)
    paper = model.simulate_slider(fig7, fig7_slider, drive, direction=direction,
                                  trajectory=True, contact="paper")
    # the path simulate_slider took before contact laws existed: kick() then slider_motion(dv)
    imp = model.simulate(fig7, drive)
    dv = model.kick(fig7, fig7_slider, np.concatenate([imp.velocities, imp.chatter_sums]),
                    direction)
    _, pos, z, v, _ = model.slider_motion(fig7_slider, drive,
                                          np.concatenate([imp.times, imp.chatter_times]), dv,
                                          3e-3, trajectory=default.t)
    for res in (default, paper):
        assert res.displacement == z and res.v_end == v
        np.testing.assert_array_equal(res.position, pos)


def test_paper_contact_fig7_value(fig7, fig7_slider):
    # Fig. 7 (thick line, 6.2 kHz): 3.40 mm/s.  Exact bits as simulate_slider gave them at
    # commit aeee3b8, before contact laws existed (regression reference, not a paper value)
    res = model.simulate_slider(fig7, fig7_slider, Drive.tone(6200.0), contact="paper")
    assert res.displacement.hex() == "0x1.5641f08a3e04fp-17"
    assert round(res.mean_velocity * 1e3, 2) == 3.40
