"""Gated bursts: a step's tones played once, each switched on and off at its own time.

A step with targets (``scenes.<scene>[].targets_um``) cannot play its summed drive until
the slowest slider has gone far enough: the faster ones would overshoot.  So each tone
gets its own envelope: it fades in over the ramp R from its start s_i, plays at full
amplitude, and fades out over R from its gate t_i, after which it is silent:

    zeta(t) = sum_i Z_i g_i(t) cos(2 pi f_i t + phi_i)

    g_i(t) = 0                                    t < s_i
           = (1 - cos(pi (t - s_i) / R)) / 2      s_i <= t < s_i + R     (fade in)
           = 1                                    s_i + R <= t < t_i
           = (1 + cos(pi (t - t_i) / R)) / 2      t_i <= t < t_i + R     (fade out)
           = 0                                    t >= t_i + R

(a tone with t_i = 0 is not played; t_i >= s_i + R otherwise).  The phases are those of
the step's summed drive, counted from t = 0 of the burst.  The raised-cosine ramps start and end with zero
slope, so zeta and zeta' are continuous everywhere: no click, and the burst starts and
ends at rest.  zeta'' steps by at most Z (pi / R)^2 / 2 at a ramp's ends, a fraction
(f R)^-2 / 8 of the tone's own w^2 Z.

During a ramp the envelope is a + b cos(W (t - t0)) with W = pi / R, so

    Z g cos(w t + phi) = a Z cos(w t + phi) + (b / 2) Z cos((w + W) t + phi - W t0)
                         + (b / 2) Z cos((w - W) t + phi + W t0),

an exact sum of constant tones.  Between two successive ramp edges the burst is such a
sum, which is a :class:`model.Drive`: :meth:`Burst.program` gives the burst as that
sequence of (duration, Drive) stretches, each with its phases advanced to its own start,
and the simulation plays them in turn with the state carried across (exactly the sum
above, no approximation).  The exported samples are the same sum at t = n / fs.

Everything is in SI units: m, s, Hz, rad.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

import model
from planner.synthesis import Waveform

#: Samples per period of the highest tone on the coarse grid of :func:`tone_peaks`.
PEAK_SAMPLES_PER_PERIOD = 16
#: Grid points per block of :func:`tone_peaks` (memory bound) and the grid maxima kept
#: from each block, of which the highest :data:`PEAK_REFINED` are refined.
PEAK_BLOCK = 200_000
PEAK_PER_BLOCK = 4
PEAK_REFINED = 8


def envelopes(t, starts_s, gates_s, ramp_s):
    """The envelope g_i(t) of every tone (see the module docstring).

    Parameters
    ----------
    t : array_like, shape (n_t,)
        Times [s] from the start of the burst.
    starts_s : array_like, shape (n_tones,)
        Each tone's start s_i [s].
    gates_s : array_like, shape (n_tones,)
        Each tone's gate t_i [s] (0: not played).
    ramp_s : float
        R [s].

    Returns
    -------
    ndarray, shape (n_tones, n_t)
        g_i(t) in [0, 1].

    Examples
    --------
    >>> g = envelopes([0.0, 0.5e-3, 1e-3, 2e-3, 2.5e-3, 3e-3], [0.0], [2e-3], 1e-3)
    >>> [round(float(x), 3) for x in g[0]]
    [0.0, 0.5, 1.0, 1.0, 0.5, 0.0]
    """
    t = np.atleast_1d(np.asarray(t, dtype=float))[None, :]
    starts = np.asarray(starts_s, dtype=float)[:, None]
    gates = np.asarray(gates_s, dtype=float)[:, None]
    w = math.pi / ramp_s
    rise = np.where(t < starts + ramp_s,
                    0.5 - 0.5 * np.cos(w * np.clip(t - starts, 0.0, ramp_s)), 1.0)
    fall = np.where(t < gates, 1.0,
                    np.where(t < gates + ramp_s,
                             0.5 + 0.5 * np.cos(w * np.clip(t - gates, 0.0, ramp_s)), 0.0))
    g = np.where(t < starts, 0.0, rise * fall)
    return np.where(gates > 0.0, g, 0.0)


def burst_samples(frequencies, amplitudes, phases, starts_s, gates_s, ramp_s, t):
    """zeta(t) [m] of a gated burst (the module docstring's sum), shape of ``t``.

    The one evaluation of a burst: :func:`gate` samples it, and
    :func:`planner.lab.exporters.verify_export` checks a file against it.
    """
    t = np.atleast_1d(np.asarray(t, dtype=float))
    f = np.asarray(frequencies, dtype=float)
    a = np.asarray(amplitudes, dtype=float)
    ph = np.asarray(phases, dtype=float)
    out = np.zeros(t.size)
    block = max(1, (1 << 22) // max(1, f.size))
    for start in range(0, t.size, block):
        tt = t[start:start + block]
        g = envelopes(tt, starts_s, gates_s, ramp_s)
        arg = 2.0 * np.pi * np.mod(np.outer(f, tt), 1.0) + ph[:, None]
        out[start:start + tt.size] = np.sum(a[:, None] * g * np.cos(arg), axis=0)
    return out


@dataclass(frozen=True)
class Burst(Waveform):
    """A step's drive played once: its tones with the envelopes of the module docstring.

    A :class:`~planner.synthesis.Waveform` whose ``samples`` hold the whole burst (from
    t = 0 to the end of the last fade-out, both at zero displacement), played once, not
    looped; ``loop_length`` is the file's length.  ``frequencies``, ``amplitudes`` and
    ``phases`` are the tones at full amplitude (the step's summed drive, as synthesised).

    Attributes
    ----------
    starts_s : ndarray, shape (n_tones,)
        Each tone's start s_i: where its fade-in starts [s], on the sample grid.
    gates_s : ndarray, shape (n_tones,)
        Each tone's gate t_i: where its fade-out starts [s]; 0 for a tone not played.
        On the sample grid, and at least ``starts_s + ramp_s`` for a played tone.
    ramp_s : float
        R, the length of every fade-in and fade-out [s], on the sample grid.
    """

    starts_s: np.ndarray | None = None
    gates_s: np.ndarray | None = None
    ramp_s: float = 0.0

    def __post_init__(self):
        super().__post_init__()
        if self.gates_s is None or self.starts_s is None:
            raise ValueError("starts_s and gates_s must be given: one of each [s] per tone")
        for name in ("starts_s", "gates_s"):
            arr = np.array(getattr(self, name), dtype=float)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        _check_gates(self.starts_s, self.gates_s, float(self.ramp_s), len(self.frequencies))

    @property
    def length_s(self) -> float:
        """The burst's length: the end of its last fade-out [s]."""
        return float(np.max(self.gates_s)) + self.ramp_s

    @property
    def played(self) -> np.ndarray:
        """Whether each tone is played (its gate is not 0), shape (n_tones,)."""
        return self.gates_s > 0.0

    def evaluate(self, t) -> np.ndarray:
        """zeta(t) [m] at arbitrary times ``t`` [s] (0 outside the burst)."""
        t = np.asarray(t, dtype=float)
        return burst_samples(self.frequencies, self.amplitudes, self.phases, self.starts_s,
                             self.gates_s, self.ramp_s, t.ravel()).reshape(t.shape)

    def program(self):
        """The burst as stretches of constant tones (see the module docstring).

        Returns
        -------
        tuple of (float, model.Drive)
            (duration [s], drive) of every stretch between two ramp edges, in order;
            each drive's phases are advanced to the stretch's start, so playing them in
            turn from t = 0 gives zeta(t) exactly.
        """
        return stretches(self.frequencies, self.amplitudes, self.phases, self.starts_s,
                         self.gates_s, self.ramp_s)


def _check_gates(starts, gates, ramp_s, n_tones):
    for name, arr in (("starts_s", starts), ("gates_s", gates)):
        if arr.shape != (n_tones,):
            raise ValueError(f"{name}: {arr.size} values for {n_tones} tones")
        if not np.all(np.isfinite(arr)) or np.any(arr < 0):
            raise ValueError(f"{name} must be finite and >= 0, {arr.tolist()!r} was given")
    if not (math.isfinite(ramp_s) and ramp_s > 0):
        raise ValueError(f"ramp_s must be positive and finite, {ramp_s!r} was given")
    short = (gates > 0) & (gates < (starts + ramp_s) * (1 - 1e-9))
    if np.any(short):
        i = int(np.nonzero(short)[0][0])
        raise ValueError(f"gates_s[{i}] = {gates[i]:g} s: a played tone's gate must be at "
                         f"least its start plus the ramp, {starts[i] + ramp_s:g} s (its "
                         "fade-in ends there)")
    if not np.any(gates > 0):
        raise ValueError("gates_s: no tone is played (every gate is 0)")


def stretches(frequencies, amplitudes, phases, starts_s, gates_s, ramp_s):
    """:meth:`Burst.program` of the given tones, starts and gates (see there)."""
    f = np.asarray(frequencies, dtype=float)
    a = np.asarray(amplitudes, dtype=float)
    ph = np.asarray(phases, dtype=float)
    starts = np.asarray(starts_s, dtype=float)
    gates = np.asarray(gates_s, dtype=float)
    _check_gates(starts, gates, float(ramp_s), f.size)
    played = gates > 0
    end = float(gates.max()) + ramp_s
    edges = sorted({0.0, end} | {float(s) for s in starts[played]}
                   | {float(s) + ramp_s for s in starts[played]}
                   | {float(g) for g in gates[played]}
                   | {float(g) + ramp_s for g in gates[played]})
    side = 1.0 / (2.0 * ramp_s)            # W / (2 pi) [Hz]
    w = math.pi / ramp_s                   # W [rad/s]
    out = []
    for s0, s1 in zip(edges[:-1], edges[1:]):
        if s1 - s0 <= 0.0:
            continue
        mid = 0.5 * (s0 + s1)
        freqs, amps, phis = [], [], []
        for i in np.nonzero(played)[0]:
            if mid < starts[i] or mid >= gates[i] + ramp_s:
                continue                                   # silent
            if mid < starts[i] + ramp_s:
                # fade in: 1/2 - 1/2 cos(W (t - s_i))
                half, t0 = -0.5, float(starts[i])
            elif mid >= gates[i]:
                half, t0 = 0.5, float(gates[i])            # fade out
            else:
                freqs.append(f[i])
                amps.append(a[i])
                phis.append(ph[i])
                continue
            # a + b cos(W (t - t0)) with a = 1/2, b = half: a negative b is a positive
            # amplitude half a turn later
            turn = math.pi if half < 0 else 0.0
            freqs += [f[i], f[i] + side, f[i] - side]
            amps += [0.5 * a[i], 0.25 * a[i], 0.25 * a[i]]
            phis += [ph[i], ph[i] - w * t0 + turn, ph[i] + w * t0 + turn]
        if not freqs:
            # a pause between tones (possible only if starts leave one): the drive off
            out.append((s1 - s0, model.Drive([1.0], [0.0])))
            continue
        freqs = np.array(freqs)
        # advance every component to the stretch's start (the simulation of a phase
        # starts its clock at 0)
        shifted = np.mod(np.array(phis) + 2.0 * np.pi * freqs * s0, 2.0 * np.pi)
        out.append((s1 - s0, model.Drive(freqs, np.array(amps), shifted)))
    return tuple(out)


def gate(waveform: Waveform, starts_s, gates_s, ramp_s) -> Burst:
    """The burst of ``waveform``'s tones with the given starts and gates.

    Parameters
    ----------
    waveform : Waveform
        The step's summed drive (a loop from :func:`planner.synthesis.synthesize`).
    starts_s : array_like, shape (n_tones,)
        Each tone's start [s].  Rounded to the sample grid.
    gates_s : array_like, shape (n_tones,)
        Each tone's gate [s]: 0 (not played) or at least its start plus ``ramp_s``.
        Rounded to the sample grid.
    ramp_s : float
        The fade-in and fade-out length [s], rounded to the sample grid.

    Returns
    -------
    Burst
        Its samples from t = 0 to the end of the last fade-out inclusive, its peak over
        continuous time (:func:`burst_peaks`), and the ``rms`` of its samples and
        ``crest_factor`` = peak / rms (what the burst plays, not the tones' sum).

    Examples
    --------
    >>> from planner.synthesis import synthesize
    >>> w = synthesize([3000.0, 5000.0], 1e-6, 200e3, seed=0)
    >>> b = gate(w, [0.0, 1e-3], [4e-3, 2e-3], 1e-3)
    >>> b.length_s, len(b.samples), abs(float(b.samples[0])), abs(float(b.samples[-1]))
    (0.005, 1001, 0.0, 0.0)
    """
    if isinstance(waveform, Burst):
        raise ValueError("waveform is already a burst: gate its loop")
    fs = float(waveform.sample_rate)
    ramp = round(float(ramp_s) * fs) / fs
    starts = np.rint(np.asarray(starts_s, dtype=float) * fs) / fs
    gates = np.rint(np.asarray(gates_s, dtype=float) * fs) / fs
    _check_gates(starts, gates, ramp, len(waveform.frequencies))
    n = int(round((float(gates.max()) + ramp) * fs))
    t = np.arange(n + 1) / fs
    samples = burst_samples(waveform.frequencies, waveform.amplitudes, waveform.phases,
                            starts, gates, ramp, t)
    peak, _ = program_peaks(stretches(waveform.frequencies, waveform.amplitudes,
                                      waveform.phases, starts, gates, ramp))
    peak = max(peak, float(np.max(np.abs(samples))))
    # the burst's own rms (the tones take turns: their sum's rms never plays)
    rms = float(np.sqrt(np.mean(samples ** 2)))
    note = (f"a burst played once ({n + 1} samples): every tone fades in over "
            f"{ramp * 1e3:g} ms from its own start and out from its own gate")
    return Burst(samples=samples, sample_rate=fs, frequencies=waveform.frequencies,
                 amplitudes=waveform.amplitudes, phases=waveform.phases,
                 crest_factor=peak / rms, loop_length=(n + 1) / fs, peak=peak,
                 rms=rms, scale=waveform.scale,
                 frequency_shift=waveform.frequency_shift,
                 warnings=tuple(waveform.warnings) + (note,), starts_s=starts,
                 gates_s=gates, ramp_s=ramp)


def tone_peaks(frequencies, amplitudes, phases, span):
    """(peak |zeta| [m], peak |zeta''| [m/s^2]) of a sum of constant tones over [0, span].

    zeta(t) = sum Z_i cos(w_i t + phi_i) and zeta''(t) = -sum w_i^2 Z_i cos(w_i t +
    phi_i) on a grid of :data:`PEAK_SAMPLES_PER_PERIOD` points per period of the
    highest tone over the span, then refined near each of the largest grid maxima by a
    bounded scalar search (the bound sum w_i^2 Z_i is only reached if every tone peaks
    together, which a low-crest-factor drive avoids by construction).

    Parameters
    ----------
    frequencies, amplitudes, phases : array_like, shape (n,)
        [Hz], [m], [rad].
    span : float
        [s].
    """
    from scipy.optimize import minimize_scalar

    f = np.asarray(frequencies, dtype=float)
    z = np.asarray(amplitudes, dtype=float)
    ph = np.asarray(phases, dtype=float)
    w = 2.0 * np.pi * f
    span = float(span)
    dt = 1.0 / (PEAK_SAMPLES_PER_PERIOD * f.max())
    n = max(1, min(int(math.ceil(span / dt)), 4_000_000))
    dt = span / n
    out = []
    for weight in (z, w * w * z):
        def value(t, weight=weight):
            return abs(float(np.sum(weight * np.cos(w * t + ph))))
        best = 0.0
        cands = []
        for start in range(0, n, PEAK_BLOCK):
            t = (np.arange(start, min(n, start + PEAK_BLOCK)) * dt)
            y = np.abs(np.cos(np.outer(t, w) + ph) @ weight)
            top = np.argsort(y)[-PEAK_PER_BLOCK:]
            cands += [(float(y[i]), float(t[i])) for i in top]
        for _, t0 in sorted(cands)[-PEAK_REFINED:]:
            res = minimize_scalar(lambda t: -value(t), bounds=(t0 - dt, t0 + dt),
                                  method="bounded", options={"xatol": dt * 1e-6})
            best = max(best, value(t0), -float(res.fun))
        out.append(best)
    return out[0], out[1]


def program_peaks(program):
    """(peak |zeta| [m], peak |zeta''| [m/s^2]) of a program of (duration, Drive)
    stretches (:meth:`Burst.program`): the largest of :func:`tone_peaks` over each.

    A stretch's refined peak may lie a grid step beyond its end; the drive there is a
    continuation of the same tones, so the peak is at most that much pessimistic.
    """
    zp = ap = 0.0
    for duration, drive in program:
        live = drive.amplitudes > 0
        if not np.any(live):
            continue
        z, a = tone_peaks(drive.frequencies[live], drive.amplitudes[live],
                          drive.phases[live], duration)
        zp, ap = max(zp, z), max(ap, a)
    return zp, ap


def burst_peaks(burst: Burst):
    """(peak |zeta| [m], peak |zeta''| [m/s^2]) of a burst over continuous time."""
    return program_peaks(burst.program())


__all__ = ["Burst", "burst_peaks", "burst_samples", "envelopes", "gate", "program_peaks",
           "stretches", "tone_peaks"]
