"""A closed-form bound that proves an impacter never reaches its wall under a drive.

Without the wall the impacter is linear (eq. 1 divided by m),

    x'' + 2 sigma x' + wn**2 x = sum_i a_i cos(w_i t + phi_i),

and its motion from rest at x0 is x(t) = x0 g1(t) + sum_i z_i(t), with g1 the free
response from (1, 0) and z_i tone i's response from rest at 0.  At a given t both are
linear, in x0 and in (cos phi_i, sin phi_i), so the largest |x(t)| over every start
x0 in [-c, c] (v0 = 0) and every set of phases is exactly

    W(t) = c |g1(t)| + sum_i |Z_i(t)|,
    Z_i(t) = X_i e^{i w_i t} + e^{-sigma t} (A_i cos(wd t) + B_i sin(wd t)),

with X_i = a_i / (wn**2 - w_i**2 + 2 i sigma w_i) the complex forced amplitude and
(A_i, B_i) the free part that starts Z_i at rest (A_i = -X_i, B_i = -(i w_i + sigma)
X_i / wd).  If W(t) < c for every t > 0, no start and no phasing of the tones ever
brings the impacter to the wall: no impact at all, so r (eq. 12) is zero from every
x0 in D over any duration.  That is what ``linear_silence`` proves, in three pieces:

1. (0, t1], t1 = pi / (2 wd): g1 >= 0 there and, h(tau) = e^{-sigma tau}
   sin(wd tau) / wd >= 0 being the impulse response, |Z_i(t)| <= a_i int_0^t h =
   a_i (1 - g1(t)) / wn**2, so W(t) <= c - (c - S / wn**2) (1 - g1(t)) with
   S = sum a_i: below c whenever the summed peak force per unit mass S is below
   wn**2 c (a drive that does not press the impacter through the gap statically).
2. [t1, t_e]: W is Lipschitz with L = c wn + sum_i (w_i |X_i| + |Z_i'|_free), so from
   a point where W(t) <= c (1 - 2 m) it stays below c (1 - m) for a step
   (c (1 - m) - W(t)) / L >= m c / L: safe steps, like the event finder's, that
   cannot step over a point where W reaches the wall.
3. [t_e, inf): W(t) <= e^{-sigma t} (c wn / wd + sum_i R_i) + sum_i |X_i|, which
   decreases; t_e is where it falls to c (1 - m).

The bound is exact for the linear motion (its only slack is the margin m and the
envelope of piece 3), conservative for the impacter (it asks for no impact at all,
where eq. (12) forgives the first), and says nothing (``NOT_PROVEN``) undamped,
at or over critical damping, or where the motion comes within 2 m c of the wall.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

#: Verdicts of :func:`linear_silence`.
NOT_PROVEN = 0
SILENT = 1
ONE_IMPACT = 2


@njit(cache=True, nogil=True)
def _tone_parts(wn, sigma, wd, w, a):
    """Per tone: X (complex forced amplitude), A, B (free part from rest), and the
    bounds R = |(A, B)|, Rd = |(A, B)'| of the free part and of its derivative."""
    n = w.size
    X = np.empty(n, dtype=np.complex128)
    A = np.empty(n, dtype=np.complex128)
    B = np.empty(n, dtype=np.complex128)
    R = np.empty(n)
    Rd = np.empty(n)
    for i in range(n):
        den = complex(wn * wn - w[i] * w[i], 2.0 * sigma * w[i])
        X[i] = a[i] / den
        A[i] = -X[i]
        B[i] = -(complex(sigma, w[i]) * X[i]) / wd
        R[i] = math.sqrt(abs(A[i]) ** 2 + abs(B[i]) ** 2)
        Rd[i] = math.sqrt(abs(-sigma * A[i] + wd * B[i]) ** 2
                          + abs(sigma * B[i] + wd * A[i]) ** 2)
    return X, A, B, R, Rd


