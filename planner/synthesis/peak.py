"""The peak of summed tones over the continuous loop, and their crest factor.

What the piezo sees is the generator's reconstructed signal, whose peak can lie between
samples: the grid's extrema are refined on the exact sum of cosines (Newton's method,
then a bounded scalar search), so no maximum hides between grid points.  In loop units
(:mod:`planner.synthesis.kernels`); amplitudes and peaks in m.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import minimize_scalar

from planner.synthesis.kernels import _cosines_at, _grid_points, _grid_signal, _reduce

#: Newton steps that move a grid extremum onto the continuous one.
NEWTON_STEPS = 6


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



def crest_factor(cycles, amplitudes, phases) -> float:
    """Crest factor ``peak / rms`` of summed tones over a continuous loop [-].

    Parameters are those of :func:`peak_of`.
    """
    a = np.asarray(amplitudes, dtype=float)
    return peak_of(cycles, a, phases) / math.sqrt(float(np.sum(a**2)) / 2)

