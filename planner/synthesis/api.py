"""The public face of drive synthesis: :func:`synthesize` one step's drive as a seamless
loop, :func:`split_tones` a step into sub-steps that each fit the piezo's limit, and
:func:`tones_from_power` the paper's amplitude convention.

:func:`synthesize` runs four steps, each in its own module: the arguments are checked
(:mod:`~planner.synthesis.validation`), the loop is chosen and the tones snapped to it
(:mod:`~planner.synthesis.loop`), the phases are optimised for a low crest factor
(:mod:`~planner.synthesis.phases`) and the continuous peak is found
(:mod:`~planner.synthesis.peak`); then the amplitudes are scaled to the peak limit if
need be, and the samples are summed (:mod:`~planner.synthesis.kernels`).  SI units:
m, s, Hz, rad.
"""

from __future__ import annotations

import copy
import math

import numpy as np

import model
from model.drive import POWER as DEFAULT_POWER  # Z0^2 w^3 = 50 m^2/s^3, the paper's convention
from model.drive import amplitude_from_power
from planner.core.rng import as_generator
from planner.synthesis.kernels import _cosine_sum
from planner.synthesis.loop import MAX_LOOP_LENGTH, _loop_for, _tolerance
from planner.synthesis.peak import peak_of
from planner.synthesis.phases import N_STARTS, _wrap, optimise_peaks, optimise_phases
from planner.synthesis.validation import _as_tone_array, _check_positive, _positive_float
from planner.synthesis.waveform import Waveform

#: Crest factor :func:`split_tones` assumes when it first guesses how many sub-steps a
#: step needs (optimistic; it adds sub-steps until every one fits).
SPLIT_CREST_GUESS = 2.0


def tones_from_power(frequencies, power: float = DEFAULT_POWER) -> np.ndarray:
    """Tone amplitudes from the power convention ``Z^2 w^3 = power``.

    Parameters
    ----------
    frequencies : array_like, shape (n_tones,)
        Tone frequencies [Hz], positive.
    power : float, optional
        ``Z^2 w^3`` per tone [m^2/s^3]; the paper's 50 by default.

    Returns
    -------
    ndarray, shape (n_tones,)
        Amplitudes ``Z = sqrt(power / w^3)`` [m], ``w = 2 pi f``.

    Examples
    --------
    >>> round(float(tones_from_power([5000.0])[0]) * 1e6, 2)   # um, as in the paper notes
    1.27
    """
    f = _as_tone_array(frequencies, "frequencies")
    _check_positive(f, "frequencies")
    return amplitude_from_power(f, _positive_float(power, "power"))