@njit(cache=True, nogil=True)
def _envelope_at(t, c, wn, sigma, wd, w, X, A, B):
    """W(t): the largest |x(t)| over x0 in [-c, c] and every phasing of the tones."""
    e = math.exp(-sigma * t)
    cw, sw = math.cos(wd * t), math.sin(wd * t)
    total = c * abs(e * (cw + sigma / wd * sw))
    for i in range(w.size):
        z = X[i] * complex(math.cos(w[i] * t), math.sin(w[i] * t)) + e * (A[i] * cw + B[i] * sw)
        total += abs(z)
    return total


@njit(cache=True, nogil=True)
def linear_envelope(wn, sigma, c, w, a, t):
    """W(t) at every t (array) for starts x0 in [-c, c] at rest; NaN unless
    0 < sigma < wn (the under-damped regime the formula is written for)."""
    out = np.empty(t.size)
    if not (sigma > 0.0 and sigma < wn):
        out[:] = np.nan
        return out
    wd = math.sqrt((wn - sigma) * (wn + sigma))
    X, A, B, _, _ = _tone_parts(wn, sigma, wd, w, a)
    for k in range(t.size):
        out[k] = _envelope_at(t[k], c, wn, sigma, wd, w, X, A, B)
    return out


@njit(cache=True, nogil=True)
def _velocity_at(t, c, wn, sigma, wd, w, X, P1, Q1):
    """V(t): the largest |x'(t)| over x0 in [-c, c] and every phasing of the tones
    (P1, Q1: the free part's derivative coefficients)."""
    e = math.exp(-sigma * t)
    cw, sw = math.cos(wd * t), math.sin(wd * t)
    total = c * wn * wn / wd * e * abs(sw)
    for i in range(w.size):
        z = (complex(0.0, w[i]) * X[i] * complex(math.cos(w[i] * t), math.sin(w[i] * t))
             + e * (P1[i] * cw + Q1[i] * sw))
        total += abs(z)
    return total


@njit(cache=True, nogil=True)
def _after_impact_at(t, c, kick, sigma, wd, w, X, A, B):
    """W_B(t): the largest x(t) after an impact at t = 0 that left the impacter at the
    wall moving away at any speed up to ``kick`` (= e v-), for every phasing."""
    e = math.exp(-sigma * t)
    cw, sw = math.cos(wd * t), math.sin(wd * t)
    total = c * e * (cw + sigma / wd * sw) + kick * max(0.0, -e * sw / wd)
    for i in range(w.size):
        z = X[i] * complex(math.cos(w[i] * t), math.sin(w[i] * t)) + e * (A[i] * cw + B[i] * sw)
        total += abs(z)
    return total


