"""Drive synthesis: invariants of the loop, the tones, the peak and the scale.

Every test checks a property a correct drive must have (the spectrum holds the tone table,
the loop repeats seamlessly, the peak is the continuous one, nothing is clipped) rather
than comparing with stored outputs.
"""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.synthesis import (
    LoopLengthError,
    Waveform,
    crest_factor,
    schroeder_phases,
    split_tones,
    synthesize,
    tones_from_power,
)

FS = 200e3
#: The benchmark's channel grid: 200 log-spaced channels over the 2-20 kHz band.
GRID = np.geomspace(2e3, 20e3, 200)


def channel_subset(n, seed):
    return np.sort(np.random.default_rng(seed).choice(GRID, n, replace=False))


def loop_spectrum(wf):
    """Amplitudes and phases at the tones from an FFT of one loop (independent of the code)."""
    loop = wf.samples[:wf.loop_points]
    spectrum = np.fft.rfft(loop) * 2 / len(loop)
    bins = np.rint(wf.frequencies * wf.loop_length).astype(int)
    return np.abs(spectrum[bins]), np.angle(spectrum[bins])


def max_step(wf):
    """Largest change a signal of these tones can make in one sample: sum 2 pi f A / fs."""
    return float(np.sum(2 * np.pi * wf.frequencies * wf.amplitudes)) / wf.sample_rate


@pytest.fixture(scope="module")
def wf25():
    return synthesize(channel_subset(25, 1), 1e-6, FS, seed=3)


def test_power_convention():
    # paper notes: Z0^2 w^3 = 50 m^2/s^3 gives Z0 = 1.27 um at 5 kHz
    assert tones_from_power([5000.0])[0] == pytest.approx(1.27e-6, abs=0.005e-6)
    f = np.array([2e3, 7e3, 19e3])
    z = tones_from_power(f, power=20.0)
    np.testing.assert_allclose(z**2 * (2 * np.pi * f) ** 3, 20.0, rtol=1e-12)


def test_default_amplitudes_follow_the_power_convention():
    f = [3000.0, 5000.0, 9000.0]
    wf = synthesize(f, None, FS, seed=0)
    np.testing.assert_allclose(wf.amplitudes, tones_from_power(wf.requested_frequencies))


def test_loop_holds_whole_cycles_within_tolerance(wf25):
    cycles = wf25.frequencies * wf25.loop_length
    np.testing.assert_allclose(cycles, np.rint(cycles), atol=1e-6)
    assert np.all(np.abs(wf25.frequency_shift) <= 1e-3 * wf25.requested_frequencies * (1 + 1e-9))
    assert len(wf25.samples) == wf25.loop_points * wf25.n_loops
    assert wf25.loop_length <= 1.0


def test_loop_point_is_continuous(wf25):
    x = wf25.samples
    # the sample after the last is the first, by periodic extension of the exact sum
    after_last = wf25.evaluate(len(x) / wf25.sample_rate)
    assert after_last == pytest.approx(x[0], abs=1e-12 * wf25.peak)
    assert abs(x[0] - x[-1]) <= max_step(wf25)
    assert np.max(np.abs(np.diff(x))) <= max_step(wf25)


def test_samples_are_the_exact_sum_of_cosines(wf25):
    t = wf25.times
    direct = np.zeros_like(t)
    for f, a, p in zip(wf25.frequencies, wf25.amplitudes, wf25.phases):
        direct += a * np.cos(2 * np.pi * f * t + p)
    # float t costs ~1e-11 rad of phase per tone at these times; the sum is exact to that
    np.testing.assert_allclose(wf25.samples, direct, rtol=0, atol=1e-9 * wf25.peak)


def test_spectrum_holds_the_tone_table(wf25):
    amp, ph = loop_spectrum(wf25)
    np.testing.assert_allclose(amp, wf25.amplitudes, rtol=1e-9)
    np.testing.assert_allclose(np.angle(np.exp(1j * (ph - wf25.phases))), 0, atol=1e-9)
    assert wf25.rms == pytest.approx(np.sqrt(np.mean(wf25.samples**2)), rel=1e-12)