def synthesize(frequencies, amplitudes, sample_rate, duration=None, seed=None, peak_limit=None,
               *, phases=None, frequency_tolerance=None, max_loop_length=MAX_LOOP_LENGTH,
               n_starts=N_STARTS, transfer=None, input_limit=None,
               acceleration_limit=None) -> Waveform:
    """Synthesise one step's drive: summed tones with minimum crest factor, as a seamless loop.

    Parameters
    ----------
    frequencies : array_like, shape (n_tones,)
        Tone frequencies [Hz]: finite, positive, distinct, below ``sample_rate / 2``.
    amplitudes : array_like, shape (n_tones,), float or None
        Tone amplitudes [m], positive; a scalar gives every tone the same amplitude;
        ``None`` uses the power convention (:func:`tones_from_power`, 50 m^2/s^3).
    sample_rate : float
        Sample rate [Hz].
    duration : float, optional
        Length of the samples [s]; it must hold a whole number of samples, and the loop is
        the shortest one that divides it.  By default the samples are one loop, the
        shortest of at most ``max_loop_length``.
    seed : None, int or numpy.random.Generator, optional
        Seeds the extra random starting points of the phase optimisation (see
        :func:`as_generator`); the same seed gives identical samples.
    peak_limit : float, optional
        The piezo's peak displacement [m].  If the optimised peak exceeds it, all
        amplitudes are scaled down by one factor (recorded in ``scale`` and ``warnings``);
        the signal is never clipped.
    phases : array_like, shape (n_tones,), optional
        Use these phases at ``t = 0`` [rad] instead of optimising (e.g. a verified plan's).
    frequency_tolerance : float or array_like, optional
        Largest allowed shift of each tone when snapping to the loop grid [Hz]; by default
        ``FREQUENCY_TOLERANCE_REL * frequencies`` (0.1 %).
    max_loop_length : float, optional
        Longest loop searched when ``duration`` is None [s].
    n_starts : int, optional
        Starting points of the phase optimisation: Schroeder's phases, then random ones.
    transfer : object, optional
        A drive chain's transfer ``H(f)`` [m/V] (anything with ``response(frequency_hz)``
        -> complex, as :class:`planner.synthesis.chain.ModelTransfer`), from the volts
        at the amplifier's input to the die's displacement.  The phases are then chosen
        for the peak of the *input* that plays the die's tones (each tone
        ``Z_i / |H(f_i)|`` at ``phi_i - arg H(f_i)``, at the snapped frequencies:
        :func:`planner.synthesis.chain.compensate`) as well as the die's (see Notes).
        The waveform is still the die's: its ``crest_factor`` and ``peak`` are the
        die's, ``peak_limit`` applies at the die.
    input_limit : float, optional
        The amplifier input's peak limit [V] (with ``transfer``).  It only weighs the
        input's peak against the die's limits when choosing the phases; nothing is
        scaled to it here (:func:`planner.planning.chain.limit_input` does that).
    acceleration_limit : float, optional
        The die's peak acceleration limit [m/s^2], weighed as ``input_limit`` is (and
        enforced by :func:`planner.planning.drives.limit_acceleration`).

    Returns
    -------
    Waveform

    Raises
    ------
    ValueError
        On a bad argument (the message names it).
    LoopLengthError
        A ValueError: no loop within the bound puts every tone within
        ``frequency_tolerance`` of a whole number of cycles.

    Notes
    -----
    Without ``transfer`` and ``acceleration_limit`` the phases minimise the die's crest
    factor (:func:`optimise_phases`).  With either, each limited peak counts relative to
    its limit, since the one nearest its limit sets every tone's amplitude: the phases
    minimise ``max(peak / peak_limit, peak acceleration / acceleration_limit, input
    peak / input_limit)`` over the limits given (:func:`optimise_peaks`), starting also
    from the die's optimum and the input's, so no worse than either.  An input without
    a limit counts relative to the peak it has under the die's optimal phases: it never
    peaks higher than that unless a die's limit binds harder.

    The crest factor that a set of phases can reach depends on the loop: a loop of length
    L holds about ``2 f_max L`` independent extrema that n phases must hold down, so longer
    loops (smaller tolerances) give higher crest factors.  See ``benchmarks/crest_factor.py``.

    Examples
    --------
    >>> wf = synthesize([3000.0, 5000.0, 7000.0], 1e-6, 200e3, seed=0)
    >>> wf.loop_length, round(wf.rms * 1e6, 4)
    (0.001, 1.2247)
    """
    f, fs, a, peak_limit, phases, tol = _checked_arguments(
        frequencies, amplitudes, sample_rate, peak_limit, phases, frequency_tolerance, n_starts)
    if input_limit is not None:
        if transfer is None:
            raise ValueError("input_limit: the amplifier input's limit needs the chain's "
                             "transfer (transfer=)")
        input_limit = _positive_float(input_limit, "input_limit")
    if acceleration_limit is not None:
        acceleration_limit = _positive_float(acceleration_limit, "acceleration_limit")
    rng = as_generator(seed)
    loop_points, cycles, n_total = _loop_for(f, fs, tol, duration, max_loop_length)
    loop_length = loop_points / fs
    f_snapped = cycles * fs / loop_points

    if phases is None and (transfer is not None or acceleration_limit is not None):
        ph = _limited_phases(cycles, f_snapped, a, rng, n_starts, peak_limit, transfer,
                             input_limit, acceleration_limit)
    elif phases is None:
        ph = optimise_phases(cycles, a, seed=rng, n_starts=n_starts)
    else:
        ph = np.asarray(phases, dtype=float)
    ph = _wrap(ph)
    peak = peak_of(cycles, a, ph)
    rms = math.sqrt(float(np.sum(a**2)) / 2)
    crest = peak / rms
    scale, warnings = _limit_scale(peak, peak_limit, crest)
    a, peak, rms = a * scale, peak * scale, rms * scale     # x * 1.0 is x, bit for bit

    loop = _cosine_sum(cycles, loop_points, a, ph)
    n_loops = 1 if n_total is None else n_total // loop_points
    samples = np.tile(loop, n_loops) if n_loops > 1 else loop
    return Waveform(samples=samples, sample_rate=fs, frequencies=f_snapped, amplitudes=a,
                    phases=ph, crest_factor=crest, loop_length=loop_length, peak=peak, rms=rms,
                    scale=scale, frequency_shift=f_snapped - f, warnings=tuple(warnings))


