"""Fitting the drive chain to a measured sweep (``vibroplan calibrate --chain``).

A lab plays one tone at a time into the amplifier, ``V cos(2 pi f t)``, and measures
the substrate's displacement with a vibrometer: its amplitude ``D`` and phase ``phi``
against the input at the same frequency, and optionally its 2nd and 3rd harmonics.
The measured transfer is ``H = D / V exp(j phi)`` [m/V].  :func:`fit_chain` keeps it
as a table (repeated frequencies averaged) and fits the model of
:class:`planner.synthesis.chain.ModelTransfer` to it (a flat gain and one
second-order resonance per peak of the gain, optionally a first-order low-pass), so
that the resonances are flagged with their frequency and Q; :func:`harmonic_levels`
turns the measured harmonics into the levels at one stroke.  SI units: m, V, Hz, rad.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from planner.synthesis.chain import ModelTransfer

#: A peak of the measured gain is a resonance when it stands this much above the lower
#: of the minima on either side of it [dB] (noise of a few per cent makes ripples of a
#: few tenths of a dB).
PEAK_PROMINENCE_DB = 3.0
#: The low-pass is kept only when it lowers the fit's rms residual by this factor [-].
LOW_PASS_GAIN = 0.7
#: Points of the written table per resonance half-power width (f / Q): a sweep a few
#: per cent apart steps over a Q-20 peak 5 % wide, and the log-frequency interpolation
#: of such a table would miss its top by 15 % (measured: 90 points over 3-60 kHz).
POINTS_PER_WIDTH = 8


@dataclass(frozen=True)
class ChainFit:
    """A measured transfer as a table and as a fitted model.

    Attributes
    ----------
    frequency_hz : ndarray, shape (n,)
        The distinct measured frequencies, increasing [Hz].
    response : ndarray of complex, shape (n,)
        The measured transfer there [m/V] (repeats averaged).
    model : ModelTransfer
        The fitted model.
    resonances : tuple of dict
        Per fitted resonance: ``frequency_hz`` (natural), ``q``, ``peak_hz`` (where the
        gain peaks), ``frequency_std_hz``, ``q_std`` (one standard error).
    gain_rms : float
        The model's rms residual in log gain (about the relative error) [-].
    phase_rms : float
        Its rms residual in phase [rad].
    """

    frequency_hz: np.ndarray
    response: np.ndarray
    model: ModelTransfer
    resonances: tuple
    gain_rms: float
    phase_rms: float

    @property
    def phase_rad(self) -> np.ndarray:
        """The measured phase, unwrapped from the lowest frequency [rad]."""
        return np.unwrap(np.angle(self.response))

    def table(self):
        """The table a spec takes: ``(frequency_hz, response)``, the measured points and,
        between them, the fitted model times the measured-to-model ratio interpolated
        in log frequency (every measured point kept exactly; between two of them the
        model's shape, so that a peak narrower than the sweep's step is not cut flat).
        Across each resonance the points are ``f / (POINTS_PER_WIDTH Q)`` apart.

        Returns
        -------
        frequency_hz : ndarray, shape (m,)
            Increasing [Hz], from the sweep's lowest to its highest frequency.
        response : ndarray of complex, shape (m,)
            [m/V].
        """
        f = self.frequency_hz
        grid = [f]
        for fr, q in self.model.resonances:
            step = 1.0 / (POINTS_PER_WIDTH * q)
            lo, hi = max(f[0], fr * (1 - 5.0 / q)), min(f[-1], fr * (1 + 5.0 / q))
            if hi > lo:
                grid.append(np.exp(np.arange(math.log(lo), math.log(hi), step)))
        fg = np.unique(np.concatenate(grid))
        ratio = self.response / self.model.response(f)
        x, lx = np.log(fg), np.log(f)
        ratio_g = np.exp(np.interp(x, lx, np.log(np.abs(ratio)))
                         + 1j * np.interp(x, lx, np.unwrap(np.angle(ratio))))
        return fg, self.model.response(fg) * ratio_g


def _peaks(f, gain_db):
    """Indices of the gain's peaks standing :data:`PEAK_PROMINENCE_DB` above the lower
    of the minima on either side."""
    out = []
    n = len(gain_db)
    for i in range(n):
        if (i > 0 and gain_db[i - 1] > gain_db[i]) or (i < n - 1 and gain_db[i + 1] >= gain_db[i]):
            continue
        # the lowest point between this peak and any higher one on each side
        lo_l = _valley(gain_db, i, -1)
        lo_r = _valley(gain_db, i, +1)
        if lo_l is None or lo_r is None:
            continue          # a peak at the sweep's end: not resolved
        if gain_db[i] - max(lo_l, lo_r) >= PEAK_PROMINENCE_DB:
            out.append(i)
    return out


def _valley(g, i, step):
    """The lowest value from ``i`` toward ``step`` until a value above ``g[i]`` or the
    end; None when the end is reached at once (no point on that side)."""
    j = i + step
    if j < 0 or j >= len(g):
        return None
    low = g[i]
    while 0 <= j < len(g) and g[j] <= g[i]:
        low = min(low, g[j])
        j += step
    return low


def _model(p, f, n_res, low_pass):
    g = math.exp(p[0])
    res = tuple((math.exp(p[1 + 2 * k]), math.exp(p[2 + 2 * k])) for k in range(n_res))
    lp = math.exp(p[1 + 2 * n_res]) if low_pass else None
    return ModelTransfer(g, res, lp)


def _residual(p, f, h, n_res, low_pass):
    m = _model(p, f, n_res, low_pass).response(f)
    r = m / h
    return np.concatenate([np.log(np.abs(r)), np.angle(r)])


def fit_chain(frequency_hz, response) -> ChainFit:
    """Fit a measured transfer.

    Parameters
    ----------
    frequency_hz : array_like, shape (n,)
        Measured frequencies [Hz] (any order; repeats are averaged).
    response : array_like of complex, shape (n,)
        The measured transfer [m/V]: displacement over input amplitude, at the
        displacement's phase against the input.

    Returns
    -------
    ChainFit

    Raises
    ------
    ValueError
        Fewer than 4 distinct frequencies, or a non-positive or non-finite value.

    Notes
    -----
    The model (:class:`~planner.synthesis.chain.ModelTransfer`) is fitted by least
    squares on ``log(H_model / H)`` (log gain and phase together, both about relative
    errors), started from the gain at the sweep's lowest frequency and, per peak of the
    measured gain, the peak's frequency and its height over that gain as Q (a
    resonance's peak is Q times the gain below it).  Standard errors come from the
    Jacobian at the optimum.
    """
    f = np.asarray(frequency_hz, dtype=float)
    h = np.asarray(response, dtype=complex)
    if f.shape != h.shape or f.ndim != 1:
        raise ValueError("frequency_hz and response must be 1-d arrays of one length")
    if not (np.all(np.isfinite(f)) and np.all(f > 0) and np.all(np.isfinite(h))
            and np.all(np.abs(h) > 0)):
        raise ValueError("every frequency must be positive and every response finite and "
                         "non-zero")
    fu, inv = np.unique(f, return_inverse=True)
    hu = np.zeros(len(fu), complex)
    np.add.at(hu, inv, h)
    hu /= np.bincount(inv)
    if len(fu) < 4:
        raise ValueError(f"a chain fit needs at least 4 distinct frequencies, {len(fu)} given")
    gain_db = 20 * np.log10(np.abs(hu))
    peaks = _peaks(fu, gain_db)
    g0 = float(np.abs(hu[0]))
    p0 = [math.log(g0)]
    for i in peaks:
        q0 = max(1.0, float(np.abs(hu[i])) / g0)
        p0 += [math.log(fu[i]), math.log(q0)]
    best = None
    for low_pass in (False, True):
        p = list(p0) + ([math.log(4 * fu[-1])] if low_pass else [])
        sol = least_squares(_residual, p, args=(fu, hu, len(peaks), low_pass),
                            method="lm" if 2 * len(fu) >= len(p) else "trf")
        rms = float(np.sqrt(np.mean(sol.fun ** 2)))
        if best is None or rms < LOW_PASS_GAIN * best[1]:
            best = (sol, rms, low_pass)
    sol, _, low_pass = best
    model = _model(sol.x, fu, len(peaks), low_pass)
    std = _std(sol)
    resonances = []
    for k, (fr, q) in enumerate(model.resonances):
        peak = fr * math.sqrt(max(0.0, 1.0 - 1.0 / (2.0 * q * q)))
        resonances.append({"frequency_hz": fr, "q": q, "peak_hz": peak,
                           "frequency_std_hz": float(fr * std[1 + 2 * k]),
                           "q_std": float(q * std[2 + 2 * k])})
    n = len(fu)
    return ChainFit(fu, hu, model, tuple(resonances),
                    float(np.sqrt(np.mean(sol.fun[:n] ** 2))),
                    float(np.sqrt(np.mean(sol.fun[n:] ** 2))))


def _std(sol):
    """One standard error of each (log) parameter from the Jacobian."""
    jac = sol.jac
    dof = max(1, len(sol.fun) - len(sol.x))
    var = float(np.sum(sol.fun ** 2)) / dof
    try:
        cov = np.linalg.inv(jac.T @ jac) * var
    except np.linalg.LinAlgError:
        return np.full(len(sol.x), np.nan)
    return np.sqrt(np.clip(np.diag(cov), 0.0, None))


def harmonic_levels(displacement_m, harmonic_m, order, stroke_m) -> float:
    """The ``order``-th harmonic's level at the stroke ``stroke_m`` [dB below the
    fundamental], the median over the measurements.

    Parameters
    ----------
    displacement_m, harmonic_m : array_like, shape (n,)
        The fundamental's and the harmonic's amplitudes at the die [m], positive.
    order : int
        2 or 3.
    stroke_m : float
        The stroke to state the level at [m].

    Notes
    -----
    A polynomial ``z = y + a2 y^2 + a3 y^3`` (:class:`~planner.synthesis.chain.
    Nonlinearity`) makes the 2nd harmonic grow as the square of the stroke and the 3rd
    as its cube, so the level relative to the fundamental moves by
    ``20 (order - 1) log10(S / D)`` dB from the stroke ``D`` a row was measured at.
    """
    d = np.asarray(displacement_m, dtype=float)
    x = np.asarray(harmonic_m, dtype=float)
    level = 20 * np.log10(x / d) + 20 * (order - 1) * np.log10(stroke_m / d)
    return float(np.median(level))


__all__ = ["ChainFit", "fit_chain", "harmonic_levels"]
