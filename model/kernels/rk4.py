"""The paper's method, kept as a reference: fixed-step RK4 with per-step impact detection.

Saitou et al. integrate eqs. (1)-(10) with fourth-order Runge-Kutta at a fixed
step.  This kernel does the same for the impacter: after each step it checks
whether x passed the wall; if so it locates the crossing on the step's cubic
Hermite interpolant (O(h^4), so the method keeps its order), re-integrates from
the start of the step to the crossing with one RK4 step of that length to get
v-, applies eq. (8), and continues from the impact with the same step size.
A crossing that enters and leaves the wall within one step is missed, as in
the paper's method: that is one of the reasons the exact solver exists.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from model.kernels.impacter import EVENT_CAP, NONFINITE, OK


@njit(cache=True, nogil=True)
def _accel(wn, sigma, w, a, phi, t, x, v):
    f = 0.0
    for i in range(w.shape[0]):
        f += a[i] * math.cos(w[i] * t + phi[i])
    return f - 2.0 * sigma * v - wn * wn * x


@njit(cache=True, nogil=True)
def _rk4_step(wn, sigma, w, a, phi, t, x, v, h):
    k1x = v
    k1v = _accel(wn, sigma, w, a, phi, t, x, v)
    k2x = v + 0.5 * h * k1v
    k2v = _accel(wn, sigma, w, a, phi, t + 0.5 * h, x + 0.5 * h * k1x, k2x)
    k3x = v + 0.5 * h * k2v
    k3v = _accel(wn, sigma, w, a, phi, t + 0.5 * h, x + 0.5 * h * k2x, k3x)
    k4x = v + h * k3v
    k4v = _accel(wn, sigma, w, a, phi, t + h, x + h * k3x, k4x)
    return (x + h / 6.0 * (k1x + 2.0 * k2x + 2.0 * k3x + k4x),
            v + h / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v))


@njit(cache=True, nogil=True)
def _hermite_crossing(x0, v0, x1, v1, h, c):
    """Fraction s in (0, 1] where the cubic Hermite interpolant reaches c."""
    lo = 0.0
    hi = 1.0
    s = (c - x0) / (x1 - x0) if x1 != x0 else 0.5
    s = min(max(s, 1e-12), 1.0)
    for _ in range(60):
        s2 = s * s
        s3 = s2 * s
        h00 = 2 * s3 - 3 * s2 + 1
        h10 = s3 - 2 * s2 + s
        h01 = -2 * s3 + 3 * s2
        h11 = s3 - s2
        val = h00 * x0 + h10 * h * v0 + h01 * x1 + h11 * h * v1 - c
        if val < 0.0:
            lo = s
        else:
            hi = s
        d = ((6 * s2 - 6 * s) * x0 + (3 * s2 - 4 * s + 1) * h * v0
             + (-6 * s2 + 6 * s) * x1 + (3 * s2 - 2 * s) * h * v1)
        s_new = s - val / d if d > 0.0 else 0.5 * (lo + hi)
        if not (lo < s_new <= hi):
            s_new = 0.5 * (lo + hi)
        if abs(s_new - s) < 1e-15:
            s = s_new
            break
        s = s_new
    return s


@njit(cache=True, nogil=True)
def run_rk4(wn, sigma, gap, e, w, a, phi, t0, t_end, x0, v0, h, max_events,
            imp_t, imp_v):
    """Fixed-step RK4 with impact detection per step (the paper's method).

    Parameters are those of :func:`model.kernels.impacter.run_impacter`, plus
    the step h [s].  Chattering is ended by sticking when |v+| falls below the
    velocity change of one step under the net force, and the impacter is
    released when the net force pulls it off the wall at a step's end.

    Returns
    -------
    status, n_events, sum_v, x_end, v_end, n_steps
    """
    capacity = imp_t.shape[0]
    t = t0
    x = x0
    v = v0
    n = 0
    sum_v = 0.0
    steps = 0
    stuck = x0 >= gap and v0 == 0.0 and _accel(wn, sigma, w, a, phi, t0, gap, 0.0) > 0.0
    while t < t_end:
        hh = min(h, t_end - t)
        steps += 1
        if stuck:
            t += hh
            if _accel(wn, sigma, w, a, phi, t, gap, 0.0) < 0.0:
                stuck = False
            continue
        xn, vn = _rk4_step(wn, sigma, w, a, phi, t, x, v, hh)
        if not (math.isfinite(xn) and math.isfinite(vn)):
            return NONFINITE, n, sum_v, x, v, steps
        if xn > gap and vn > -math.inf:
            s = _hermite_crossing(x, v, xn, vn, hh, gap)
            hc = s * hh
            xc, vc = _rk4_step(wn, sigma, w, a, phi, t, x, v, hc)
            if vc <= 0.0:
                # crossing located behind a maximum: accept as a grazing contact
                vc = max(vn, 0.0)
            if n >= max_events:
                return EVENT_CAP, n, sum_v, x, v, steps
            if n < capacity:
                imp_t[n] = t + hc
                imp_v[n] = vc
            n += 1
            if n >= 2:
                sum_v += vc
            t = t + hc
            x = gap
            v = -e * vc
            acc = _accel(wn, sigma, w, a, phi, t, gap, v)
            if acc > 0.0 and abs(v) < acc * h:
                stuck = True
                v = 0.0
        else:
            t += hh
            x = xn
            v = vn
    return OK, n, sum_v, x, v, steps


@njit(cache=True, nogil=True)
def rk4_response(wn, sigma, gap, e, w, a, phi, t_end, x0, v0, h, max_events):
    """sum_v (eq. 12 numerator over m) by the paper's RK4; returns (status, n, sum_v)."""
    empty = np.empty(0)
    res = run_rk4(wn, sigma, gap, e, w, a, phi, 0.0, t_end, x0, v0, h, max_events,
                  empty, empty)
    return res[0], res[1], res[2]
