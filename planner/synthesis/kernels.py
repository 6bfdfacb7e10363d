"""Kernels of drive synthesis: exact and gridded sums of cosines over one loop.

Kernels work in loop units: a tone is its whole number of cycles ``k`` per loop, time is
the loop fraction ``u`` in [0, 1).  They take plain numpy arrays (amplitudes [m], phases
[rad]) and know nothing of :class:`~planner.synthesis.waveform.Waveform` or of hertz.
They are vectorised numpy, not numba: each call is one matrix product of cosines or one
inverse real FFT, which numpy and scipy already run at full speed.
"""

from __future__ import annotations

import numpy as np
import scipy.fft

#: Points per cycle of the highest tone on the phase optimiser's FFT grid.  Eight points per
#: cycle keep the grid's L_p norms close to the continuous ones; the reported peak does not
#: rely on the grid (it is refined by Newton's method on the exact sum).
GRID_POINTS_PER_CYCLE = 8

#: Elements per block of the exact cosine sum (tones x samples), to bound memory.
BLOCK_ELEMENTS = 1 << 22


def _cosine_sum(cycles, n_points, amplitudes, phases) -> np.ndarray:
    """The exact sum of cosines on one loop's samples.

    Parameters
    ----------
    cycles : ndarray of int, shape (n_tones,)
        Whole cycles per loop of each tone.
    n_points : int
        Samples per loop.
    amplitudes : ndarray, shape (n_tones,)
        [m].
    phases : ndarray, shape (n_tones,)
        [rad].

    Returns
    -------
    ndarray, shape (n_points,)
        ``sum_i a_i cos(2 pi k_i n / N + phi_i)`` [m].

    Notes
    -----
    ``k n mod N`` is reduced in integers before the cosine, so every argument is exact to
    one rounding and sample ``n + N`` is bit-identical to sample ``n``.
    """
    k = np.asarray(cycles, dtype=np.int64)[:, None]
    out = np.empty(n_points)
    block = max(1, BLOCK_ELEMENTS // len(cycles))
    step = 2 * np.pi / n_points
    for start in range(0, n_points, block):
        n = np.arange(start, min(n_points, start + block), dtype=np.int64)
        arg = (k * n) % n_points * step + phases[:, None]
        out[start:start + len(n)] = amplitudes @ np.cos(arg)
    return out


def _cosines_at(cycles, amplitudes, phases, u):
    """``sum_i a_i cos(2 pi k_i u + phi_i)`` at loop fractions ``u``, shape (n_u,)."""
    out = np.empty(len(u))
    block = max(1, BLOCK_ELEMENTS // len(cycles))
    for start in range(0, len(u), block):
        uu = u[start:start + block]
        arg = 2 * np.pi * np.mod(np.outer(cycles, uu), 1.0) + phases[:, None]
        out[start:start + len(uu)] = amplitudes @ np.cos(arg)
    return out


def _grid_points(cycles) -> int:
    """FFT grid size for a loop whose highest tone makes ``max(cycles)`` cycles."""
    return scipy.fft.next_fast_len(int(GRID_POINTS_PER_CYCLE * max(cycles)), real=True)


def _grid_signal(cycles, amplitudes, phases, m) -> np.ndarray:
    """The loop on an m-point grid (exact, via one inverse real FFT), shape (m,)."""
    spectrum = np.zeros(m // 2 + 1, dtype=complex)
    spectrum[cycles] = 0.5 * m * amplitudes * np.exp(1j * phases)
    return scipy.fft.irfft(spectrum, m)


def _reduce(cycles):
    """Divide out the common factor of the cycle counts (the loop may hold several periods)."""
    g = int(np.gcd.reduce(np.asarray(cycles, dtype=np.int64)))
    return np.asarray(cycles, dtype=np.int64) // g

