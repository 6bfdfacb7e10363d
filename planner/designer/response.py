"""Response analysis of one impacter: the band where it responds, the min/max curves
over x0 (Fig. 10), and each forbidden frequency's margin."""

from __future__ import annotations

import math
import warnings

import numpy as np

from model import Impacter, SolverWarning, sweep
from model.drive import POWER
from planner.designer.runs import _default_x0s, _responds, _runs, _Tones


#: Dense re-scans of a margin that found a response inside it (each narrows it) [-].
MARGIN_RESCANS = 3


def _bisect_edge(impacter, tones, x0s, window, f_in, f_out, tol):
    """Boundary between a responding f_in and a silent f_out, on the f_in side [Hz]."""
    while abs(f_out - f_in) > tol:
        mid = 0.5 * (f_in + f_out)
        if _responds(impacter, tones, [mid], x0s, window)[0]:
            f_in = mid
        else:
            f_out = mid
    return f_in


def response_band(impacter, x0s=None, power=POWER, window=3e-3, f_lo=None, f_hi=None, *,
                  amplitude=None, points=96, tol_hz=None):
    """The frequency band where an impacter responds from some initial state.

    Parameters
    ----------
    impacter : model.Impacter
    x0s : array_like, shape (n_x0,), optional
        Initial positions [m] (v0 = 0); default: the designer's grid over [-c, c]
        (33 uniform points, +c just inside the wall, and points near the wall).
    power : float
        Z0^2 w^3 of each tone [m^2/s^3] (ignored with ``amplitude``).
    window : float
        Simulated time t_f - t_0 [s].
    f_lo, f_hi : float, optional
        Scanned range [Hz]; default 0.5 and 2 times the natural frequency.
    amplitude : float, optional
        Fixed tone amplitude Z0 [m] instead of the power convention.
    points : int
        Uniform scan points in [f_lo, f_hi]; both edges are then bisected.
    tol_hz : float, optional
        Edge tolerance [Hz]; default 1e-4 of the natural frequency.

    Returns
    -------
    lo_hz, hi_hz : float
        The lowest and highest frequency in [f_lo, f_hi] at which some x0 gives a
        counted impact (eq. 12, r > 0) [Hz]; (nan, nan) if none.  The band is the
        hull: isolated responding frequencies inside it are included.

    Examples
    --------
    >>> from model import Impacter
    >>> imp = Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6).with_natural_frequency(5200)
    >>> lo, hi = response_band(imp, f_lo=4000, f_hi=9000)       # doctest: +SKIP
    """
    if not isinstance(impacter, Impacter):
        raise ValueError(f"impacter must be a model.Impacter, {type(impacter).__name__} was given")
    tones = _Tones(power, amplitude)
    nu_n = impacter.natural_frequency
    f_lo = 0.5 * nu_n if f_lo is None else float(f_lo)
    f_hi = 2.0 * nu_n if f_hi is None else float(f_hi)
    if not (0 < f_lo < f_hi and math.isfinite(f_hi)):
        raise ValueError(f"need 0 < f_lo < f_hi, got f_lo={f_lo!r}, f_hi={f_hi!r}")
    if int(points) < 2:
        raise ValueError(f"points must be >= 2, {points!r} was given")
    tol = 1e-4 * nu_n if tol_hz is None else float(tol_hz)
    x0s = _default_x0s(impacter) if x0s is None else np.asarray(x0s, dtype=float)
    window = float(window)
    freqs = np.linspace(f_lo, f_hi, int(points))
    hit = _responds(impacter, tones, freqs, x0s, window)
    idx = np.flatnonzero(hit)
    if idx.size == 0:
        return math.nan, math.nan
    i, j = idx[0], idx[-1]
    lo = freqs[i] if i == 0 else _bisect_edge(impacter, tones, x0s, window, freqs[i],
                                              freqs[i - 1], tol)
    hi = freqs[j] if j == freqs.size - 1 else _bisect_edge(impacter, tones, x0s, window,
                                                           freqs[j], freqs[j + 1], tol)
    return float(lo), float(hi)


def response_curves(impacter, frequencies, x0s=None, power=POWER, window=3e-3, *,
                    amplitude=None):
    """min and max over x0 of r (eq. 12) at each frequency, for Fig. 10 [N].

    Parameters
    ----------
    impacter : model.Impacter
    frequencies : array_like, shape (n_freq,)
        [Hz].
    x0s : array_like, shape (n_x0,), optional
        [m]; default the designer's grid over [-c, c].

    Returns
    -------
    r_min, r_max : ndarray, shape (n_freq,)
        [N].
    """
    tones = _Tones(power, amplitude)
    f = np.asarray(frequencies, dtype=float)
    x0s = _default_x0s(impacter) if x0s is None else np.asarray(x0s, dtype=float)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SolverWarning)
        if tones.amplitude is None:
            r = sweep(impacter, f, x0s, tones.power, window)
        else:
            r = np.array([_runs(impacter, tones, fi, x0s, window, False)[0] for fi in f])
    return r.min(axis=1), r.max(axis=1)


