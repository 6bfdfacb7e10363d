"""Phases of minimum crest factor (peak / rms) for summed tones on a loop.

The rms of summed tones, which fixes their amplitudes, does not depend on their phases;
the peak, which hits the piezo's limit, does.  Starting from Schroeder's phases [1]_ (and
random ones from the seed), L_p-norm minimisation with p raised toward infinity [2]_
approaches the minimax problem, and a minimax (L_inf) polish by sequential linear
programmes finishes it.  Deterministic for a seed.  Phases in rad, in loop units
(:mod:`planner.synthesis.kernels`).  Per-tone amplitudes and phase offsets let the
optimised signal be the amplifier's input through a drive chain rather than the die's
displacement (:func:`optimise_phases`, ``offsets``); :func:`optimise_peaks` holds down
several such signals of the same tones at once (the die's displacement and acceleration
and the amplifier's input, each relative to its limit: the one nearest its limit sets
the step's amplitude).

What limits the crest factor is the loop, not this optimiser: a loop of length L holds
about ``2 f_max L`` extrema for n phases to hold down.  On the planner's band (4.45-51 kHz)
at its 0.1 % snapping bound, loops are 26-55 ms, and 25 or 50 equal tones end at 2.5-2.7
on a local minimax optimum (n extrema equal, the linear programme finding no descent);
ten starts gain about 1 %.  ``benchmarks/crest_factor.py`` measures it.

References
----------
.. [1] M. R. Schroeder, "Synthesis of low-peak-factor signals and binary sequences with
   low autocorrelation", IEEE Trans. Inf. Theory 16(1), 85-89, 1970.
.. [2] P. Guillaume, J. Schoukens, R. Pintelon, I. Kollar, "Crest-factor minimization using
   nonlinear Chebyshev approximation methods", IEEE Trans. Instrum. Meas. 40(6), 982-989, 1991.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.fft
from scipy.optimize import linprog, minimize

from planner.core.rng import as_generator
from planner.synthesis.kernels import _grid_points, _grid_signal, _reduce
from planner.synthesis.peak import _extrema, peak_of

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



def optimise_phases(cycles, amplitudes, seed=None, n_starts=N_STARTS, *,
                    offsets=None) -> np.ndarray:
    """Phases that minimise the crest factor of summed tones on a loop.

    Parameters
    ----------
    cycles : array_like of int, shape (n_tones,)
        Whole cycles of each tone per loop (distinct, positive).
    amplitudes : array_like, shape (n_tones,)
        Amplitude of each tone in the signal whose crest factor is minimised [m, or V].
    seed : None, int or numpy.random.Generator, optional
        For the random starting points (see :func:`as_generator`).
    n_starts : int, optional
        Schroeder's phases, then ``n_starts - 1`` uniformly random ones.
    offsets : array_like, shape (n_tones,), optional
        Phase added to each tone in the signal whose crest factor is minimised [rad]
        (none by default): the phases ``phi`` returned minimise the peak of
        ``sum_i amplitudes_i cos(2 pi k_i u + phi_i + offsets_i)``.  Through a linear
        drive chain of transfer ``H_i = |H_i| exp(j alpha_i)`` at tone i (volts at the
        amplifier's input to displacement at the die), die tones ``z_i`` need an input of
        amplitudes ``z_i / |H_i|`` and phases ``phi_i - alpha_i``: pass those amplitudes
        and ``offsets = -alpha`` to minimise the crest factor of the *input* (where the
        amplifier's voltage limit applies) and get the die's phases ``phi``.

    Returns
    -------
    ndarray, shape (n_tones,)
        Phases at ``u = 0`` [rad] (without the offsets).

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
    offset = _offsets(offsets, len(k_full))
    if len(k_full) == 1:
        return np.zeros(1) - offset
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
    # every phase is free, so the optimum of the offset signal is the plain one's, less
    # the offsets (the offsets only move it); x - 0.0 is x, bit for bit
    return _minimax_polish(k, a, best, m) - offset


def optimise_peaks(cycles, amplitudes, offsets, seed=None, n_starts=N_STARTS, *,
                   starts=()) -> np.ndarray:
    """Phases that minimise the largest peak of several signals made of the same tones.

    Parameters
    ----------
    cycles : array_like of int, shape (n_tones,)
        Whole cycles of each tone per loop (distinct, positive).
    amplitudes : array_like, shape (n_signals, n_tones)
        Row j: each tone's amplitude in signal j [-].  Divide a row by the signal's
        limit to minimise the largest peak *relative to its limit*.
    offsets : array_like, shape (n_signals, n_tones)
        Row j: the phase each tone has in signal j beyond ``phi`` [rad]: signal j is
        ``x_j(u) = sum_i amplitudes_ji cos(2 pi k_i u + phi_i + offsets_ji)``.
    seed : None, int or numpy.random.Generator, optional
        For the random starting points (see :func:`as_generator`).
    n_starts : int, optional
        Schroeder's phases (for the row of the largest rms), then ``n_starts - 1``
        uniformly random ones.
    starts : sequence of array_like, shape (n_tones,), optional
        Phases to start from as well (each signal's own optimum, say): the result's
        largest peak is no higher than any of theirs.

    Returns
    -------
    ndarray, shape (n_tones,)
        ``phi`` [rad].

    Notes
    -----
    Through a drive chain one step's phases set three peaks, each with its own limit:
    the die's displacement (``amplitudes = Z``), its acceleration (``w^2 Z``) and the
    amplifier's input (``Z / |H|``, ``offsets = -arg H``).  The tones' common scale is
    set by the one nearest its limit, so the phases worth having minimise
    ``max_j peak_j / limit_j``.  As :func:`optimise_phases`: L_p continuation [2]_ on
    the signals together (the L_p norm over all their grid points), then the minimax
    polish on the extrema of every signal within ``MINIMAX_BAND`` of the largest peak.
    """
    k_full = np.asarray(cycles, dtype=np.int64)
    a = np.atleast_2d(np.asarray(amplitudes, dtype=float))
    o = np.atleast_2d(np.asarray(offsets, dtype=float))
    n = len(k_full)
    if a.shape != (len(a), n) or o.shape != a.shape:
        raise ValueError(f"amplitudes {a.shape} and offsets {o.shape} must both be "
                         f"(n_signals, {n})")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(o))):
        raise ValueError("amplitudes and offsets must be finite")
    given = [np.asarray(ph, dtype=float) for ph in starts]
    if any(ph.shape != (n,) for ph in given):
        raise ValueError(f"starts: every one must have {n} phases")
    if n == 1:
        # one tone: every peak is its amplitude, whatever the phase
        return given[0] if given else np.zeros(1)
    rng = as_generator(seed)
    # in units of the largest rms (as optimise_phases: the linear programmes' tolerances)
    a = a / math.sqrt(float(np.max(np.sum(a**2, axis=1))) / 2)
    k = _reduce(k_full)
    m = _grid_points(k)
    order = np.argsort(k)
    loud = int(np.argmax(np.sum(a**2, axis=1)))
    first = np.empty(n)
    first[order] = schroeder_phases(a[loud][order])
    tries = [first - o[loud]] + [rng.uniform(0, 2 * np.pi, n) for _ in range(n_starts - 1)]
    best, best_peak = None, np.inf
    for ph in given + [_lp_joint(k, a, o, ph, m) for ph in tries + given]:
        peak = _joint_grid_peak(k, a, o, ph, m)
        if peak < best_peak:
            best, best_peak = ph, peak
    best = _minimax_joint(k, a, o, best, m)
    # the polish lowers the continuous peak of what it starts from; a given start that
    # was lower on the continuous loop than on the grid is kept over it
    return min([best] + given, key=lambda ph: _joint_peak(k, a, o, ph))


