"""Exact stick-slip simulation of the slider between impact kicks.

The slider obeys eqs. (6)-(7) (with the paper's sign typo fixed: dynamic
friction is F_d zeta'/|zeta'|, opposing the velocity), divided by M:

    stuck (V = 0, |f(t)| < fs):  V' = 0
    slipping with s = sign(V):   V' = -beta V + f(t) - s fd,

with beta = B/M, fs = F_s/M, fd = F_d/M and f(t) = sum a_i cos(w_i t + phi_i)
the inertial forcing per unit mass (a_i = w_i^2 Z_i).  A slip phase is a linear
first-order ODE with sinusoidal forcing: its closed form (written with
phi1 = (1 - e^{-beta tau})/beta and phi2 = (tau - phi1)/beta, both stable as
beta -> 0) gives V and the position exactly.  The end of a slip (V reaching 0)
and the start of one (|f| reaching fs) are found by the safe steps of
:mod:`model.kernels.impacter`.  Kicks from impacts change V instantaneously at
given times: by given velocity changes (eq. 10, the paper's contact law), or by
the two-body law of :mod:`model.kernels.contact`, which needs the slider's
velocity at the instant of the impact and so is applied here.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from model.kernels.contact import PAPER, two_body_kick
from model.kernels.impacter import EPS, NOISE, NONFINITE, OK, STEP_CAP, safe_step


@njit(cache=True, nogil=True)
def _phi12(beta, tau):
    """phi1 = (1 - e^{-beta tau}) / beta and phi2 = (tau - phi1) / beta [s, s^2]."""
    bt = beta * tau
    if bt < 1e-4:
        # series: no cancellation for small beta tau (exact limit at beta = 0)
        phi1 = tau * (1.0 - bt / 2.0 + bt * bt / 6.0 - bt * bt * bt / 24.0)
        phi2 = tau * tau * (0.5 - bt / 6.0 + bt * bt / 24.0 - bt * bt * bt / 120.0)
    else:
        phi1 = -math.expm1(-bt) / beta
        phi2 = (tau - phi1) / beta
    return phi1, phi2


@njit(cache=True, nogil=True)
def _slip_start(w, cr, ci, t_a, ca, sa, re_a):
    """Fill ``ca``, ``sa`` (cos, sin of w t_a) and ``re_a`` (Re[c e^{i w t_a}]) of a slip
    started at t_a [s]: what every :func:`_slip_state` of that slip reads."""
    for i in range(w.shape[0]):
        ca[i] = math.cos(w[i] * t_a)
        sa[i] = math.sin(w[i] * t_a)
        re_a[i] = cr[i] * ca[i] - ci[i] * sa[i]


@njit(cache=True, nogil=True)
def _slip_state(beta, fd, s, w, cr, ci, t_a, z_a, v_a, t, ca, sa, re_a):
    """Position [m] and velocity [m/s] at t of a slip started at (t_a, z_a, v_a);
    ``ca``, ``sa``, ``re_a`` of :func:`_slip_start` at t_a (computed once per slip: the
    same digits as computed here each time, at half the trigonometry)."""
    tau = t - t_a
    phi1, phi2 = _phi12(beta, tau)
    decay = math.exp(-beta * tau)
    v = decay * v_a - s * fd * phi1
    z = z_a + v_a * phi1 - s * fd * phi2
    for i in range(w.shape[0]):
        ct = math.cos(w[i] * t)
        st = math.sin(w[i] * t)
        # Re[c e^{i w t}] = cr cos - ci sin
        re_t = cr[i] * ct - ci[i] * st
        v += re_t - decay * re_a[i]
        # Re[c (e^{iwt} - e^{iwta}) / (i w)] = (cr (sin t - sin a) + ci (cos t - cos a)) / w
        z += (cr[i] * (st - sa[i]) + ci[i] * (ct - ca[i])) / w[i] - re_a[i] * phi1
    return z, v


@njit(cache=True, nogil=True)
def _kicked(contact, v, k, kick_dv, kick_rec):
    """Slider velocity [m/s] after kick k, from v [m/s] just before it."""
    if contact == PAPER:
        return v + kick_dv[k]
    return two_body_kick(v, kick_rec[k])


@njit(cache=True, nogil=True)
def run_slider(contact, beta, fs, fd, w, a, phi, kick_t, kick_dv, kick_rec, t0, t_end,
               z0, v0, max_steps, sample_t, sample_z, f_bound=0.0):
    """Simulate the slider exactly from t0 to t_end under forcing and kicks.

    Parameters
    ----------
    contact : int
        Contact law of :mod:`model.kernels.contact`: PAPER applies ``kick_dv``,
        TWO_BODY computes each kick from ``kick_rec`` and the slider velocity at
        the kick.
    beta : float
        B / M [1/s].
    fs, fd : float
        Static and dynamic friction per unit mass, F_s/M and F_d/M [m/s^2].
    w, a, phi : ndarray, shape (n_tones,)
        Forcing per unit mass: angular frequency [rad/s], amplitude w^2 Z
        [m/s^2], phase [rad].
    kick_t : ndarray, shape (n_kicks,)
        Sorted kick times [s].
    kick_dv : ndarray, shape (n_kicks,)
        Velocity changes [m/s] (eq. 10); read with PAPER only.
    kick_rec : ndarray, shape (n_kicks, N_COLS)
        Per-kick record of :mod:`model.kernels.contact` (v-, direction, gain,
        cos(theta), e, chatter flag); read with TWO_BODY only.
    t0, t_end : float
        Time window [s].
    z0, v0 : float
        Initial position [m] and velocity [m/s].
    max_steps : int
        Cap on root-finding steps.
    sample_t, sample_z : ndarray, shape (n_samples,)
        Sorted sample times [s]; receives positions [m].
    f_bound : float, optional
        An upper bound of |f(t)| over [t0, t_end] [m/s^2] (0: none, sum |a_i| is used).
        Where it stays under the slip threshold, a stuck slider stays stuck until the
        next kick without stepping through the forcing (the same result).

    Returns
    -------
    status, z_end, v_end, n_steps
    """
    n_t = w.shape[0]
    cr = np.empty(n_t)
    ci = np.empty(n_t)
    ca = np.empty(n_t)
    sa = np.empty(n_t)
    re_a = np.empty(n_t)
    amp_v = 0.0
    bound_f2 = 0.0
    fmax = 0.0
    for i in range(n_t):
        # c = a e^{i phi} / (beta + i w)
        den = beta * beta + w[i] * w[i]
        ar = a[i] * math.cos(phi[i])
        ai = a[i] * math.sin(phi[i])
        cr[i] = (ar * beta + ai * w[i]) / den
        ci[i] = (ai * beta - ar * w[i]) / den
        amp_v += math.sqrt(cr[i] ** 2 + ci[i] ** 2)
        bound_f2 += abs(a[i]) * w[i] * w[i]
        fmax += abs(a[i])
    bound_c2 = 0.0
    for i in range(n_t):
        bound_c2 += math.sqrt(cr[i] ** 2 + ci[i] ** 2) * w[i] * w[i]

    nk = kick_t.shape[0]
    k = 0
    while k < nk and kick_t[k] < t0:
        k += 1
    ns = sample_t.shape[0]
    si = 0
    t = t0
    z = z0
    v = v0
    steps = 0
    tolf = NOISE * EPS * (fs + fmax)
    # |f| <= f_bound <= sum |a_i| = fmax (f computed within n_t roundings of fmax): when
    # that stays under the slip threshold fs - tolf, a stuck slider stays stuck until the
    # next kick, and the stuck phase need not be stepped through (the die's drive below
    # static friction: the common case, where only the kicks move the slider)
    bound = fmax if f_bound <= 0.0 else min(f_bound, fmax)
    never_slips = fs > 0.0 and bound + 4.0 * (n_t + 1) * EPS * fmax < fs - tolf
    while t < t_end:
        t_next = kick_t[k] if k < nk else t_end
        t_next = min(t_next, t_end)
        if v == 0.0:
            # stuck until the next kick or until |f| reaches fs
            start_slip = False
            s = 0.0
            if never_slips and t < t_next:
                while si < ns and sample_t[si] < t_next:
                    sample_z[si] = z
                    si += 1
                t = t_next
            while t < t_next:
                steps += 1
                if steps > max_steps:
                    return STEP_CAP, z, v, steps
                f = 0.0
                df = 0.0
                for i in range(n_t):
                    arg = w[i] * t + phi[i]
                    f += a[i] * math.cos(arg)
                    df -= a[i] * w[i] * math.sin(arg)
                if abs(f) >= fs - tolf and fs > 0.0 or (fs == 0.0 and f != 0.0):
                    start_slip = True
                    s = 1.0 if f > 0.0 else -1.0
                    break
                h = min(safe_step(f - fs, df, bound_f2), safe_step(-f - fs, -df, bound_f2))
                t_new = min(t + max(h, 4.0 * EPS * max(abs(t), 1e-9)), t_next)
                while si < ns and sample_t[si] < t_new:
                    sample_z[si] = z
                    si += 1
                t = t_new
            if not start_slip:
                if k < nk and t >= kick_t[k] and t < t_end:
                    v = _kicked(contact, v, k, kick_dv, kick_rec)
                    k += 1
                continue
        else:
            s = 1.0 if v > 0.0 else -1.0
        # slip phase from (t, z, v) with direction s, until V = 0 or the next kick
        t_a = t
        z_a = z
        v_a = v
        _slip_start(w, cr, ci, t_a, ca, sa, re_a)
        tolv = NOISE * EPS * (abs(v_a) + amp_v + fd * (t_end - t_a))
        stopped = False
        while True:
            steps += 1
            if steps > max_steps:
                return STEP_CAP, z, v, steps
            z, v = _slip_state(beta, fd, s, w, cr, ci, t_a, z_a, v_a, t, ca, sa, re_a)
            if not (math.isfinite(z) and math.isfinite(v)):
                return NONFINITE, z, v, steps
            g = -s * v
            f = 0.0
            for i in range(n_t):
                f += a[i] * math.cos(w[i] * t + phi[i])
            dv = -beta * v + f - s * fd
            if g >= -tolv and -s * dv >= 0.0:
                stopped = True
                break
            decay = math.exp(-beta * (t - t_a))
            m2 = decay * (beta * beta * (abs(v_a) + amp_v) + beta * fd) + bound_c2
            h = safe_step(min(g, -tolv), -s * dv, m2)
            t_new = t + h
            if t_new == t:
                stopped = True
                break
            if t_new >= t_next:
                t_new = t_next
            while si < ns and sample_t[si] < t_new:
                zs, _ = _slip_state(beta, fd, s, w, cr, ci, t_a, z_a, v_a, sample_t[si],
                                    ca, sa, re_a)
                sample_z[si] = zs
                si += 1
            t = t_new
            if t >= t_next:
                z, v = _slip_state(beta, fd, s, w, cr, ci, t_a, z_a, v_a, t, ca, sa, re_a)
                break
        if stopped:
            v = 0.0
            # at V = 0: the stuck branch decides whether a new slip starts (|f| >= fs)
            continue
        if k < nk and t >= kick_t[k] and t < t_end:
            v = _kicked(contact, v, k, kick_dv, kick_rec)
            k += 1
    while si < ns:
        sample_z[si] = z
        si += 1
    return OK, z, v, steps
