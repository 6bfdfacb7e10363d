"""Drive synthesis: the summed-tone substrate displacement of one step, as a seamless loop.

A step drives every impacter that must move with its own tone, all at once, through one
piezo shaker.  The substrate displacement is

    zeta(t) = sum_i Z_i cos(2 pi f_i t + phi_i)                                   (5)

(the paper's eq. (5) summed over tones).  The piezo has a peak-displacement limit, so the
*phases* decide how much amplitude every tone can get: the peak of the sum is what hits
the limit, and the rms (which fixes the tones' amplitudes) is phase-independent.  This
module chooses

- the **loop**: a whole number of samples in which every tone makes a whole number of
  cycles, so that a generator can repeat it with no discontinuity.  Each frequency is
  snapped to the loop's grid ``1 / L`` within a stated tolerance and the shift is reported;
- the **phases**: minimum crest factor (peak / rms), starting from Schroeder's phases and
  improving by L_p-norm minimisation with p raised toward infinity, finished by a minimax
  (L_inf) polish; deterministic for a seed;
- the **scale**: if the optimised peak still exceeds the piezo's limit, every amplitude is
  scaled down by one reported factor (never clipped); :func:`split_tones` offers the
  alternative of splitting a step into sub-steps that each fit.

Everything is in SI units: m, s, Hz, rad.  The phase optimisation evaluates the loop on an
oversampled FFT grid; the samples themselves are an exact sum of cosines, with the
argument reduced in integers so the loop repeats bit for bit.

References
----------
.. [1] M. R. Schroeder, "Synthesis of low-peak-factor signals and binary sequences with
   low autocorrelation", IEEE Trans. Inf. Theory 16(1), 85-89, 1970.
.. [2] P. Guillaume, J. Schoukens, R. Pintelon, I. Kollar, "Crest-factor minimization using
   nonlinear Chebyshev approximation methods", IEEE Trans. Instrum. Meas. 40(6), 982-989, 1991.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy.fft
from scipy.optimize import linprog, minimize, minimize_scalar

import model

from model.drive import POWER as DEFAULT_POWER  # Z0^2 w^3 = 50 m^2/s^3, the paper's convention
from model.drive import amplitude_from_power

#: Default snapping tolerance, relative to each tone's frequency [-].  Response bands are a
#: few percent wide (paper notes), so a 0.1 % shift is far inside a channel; it allows loops
#: of about 0.25 s at 2 kHz and shorter ones for higher tones.  (A plan plays a single tone
#: within SINGLE_TONE_TOLERANCE_REL: planner.planning.drives.)
FREQUENCY_TOLERANCE_REL = 1e-3

#: Longest loop searched when no duration is given [s]; 1 s at 200 kS/s is 200 k points,
#: well inside a Keysight 33500B's standard 1 M-point memory.
MAX_LOOP_LENGTH = 1.0

#: Points per cycle of the highest tone on the phase optimiser's FFT grid.  Eight points per
#: cycle keep the grid's L_p norms close to the continuous ones; the reported peak does not
#: rely on the grid (it is refined by Newton's method on the exact sum).
GRID_POINTS_PER_CYCLE = 8

#: Exponents of the L_p continuation [2]: each stage starts from the previous optimum.
LP_EXPONENTS = (4, 16, 64, 256)

#: BFGS iterations per L_p stage.  More iterations do not lower the final crest factor
#: (the minimax polish does the rest); fewer leave a visible gap.
LP_MAXITER = 40

#: Starting points of the optimisation: Schroeder's phases plus random ones from the seed.
#: On sparse, log-spaced tone sets extra starts gain about 1 % each, at the cost of time.
N_STARTS = 2

#: Minimax polish: at most this many linear programmes, from this trust radius [rad],
#: on the extrema within MINIMAX_BAND (relative) of the peak.  It stops when a step lowers
#: the peak by less than MINIMAX_RTOL or the radius halves below MINIMAX_MIN_RADIUS [rad]:
#: on 2-20 kHz tone sets the first step gains 1-2 %, the rest together about 0.1 %.
MINIMAX_ITERATIONS = 30
MINIMAX_RADIUS = 0.1
MINIMAX_BAND = 0.15
MINIMAX_RTOL = 1e-3
MINIMAX_MIN_RADIUS = 1e-2

#: Newton steps that move a grid extremum onto the continuous one.
NEWTON_STEPS = 6

#: Elements per block of the exact cosine sum (tones x samples), to bound memory.
BLOCK_ELEMENTS = 1 << 22

#: Crest factor :func:`split_tones` assumes when it first guesses how many sub-steps a
#: step needs (optimistic; it adds sub-steps until every one fits).
SPLIT_CREST_GUESS = 2.0


# --------------------------------------------------------------------------- result type


class LoopLengthError(ValueError):
    """No loop within the bound puts every tone within tolerance of whole cycles."""


@dataclass(frozen=True)
class Waveform:
    """One step's drive: a sampled loop of summed tones, with its tone table.

    Attributes
    ----------
    samples : ndarray, shape (n_samples,)
        Substrate displacement [m] at ``t = n / sample_rate``; a whole number of loops.
        Read-only.
    sample_rate : float
        Sample rate [Hz].
    frequencies : ndarray, shape (n_tones,)
        Tone frequencies as synthesised [Hz]: each on the loop's grid ``1 / loop_length``.
        Same order as requested.
    amplitudes : ndarray, shape (n_tones,)
        Tone amplitudes in the samples [m], after ``scale``.
    phases : ndarray, shape (n_tones,)
        Tone phases at ``t = 0`` [rad], in ``(-pi, pi]``.
    crest_factor : float
        ``peak / rms`` [-], with the continuous-time peak.
    loop_length : float
        Length of one seamless loop [s]; every tone makes a whole number of cycles in it.
    peak : float
        Peak of ``|zeta(t)|`` over continuous time [m] (what the piezo sees after the
        generator's reconstruction filter); at least ``max(abs(samples))``.
    rms : float
        Root mean square of ``zeta`` [m], ``sqrt(sum(amplitudes**2) / 2)``.
    scale : float
        Factor applied to the requested amplitudes to meet ``peak_limit`` [-]; 1 if none.
    frequency_shift : ndarray, shape (n_tones,)
        ``frequencies`` minus the requested frequencies [Hz] (snapping to the loop grid).
    warnings : tuple of str
        Everything a user should know: scaling, large shifts.
    """

    samples: np.ndarray = field(repr=False)
    sample_rate: float
    frequencies: np.ndarray
    amplitudes: np.ndarray
    phases: np.ndarray
    crest_factor: float
    loop_length: float
    peak: float
    rms: float
    scale: float = 1.0
    frequency_shift: np.ndarray | None = None
    warnings: tuple[str, ...] = ()

    def __post_init__(self):
        n = len(self.frequencies)
        for name in ("amplitudes", "phases"):
            if len(getattr(self, name)) != n:
                raise ValueError(f"{name}: {len(getattr(self, name))} values for {n} frequencies")
        if self.frequency_shift is None:
            object.__setattr__(self, "frequency_shift", np.zeros(n))
        for name in ("samples", "frequencies", "amplitudes", "phases", "frequency_shift"):
            arr = np.array(getattr(self, name), dtype=float)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "warnings", tuple(self.warnings))

    @property
    def loop_points(self) -> int:
        """Samples in one loop [-]."""
        return int(round(self.loop_length * self.sample_rate))

    @property
    def n_loops(self) -> int:
        """Whole loops in :attr:`samples` [-]."""
        return len(self.samples) // self.loop_points

    @property
    def duration(self) -> float:
        """Length of :attr:`samples` [s]."""
        return len(self.samples) / self.sample_rate

    @property
    def times(self) -> np.ndarray:
        """Sample times [s], shape (n_samples,)."""
        return np.arange(len(self.samples)) / self.sample_rate

    @property
    def requested_frequencies(self) -> np.ndarray:
        """The frequencies asked for, before snapping to the loop grid [Hz]."""
        return self.frequencies - self.frequency_shift

    def evaluate(self, t) -> np.ndarray:
        """The exact sum of cosines at arbitrary times.

        Parameters
        ----------
        t : array_like
            Times [s].

        Returns
        -------
        ndarray
            ``zeta(t)`` [m], the shape of ``t``.
        """
        t = np.asarray(t, dtype=float)
        cycles = np.rint(self.frequencies * self.loop_length)
        u = np.mod(t / self.loop_length, 1.0)
        flat = _cosines_at(cycles, self.amplitudes, self.phases, u.ravel())
        return flat.reshape(t.shape)


# --------------------------------------------------------------------------- public API


# the one seed -> Generator helper (None means seed 0, as everywhere in vibroplan)
from planner._random import as_generator  # noqa: E402


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


#: Memory per point of the longest loop searched [bytes]: the candidate loop lengths
#: (int64), the loop's samples, their copies in an export and its read-back check.
LOOP_BYTES_PER_POINT = 48


def check_loop_memory(points: int, what: str) -> None:
    """Refuse, before allocating, a loop search or signal of ``points`` samples that the
    machine's memory cannot hold (:func:`planner._limits.check_memory`)."""
    from planner._limits import check_memory

    check_memory(LOOP_BYTES_PER_POINT * float(points), f"{what} ({points:.4g} points)")


def synthesize(frequencies, amplitudes, sample_rate, duration=None, seed=None, peak_limit=None,
               *, phases=None, frequency_tolerance=None, max_loop_length=MAX_LOOP_LENGTH,
               n_starts=N_STARTS) -> Waveform:
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
    The crest factor that a set of phases can reach depends on the loop: a loop of length
    L holds about ``2 f_max L`` independent extrema that n phases must hold down, so longer
    loops (smaller tolerances) give higher crest factors.  See ``benchmarks/crest_factor.py``.

    Examples
    --------
    >>> wf = synthesize([3000.0, 5000.0, 7000.0], 1e-6, 200e3, seed=0)
    >>> wf.loop_length, round(wf.rms * 1e6, 4)
    (0.001, 1.2247)
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
    rng = as_generator(seed)

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
    loop_length = loop_points / fs
    f_snapped = cycles * fs / loop_points

    if phases is None:
        ph = optimise_phases(cycles, a, seed=rng, n_starts=n_starts)
    else:
        ph = np.asarray(phases, dtype=float)
    ph = _wrap(ph)
    peak = peak_of(cycles, a, ph)
    rms = math.sqrt(float(np.sum(a**2)) / 2)
    crest = peak / rms

    warnings = []
    scale = 1.0
    if peak_limit is not None and peak > peak_limit:
        scale = peak_limit / peak
        a = a * scale
        warnings.append(
            f"peak {peak * 1e6:.4g} um exceeds peak_limit {peak_limit * 1e6:.4g} um at crest "
            f"factor {crest:.3f}: every amplitude scaled by {scale:.4f} (not clipped); "
            f"split_tones() splits the step into sub-steps instead")
        peak *= scale
        rms *= scale

    loop = _cosine_sum(cycles, loop_points, a, ph)
    n_loops = 1 if n_total is None else n_total // loop_points
    samples = np.tile(loop, n_loops) if n_loops > 1 else loop
    return Waveform(samples=samples, sample_rate=fs, frequencies=f_snapped, amplitudes=a,
                    phases=ph, crest_factor=crest, loop_length=loop_length, peak=peak, rms=rms,
                    scale=scale, frequency_shift=f_snapped - f, warnings=tuple(warnings))


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


# --------------------------------------------------------------------------- loop choice


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


# --------------------------------------------------------------------------- kernels
# Kernels work in loop units: a tone is its whole number of cycles k per loop, time is the
# loop fraction u in [0, 1).  They take plain arrays and know nothing of Waveform.


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


def _extrema(cycles, amplitudes, phases, m, band):
    """Continuous-time extrema of |x| within ``band`` (relative) of the largest.

    Parameters
    ----------
    cycles, amplitudes, phases : ndarray, shape (n_tones,)
        The tones, in loop units.
    m : int
        Grid size.
    band : float
        Keep extrema with ``|x| >= (1 - band) * peak``.

    Returns
    -------
    u : ndarray
        Loop fractions of the extrema.
    x : ndarray
        Values of the sum there (signed) [m].

    Notes
    -----
    Near a maximum t* of |x| (where x' = 0) the nearest grid point is at most h/2 away and
    lower by at most ``|x''|max h^2 / 8``, so grid maxima within that bound of the grid's
    highest are refined by Newton's method on the exact sum; none can hide between points.
    """
    x = _grid_signal(cycles, amplitudes, phases, m)
    ax = np.abs(x)
    w = 2 * np.pi * cycles
    curvature = float(np.sum(amplitudes * w**2)) / (8 * m * m)
    top = float(ax.max())
    lower = min((1 - band) * top, top - curvature)
    local = (ax >= np.roll(ax, 1)) & (ax >= np.roll(ax, -1)) & (ax >= lower)
    idx = np.nonzero(local)[0]
    u = idx / m
    h = 1.0 / m
    for _ in range(NEWTON_STEPS):
        theta = 2 * np.pi * np.mod(np.outer(u, cycles), 1.0) + phases
        d1 = -(np.sin(theta) * (amplitudes * w)).sum(axis=1)
        d2 = -(np.cos(theta) * (amplitudes * w**2)).sum(axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            step = np.where(d2 != 0, -d1 / d2, 0.0)
        u = u + np.clip(step, -h, h)
    values = _cosines_at(cycles, amplitudes, phases, np.mod(u, 1.0))
    # Newton may wander off a maximum onto a minimum of x; keep the grid value if it is higher
    keep = np.abs(values) >= ax[idx]
    u = np.where(keep, np.mod(u, 1.0), idx / m)
    values = np.where(keep, values, x[idx])
    sel = np.abs(values) >= (1 - band) * np.abs(values).max()
    return u[sel], values[sel]


def peak_of(cycles, amplitudes, phases) -> float:
    """Peak of ``|sum_i a_i cos(2 pi k_i u + phi_i)|`` over the continuous loop.

    Parameters
    ----------
    cycles : array_like of int, shape (n_tones,)
        Whole cycles of each tone per loop.
    amplitudes : array_like, shape (n_tones,)
        [m].
    phases : array_like, shape (n_tones,)
        [rad].

    Returns
    -------
    float
        The peak [m].
    """
    k = _reduce(cycles)
    a = np.asarray(amplitudes, dtype=float)
    ph = np.asarray(phases, dtype=float)
    m = _grid_points(k)
    u, values = _extrema(k, a, ph, m, band=0.0)
    top = float(np.abs(values).max())
    # Newton (in _extrema) can step the wrong way where two extrema nearly merge and then
    # falls back to the grid value, below the true peak; a bounded scalar search over the
    # grid cell on either side of every candidate cannot (found by hypothesis: 8 tones,
    # Newton's peak 2e-4 below the samples').  Only the reported peak pays for it.
    x = np.abs(_grid_signal(k, a, ph, m))
    lower = top - float(np.sum(a * (2 * np.pi * k) ** 2)) / (8 * m * m)
    cand = np.nonzero((x >= np.roll(x, 1)) & (x >= np.roll(x, -1)) & (x >= lower))[0]

    def neg(v):
        return -abs(float(_cosines_at(k, a, ph, np.array([v % 1.0]))[0]))

    for i in cand:
        res = minimize_scalar(neg, bounds=((i - 1) / m, (i + 1) / m), method="bounded",
                              options={"xatol": 1e-6 / m})
        top = max(top, -float(res.fun))
    return top


def schroeder_phases(amplitudes) -> np.ndarray:
    """Schroeder's low-peak phases for tones in frequency order [1]_.

    Parameters
    ----------
    amplitudes : array_like, shape (n_tones,)
        Tone amplitudes, in increasing frequency order.

    Returns
    -------
    ndarray, shape (n_tones,)
        ``phi_n = -2 pi sum_{l<n} (n - l) p_l`` [rad], with ``p_l`` the tone's share of the
        power ([1]_, eq. 11, phi_1 = 0).
    """
    a = np.asarray(amplitudes, dtype=float)
    p = a**2 / np.sum(a**2)
    n = np.arange(len(a))
    # sum_{l<n} (n - l) p_l = n * P(n) - Q(n) with P, Q the prefix sums of p and l p
    prefix_p = np.concatenate(([0.0], np.cumsum(p)[:-1]))
    prefix_lp = np.concatenate(([0.0], np.cumsum(n * p)[:-1]))
    return -2 * np.pi * (n * prefix_p - prefix_lp)


def crest_factor(cycles, amplitudes, phases) -> float:
    """Crest factor ``peak / rms`` of summed tones over a continuous loop [-].

    Parameters are those of :func:`peak_of`.
    """
    a = np.asarray(amplitudes, dtype=float)
    return peak_of(cycles, a, phases) / math.sqrt(float(np.sum(a**2)) / 2)


def optimise_phases(cycles, amplitudes, seed=None, n_starts=N_STARTS) -> np.ndarray:
    """Phases that minimise the crest factor of summed tones on a loop.

    Parameters
    ----------
    cycles : array_like of int, shape (n_tones,)
        Whole cycles of each tone per loop (distinct, positive).
    amplitudes : array_like, shape (n_tones,)
        Tone amplitudes [m].
    seed : None, int or numpy.random.Generator, optional
        For the random starting points (see :func:`as_generator`).
    n_starts : int, optional
        Schroeder's phases, then ``n_starts - 1`` uniformly random ones.

    Returns
    -------
    ndarray, shape (n_tones,)
        Phases at ``u = 0`` [rad].

    Notes
    -----
    From each start, L_p-norm minimisation with p = 4, 16, 64, 256 [2]_ (BFGS, the
    gradient by one real FFT per evaluation) approaches the minimax problem; the best
    result then gets a minimax polish: sequential linear programmes that lower the highest
    extrema together within a trust region, each step kept only if the continuous peak
    falls.  Deterministic for a seed.
    """
    k_full = np.asarray(cycles, dtype=np.int64)
    a = np.asarray(amplitudes, dtype=float)
    if len(k_full) == 1:
        return np.zeros(1)
    rng = as_generator(seed)
    # work in rms units: the phases do not depend on the scale, and the linear programmes'
    # absolute tolerances (1e-7) would otherwise be of the order of amplitudes in metres
    a = a / math.sqrt(float(np.sum(a**2)) / 2)
    k = _reduce(k_full)
    m = _grid_points(k)
    order = np.argsort(k)
    starts = [np.empty(len(k))]
    starts[0][order] = schroeder_phases(a[order])
    starts += [rng.uniform(0, 2 * np.pi, len(k)) for _ in range(n_starts - 1)]
    best, best_cf = None, np.inf
    for ph in starts:
        ph = _lp_continuation(k, a, ph, m)
        cf = _grid_crest(k, a, ph, m)
        if cf < best_cf:
            best, best_cf = ph, cf
    return _minimax_polish(k, a, best, m)


def _grid_crest(k, a, ph, m):
    x = _grid_signal(k, a, ph, m)
    return float(np.abs(x).max()) / math.sqrt(float(np.sum(a**2)) / 2)


def _lp_continuation(k, a, ph, m):
    """L_p minimisation of the grid signal for increasing p (see :func:`optimise_phases`)."""
    rms = math.sqrt(float(np.sum(a**2)) / 2)
    spectrum = np.zeros(m // 2 + 1, dtype=complex)

    for p in LP_EXPONENTS:
        def objective(phi, p=p):
            spectrum[k] = 0.5 * m * a * np.exp(1j * phi)
            x = scipy.fft.irfft(spectrum, m) / rms
            top = float(np.abs(x).max())
            y = x / top                      # |y| <= 1: no overflow at large p
            yp1 = np.abs(y) ** (p - 1)
            s = float(np.mean(yp1 * np.abs(y)))
            value = top * s ** (1 / p)      # (mean |x|^p)^(1/p), the L_p norm per rms
            # d value / d phi_i = s^(1/p - 1) / m * sum_n |y|^(p-1) sgn(y) dx_n/dphi_i,
            # dx_n/dphi_i = -a_i sin(2 pi k_i n / m + phi_i) / rms: one rfft gives all i
            r = scipy.fft.rfft(yp1 * np.sign(y))[k]
            grad = -s ** (1 / p - 1) / m * a / rms * np.imag(np.exp(1j * phi) * np.conj(r))
            return value, grad

        # BFGS, not L-BFGS-B: with tens of phases the dense update is cheap, and scipy's
        # L-BFGS-B pays a multithreaded-BLAS overhead per iteration that dominates here
        ph = minimize(objective, ph, jac=True, method="BFGS",
                      options={"maxiter": LP_MAXITER}).x
    return ph


def _minimax_polish(k, a, ph, m):
    """Lower the continuous peak by sequential linear programmes (the p -> infinity limit).

    At the extrema u_j within ``MINIMAX_BAND`` of the peak, the first-order change of
    x(u_j) with the phases is ``-a_i sin(theta_ij) dphi_i`` (the extrema's own motion is
    second order), so ``min s  s.t.  sgn_j (x_j + J_j dphi) <= s, |dphi| <= r`` is a linear
    programme.  A step is kept if the continuous peak falls, otherwise r is halved.
    """
    n = len(k)
    w = 2 * np.pi * k
    u, x = _extrema(k, a, ph, m, MINIMAX_BAND)
    peak = float(np.abs(x).max())
    radius = MINIMAX_RADIUS
    cost = np.zeros(n + 1)
    cost[-1] = 1.0
    for _ in range(MINIMAX_ITERATIONS):
        theta = np.outer(u, w) + ph
        sign = np.sign(x)[:, None]
        a_ub = np.hstack([-sign * np.sin(theta) * a, -np.ones((len(u), 1))])
        b_ub = -np.abs(x)
        res = linprog(cost, A_ub=a_ub, b_ub=b_ub,
                      bounds=[(-radius, radius)] * n + [(None, None)], method="highs")
        if res.status != 0:
            break
        trial = ph + res.x[:n]
        u_t, x_t = _extrema(k, a, trial, m, MINIMAX_BAND)
        peak_t = float(np.abs(x_t).max())
        if peak_t < peak:
            gain = 1 - peak_t / peak
            ph, u, x, peak = trial, u_t, x_t, peak_t
            if gain < MINIMAX_RTOL:
                break
        else:
            radius /= 2
            if radius < MINIMAX_MIN_RADIUS:
                break
    return ph


# --------------------------------------------------------------------------- validation


def _as_tone_array(values, name) -> np.ndarray:
    arr = np.atleast_1d(np.asarray(values, dtype=float))
    if arr.ndim != 1 or len(arr) == 0:
        raise ValueError(f"{name} must be a non-empty 1-D sequence, shape {arr.shape} was given")
    bad = np.nonzero(~np.isfinite(arr))[0]
    if len(bad):
        raise ValueError(f"{name}[{bad[0]}] must be finite, {arr[bad[0]]} was given")
    return arr


def _check_positive(arr, name):
    bad = np.nonzero(arr <= 0)[0]
    if len(bad):
        raise ValueError(f"{name}[{bad[0]}] must be positive, {arr[bad[0]]:g} was given")


def _positive_float(value, name) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, {value!r} was given") from None
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be positive and finite, {value!r} was given")
    return v


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


def _tolerance(frequency_tolerance, f) -> np.ndarray:
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


def _whole_samples(duration, fs) -> int:
    n = int(round(duration * fs))
    if n < 1 or abs(duration * fs - n) > 1e-6 * max(1.0, n):
        raise ValueError(f"duration must hold a whole number of samples at {fs:g} Hz, "
                         f"{duration!r} s holds {duration * fs:.6g}")
    return n


def _wrap(phases) -> np.ndarray:
    """Phases into (-pi, pi] [rad]."""
    w = np.mod(np.asarray(phases, dtype=float) + np.pi, 2 * np.pi) - np.pi
    return np.where(w == -np.pi, np.pi, w)


__all__ = ["Waveform", "LoopLengthError", "synthesize", "tones_from_power", "split_tones", "as_generator",
           "optimise_phases", "schroeder_phases", "peak_of", "crest_factor",
           "DEFAULT_POWER", "FREQUENCY_TOLERANCE_REL", "MAX_LOOP_LENGTH"]