def test_peak_is_the_continuous_peak(wf25):
    # no point of a 40x finer grid is above the reported peak, and the peak is reached
    t = np.linspace(0, wf25.loop_length, 40 * wf25.loop_points, endpoint=False)
    fine = np.abs(wf25.evaluate(t)).max()
    assert fine <= wf25.peak * (1 + 1e-12)
    assert fine >= wf25.peak * (1 - 1e-4)
    assert np.abs(wf25.samples).max() <= wf25.peak * (1 + 1e-12)
    assert wf25.crest_factor == pytest.approx(wf25.peak / wf25.rms, rel=1e-12)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_crest_factor_below_schroeder_and_random(seed):
    f = channel_subset(25, seed)
    wf = synthesize(f, 1e-6, FS, seed=seed)
    cycles = np.rint(wf.frequencies * wf.loop_length).astype(int)
    a = np.full(25, 1e-6)
    schroeder = crest_factor(cycles, a, schroeder_phases(a))
    rand = crest_factor(cycles, a, np.random.default_rng(seed).uniform(0, 2 * np.pi, 25))
    assert wf.crest_factor < schroeder
    assert wf.crest_factor < rand
    assert wf.crest_factor < 2.9   # random phases give 3.4-4.5 on these sets


def test_same_seed_same_bytes():
    f = channel_subset(12, 7)
    a = synthesize(f, 1e-6, FS, seed=11)
    b = synthesize(f, 1e-6, FS, seed=np.random.default_rng(11))
    assert a.samples.tobytes() == b.samples.tobytes()
    assert a.phases.tobytes() == b.phases.tobytes()
    # the seed reaches the phases: on this set seed 11's random start loses to
    # Schroeder's (as do seeds 0, 2-6), seed 1's wins, so seed 1 gives other phases
    c = synthesize(f, 1e-6, FS, seed=1)
    assert not np.allclose(c.phases, a.phases)
    assert c.samples.tobytes() != a.samples.tobytes()


def test_given_phases_are_kept():
    ph = [0.3, -1.2, 2.5]
    wf = synthesize([3000.0, 4000.0, 6500.0], 1e-6, FS, phases=ph)
    np.testing.assert_allclose(wf.phases, ph)
    np.testing.assert_allclose(loop_spectrum(wf)[1], ph, atol=1e-9)


def test_duration_is_a_whole_number_of_loops():
    wf = synthesize([3000.0, 5000.0], 1e-6, FS, duration=0.01, seed=0)
    assert len(wf.samples) == 2000
    assert wf.n_loops * wf.loop_points == 2000
    assert wf.duration == pytest.approx(0.01)
    np.testing.assert_array_equal(wf.samples[:wf.loop_points],
                                  wf.samples[-wf.loop_points:])


def test_peak_limit_scales_and_never_clips():
    f = channel_subset(10, 4)
    free = synthesize(f, 1e-6, FS, seed=5)
    limit = 0.5 * free.peak
    wf = synthesize(f, 1e-6, FS, seed=5, peak_limit=limit)
    assert wf.scale == pytest.approx(limit / free.peak, rel=1e-12)
    assert wf.peak <= limit * (1 + 1e-12)
    assert np.abs(wf.samples).max() <= limit * (1 + 1e-12)
    np.testing.assert_allclose(wf.amplitudes, 1e-6 * wf.scale, rtol=1e-12)
    # same shape, only smaller: the crest factor and the spectrum's phases are unchanged
    assert wf.crest_factor == pytest.approx(free.crest_factor, rel=1e-12)
    np.testing.assert_allclose(wf.samples, free.samples * wf.scale, rtol=0, atol=1e-15)
    assert any("scaled by" in w and "not clipped" in w for w in wf.warnings)
    assert free.scale == 1.0 and free.warnings == ()