def _band_and_margins(impacter, tones, frequency, forbidden, x0s, window, budget):
    """The response band around the target and each forbidden frequency's margin.

    One scan serves both, so they agree: ``8 margin_points`` frequencies over 0.5x the
    lowest to 1.5x the highest of the target, nu_n and the forbidden frequencies,
    plus ``margin_points`` on each side of every nu_j out to |nu - nu_j| (the target
    responds, so no margin is larger).  The band's edges and, for each nu_j, the
    nearest responding scan frequency (on either side; both when within a scan step
    of each other) are then bisected to ``margin_tol`` times the frequency.

    Returns
    -------
    band : (float, float)
        Lowest and highest responding frequency of the scan range [Hz] (nan if none).
    margins : list of float
        [Hz]; 0 where the design responds at nu_j itself.
    """
    points = budget.margin_points
    span = [frequency, impacter.natural_frequency] + list(forbidden)
    grids = [np.linspace(0.5 * min(span), 1.5 * max(span), 8 * points), [frequency],
             list(forbidden)]
    for f in forbidden:
        k = np.arange(1, points + 1) * (abs(frequency - f) / points)
        grids += [f + k, f - k]
    scan = np.unique(np.concatenate([np.asarray(g, dtype=float) for g in grids]))
    scan = scan[scan > 0]
    hit = _responds(impacter, tones, scan, x0s, window)

    def edge(i, toward):
        """Bisect between responding scan[i] and its neighbour in direction ``toward``."""
        j = i + toward
        if j < 0 or j >= scan.size:
            return float(scan[i])
        return _bisect_edge(impacter, tones, x0s, window, scan[i], scan[j],
                            budget.margin_tol * scan[i])

    idx = np.flatnonzero(hit)
    if idx.size == 0:
        return (math.nan, math.nan), [abs(frequency - f) for f in forbidden]
    band = (edge(idx[0], -1), edge(idx[-1], +1))
    margins = []
    for f in forbidden:
        i0 = int(np.searchsorted(scan, f))          # scan[i0] == f
        if hit[i0]:
            margins.append(0.0)
            continue
        below, above = idx[idx < i0], idx[idx > i0]
        cands = []
        if below.size:
            cands.append((f - scan[below[-1]], below[-1], +1))
        if above.size:
            cands.append((scan[above[0]] - f, above[0], -1))
        nearest = min(c[0] for c in cands)
        best = abs(frequency - f)
        for dist, i, toward in cands:
            # the edge lies between scan[i] and its neighbour towards nu_j
            if dist - abs(scan[i] - scan[i + toward]) <= nearest:
                best = min(best, abs(edge(i, toward) - f))
        margins.append(float(best))
    confirmed = []
    for f, m in zip(forbidden, margins):
        m, edge = _confirm_margin(impacter, tones, f, m, x0s, window, budget)
        confirmed.append(m)
        if edge is not None:
            # a response the scan missed, outside the band: the band reaches it
            band = (min(band[0], edge), max(band[1], edge))
    return band, confirmed


def _confirm_margin(impacter, tones, f, margin, x0s, window, budget):
    """(margin, edge): ``margin`` [Hz] around the forbidden ``f``, narrowed to the
    nearest response a denser scan finds inside it, and that response's bisected
    edge [Hz] (None when the scan finds none).

    The responding set need not be an interval: a superharmonic island (found: a
    Table II design answering at 3208 Hz inside a 3000 Hz margin the scan put at
    281 Hz) can sit between the scan's points.  ``2 margin_points + 1`` frequencies
    across [f - m, f + m] are checked; a response narrows the margin to its bisected
    edge, and the narrower interval is scanned again (at most MARGIN_RESCANS times).
    """
    found = None
    for _ in range(MARGIN_RESCANS):
        if margin <= 0.0:
            break
        dense = f + margin * np.linspace(-1.0, 1.0, 2 * budget.margin_points + 1)
        dense = dense[(dense > 0) & (np.abs(dense - f) < margin)]
        hit = _responds(impacter, tones, dense, x0s, window)
        if not np.any(hit):
            break
        # the responding frequency nearest f, bisected towards f's silent neighbour
        order = np.argsort(np.abs(dense - f), kind="stable")
        i = int(order[np.argmax(hit[order])])
        toward = 1 if dense[i] < f else -1
        j = i + toward
        quiet = dense[j] if 0 <= j < dense.size and not hit[j] else f
        edge = _bisect_edge(impacter, tones, x0s, window, float(dense[i]), float(quiet),
                            budget.margin_tol * float(dense[i]))
        margin, found = abs(edge - f), edge
    return margin, found