def _limited_phases(cycles, f, a, rng, n_starts, peak_limit, transfer, input_limit,
                    acceleration_limit):
    """The phases of the smallest largest peak relative to its limit (see
    :func:`synthesize`'s Notes): ``cycles``, ``f`` [Hz] and ``a`` [m] the snapped tones.

    Raises
    ------
    ValueError
        A transfer not finite and nonzero at a tone (naming it).
    """
    # the die's own optimum first, from the same draws as without a chain; the input's
    # from the same random starts
    same = copy.deepcopy(rng)
    die = optimise_phases(cycles, a, seed=rng, n_starts=n_starts)
    if len(a) == 1:
        return die              # one tone: every peak is its amplitude, whatever the phase
    starts, rows, offsets = [die], [], []
    if peak_limit is not None:
        rows.append(a / peak_limit)
        offsets.append(np.zeros(len(a)))
    if acceleration_limit is not None:
        rows.append((2 * np.pi * f) ** 2 * a / acceleration_limit)
        offsets.append(np.zeros(len(a)))
    if transfer is not None:
        h = np.asarray(transfer.response(f), dtype=complex)
        bad = np.nonzero(~np.isfinite(h) | (h == 0))[0]
        if len(bad):
            i = int(bad[0])
            raise ValueError(f"transfer: H({f[i]:g} Hz) = {h[i]}: a tone needs a finite, "
                             "nonzero transfer to be played")
        v, turn = a / np.abs(h), -np.angle(h)
        starts.append(optimise_phases(cycles, v, seed=same, n_starts=n_starts, offsets=turn))
        # no input limit: the input counts relative to its peak under the die's phases
        limit = peak_of(cycles, v, die + turn) if input_limit is None else input_limit
        rows.append(v / limit)
        offsets.append(turn)
    return optimise_peaks(cycles, np.array(rows), np.array(offsets), seed=rng,
                          n_starts=n_starts, starts=starts)


def _checked_arguments(frequencies, amplitudes, sample_rate, peak_limit, phases,
                       frequency_tolerance, n_starts):
    """:func:`synthesize`'s arguments checked, in SI: ``(f, fs, a, peak_limit, phases,
    tol)`` (``phases`` and ``peak_limit`` None when not given).

    Raises
    ------
    ValueError
        Naming the first bad argument, in the order of :func:`synthesize`'s parameters.
    """
    f = _as_tone_array(frequencies, "frequencies")
    n = len(f)
    fs = _positive_float(sample_rate, "sample_rate")
    _check_positive(f, "frequencies")
    above = np.nonzero(f >= fs / 2)[0]
    if len(above):
        i = int(above[0])
        raise ValueError(f"frequencies[{i}] = {f[i]:g} Hz is at or above the Nyquist frequency "
                         f"{fs / 2:g} Hz of sample_rate {fs:g} Hz: raise sample_rate")
    if len(np.unique(f)) != n:
        raise ValueError("frequencies must be distinct: a repeated tone is one tone")
    a = _tone_amplitudes(amplitudes, f)
    # the model's unit checks at the edge: tones in Hz (not kHz), amplitudes and the
    # peak limit in m (not um)
    model.Drive(f, a)
    if peak_limit is not None:
        peak_limit = _positive_float(peak_limit, "peak_limit")
        model.Drive([f[0]], [peak_limit])
    if phases is not None:
        phases = _as_tone_array(phases, "phases")
        if len(phases) != n:
            raise ValueError(f"phases: {len(phases)} values for {n} frequencies")
    tol = _tolerance(frequency_tolerance, f)
    if n_starts < 1:
        raise ValueError(f"n_starts must be at least 1, {n_starts} was given")
    return f, fs, a, peak_limit, phases, tol


