"""Gated bursts (planner.synthesis.gating): the envelopes, the exact program of constant-tone
stretches the simulation plays, the samples a lab plays, their peaks."""

import numpy as np
import pytest

from planner.synthesis.gating import Burst, burst_peaks, envelopes, gate, tone_peaks
from planner.synthesis import synthesize

FS = 200e3


@pytest.fixture(scope="module")
def loop():
    return synthesize([6000.0, 9100.0, 13300.0, 21700.0], 1e-6, FS, seed=0)


@pytest.mark.parametrize("starts, gates", [
    ([0.0, 0.0, 0.0, 0.0], [4e-3, 2e-3, 6.5e-3, 1e-3]),          # together, each its gate
    ([0.0, 2.5e-3, 5.0e-3, 0.0], [2e-3, 4.5e-3, 7e-3, 0.0]),      # one after the other, one silent
    ([1e-3, 1.2e-3, 0.0, 3e-3], [3e-3, 2.2e-3, 4e-3, 3.5e-3]),    # overlapping ramps
])
def test_program_is_the_samples_exactly(loop, starts, gates):
    """The stretches of constant tones the simulation plays in turn are the exported sum
    (ramps as three tones each, phases advanced to each stretch's start)."""
    burst = gate(loop, starts, gates, 0.5e-3)
    t0, worst = 0.0, 0.0
    for duration, drive in burst.program():
        tau = np.linspace(0.0, duration, 37)
        worst = max(worst, float(np.abs(drive.displacement(tau) - burst.evaluate(t0 + tau)).max()))
        t0 += duration
    assert t0 == pytest.approx(burst.length_s, abs=1e-12)
    assert worst < 1e-18                           # of a peak ~1e-6 m
    np.testing.assert_allclose(burst.samples, burst.evaluate(burst.times), rtol=0, atol=1e-18)
    assert burst.samples[0] == 0.0 and burst.samples[-1] == 0.0


def test_envelope_has_no_click(loop):
    """Displacement and velocity are continuous at every ramp edge: the one-sided slopes
    on either side of an edge agree to the discretisation error, where switching a tone
    off at once would jump the velocity by w Z (or the displacement by Z)."""
    burst = gate(loop, [0.0, 0.0, 1e-3, 0.0], [3e-3, 2e-3, 4e-3, 2.5e-3], 0.5e-3)
    h = 1e-9
    vmax = float(np.sum(2 * np.pi * loop.frequencies * loop.amplitudes))
    edges = sorted({0.5e-3, 1e-3, 1.5e-3, 2e-3, 2.5e-3, 3e-3, 3.5e-3, 4e-3})
    for e in edges:
        x = burst.evaluate(np.array([e - 2 * h, e - h, e, e + h, e + 2 * h]))
        left, right = (x[2] - x[0]) / (2 * h), (x[4] - x[2]) / (2 * h)
        assert abs(right - left) < 1e-3 * vmax, e
        assert abs(x[3] - x[1]) < 3 * h * vmax


def test_envelopes_shape():
    g = envelopes(np.array([0.0, 1e-3, 1.25e-3, 1.5e-3, 3e-3, 3.5e-3, 4e-3, 5e-3]),
                  [1e-3, 0.0], [3e-3, 0.0], 1e-3)
    np.testing.assert_allclose(g[0], [0.0, 0.0, 0.5 - 0.5 * np.cos(np.pi / 4), 0.5, 1.0,
                                      0.5, 0.0, 0.0], atol=1e-15)
    assert not g[1].any()                          # gate 0: not played


@pytest.mark.parametrize("starts, gates, why", [
    ([0.0, 0.0, 0.0, 0.0], [0.2e-3, 1e-3, 1e-3, 1e-3], r"gates_s\[0\] = 0.0002 s"),
    ([0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0], "no tone is played"),
    ([0.0, 0.0, 0.0], [1e-3, 1e-3, 1e-3], "starts_s: 3 values for 4 tones"),
    ([-1e-3, 0.0, 0.0, 0.0], [1e-3, 1e-3, 1e-3, 1e-3], "starts_s must be finite and >= 0"),
])
def test_bad_gates_are_refused(loop, starts, gates, why):
    with pytest.raises(ValueError, match=why):
        gate(loop, starts, gates, 0.5e-3)


def test_burst_is_not_gated_again(loop):
    burst = gate(loop, [0.0] * 4, [1e-3] * 4, 0.5e-3)
    assert isinstance(burst, Burst)
    with pytest.raises(ValueError, match="already a burst"):
        gate(burst, [0.0] * 4, [1e-3] * 4, 0.5e-3)


def test_peaks_of_one_tone_and_of_a_burst(loop):
    # one tone over whole periods peaks at its amplitude, its acceleration at w^2 Z
    z, a = tone_peaks([5000.0], [2e-6], [0.3], 1e-3)
    assert z == pytest.approx(2e-6, rel=1e-9)
    assert a == pytest.approx((2 * np.pi * 5000.0) ** 2 * 2e-6, rel=1e-9)
    burst = gate(loop, [0.0, 2.5e-3, 5.0e-3, 0.0], [2e-3, 4.5e-3, 7e-3, 0.0], 0.5e-3)
    zp, ap = burst_peaks(burst)
    assert zp >= np.abs(burst.samples).max() and burst.peak == pytest.approx(zp)
    # one tone at a time: never more than the loudest tone plus what its ramps add
    w = 2 * np.pi * loop.frequencies[:3]
    assert zp <= loop.amplitudes[:3].max() * (1 + 1e-9)
    assert ap <= float(np.max(w ** 2 * loop.amplitudes[:3])) * (1 + np.pi / (0.5e-3 * w.min()))