def test_split_tones_fits_every_sub_step():
    f = channel_subset(12, 9)
    whole = synthesize(f, 1e-6, FS, seed=0)
    limit = 0.6 * whole.peak
    parts = split_tones(f, 1e-6, FS, limit, seed=0)
    assert len(parts) >= 2
    idx = np.concatenate([i for i, _ in parts])
    assert sorted(idx.tolist()) == list(range(12))
    for i, wf in parts:
        assert wf.peak <= limit and wf.scale == 1.0
        np.testing.assert_allclose(wf.requested_frequencies, f[i], rtol=1e-12)


def test_split_rejects_a_tone_above_the_limit():
    with pytest.raises(ValueError, match="amplitudes"):
        split_tones([3000.0, 5000.0], [1e-6, 5e-6], FS, 2e-6)


def test_no_loop_within_tolerance():
    with pytest.raises(LoopLengthError, match="frequency_tolerance"):
        synthesize([3000.1234567, 4000.7654321], 1e-6, FS, frequency_tolerance=0.0,
                   max_loop_length=0.01)


@pytest.mark.parametrize("kwargs, name", [
    ({"amplitudes": [1e-6, -1e-6]}, "amplitudes"),
    ({"frequencies": [3000.0, np.nan]}, "frequencies"),
    ({"amplitudes": [1e-6, 1e-6, 1e-6]}, "amplitudes"),
    ({"frequencies": [3000.0, -4000.0]}, "frequencies"),
    ({"frequencies": [3000.0, 150e3]}, "Nyquist"),
    ({"frequencies": [3000.0, 3000.0]}, "distinct"),
    ({"sample_rate": 0.0}, "sample_rate"),
    ({"duration": 1.234567e-6}, "duration"),
    ({"peak_limit": -1.0}, "peak_limit"),
    ({"seed": "x"}, "seed"),
    ({"phases": [0.0]}, "phases"),
    ({"frequency_tolerance": [-1.0, 1.0]}, "frequency_tolerance"),
])
def test_validation_names_the_argument(kwargs, name):
    args = {"frequencies": [3000.0, 4000.0], "amplitudes": [1e-6, 1e-6], "sample_rate": FS}
    args.update(kwargs)
    with pytest.raises(ValueError, match=name):
        synthesize(**args)


def test_waveform_is_immutable(wf25):
    with pytest.raises(ValueError):
        wf25.samples[0] = 1.0
    with pytest.raises(AttributeError):
        wf25.scale = 2.0


def test_waveform_checks_its_tone_table():
    with pytest.raises(ValueError, match="phases"):
        Waveform(samples=np.zeros(4), sample_rate=4.0, frequencies=[1.0], amplitudes=[1.0],
                 phases=[0.0, 1.0], crest_factor=1.0, loop_length=1.0, peak=1.0, rms=1.0)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(min_value=0, max_value=199), min_size=1, max_size=8, unique=True),
       st.floats(min_value=0.2, max_value=5.0), st.integers(min_value=0, max_value=2**31))
def test_invariants_hold_for_any_tone_set(channels, spread, seed):
    f = GRID[sorted(channels)]
    a = tones_from_power(f) * spread
    wf = synthesize(f, a, FS, seed=seed)
    assert np.all(np.isfinite(wf.samples))
    cycles = wf.frequencies * wf.loop_length
    np.testing.assert_allclose(cycles, np.rint(cycles), atol=1e-6)
    assert np.all(np.abs(wf.frequency_shift) <= 1e-3 * f * (1 + 1e-9))
    assert np.abs(wf.samples).max() <= wf.peak * (1 + 1e-12)
    assert 1.0 <= wf.crest_factor <= math.sqrt(2 * len(f)) * (1 + 1e-9)   # sum of amplitudes
    amp, _ = loop_spectrum(wf)
    np.testing.assert_allclose(amp, wf.amplitudes, rtol=1e-9)
    assert abs(wf.samples[0] - wf.samples[-1]) <= max_step(wf)


# ------------------------------------------------------------ through a drive chain


def resonance(f, f_r, q):
    """A second-order resonance over a flat gain of 1: ``1 / (1 - (f/f_r)^2 + j f/(f_r q))``
    (a piezo stack's first mode; |H| = q at f_r, the phase turning from 0 to -180 deg)."""
    r = np.asarray(f) / f_r
    return 1.0 / (1.0 - r**2 + 1j * r / q)