def _joint_grid_peak(k, a, o, ph, m):
    return max(float(np.abs(_grid_signal(k, aj, ph + oj, m)).max()) for aj, oj in zip(a, o))


def _joint_peak(k, a, o, ph):
    """The largest continuous peak of the signals (:func:`optimise_peaks`)."""
    return max(peak_of(k, aj, ph + oj) for aj, oj in zip(a, o))


def _lp_joint(k, a, o, ph, m):
    """L_p minimisation of every signal's grid points together (:func:`optimise_peaks`),
    for increasing p: :func:`_lp_continuation` over several signals."""
    spectrum = np.zeros((len(a), m // 2 + 1), dtype=complex)
    total = len(a) * m

    for p in LP_EXPONENTS:
        def objective(phi, p=p):
            spectrum[:, k] = 0.5 * m * a * np.exp(1j * (phi + o))
            x = scipy.fft.irfft(spectrum, m, axis=1)
            top = float(np.abs(x).max())
            y = x / top
            yp1 = np.abs(y) ** (p - 1)
            s = float(np.sum(yp1 * np.abs(y))) / total
            value = top * s ** (1 / p)
            # as _lp_continuation's gradient, summed over the signals
            r = scipy.fft.rfft(yp1 * np.sign(y), axis=1)[:, k]
            grad = -s ** (1 / p - 1) / total * np.sum(
                a * np.imag(np.exp(1j * (phi + o)) * np.conj(r)), axis=0)
            return value, grad

        ph = minimize(objective, ph, jac=True, method="BFGS",
                      options={"maxiter": LP_MAXITER}).x
    return ph


def _joint_extrema(k, a, o, ph, m):
    """Every signal's continuous extrema within ``MINIMAX_BAND`` of the largest peak:
    (signal index, loop fraction, value) arrays, and that peak."""
    found = [_extrema(k, aj, ph + oj, m, MINIMAX_BAND) for aj, oj in zip(a, o)]
    peak = max(float(np.abs(x).max()) for _, x in found)
    js, us, xs = [], [], []
    for j, (u, x) in enumerate(found):
        keep = np.abs(x) >= (1 - MINIMAX_BAND) * peak
        js.append(np.full(int(np.sum(keep)), j))
        us.append(u[keep])
        xs.append(x[keep])
    return np.concatenate(js), np.concatenate(us), np.concatenate(xs), peak


def _minimax_joint(k, a, o, ph, m):
    """:func:`_minimax_polish` over several signals: the linear programme holds down the
    extrema of every signal near the largest peak together."""
    n = len(k)
    w = 2 * np.pi * k
    j, u, x, peak = _joint_extrema(k, a, o, ph, m)
    radius = MINIMAX_RADIUS
    cost = np.zeros(n + 1)
    cost[-1] = 1.0
    for _ in range(MINIMAX_ITERATIONS):
        theta = np.outer(u, w) + ph + o[j]
        sign = np.sign(x)[:, None]
        a_ub = np.hstack([-sign * np.sin(theta) * a[j], -np.ones((len(u), 1))])
        res = linprog(cost, A_ub=a_ub, b_ub=-np.abs(x),
                      bounds=[(-radius, radius)] * n + [(None, None)], method="highs")
        if res.status != 0:
            break
        trial = ph + res.x[:n]
        j_t, u_t, x_t, peak_t = _joint_extrema(k, a, o, trial, m)
        if peak_t < peak:
            gain = 1 - peak_t / peak
            ph, j, u, x, peak = trial, j_t, u_t, x_t, peak_t
            if gain < MINIMAX_RTOL:
                break
        else:
            radius /= 2
            if radius < MINIMAX_MIN_RADIUS:
                break
    return ph


def _offsets(offsets, n) -> np.ndarray:
    """``offsets`` [rad] checked: shape (n,), finite; zeros when None."""
    if offsets is None:
        return np.zeros(n)
    o = np.asarray(offsets, dtype=float)
    if o.shape != (n,):
        raise ValueError(f"offsets: shape {o.shape} for {n} tones")
    bad = np.nonzero(~np.isfinite(o))[0]
    if len(bad):
        raise ValueError(f"offsets[{bad[0]}] must be finite, {o[bad[0]]} was given")
    return o


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
    One signal of :func:`_minimax_joint`, which does it (the same digits).
    """
    return _minimax_joint(k, np.asarray(a)[None, :], np.zeros((1, len(k))), ph, m)


def _wrap(phases) -> np.ndarray:
    """Phases into (-pi, pi] [rad]."""
    w = np.mod(np.asarray(phases, dtype=float) + np.pi, 2 * np.pi) - np.pi
    return np.where(w == -np.pi, np.pi, w)

