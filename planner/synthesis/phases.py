"""Phases of minimum crest factor (peak / rms) for summed tones on a loop.

The rms of summed tones, which fixes their amplitudes, does not depend on their phases;
the peak, which hits the piezo's limit, does.  Starting from Schroeder's phases [1]_ (and
random ones from the seed), L_p-norm minimisation with p raised toward infinity [2]_
approaches the minimax problem, and a minimax (L_inf) polish by sequential linear
programmes finishes it.  Deterministic for a seed.  Phases in rad, in loop units
(:mod:`planner.synthesis.kernels`).  Per-tone amplitudes and phase offsets let the
optimised signal be the amplifier's input through a drive chain rather than the die's
displacement (:func:`optimise_phases`, ``offsets``).

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
from planner.synthesis.peak import _extrema

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



def _wrap(phases) -> np.ndarray:
    """Phases into (-pi, pi] [rad]."""
    w = np.mod(np.asarray(phases, dtype=float) + np.pi, 2 * np.pi) - np.pi
    return np.where(w == -np.pi, np.pi, w)