def test_optimised_through_a_resonance_is_the_amplifier_input():
    """Phases chosen for the amplifier's *input* through a chain with a resonance (x3 at
    one tone, the phase turning by ~180 deg across the band): the input's crest factor is
    the optimiser's own, far below that of the die-optimised phases compensated, and the
    input through the chain gives the die the designed tones (FFT)."""
    from planner.synthesis import optimise_phases

    f = channel_subset(25, 4)
    z = np.full(25, 1e-6)                      # the tones the die must feel [m]
    first = synthesize(f, z, FS, seed=0)       # the loop and snapped tones
    fr = first.frequencies[12]
    h = resonance(first.frequencies, fr, 3.0)  # um/V-like gain: x3 at tone 12
    assert abs(h[12]) == pytest.approx(3.0)
    v = z / np.abs(h)                          # the input's amplitudes [V per m/(m/V)]
    cycles = np.rint(first.frequencies * first.loop_length).astype(int)

    die_phases = optimise_phases(cycles, v, seed=0, offsets=-np.angle(h))
    input_phases = die_phases - np.angle(h)
    input_crest = crest_factor(cycles, v, input_phases)
    # the offsets only move the optimum: the same crest factor as optimising v directly
    plain = optimise_phases(cycles, v, seed=0)
    assert input_crest == pytest.approx(crest_factor(cycles, v, plain), rel=1e-12)
    # phases optimised for the die, then compensated, give the input a far higher peak
    naive = crest_factor(cycles, v, optimise_phases(cycles, z, seed=0) - np.angle(h))
    assert input_crest < 0.85 * naive
    assert input_crest < 2.9

    # the amplifier input as a waveform, through the chain by FFT: the designed tones
    wf = synthesize(first.frequencies, v, FS, phases=input_phases, frequency_tolerance=1e-6)
    assert wf.loop_length == first.loop_length
    assert wf.crest_factor == pytest.approx(input_crest, rel=1e-12)
    loop = wf.samples[:wf.loop_points]
    spectrum = np.fft.rfft(loop) * 2 / len(loop)
    bins = np.rint(wf.frequencies * wf.loop_length).astype(int)
    die = spectrum[bins] * h
    np.testing.assert_allclose(np.abs(die), z, rtol=1e-9)
    np.testing.assert_allclose(np.angle(die * np.exp(-1j * die_phases)), 0.0, atol=1e-9)


def test_offsets_are_checked():
    from planner.synthesis import optimise_phases

    with pytest.raises(ValueError, match=r"offsets\[1\]"):
        optimise_phases([3, 5], [1.0, 1.0], offsets=[0.0, np.nan])
    with pytest.raises(ValueError, match="offsets: shape"):
        optimise_phases([3, 5], [1.0, 1.0], offsets=[0.0])


#: Chains that scale and turn the 25 tones of ``channel_subset(25, 4)`` (2.2-19 kHz):
#: label -> (resonance [Hz], Q, low-pass [Hz] or None, the least relative fall of the
#: amplifier input's crest factor).  Every one over a flat 1 um/V.
INPUT_CHAINS = {
    "Q 3 mid-band": (6000.0, 3.0, None, 0.05),
    "Q 20 mid-band": (9000.0, 20.0, None, 0.05),
    "Q 10 and a low-pass": (12000.0, 10.0, 8000.0, 0.03),
}