@njit(cache=True, nogil=True)
def linear_silence(wn, sigma, c, e, w, a, margin, max_steps):
    """Prove that the impacter responds to no start x0 in [-c, c] (v0 = 0) and no phasing.

    SILENT when the wall-free motion never reaches x = c (no impact at all);
    ONE_IMPACT when it may reach it, but the motion after any such first impact, from
    the wall with the rebound e v- (v- at most the fastest the wall-free motion moves
    where it can touch), never comes back: eq. (12), which excludes the first impact,
    is then zero too.  Otherwise NOT_PROVEN.

    Parameters
    ----------
    wn, sigma : float
        Natural angular frequency [rad/s] and b / (2 m) [1/s].
    c : float
        The gap [m], > 0.
    e : float
        Coefficient of restitution (eq. 8).
    w, a : ndarray
        Tones' angular frequencies [rad/s] and forcing amplitudes per unit mass
        [m/s^2] (>= 0).
    margin : float
        m in (0, 0.25): after the first quarter (half, after an impact) period the
        motion is proven below c (1 - m) where it is proven at all.
    max_steps : int
        Safe steps allowed before giving up (NOT_PROVEN).

    Returns
    -------
    verdict : int
        SILENT, ONE_IMPACT or NOT_PROVEN.
    peak : float
        The largest W / c seen after the first quarter period of the wall-free motion
        (a diagnostic: above 1 where one impact is possible).
    steps : int
        Safe steps taken.
    """
    if not (sigma > 0.0 and sigma < wn and c > 0.0):
        return NOT_PROVEN, math.nan, 0
    wd = math.sqrt((wn - sigma) * (wn + sigma))
    S = 0.0
    for i in range(a.size):
        S += abs(a[i])
    # piece 1: the summed peak force must not press the impacter through the gap (nor
    # hold it at the wall: no sticking, no chattering)
    if S >= wn * wn * c * (1.0 - margin):
        return NOT_PROVEN, math.nan, 0
    X, A, B, R, Rd = _tone_parts(wn, sigma, wd, w, a)
    n = w.size
    P1 = np.empty(n, dtype=np.complex128)
    Q1 = np.empty(n, dtype=np.complex128)
    level = c * (1.0 - margin)
    x_sum, r_sum, lip, lip_v = 0.0, c * wn / wd, c * wn, c * (wn * wn + 2.0 * sigma * wn)
    for i in range(n):
        P1[i] = -sigma * A[i] + wd * B[i]
        Q1[i] = -sigma * B[i] - wd * A[i]
        p2 = -sigma * P1[i] + wd * Q1[i]
        q2 = -sigma * Q1[i] - wd * P1[i]
        x_sum += abs(X[i])
        r_sum += R[i]
        lip += w[i] * abs(X[i]) + Rd[i]
        lip_v += w[i] * w[i] * abs(X[i]) + math.sqrt(abs(p2) ** 2 + abs(q2) ** 2)
    if x_sum >= level:
        return NOT_PROVEN, x_sum / c, 0
    # piece 3: from t_end on the decaying envelope stays below the level
    t_end = math.log(max(r_sum / (level - x_sum), 1.0)) / sigma
    # whether a first impact could be survived at all: a motion that leaves the wall
    # at rest and comes back within about a period makes one impact fatal (checked on
    # a few points, so this only decides how soon to give up, never the verdict)
    period = 2.0 * math.pi / wd
    fatal = False
    for k in range(17):
        tk = period * (0.75 + k / 32.0)
        if _after_impact_at(tk, c, 0.0, sigma, wd, w, X, A, B) > c * (1.0 - 2.0 * margin):
            fatal = True
            break
    # piece 2: safe steps from the end of piece 1; where W may touch the wall, fine
    # steps that record the fastest the motion can arrive there (v1)
    h_touch = margin * c / lip
    t = 0.5 * math.pi / wd
    peak = 0.0
    steps = 0
    v1 = -1.0
    while t < t_end:
        W = _envelope_at(t, c, wn, sigma, wd, w, X, A, B)
        if W > peak:
            peak = W
        steps += 1
        if steps > max_steps:
            return NOT_PROVEN, peak / c, steps
        if W <= c * (1.0 - 2.0 * margin):
            t += (level - W) / lip
        else:
            if W + lip * h_touch >= c:
                # the wall may be reached in [t, t + h_touch]: at most this fast
                if fatal:
                    return NOT_PROVEN, W / c, steps
                v1 = max(v1, _velocity_at(t, c, wn, sigma, wd, w, X, P1, Q1)
                         + lip_v * h_touch)
            t += h_touch
    if v1 < 0.0:
        return SILENT, peak / c, steps
    # after a first impact: from the wall with a rebound speed up to e v1
    kick = e * v1
    lip_b = c * wn + kick * wn / wd
    for i in range(n):
        lip_b += w[i] * abs(X[i]) + Rd[i]
    t_end = math.log(max((r_sum + kick / wd) / (level - x_sum), 1.0)) / sigma
    # (0, pi / wd]: g2 >= 0 keeps the rebound's term out and h >= 0 bounds every tone
    # by a_i (1 - g1) / wn^2, so W_B <= c - (c - S / wn^2) (1 - g1) < c
    t = math.pi / wd
    while t < t_end:
        W = _after_impact_at(t, c, kick, sigma, wd, w, X, A, B)
        steps += 1
        if W > c * (1.0 - 2.0 * margin) or steps > max_steps:
            return NOT_PROVEN, peak / c, steps
        t += (level - W) / lip_b
    return ONE_IMPACT, peak / c, steps
