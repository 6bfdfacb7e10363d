"""Reproductions of the paper's simulated results (Saitou, Wang, Wou, JMEMS 2000)."""

import numpy as np

import model
from model import Drive


def test_fig7_impact_every_cycle_at_6200(fig7):
    # Fig. 7 (thick line): at 6.2 kHz "the impactor rapidly acquire enough momentum to
    # impact the wall at each cycle"
    res = model.simulate(fig7, Drive.tone(6200.0), duration=3e-3)
    assert res.status == "ok"
    intervals = np.diff(res.times)
    # after the first three (transient) impacts, one impact per drive period
    np.testing.assert_allclose(intervals[3:], 1 / 6200.0, rtol=0.02)
    assert res.n_impacts == 17


def test_fig7_slider_four_times_faster(fig7, fig7_slider):
    # Fig. 7: "an average slider velocity with 6.2 kHz is approximately four times larger
    # than with 5.2 kHz"
    fast = model.simulate_slider(fig7, fig7_slider, Drive.tone(6200.0))
    slow = model.simulate_slider(fig7, fig7_slider, Drive.tone(5200.0))
    ratio = fast.mean_velocity / slow.mean_velocity
    assert 3.0 < ratio < 5.0
    # "moves a few mm/s"
    assert 1e-3 < fast.mean_velocity < 10e-3


def test_fig7_at_natural_frequency_weaker_impacts(fig7):
    # Fig. 7 (thin line, exact resonance: the undamped secular case): the amplitude builds up
    # slowly, so there are fewer and weaker impacts than at 6.2 kHz
    slow = model.simulate(fig7, Drive.tone(5200.0))
    fast = model.simulate(fig7, Drive.tone(6200.0))
    assert slow.status == "ok"
    assert 0 < slow.n_impacts < fast.n_impacts
    assert slow.velocities.mean() < 0.6 * fast.velocities.mean()


def collapse_frequency(freqs, r):
    """First frequency above the response peak where r falls below a third of the peak."""
    peak = int(np.argmax(r))
    after = np.nonzero(r[peak:] < r[peak] / 3)[0]
    return freqs[peak + after[0]]


def test_fig9_collapse_rises_with_initial_position(fig7):
    # Fig. 9: the response rises with frequency above nu_n, then collapses at a frequency
    # that increases with x(t0) = 0, 1, 2, 3 um
    freqs = np.arange(5000.0, 8001.0, 10.0)
    x0s = np.array([0.0, 1.0, 2.0, 3.0]) * 1e-6
    r = model.sweep(fig7, freqs, x0s)
    collapse = [collapse_frequency(freqs, r[:, j]) for j in range(4)]
    assert all(a < b for a, b in zip(collapse, collapse[1:])), collapse
    # hardening: the peak response lies above the natural frequency
    assert np.all(freqs[np.argmax(r, axis=0)] > 5200.0)
    # r just below collapse exceeds r at nu_n for x0 = 0
    assert r[:, 0].max() > 2 * r[freqs == 5200.0, 0][0]
