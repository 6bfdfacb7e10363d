"""Exact event-driven simulation of one impacter against the slider wall.

The impacter moves freely (closed form of :mod:`model.kernels.closed_form`) until
x reaches the wall at x = gap, where the impact law (8) reverses its velocity,
v+ = -e v-.  Impacts are located by *safe steps*: from a point where
g = x - gap < 0 the Taylor bound

    g(t + h) <= g + g' h + M2 h^2 / 2,   M2 >= max |x''| over the rest of the run,

is negative for every h below the positive root of its right-hand side, so the
step to that root cannot jump over a crossing, grazing (tangential) contacts
included.  Near a transversal crossing the steps converge quadratically onto it
from below; a trajectory that passes at any distance above the floating-point
noise of x is stepped past without inventing an impact.

Chattering (impacts accumulating in finite time, as v- shrinks geometrically by
e under a force pressing into the wall) is summed in closed form once the
accumulation time drops below a tiny fraction of a period, and the impacter
then *sticks* at the wall until the net force pulls it away (release found by
the same safe steps on the force).  Leaving the wall from rest uses third- or
fourth-order Taylor bounds, since there g = g' = 0.

Every run ends with a status: OK, EVENT_CAP or STEP_CAP (the caps are arguments,
so no run can hang) or NONFINITE.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from model.kernels.closed_form import (
    REGULAR,
    UNDER,
    derive,
    forcing,
    forcing_bound,
    homogeneous_basis,
    homogeneous_bound,
    homogeneous_regime,
    particular_bound,
    particular_jet_ref,
    particular_ref,
    tone_coefficients,
)

# the kernel's constants and step helpers, also read as model.kernels.impacter.NAME
from model.kernels.impacter_steps import (  # noqa: F401
    OK,
    EVENT_CAP,
    STEP_CAP,
    NONFINITE,
    IMPACT,
    CHATTER_TAIL,
    EPS,
    NOISE,
    CHATTER_TIME,
    MAX_EVENTS,
    MAX_STEPS,
    CHATTER_LOCAL,
    CHATTER_ORDER,
    _FACTORIALS,
    BEAT_WINDOW,
    TAYLOR_WINDOW,
    safe_step,
    _window_step,
    _window_tables,
    _window_bounds,
    _landing,
    _leave_step,
    _push_event,
    _wall_flight,
    _series_value,
    _fill_series,
    _envelope_step,
    _basis,
    _hbound,
    _amplitude,
    _fill_free,
    _fill_const,
)


@njit(cache=True, nogil=True)
def run_impacter(wn, sigma, gap, e, w, a, phi, coef, t0, t_end, x0, v0, stuck0,
                 stop_after, max_events, max_steps, imp_t, imp_v, imp_kind,
                 sample_t, sample_x):
    """Simulate one impacter exactly from t0 to t_end.

    Parameters
    ----------
    wn : float
        Undamped natural angular frequency sqrt(k/m) [rad/s].
    sigma : float
        b / (2 m) [1/s].
    gap : float
        Wall position c [m].
    e : float
        Coefficient of restitution, eq. (8) [-].
    w, a, phi : ndarray, shape (n_tones,)
        Tones of the forcing per unit mass: angular frequency [rad/s],
        amplitude cos(theta) w^2 Z [m/s^2], phase [rad].
    coef : ndarray, shape (n_tones, N_COEF)
        ``tone_coefficients(wn, sigma, w, a, phi)``, passed in so that sweeps
        compute it once per frequency.
    t0, t_end : float
        Start and end of the run [s], 0 <= t0 < t_end.
    x0, v0 : float
        Initial position [m] (<= gap) and velocity [m/s].
    stuck0 : bool
        Start in the sticking phase (requires x0 == gap, v0 == 0).
    stop_after : int
        Stop at the stop_after-th impact (0: never).  2 answers "does it
        respond?" (eq. 12 counts impacts from the second on).
    max_events, max_steps : int
        Caps; reaching one ends the run with EVENT_CAP or STEP_CAP.
    imp_t, imp_v : ndarray, shape (capacity,)
        Receive impact times [s] and velocities v- [m/s]; capacity 0 records
        nothing (response-only runs keep no event list).
    imp_kind : ndarray of int64, shape (capacity,)
        IMPACT, or CHATTER_TAIL for a summed chatter sequence (its "time" is the
        accumulation point and its "velocity" the sum of the sequence's v-).
    sample_t : ndarray, shape (n_samples,)
        Sorted times [s] at which to record the position (may be empty).
    sample_x : ndarray, shape (n_samples,)
        Receives the positions [m].

    Returns
    -------
    status, n_events, sum_v, t_stop, x_end, v_end, stuck_end, n_steps
        n_events counts impacts and chatter tails; sum_v [m/s] is the sum of v-
        over every event but the first (eq. 12); t_stop [s] is where the run
        ended (t_end unless stopped early or capped).
    """
    regime, fr, kappa = homogeneous_regime(wn, sigma)
    tmax = max(abs(t0), abs(t_end))
    pb0 = particular_bound(coef, 0, tmax)
    pb1 = particular_bound(coef, 1, tmax)
    pb2 = particular_bound(coef, 2, tmax)
    pb3 = particular_bound(coef, 3, tmax)
    pb4 = particular_bound(coef, 4, tmax)
    fb2 = forcing_bound(w, a, 2)
    fmax = forcing_bound(w, a, 0)
    wmax = wn
    for i in range(w.shape[0]):
        wmax = max(wmax, w[i])
    chatter_time = CHATTER_TIME * 2.0 * math.pi / wmax
    window = BEAT_WINDOW * 2.0 * math.pi / wmax
    tolf = NOISE * EPS * (wn * wn * gap + fmax)
    series = np.empty(CHATTER_ORDER + 1)
    inv_s = 1.0 / fr if regime == UNDER else 1.0
    n_samples = sample_t.shape[0]
    w_const, w_grow, w_lim = _window_tables(coef)
    has_beat = False
    for i in range(coef.shape[0]):
        if coef[i, 3] != REGULAR:
            has_beat = True
    # one regular tone (every sweep): the beat envelope bounds x, see _envelope_step
    one_tone = regime == UNDER and coef.shape[0] == 1 and coef[0, 3] == REGULAR
    tone_w = coef[0, 0] if one_tone else 1.0
    tone_amp2 = coef[0, 1] ** 2 + coef[0, 2] ** 2 if one_tone else 0.0

    si = 0
    t = t0
    x = x0
    v = v0
    stuck = stuck0
    n_events = 0
    sum_v = 0.0
    steps = 0
    status = OK

    while t < t_end:
        if stuck:
            # sticking phase: x = gap, v = 0 while the net force presses on the wall:
            # G = wn^2 gap - f(t) <= 0.  Find where G crosses zero upwards.
            released = False
            while True:
                steps += 1
                if steps > max_steps:
                    status = STEP_CAP
                    break
                f, df = forcing(w, a, phi, t)
                G = wn * wn * gap - f
                G1 = df * -1.0
                if G > 0.0 or (G >= -tolf and G1 > 0.0):
                    released = True
                    break
                h = safe_step(min(G, -tolf), G1, fb2)
                t_new = t + h
                if t_new >= t_end:
                    si = _fill_const(sample_t, sample_x, si, t_end, gap)
                    t = t_end
                    break
                if t_new == t:
                    t_new = t + 4.0 * EPS * max(abs(t), chatter_time)
                si = _fill_const(sample_t, sample_x, si, t_new, gap)
                t = t_new
            if status != OK:
                break
            x = gap
            v = 0.0
            if not released:
                break
            stuck = False

        # free-flight segment starting at (t, x, v)
        seg_t0 = t
        x_start = x
        v_start = v
        xp, vp, ap, jp = particular_jet_ref(coef, t, seg_t0)
        p = x - xp
        q = (v - vp) + sigma * p
        p1, q1 = derive(p, q, sigma, kappa)
        p2, q2 = derive(p1, q1, sigma, kappa)
        p3, q3 = derive(p2, q2, sigma, kappa)
        p4, q4 = derive(p3, q3, sigma, kappa)
        tau_end = t_end - seg_t0
        # coefficients of E S wd (see _basis)
        qs = q * inv_s
        q1s = q1 * inv_s
        q2s = q2 * inv_s
        q3s = q3 * inv_s
        if has_beat:
            # beat tones are referred to the segment's start: their bounds grow only
            # with the segment's length, not with the time since t = 0
            pb0 = particular_bound(coef, 0, tau_end)
            pb1 = particular_bound(coef, 1, tau_end)
            pb2 = particular_bound(coef, 2, tau_end)
            pb3 = particular_bound(coef, 3, tau_end)
            pb4 = particular_bound(coef, 4, tau_end)
        # per-segment constants of the UNDER bounds (times e^{-sigma tau} each step)
        amp0 = _amplitude(regime, fr, p, q, tau_end)
        amp2 = _amplitude(regime, fr, p2, q2, tau_end)
        amp4 = _amplitude(regime, fr, p4, q4, tau_end)
        # (UNDER: at tau = 0 the bound is the segment constant itself)
        amp = _hbound(regime, sigma, fr, p, q, 0.0, tau_end, 1.0, amp0)
        tolx = NOISE * EPS * (abs(gap) + amp + pb0)
        tola = NOISE * EPS * (wn * wn * (abs(gap) + amp) + pb2 + fmax)
        # an impact needs v above the rounding noise of v: a contact at a velocity
        # within it is a touch at rest (stick or leave), not an impact
        tolv = NOISE * EPS * (_hbound(regime, sigma, fr, p1, q1, 0.0, tau_end, 1.0,
                                      _amplitude(regime, fr, p1, q1, tau_end)) + pb1)
        tolj = NOISE * EPS * (_hbound(regime, sigma, fr, p3, q3, 0.0, tau_end, 1.0,
                                      _amplitude(regime, fr, p3, q3, tau_end))
                              + pb3 + wn * tola)
        new_segment = False
        while True:
            steps += 1
            if steps > max_steps:
                status = STEP_CAP
                break
            tau = t - seg_t0
            if tau == 0.0:
                # the segment's start: its state is known exactly (v = 0 after a
                # release, not the rounding noise of p1 + vp, which may be > 0)
                ec = 1.0
                es = 0.0
                env = 1.0
                x = x_start
                v = v_start
            else:
                # es carries the factor wd of UNDER bases (no division per step)
                ec, es, env = _basis(regime, sigma, fr, tau)
                xp, vp, ap, jp = particular_jet_ref(coef, t, seg_t0)
                x = p * ec + qs * es + xp
                v = p1 * ec + q1s * es + vp
            if not (math.isfinite(x) and math.isfinite(v)):
                status = NONFINITE
                break
            g = x - gap
            if has_beat:
                # bounds over the window [tau, tau + window] only: a beat tone's grows
                # with the time since the segment's start (secular at resonance)
                h_cap = window
                wb0, wb2, wb4 = _window_bounds(w_const, w_grow, w_lim, tau + window)
            else:
                h_cap = math.inf
                wb0 = pb0
                wb2 = pb2
                wb4 = pb4
            m2 = _hbound(regime, sigma, fr, p2, q2, tau, tau_end, env, amp2) + wb2
            contact = g >= -tolx
            if not contact:
                x_hi = _hbound(regime, sigma, fr, p, q, tau, tau_end, env, amp0) + wb0
                if x_hi < gap - tolx:
                    # x stays below the wall over the rest of the run (or the window)
                    h = h_cap
                else:
                    h = min(safe_step(g, v, m2), h_cap)
                    if t + h == t:  # within time resolution of the wall: contact
                        contact = True
                    else:
                        if v > 0.0:
                            # approaching: the fourth-order bound converges faster
                            acc = p2 * ec + q2s * es + ap
                            jerk = p3 * ec + q3s * es + jp
                            m4 = _hbound(regime, sigma, fr, p4, q4, tau, tau_end, env,
                                         amp4) + wb4
                            h = max(h, _window_step(g, v, acc + tola, jerk + tolj, m2, m4,
                                                    min(TAYLOR_WINDOW * h, h_cap)))
                            s_lin = -g / v
                            if m4 * s_lin * s_lin * s_lin <= 6.0 * NOISE * EPS * v:
                                s_land = _landing(g, v, acc, jerk, m4, tola, tolj, tolx)
                                if 0.0 < s_land and t + s_land < t_end:
                                    # the wall is reached at t + s_land, and within the
                                    # rounding noise of x before: land on it there
                                    t_new = t + s_land
                                    si = _fill_free(sample_t, sample_x, si, t_new, regime,
                                                    sigma, fr, p, q, seg_t0, coef)
                                    v = v + s_land * (acc + 0.5 * s_land * jerk)
                                    t = t_new
                                    g = 0.0
                                    contact = True
                        if not contact and one_tone:
                            xh = x - xp
                            vh = v - vp
                            h = max(h, _envelope_step(xh, -(vh + sigma * xh) / fr, xp,
                                                      -vp / tone_w, tone_amp2,
                                                      tone_w - fr, gap - tolx))
            if contact and v > tolv:
                # impact, eq. (8), then the short flights of a chatter sequence
                vminus = v
                if g != 0.0:
                    # contact is declared within the noise of x or within the time
                    # resolution of t (at t ~ 8 s a step of 1 ulp moves x by 1e-16 m,
                    # and a rounded t + h may land just past the wall): take v- at the
                    # wall, v^2 + 2 x'' (gap - x), so that resetting x to the wall
                    # neither adds nor removes energy (it drifted by 4e-11 per impact)
                    acc = p2 * ec + q2s * es + ap
                    vminus = math.sqrt(max(v * v - 2.0 * acc * g, v * v * 0.25))
                while True:
                    status = _push_event(imp_t, imp_v, imp_kind, n_events, t, vminus,
                                         IMPACT, max_events)
                    if status != OK:
                        break
                    n_events += 1
                    if n_events >= 2:
                        sum_v += vminus
                    if stop_after > 0 and n_events >= stop_after:
                        return OK, n_events, sum_v, t, gap, -e * vminus, False, steps
                    x = gap
                    v = -e * vminus
                    f, _ = forcing(w, a, phi, t)
                    acc_wall = f - wn * wn * gap - 2.0 * sigma * v
                    if not (acc_wall > 0.0 and 0.0 < e < 1.0):
                        break
                    t_acc = 2.0 * e * vminus / (acc_wall * (1.0 - e))
                    if t_acc < chatter_time:
                        # chatter: sum the geometric sequence v-_{k+1} = e v-_k
                        tail = vminus * e / (1.0 - e)
                        if tail > 0.0:
                            status = _push_event(imp_t, imp_v, imp_kind, n_events, t + t_acc,
                                                 tail, CHATTER_TAIL, max_events)
                            if status != OK:
                                break
                            n_events += 1
                            sum_v += tail
                            if stop_after > 0 and n_events >= stop_after:
                                return OK, n_events, sum_v, t + t_acc, gap, 0.0, True, steps
                        t_new = min(t + t_acc, t_end)
                        si = _fill_const(sample_t, sample_x, si, t_new, gap)
                        t = t_new
                        v = 0.0
                        stuck = True
                        break
                    # a flight this short is below the resolution of the closed form
                    # (x - gap is a difference of terms as large as the motion): take it
                    # from the series of x at the wall instead, the same function
                    s_fl, vminus = _wall_flight(w, a, phi, t, wn, sigma, gap, v,
                                               max(wmax, 2.0 * sigma), series)
                    if s_fl <= 0.0 or t + s_fl == t:
                        break
                    steps += 1
                    if steps > max_steps:
                        status = STEP_CAP
                        break
                    if t + s_fl >= t_end:
                        si = _fill_series(sample_t, sample_x, si, t_end, t, series)
                        x = gap + _series_value(series, t_end - t, 0)
                        v = _series_value(series, t_end - t, 1)
                        t = t_end
                        break
                    si = _fill_series(sample_t, sample_x, si, t + s_fl, t, series)
                    t = t + s_fl
                if status != OK or t >= t_end:
                    break
                new_segment = True
                break
            if contact:
                # at the wall and not approaching it: leave, or stick if pressed on it
                acc = p2 * ec + q2s * es + ap
                jerk = p3 * ec + q3s * es + jp
                m4 = _hbound(regime, sigma, fr, p4, q4, tau, tau_end, env, amp4) + pb4
                h = 0.0
                if v < 0.0:
                    # moving off the wall: v stays < 0 (x falls) for h < -v / m2, and
                    # g <= tolx + v h + m h^2 / 2 stays < 0 until its larger root,
                    # with m = m2 or the fourth-order bound
                    h = max(-v / m2 if m2 > 0.0 else math.inf, _leave_step(v, m2, tolx))
                    big_h = TAYLOR_WINDOW * h
                    m2e = max(acc + tola, acc + tola + big_h * ((jerk + tolj) / 3.0
                                                                 + m4 * big_h / 12.0))
                    h = max(h, min(big_h, _leave_step(v, m2e, tolx)))
                if acc < -tola:
                    # leaving from rest: g <= acc h^2 / 2 + m3 h^3 / 6 (half its root)
                    m3 = homogeneous_bound(regime, sigma, fr, p3, q3, tau, tau_end) + pb3
                    h = max(h, -1.5 * acc / m3)
                elif acc <= tola and jerk < 0.0:
                    # at rest with no force on the wall: g <= jerk h^3 / 6 + m4 h^4 / 24
                    h = max(h, -2.0 * jerk / m4)
                if h <= 0.0 or t + h == t:
                    if acc >= -tola:
                        x = gap
                        v = 0.0
                        stuck = True
                        new_segment = True
                        break
                    h = 4.0 * EPS * max(abs(t), chatter_time)
            t_new = t + h
            if t_new >= t_end:
                si = _fill_free(sample_t, sample_x, si, t_end, regime, sigma, fr, p, q,
                                seg_t0, coef)
                ec, es = homogeneous_basis(regime, sigma, fr, t_end - seg_t0)
                xp, vp, _ = particular_ref(coef, t_end, seg_t0)
                x = min(p * ec + q * es + xp, gap)
                v = p1 * ec + q1 * es + vp
                t = t_end
                break
            if si < n_samples:
                si = _fill_free(sample_t, sample_x, si, t_new, regime, sigma, fr, p, q,
                                seg_t0, coef)
            t = t_new
        if status != OK or not new_segment:
            break

    if status == OK:
        # samples at or after t_end (the end point itself)
        ns = sample_t.shape[0]
        while si < ns:
            sample_x[si] = x
            si += 1
    return status, n_events, sum_v, t, x, v, stuck, steps


@njit(cache=True, nogil=True)
def _response_one(wn, sigma, gap, e, w, a, phi, coef, t0, t_end, x0, v0,
                  stop_after, max_events, max_steps):
    empty = np.empty(0)
    kinds = np.empty(0, dtype=np.int64)
    stuck0 = x0 == gap and v0 == 0.0
    return run_impacter(wn, sigma, gap, e, w, a, phi, coef, t0, t_end, x0, v0, stuck0,
                        stop_after, max_events, max_steps, empty, empty, kinds,
                        empty, empty)


@njit(cache=True, parallel=True, nogil=True)
def response_grid(wn, sigma, gap, e, w, a, phi, starts, x0s, v0s, t_end, stop_after,
                  max_events, max_steps):
    """Sums of v- (eq. 12 numerator / m) of every drive from every initial state, in parallel.

    The one parallel entry point of the response runs: ``model.responses`` (one drive,
    many initial states) and :func:`sweep_batch` (one tone per frequency) both call it,
    so the exact kernel is compiled once for them (numba re-optimises a callee inside
    every entry point that calls it).

    Parameters
    ----------
    w, a, phi : ndarray, shape (n_tones,)
        The tones of every drive, one after the other [rad/s, m/s^2, rad].
    starts : ndarray of int64, shape (n_drives + 1,)
        Drive d plays tones ``starts[d]:starts[d + 1]``.
    x0s, v0s : ndarray, shape (n_x0,)
        Initial states [m, m/s], each run from every drive.

    Returns
    -------
    sum_v : ndarray, shape (n_drives, n_x0)
        [m/s]; r = m sum_v / t_end.
    n_events, status : ndarray of int64, shape (n_drives, n_x0)
    """
    nd = starts.shape[0] - 1
    nx = x0s.shape[0]
    # every tone's constants, once, shared by every initial state (one row per tone,
    # independent of the other tones of its drive)
    coef = tone_coefficients(wn, sigma, w, a, phi)
    sum_v = np.zeros((nd, nx))
    n_events = np.zeros((nd, nx), dtype=np.int64)
    status = np.zeros((nd, nx), dtype=np.int64)
    for k in prange(nd * nx):
        d = k // nx
        j = k % nx
        s0 = starts[d]
        s1 = starts[d + 1]
        res = _response_one(wn, sigma, gap, e, w[s0:s1], a[s0:s1], phi[s0:s1],
                            coef[s0:s1], 0.0, t_end, x0s[j], v0s[j], stop_after,
                            max_events, max_steps)
        status[d, j] = res[0]
        n_events[d, j] = res[1]
        sum_v[d, j] = res[2]
    return sum_v, n_events, status


def sweep_batch(wn, sigma, gap, e, w_list, a_list, x0s, t_end, stop_after,
                max_events, max_steps):
    """One-tone responses over a frequency x initial-position grid, in parallel
    (:func:`response_grid` with one single-tone drive per frequency).

    Parameters
    ----------
    w_list, a_list : ndarray, shape (n_freq,)
        Angular frequency [rad/s] and forcing amplitude per unit mass [m/s^2].
    x0s : ndarray, shape (n_x0,)
        Initial positions [m], v0 = 0.

    Returns
    -------
    sum_v : ndarray, shape (n_freq, n_x0)
        [m/s] (eq. 12 numerator over m).
    status : ndarray of int64, shape (n_freq, n_x0)
    """
    w_list = _vector(w_list)
    x0s = _vector(x0s)
    starts = np.arange(w_list.shape[0] + 1, dtype=np.int64)
    sum_v, _, status = response_grid(
        float(wn), float(sigma), float(gap), float(e), w_list, _vector(a_list),
        np.zeros(w_list.shape[0]), starts, x0s, np.zeros(x0s.shape[0]), float(t_end),
        int(stop_after), int(max_events), int(max_steps))
    return sum_v, status


def _vector(x):
    """A writable C-contiguous float64 copy-if-needed of ``x``: one specialisation of
    :func:`response_grid` whatever the caller holds (a read-only array, e.g. a frozen
    Drive's phases, is a different numba type and would compile the kernel again)."""
    x = np.asarray(x, dtype=np.float64)
    if not (x.flags.c_contiguous and x.flags.writeable):
        x = np.array(x, dtype=np.float64, order="C")
    return x


@njit(cache=True, nogil=True)
def response_single(wn, sigma, gap, e, w, a, phi, t_end, x0, v0, stop_after,
                    max_events, max_steps):
    """One response-only run (no events kept, no trajectory): (status, n_events, sum_v)."""
    coef = tone_coefficients(wn, sigma, w, a, phi)
    res = _response_one(wn, sigma, gap, e, w, a, phi, coef, 0.0, t_end, x0, v0,
                        stop_after, max_events, max_steps)
    return res[0], res[1], res[2]