@pytest.mark.parametrize("label", sorted(INPUT_CHAINS))
def test_synthesize_through_a_chain_lowers_the_inputs_crest_factor(label):
    """``synthesize(..., transfer=)``: the die's tones as before, their phases chosen for
    the amplifier input, whose crest factor is below that of the die's optimised phases
    compensated afterwards (the same seed, loop and tones)."""
    from planner.synthesis.chain import ModelTransfer, compensate

    f_res, q, low_pass, fall = INPUT_CHAINS[label]
    transfer = ModelTransfer(1e-6, ((f_res, q),), low_pass)
    f = channel_subset(25, 4)
    z = tones_from_power(f)
    die = synthesize(f, z, FS, seed=0)
    wired = synthesize(f, z, FS, seed=0, transfer=transfer)
    assert wired.loop_length == die.loop_length
    assert np.array_equal(wired.frequencies, die.frequencies)
    assert np.array_equal(wired.amplitudes, die.amplitudes)
    before = compensate(die, transfer).crest_factor
    after = compensate(wired, transfer).crest_factor
    assert after <= (1 - fall) * before, (before, after)
    # the samples are still the die's tones (FFT)
    amps, phases = loop_spectrum(wired)
    np.testing.assert_allclose(amps, wired.amplitudes, rtol=1e-9)


def test_limited_phases_are_no_worse_than_the_dies_or_the_inputs():
    """With an input and an acceleration limit the phases minimise the largest peak
    relative to its limit: no higher than the die's own optimum's or the input's."""
    from planner.synthesis import optimise_phases, peak_of
    from planner.synthesis.chain import ModelTransfer

    transfer = ModelTransfer(1e-6, ((6000.0, 3.0),))
    f = channel_subset(25, 4)
    z = tones_from_power(f)
    die = synthesize(f, z, FS, seed=0)
    cycles = np.rint(die.frequencies * die.loop_length).astype(int)
    h = transfer.response(die.frequencies)
    w2 = (2 * np.pi * die.frequencies) ** 2

    def worst(ph, input_limit, acceleration_limit):
        return max(peak_of(cycles, z, ph) / 30e-6,
                   peak_of(cycles, w2 * z, ph) / acceleration_limit,
                   peak_of(cycles, z / np.abs(h), ph - np.angle(h)) / input_limit)

    input_phases = optimise_phases(cycles, z / np.abs(h), seed=0, offsets=-np.angle(h))
    # limits that bind in turn (the die's phases peak at 13.9 um, 2.1e4 m/s^2 and
    # 16.4 V): the input's, the acceleration's, both about equally
    for input_limit, acceleration_limit in ((5.0, 1e9), (1e3, 1e4), (16.0, 2.0e4)):
        got = synthesize(f, z, FS, seed=0, peak_limit=30e-6, transfer=transfer,
                         input_limit=input_limit, acceleration_limit=acceleration_limit)
        value = worst(got.phases, input_limit, acceleration_limit)
        assert value <= worst(die.phases, input_limit, acceleration_limit) * (1 + 1e-9)
        assert value <= worst(input_phases, input_limit, acceleration_limit) * (1 + 1e-6)
    with pytest.raises(ValueError, match="input_limit: .* needs the chain's transfer"):
        synthesize(f, z, FS, input_limit=1.0)
    with pytest.raises(ValueError, match="acceleration_limit must be positive"):
        synthesize(f, z, FS, transfer=transfer, acceleration_limit=0.0)


def test_optimise_peaks_is_no_higher_than_its_starts_and_checks_its_arguments():
    from planner.synthesis import peak_of
    from planner.synthesis.phases import optimise_peaks

    rng = np.random.default_rng(5)
    cycles = np.array([7, 11, 13, 17, 19, 23, 29])
    amps = rng.uniform(0.5, 2.0, (3, 7))
    offsets = rng.uniform(-np.pi, np.pi, (3, 7))
    starts = [rng.uniform(0, 2 * np.pi, 7) for _ in range(2)]

    def largest(ph):
        return max(peak_of(cycles, a, ph + o) for a, o in zip(amps, offsets))

    got = optimise_peaks(cycles, amps, offsets, seed=0, starts=starts)
    assert largest(got) <= min(largest(s) for s in starts)
    # deterministic for a seed
    assert np.array_equal(got, optimise_peaks(cycles, amps, offsets, seed=0, starts=starts))
    with pytest.raises(ValueError, match="offsets"):
        optimise_peaks(cycles, amps, offsets[:, :3])
    with pytest.raises(ValueError, match="starts"):
        optimise_peaks(cycles, amps, offsets, starts=[np.zeros(3)])
