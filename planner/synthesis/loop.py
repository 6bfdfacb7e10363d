"""The loop: the shortest whole number of samples in which every tone makes whole cycles.

A generator repeats the loop with no discontinuity.  Each frequency is snapped to the
loop's grid ``1 / L`` within a stated tolerance, and the shift is reported by
:func:`planner.synthesis.synthesize`.  Frequencies in Hz, lengths in samples or s.
"""

from __future__ import annotations

import math

import numpy as np

from planner.synthesis.kernels import BLOCK_ELEMENTS
from planner.synthesis.validation import _as_tone_array, _positive_float, _whole_samples

#: Default snapping tolerance, relative to each tone's frequency [-].  Response bands are a
#: few percent wide (paper notes), so a 0.1 % shift is far inside a channel; it allows loops
#: of about 0.25 s at 2 kHz and shorter ones for higher tones.  (A plan plays a single tone
#: within SINGLE_TONE_TOLERANCE_REL: planner.planning.drives.)
FREQUENCY_TOLERANCE_REL = 1e-3

#: Longest loop searched when no duration is given [s]; 1 s at 200 kS/s is 200 k points,
#: well inside a Keysight 33500B's standard 1 M-point memory.
MAX_LOOP_LENGTH = 1.0

#: Memory per point of the longest loop searched [bytes]: the candidate loop lengths
#: (int64), the loop's samples, their copies in an export and its read-back check.
LOOP_BYTES_PER_POINT = 48


def check_loop_memory(points: int, what: str) -> None:
    """Refuse, before allocating, a loop search or signal of ``points`` samples that the
    machine's memory cannot hold (:func:`planner.runtime.limits.check_memory`)."""
    from planner.runtime.limits import check_memory

    check_memory(LOOP_BYTES_PER_POINT * float(points), f"{what} ({points:.4g} points)")


def _tolerance(frequency_tolerance, f) -> np.ndarray:
    """Largest shift of each tone [Hz], shape (n_tones,): ``frequency_tolerance`` (a
    scalar or one per tone, >= 0) or by default ``FREQUENCY_TOLERANCE_REL * f``."""
    if frequency_tolerance is None:
        return FREQUENCY_TOLERANCE_REL * f
    tol = _as_tone_array(frequency_tolerance, "frequency_tolerance")
    if np.ndim(frequency_tolerance) == 0:
        tol = np.full(len(f), tol[0])
    if len(tol) != len(f):
        raise ValueError(f"frequency_tolerance: {len(tol)} values for {len(f)} frequencies")
    bad = np.nonzero(tol < 0)[0]
    if len(bad):
        raise ValueError(f"frequency_tolerance[{bad[0]}] must be >= 0, {tol[bad[0]]:g} was given")
    return tol


class LoopLengthError(ValueError):
    """No loop within the bound puts every tone within tolerance of whole cycles."""


def _loop_for(f, fs, tol, duration, max_loop_length):
    """The loop of :func:`planner.synthesis.synthesize`'s tones (its loop step).

    Parameters
    ----------
    f : ndarray, shape (n_tones,)
        Requested frequencies [Hz], validated.
    fs : float
        Sample rate [Hz].
    tol : ndarray, shape (n_tones,)
        Allowed shift per tone [Hz].
    duration : float or None
        Length of the samples [s]: the loop is the shortest whole fraction of it.  None:
        the samples are one loop, of at most ``max_loop_length``.
    max_loop_length : float
        Longest loop searched when ``duration`` is None [s].

    Returns
    -------
    loop_points : int
        Samples in one loop.
    cycles : ndarray of int, shape (n_tones,)
        Whole cycles of each tone in the loop.
    n_total : int or None
        Samples of ``duration``, None without one.

    Raises
    ------
    ValueError
        A bad ``duration`` or ``max_loop_length``, or a loop the memory cannot hold.
    LoopLengthError
        No candidate loop puts every tone within ``tol`` of whole cycles.
    """
    if duration is None:
        max_points = int(math.floor(_positive_float(max_loop_length, "max_loop_length") * fs))
        check_loop_memory(max_points, f"sample_rate {fs:g} Hz: a loop of up to "
                                      f"{max_loop_length:g} s")
        candidates = np.arange(1, max_points + 1)
        n_total = None
    else:
        n_total = _whole_samples(_positive_float(duration, "duration"), fs)
        check_loop_memory(n_total, f"sample_rate {fs:g} Hz for {duration:g} s")
        candidates = _divisors(n_total)
    loop_points, cycles = _choose_loop(f, fs, tol, candidates)
    if loop_points is None:
        bound = (f"{max_loop_length:g} s" if duration is None
                 else f"whole fractions of duration {duration:g} s")
        raise LoopLengthError(
            f"frequency_tolerance: no loop of {bound} at {fs:g} Hz puts every tone within "
            f"tolerance of a whole number of cycles; raise frequency_tolerance, "
            f"max_loop_length or duration")
    return loop_points, cycles, n_total


def _choose_loop(f, fs, tol, candidates):
    """The shortest candidate loop that holds every tone within tolerance.

    Parameters
    ----------
    f : ndarray, shape (n_tones,)
        Requested frequencies [Hz].
    fs : float
        Sample rate [Hz].
    tol : ndarray, shape (n_tones,)
        Allowed shift per tone [Hz].
    candidates : ndarray of int, ascending
        Loop lengths to try [samples].

    Returns
    -------
    loop_points : int or None
        The chosen loop [samples], None if no candidate fits.
    cycles : ndarray of int, shape (n_tones,)
        Whole cycles of each tone in the loop; ``f_snapped = cycles * fs / loop_points``.
    """
    order = np.argsort(f)
    fo, to = f[order], tol[order]
    block = max(1, BLOCK_ELEMENTS // (4 * len(f)))
    for start in range(0, len(candidates), block):
        n_pts = candidates[start:start + block].astype(float)[:, None]
        k = np.rint(fo * n_pts / fs)
        shift = k * fs / n_pts - fo
        ok = np.all(np.abs(shift) <= to * (1 + 1e-12), axis=1)
        ok &= k[:, 0] >= 1
        ok &= np.all(2 * k < n_pts, axis=1)
        ok &= np.all(np.diff(k, axis=1) > 0, axis=1)  # distinct tones stay distinct
        hit = np.nonzero(ok)[0]
        if len(hit):
            j = int(hit[0])
            cycles = np.empty(len(f), dtype=np.int64)
            cycles[order] = k[j].astype(np.int64)
            return int(candidates[start + j]), cycles
    return None, None


def _divisors(n: int) -> np.ndarray:
    """All divisors of ``n``, ascending."""
    small = [d for d in range(1, math.isqrt(n) + 1) if n % d == 0]
    return np.array(sorted(set(small) | {n // d for d in small}), dtype=np.int64)