def _limit_scale(peak, peak_limit, crest) -> tuple[float, list[str]]:
    """The factor on every amplitude that brings ``peak`` [m] down to ``peak_limit`` [m]
    (1 when it fits or there is no limit), and the warning that says so."""
    if peak_limit is None or not peak > peak_limit:
        return 1.0, []
    scale = peak_limit / peak
    return scale, [
        f"peak {peak * 1e6:.4g} um exceeds peak_limit {peak_limit * 1e6:.4g} um at crest "
        f"factor {crest:.3f}: every amplitude scaled by {scale:.4f} (not clipped); "
        f"split_tones() splits the step into sub-steps instead"]


def split_tones(frequencies, amplitudes, sample_rate, peak_limit, *, seed=None,
                **options) -> list[tuple[np.ndarray, Waveform]]:
    """Split a step's tones into sub-steps whose drives each fit within the piezo's limit.

    The alternative to scaling: instead of lowering every amplitude, play the tones in
    groups, one after the other, each at full amplitude.

    Parameters
    ----------
    frequencies, amplitudes, sample_rate, seed
        As in :func:`synthesize`.
    peak_limit : float
        The piezo's peak displacement [m].
    **options
        Passed to :func:`synthesize` (``duration``, ``frequency_tolerance``, ...).

    Returns
    -------
    list of (ndarray, Waveform)
        For every sub-step, the indices of its tones (into ``frequencies``) and its
        synthesised drive, whose ``peak`` is at most ``peak_limit`` and ``scale`` is 1.

    Raises
    ------
    ValueError
        If a single tone's amplitude already exceeds ``peak_limit``.

    Notes
    -----
    Tones are dealt to sub-steps largest power first, each to the sub-step with the least
    power so far, so every sub-step gets about the same rms.  The number of sub-steps starts
    at the least that could fit at crest factor ``SPLIT_CREST_GUESS`` and grows by one until
    every optimised sub-step fits.
    """
    f = _as_tone_array(frequencies, "frequencies")
    a = _tone_amplitudes(amplitudes, f)
    limit = _positive_float(peak_limit, "peak_limit")
    if np.any(a > limit):
        i = int(np.argmax(a))
        raise ValueError(f"amplitudes[{i}] = {a[i]:g} m alone exceeds peak_limit {limit:g} m: "
                         f"no split can fit it; lower it")
    rng = as_generator(seed)
    n_groups = max(1, math.ceil(float(np.sum(a**2)) / 2 * (SPLIT_CREST_GUESS / limit) ** 2))
    order = np.argsort(-a, kind="stable")
    while True:
        groups = [[] for _ in range(min(n_groups, len(f)))]
        power = np.zeros(len(groups))
        for i in order:
            g = int(np.argmin(power))
            groups[g].append(i)
            power[g] += a[i] ** 2
        result = []
        for g in groups:
            idx = np.sort(np.array(g))
            wf = synthesize(f[idx], a[idx], sample_rate, seed=rng, **options)
            if wf.peak > limit:
                break
            result.append((idx, wf))
        else:
            return result
        n_groups += 1



def _tone_amplitudes(amplitudes, f) -> np.ndarray:
    if amplitudes is None:
        return tones_from_power(f)
    a = _as_tone_array(amplitudes, "amplitudes")
    if np.ndim(amplitudes) == 0:
        a = np.full(len(f), a[0])
    if len(a) != len(f):
        raise ValueError(f"amplitudes: {len(a)} values for {len(f)} frequencies")
    _check_positive(a, "amplitudes")
    return a

