"""Constants and step helpers of the impacter kernel (:mod:`model.kernels.impacter`).

The status codes and event kinds of a run, the rounding allowance of the bounds, the
chatter series' order, and the small numba functions :func:`~model.kernels.impacter.
run_impacter` is built from: safe steps from Taylor and envelope bounds, the landing and
leaving tests at the wall, the wall flight of a chatter sequence, the dense-output fills
and the event buffer.  Their equations are in :mod:`model.kernels.impacter`'s notes.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from model.kernels.closed_form import (
    REGULAR,
    UNDER,
    homogeneous_basis,
    homogeneous_bound,
    particular_ref,
)


OK = 0
EVENT_CAP = 1
STEP_CAP = 2
NONFINITE = 3

#: Impact kinds in a recorded event list.
IMPACT = 0
CHATTER_TAIL = 1  # the closed-form sum of an accumulating chatter sequence

EPS = 2.220446049250313e-16
#: Floating-point noise allowance of a closed-form evaluation, in units of eps
#: times the magnitudes summed: a crossing closer than this to the wall is contact.
NOISE = 32.0
#: A chatter sequence whose remaining accumulation time is below this fraction of
#: the shortest period is summed in closed form and the impacter sticks.
CHATTER_TIME = 1e-9
#: Defaults for the caps that keep every run finite.
MAX_EVENTS = 1_000_000
MAX_STEPS = 50_000_000
#: Flights from the wall shorter than CHATTER_LOCAL / rate (rate: the fastest of wn,
#: the drive frequencies and 2 sigma) are taken from the Taylor series of x at the
#: wall, to order CHATTER_ORDER (remainder below 0.5^25 / 25! ~ 2e-33 of the motion).
#: The closed form cannot resolve low flights: its x - gap carries the rounding noise
#: of terms as large as the whole motion, 1e-10 of the speed of a 1e-12 m flight.
CHATTER_LOCAL = 0.5
CHATTER_ORDER = 24
_FACTORIALS = np.array([float(math.factorial(k)) for k in range(CHATTER_ORDER + 1)])
#: With beat tones, bounds hold over windows of this many shortest periods (the
#: step is capped there): a beat tone's bound grows with its time since t_ref.
BEAT_WINDOW = 0.75
#: Window of the fourth-order safe step, as a multiple of the second-order one:
#: the bound is tried once on [0, TAYLOR_WINDOW h2] (a second try costs as much
#: latency as a third of a step and gains less).
TAYLOR_WINDOW = 2.0


@njit(cache=True, inline='always')
def safe_step(g, g1, m2):
    """Largest h with g + g1 h + m2 h^2 / 2 < 0 on [0, h), for g < 0 [s].

    m2 may be negative (a concave bound): then the parabola may never reach 0.
    """
    disc = g1 * g1 - 2.0 * m2 * g
    if disc < 0.0:  # only when m2 < 0: the concave bound stays below 0
        return math.inf
    sq = math.sqrt(disc)
    if g1 >= 0.0:
        den = g1 + sq
        return math.inf if den == 0.0 else -2.0 * g / den
    if m2 <= 0.0:
        return math.inf
    return (-g1 + sq) / m2


@njit(cache=True, inline='always')
def _window_step(g, v, acc, jerk, m2, m4, big_h):
    """A safe step of at most big_h from the fourth-order Taylor bound [s].

    For 0 <= h <= H,  g(t + h) <= g + v h + (h^2 / 2) (acc + jerk h / 3 + m4 h^2 / 12)
    and the bracket, convex in h, is at most max(acc, acc + jerk H / 3 + m4 H^2 / 12):
    a quadratic bound valid on [0, H] whose safe step, capped at H, is safe.
    acc and jerk must already carry their rounding allowance (upper bounds of the
    second and third derivatives); m2 and m4 bound the second and fourth over the
    rest of the run.
    """
    m2e = max(acc, acc + big_h * (jerk / 3.0 + m4 * big_h / 12.0))
    return min(big_h, safe_step(g, v, min(m2e, m2)))


@njit(cache=True, nogil=True)
def _window_tables(coef):
    """Constants of :func:`_window_bounds`, per run.

    Returns
    -------
    const : ndarray, shape (3,)
        The parts of the bounds of orders 0, 2, 4 that do not grow with tau.
    grow : ndarray, shape (n_tones, 3)
        |G| w^n of each beat tone (0 for regular tones), multiplying min(tau, lim).
    lim : ndarray, shape (n_tones,)
        2 / |lambda| of each beat tone (see :func:`particular_bound`).
    """
    n = coef.shape[0]
    const = np.zeros(3)
    grow = np.zeros((n, 3))
    lim = np.full(n, math.inf)
    for i in range(n):
        w = coef[i, 0]
        amp = math.sqrt(coef[i, 1] ** 2 + coef[i, 2] ** 2)
        for k in range(3):
            order = 2 * k
            if coef[i, 3] == REGULAR:
                const[k] += amp * w ** order
            else:
                sg = coef[i, 4]
                dl = coef[i, 5]
                lam = math.sqrt(sg * sg + dl * dl)
                if lam > 0.0:
                    lim[i] = 2.0 / lam
                mu = math.sqrt(sg * sg + (w + dl) ** 2)
                grow[i, k] = amp * w ** order
                for j in range(order):
                    const[k] += amp * w ** (order - 1 - j) * mu ** j
    return const, grow, lim


@njit(cache=True, inline='always')
def _window_bounds(const, grow, lim, tau_w):
    """Bounds on the particular part and its second and fourth derivatives over
    [t_ref, t_ref + tau_w], beat tones referred to t_ref: particular_bound with
    tmax = tau_w, from the tables of :func:`_window_tables`."""
    b0 = const[0]
    b2 = const[1]
    b4 = const[2]
    for i in range(grow.shape[0]):
        e1 = min(tau_w, lim[i])
        b0 += grow[i, 0] * e1
        b2 += grow[i, 1] * e1
        b4 += grow[i, 2] * e1
    return b0, b2, b4


@njit(cache=True, inline='always')
def _landing(g, v, acc, jerk, m4, tola, tolj, tolx):
    """Time s* to the wall when an approach is within a step of it [s]; -1 if not.

    Approaching (g < 0 < v), g(s) = T(s) + R(s) with T = g + v s + acc s^2 / 2 +
    jerk s^3 / 6 and |R| <= m4 s^4 / 24 + tola s^2 / 2 + tolj s^3 / 6 (remainder and
    the rounding of acc and jerk).  When T increases on [0, s*] (T' >= v / 2), |R(s*)|
    is below half the rounding noise of x and the error of T'(s*) as v- is below
    NOISE * EPS * v, x stays below the wall (up to its noise) until s* and reaches it
    there: the impact is at s* with v- = T'(s*), which saves the last step of the
    approach.
    """
    s = -g / v
    for _ in range(3):
        dt = v + s * (acc + 0.5 * s * jerk)
        if not dt > 0.0:
            return -1.0
        s -= (g + s * (v + s * (0.5 * acc + s * jerk / 6.0))) / dt
    if not s > 0.0:
        return -1.0
    if abs(acc) * s + 0.5 * abs(jerk) * s * s > 0.5 * v:
        return -1.0
    if not s * s * (0.5 * tola + s * (tolj / 6.0 + s * m4 / 24.0)) <= 0.5 * tolx:
        return -1.0
    if not s * (tola + s * (0.5 * tolj + s * m4 / 6.0)) <= NOISE * EPS * v:
        return -1.0
    return s


@njit(cache=True, nogil=True)
def _leave_step(v, m2, tol):
    """Larger root of tol + v h + m2 h^2 / 2 for v < 0: a safe step off the wall [s].

    From the wall (g within tol of 0) moving away (v < 0), the bound is negative
    from about tol / |v| (below the rounding noise of x) to this root.
    """
    if m2 <= 0.0:
        return math.inf
    disc = v * v - 2.0 * m2 * tol
    if disc <= 0.0:
        return 0.0
    return (-v + math.sqrt(disc)) / m2


@njit(cache=True, nogil=True)
def _push_event(imp_t, imp_v, imp_kind, n, t, v, kind, max_events):
    """Record event n (if there is room); EVENT_CAP when the caps forbid it."""
    if n >= max_events:
        return EVENT_CAP
    capacity = imp_t.shape[0]
    if n < capacity:
        imp_t[n] = t
        imp_v[n] = v
        imp_kind[n] = kind
    elif capacity > 0:
        return EVENT_CAP
    return OK


@njit(cache=True, nogil=True)
def _wall_flight(w, a, phi, t, wn, sigma, gap, v, rate, series):
    """A short flight from the wall by the Taylor series of x at t [s, m/s].

    From (t, x = gap, v < 0) the free motion has the derivatives
    x^(k) = f^(k-2) - 2 sigma x^(k-1) - wn^2 x^(k-2) (eq. 1 differentiated), all
    exact from the drive's derivatives, and g(s) = sum_k x^(k) s^k / k!.  Its
    first positive root is found by Newton on g(s) / s.  The series is used
    only when the flight is short (rate s <= CHATTER_LOCAL, so the terms beyond
    order CHATTER_ORDER are below 1e-32 of the motion) and when its quadratic
    term dominates the higher ones on [0, s] (so g / s increases there and the
    root is the first and only one).

    Parameters
    ----------
    series : ndarray, shape (CHATTER_ORDER + 1,)
        Receives x^(k)(t) [m/s^k] (series[0] = gap).

    Returns
    -------
    s, v_minus : float
        Flight time [s] and velocity at the return [m/s]; s = -1 when the
        series does not apply (the caller uses the closed form).
    """
    n = series.shape[0]
    for k in range(n):
        series[k] = 0.0
    # forcing derivatives f^(j)(t), j = 0 .. n - 3, into series[2:] for now
    for i in range(w.shape[0]):
        arg = w[i] * t + phi[i]
        c = math.cos(arg)
        sn = math.sin(arg)
        m = a[i]
        for j in range(n - 2):
            r = j % 4
            val = c if r == 0 else (-sn if r == 1 else (-c if r == 2 else sn))
            series[j + 2] += m * val
            m *= w[i]
    series[0] = gap
    series[1] = v
    wn2 = wn * wn
    for k in range(2, n):
        series[k] = series[k] - 2.0 * sigma * series[k - 1] - wn2 * series[k - 2]
    d2 = series[2]
    if not (v < 0.0 and d2 > 0.0):
        return -1.0, 0.0
    s = -2.0 * v / d2
    if not (s * rate <= CHATTER_LOCAL):
        return -1.0, 0.0
    for _ in range(30):
        # Q(s) = g(s) / s = sum_{k>=1} x^(k) s^(k-1) / k! and its derivative
        q = 0.0
        dq = 0.0
        for k in range(n - 1, 0, -1):
            inv = 1.0 / _FACTORIALS[k]
            dq = dq * s + q
            q = q * s + series[k] * inv
        step = q / dq if dq > 0.0 else 0.0
        s -= step
        if not (s > 0.0) or abs(step) <= 4.0 * EPS * s:
            break
    if not (s > 0.0 and s * rate <= CHATTER_LOCAL):
        return -1.0, 0.0
    # Q' >= d2 / 2 - sum_{k>=3} |x^(k)| (k - 1) s^(k-2) / k! > 0 on [0, s]
    rest = 0.0
    sp = 1.0
    for k in range(3, n):
        sp *= s
        rest += abs(series[k]) * (k - 1) * sp / _FACTORIALS[k]
    if not (rest < 0.25 * d2):
        return -1.0, 0.0
    v_minus = _series_value(series, s, 1)
    if not (v_minus > 0.0):
        return -1.0, 0.0
    return s, v_minus


@njit(cache=True, nogil=True)
def _series_value(series, s, order):
    """order-th derivative (0 or 1) of sum_{k>=1} series[k] s^k / k! at s."""
    n = series.shape[0]
    total = 0.0
    for k in range(n - 1, order - 1, -1):
        if k == 0:
            break
        total = total * s + series[k] / _FACTORIALS[k - order]
    return total * s if order == 0 else total


@njit(cache=True, nogil=True)
def _fill_series(sample_t, sample_x, si, t_b, t_a, series):
    """Positions gap + g(t - t_a) from a wall series at the samples below t_b."""
    ns = sample_t.shape[0]
    while si < ns and sample_t[si] < t_b:
        sample_x[si] = series[0] + _series_value(series, sample_t[si] - t_a, 0)
        si += 1
    return si


@njit(cache=True, inline='always')
def _envelope_step(zhr, zhi, zpr, zpi, amp_p2, delta, level):
    """A safe step from the beat envelope, for one regular tone [s].

    With one tone the motion is x = Re(Z_h + Z_p), two phasors turning at the
    damped frequency wd and at the drive frequency w, the first one shrinking by
    e^{-sigma tau}.  So for s >= 0, x(t + s) <= max(|Z_p|, |Z_p + R e^{i theta(s)}|)
    with R = |Z_h(t)| and theta turning at delta = w - wd relative to Z_p: the
    beat envelope, which changes at the slow rate delta, not at w.  While it
    stays below the wall no impact can happen; its square,
    G(s) = |Z_p|^2 + R^2 + 2 Re(Z_p conj(Z_h) e^{i delta s}) - level^2, has
    |G''| <= 2 |Z_p| R delta^2, which gives a safe step as for x itself.

    Parameters
    ----------
    zhr, zhi, zpr, zpi : float
        Real and imaginary parts of Z_h and Z_p at t [m]; the real parts are
        x_h and x_p.
    amp_p2 : float
        |Z_p|^2 [m^2], constant.
    delta : float
        w - wd [rad/s].
    level : float
        The wall less the rounding allowance of x [m].

    Returns
    -------
    h : float
        0 when the envelope is at or above the level.
    """
    if amp_p2 >= level * level or level <= 0.0:
        return 0.0
    amp_h2 = zhr * zhr + zhi * zhi
    cr = zpr * zhr + zpi * zhi
    ci = zpi * zhr - zpr * zhi
    tol = NOISE * EPS * (amp_p2 + amp_h2 + level * level)
    big_g = amp_p2 + amp_h2 + 2.0 * cr - level * level + tol
    if big_g >= 0.0:
        return 0.0
    return safe_step(big_g, -2.0 * delta * ci,
                     2.0 * delta * delta * math.sqrt(amp_p2 * amp_h2))


@njit(cache=True, inline='always')
def _basis(regime, sigma, fr, tau):
    """(E C, E S s, decay) at tau [s], s = wd (UNDER) or 1: :func:`homogeneous_basis`
    with E S scaled so that the step needs no division; decay = e^{-sigma tau}
    scales UNDER bounds.  The exponential is skipped when sigma == 0.
    """
    if regime == UNDER:
        env = 1.0 if sigma == 0.0 else math.exp(-sigma * tau)
        arg = fr * tau
        return env * math.cos(arg), env * math.sin(arg), env
    ec, es = homogeneous_basis(regime, sigma, fr, tau)
    return ec, es, 1.0


@njit(cache=True, inline='always')
def _hbound(regime, sigma, fr, p, q, tau, tau_end, env, amp):
    """Bound on |E (p C + q S)| over [tau, tau_end]; amp from :func:`_amplitude`."""
    if regime == UNDER:
        return env * amp
    return homogeneous_bound(regime, sigma, fr, p, q, tau, tau_end)


@njit(cache=True, inline='always')
def _amplitude(regime, fr, p, q, tau_end):
    """Segment constant of an UNDER bound: homogeneous_bound / e^{-sigma tau}."""
    if regime != UNDER:
        return 0.0
    a = math.sqrt(p * p + (q / fr) ** 2) if fr > 0.0 else math.inf
    return min(a, abs(p) + abs(q) * tau_end)


@njit(cache=True, nogil=True)
def _fill_free(sample_t, sample_x, si, t_b, regime, sigma, fr, p, q, seg_t0, coef):
    """Closed-form positions at the sample times below t_b; returns the next index."""
    ns = sample_t.shape[0]
    while si < ns and sample_t[si] < t_b:
        ts = sample_t[si]
        ec, es = homogeneous_basis(regime, sigma, fr, ts - seg_t0)
        xp, _, _ = particular_ref(coef, ts, seg_t0)
        sample_x[si] = p * ec + q * es + xp
        si += 1
    return si


@njit(cache=True, nogil=True)
def _fill_const(sample_t, sample_x, si, t_b, value):
    ns = sample_t.shape[0]
    while si < ns and sample_t[si] < t_b:
        sample_x[si] = value
        si += 1
    return si
