"""Closed-form solution of the impacter's equation between impacts.

Between impacts the impacter obeys eq. (1) of Saitou et al. (2000) divided by m,

    x'' + 2 sigma x' + wn**2 x = sum_i a_i cos(w_i t + phi_i),          (1)

with sigma = b / (2 m) [1/s], wn = sqrt(k / m) [rad/s] and a_i = cos(theta) w_i**2 Z_i
[m/s^2] the inertial forcing per unit mass of tone i (eq. 5, summed over tones).
Its solution is x = x_h + x_p: a homogeneous part set by the state at the start of
the free-flight segment, and a particular part that is a fixed function of absolute
time.  Every function here is a pure numba kernel of floats and arrays in SI units.

Homogeneous part
    x_h(tau) = E(tau) (p C(tau) + q S(tau)),  tau = t - t0,
    with (E C, E S) = (e^{-sigma tau} cos(wd tau), e^{-sigma tau} sin(wd tau)/wd)
    (under-damped and undamped), (e^{-sigma tau}, tau e^{-sigma tau}) (critical), or
    the hyperbolic pair written with ``expm1`` (over-damped), so that all regimes,
    including damping ratios within 1e-12 of critical, are evaluated without
    cancellation.  Differentiation maps (p, q) -> (q - sigma p, kappa p - sigma q)
    with kappa = -wd**2, 0 or +gamma**2, so any derivative has the same form.

Particular part, per tone
    regular:  P cos(w t) + Q sin(w t) with P + iQ* from the transfer function;
    beat:     for a lightly damped impacter (sigma < BEAT_DETUNING wn) driven near
              (or exactly at) resonance, Re[G e^{i w t} E1(t)] with
              E1(t) = expm1(lambda t) / lambda  (E1 = t at lambda = 0),
              lambda = -sigma + i (wd - w) and G = -i a e^{i phi} / (wd + w - i sigma).
              This is the particular solution Re[a e^{i phi} H (e^{i w t} - e^{mu t})]
              (H the transfer function, mu = -sigma + i wd) with the factor that
              vanishes at resonance cancelled analytically: it is exact for every
              detuning and damping, equal to the secular solution
              a t sin(w t + phi) / (2 w) at exact undamped resonance, and free of the
              cancellation that costs the regular form log10(1 / detuning) digits
              (and, with damping ratio 1e-9, nine digits and millions of steps).
              Its derivatives follow from F = e^{i w t} E1:  F' = i w F + M,
              M = e^{mu t}, M' = mu M.

Bounds
    ``*_bound`` functions give rigorous bounds on |x^(n)| over a time window.  The
    event finder uses them so that no crossing of the wall can hide between steps.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

#: Regimes of the homogeneous solution.
UNDER = 0
CRITICAL = 1
OVER = 2

#: Tone kinds in a coefficient table.
REGULAR = 0.0
BEAT = 1.0

#: A tone within this relative detuning of wn, on an impacter with sigma below this
#: fraction of wn, uses the beat form: the regular form loses log10(1/detuning)
#: digits to cancellation there (and log10(wn / sigma) at exact resonance).
BEAT_DETUNING = 1e-2

#: Columns of a tone-coefficient table, shape (n_tones, N_COEF).
#:   regular: [w, P, Q, REGULAR, 0, 0]
#:   beat:    [w, Re G, Im G, BEAT, sigma, wd - w]
N_COEF = 6


@njit(cache=True, nogil=True)
def homogeneous_regime(wn, sigma):
    """Regime and characteristic numbers of x'' + 2 sigma x' + wn^2 x = 0.

    Returns
    -------
    regime : int
        UNDER (including undamped), CRITICAL or OVER.
    freq : float
        Damped angular frequency wd [rad/s] (UNDER), 0 (CRITICAL), or
        gamma = sqrt(sigma^2 - wn^2) [1/s] (OVER).
    kappa : float
        -wd^2, 0 or gamma^2 [1/s^2], the constant of the derivative map.
    """
    if sigma < wn:
        wd = math.sqrt((wn - sigma) * (wn + sigma))
        return UNDER, wd, -wd * wd
    elif sigma == wn:
        return CRITICAL, 0.0, 0.0
    else:
        g = math.sqrt((sigma - wn) * (sigma + wn))
        return OVER, g, g * g


@njit(cache=True, nogil=True)
def homogeneous_basis(regime, sigma, freq, tau):
    """(E C, E S) at tau [s]: the two basis functions of the homogeneous part."""
    if regime == UNDER:
        e = math.exp(-sigma * tau)
        arg = freq * tau
        return e * math.cos(arg), e * math.sin(arg) / freq
    elif regime == CRITICAL:
        e = math.exp(-sigma * tau)
        return e, tau * e
    else:
        slow = math.exp(-(sigma - freq) * tau)
        fast = math.exp(-(sigma + freq) * tau)
        return 0.5 * (slow + fast), slow * (-math.expm1(-2.0 * freq * tau)) / (2.0 * freq)


@njit(cache=True, nogil=True)
def derive(p, q, sigma, kappa):
    """Coefficients of the derivative of E (p C + q S): same basis, new (p, q)."""
    return q - sigma * p, kappa * p - sigma * q


@njit(cache=True, nogil=True)
def homogeneous_bound(regime, sigma, freq, p, q, tau_a, tau_b):
    """Bound on |E(tau) (p C(tau) + q S(tau))| for tau in [tau_a, tau_b].

    Pass the coefficients of the n-th derivative (from :func:`derive`) to bound
    the n-th derivative.
    """
    if regime == UNDER:
        env = math.exp(-sigma * tau_a)
        a = math.sqrt(p * p + (q / freq) ** 2) if freq > 0.0 else math.inf
        b = abs(p) + abs(q) * tau_b
        return env * min(a, b)
    # critical and over-damped: E C <= e^{-alpha tau}, E S <= tau e^{-alpha tau}
    alpha = sigma - freq if regime == OVER else sigma
    decay = math.exp(-alpha * tau_a)
    # max of tau e^{-alpha tau} over [tau_a, tau_b]: it peaks at 1/alpha
    if alpha <= 0.0:
        te = tau_b
    else:
        peak = 1.0 / alpha
        if peak < tau_a:
            te = tau_a * decay
        elif peak > tau_b:
            te = tau_b * math.exp(-alpha * tau_b)
        else:
            te = peak * math.exp(-1.0)
    return abs(p) * decay + abs(q) * te


@njit(cache=True, nogil=True)
def tone_coefficients(wn, sigma, w, a, phi):
    """Particular-solution coefficients of every tone of the drive.

    Parameters
    ----------
    wn : float
        Undamped natural angular frequency [rad/s].
    sigma : float
        b / (2 m) [1/s].
    w, a, phi : ndarray, shape (n,)
        Angular frequencies [rad/s], forcing amplitudes per unit mass [m/s^2]
        and phases [rad] of the tones.

    Returns
    -------
    coef : ndarray, shape (n, N_COEF)
        One row per tone, see the module docstring.
    """
    n = w.shape[0]
    coef = np.zeros((n, N_COEF))
    for i in range(n):
        wi = w[i]
        ai = a[i]
        if sigma < BEAT_DETUNING * wn and abs(wi - wn) < BEAT_DETUNING * wn:
            wd = math.sqrt((wn - sigma) * (wn + sigma))
            # G = -i a e^{i phi} / (wd + w - i sigma)
            g = complex(0.0, -ai) * complex(math.cos(phi[i]), math.sin(phi[i])) \
                / complex(wd + wi, -sigma)
            coef[i, 0] = wi
            coef[i, 1] = g.real
            coef[i, 2] = g.imag
            coef[i, 3] = BEAT
            coef[i, 4] = sigma
            coef[i, 5] = wd - wi
        else:
            # x_p = Re[a e^{i phi} H e^{i w t}], H = 1 / (wn^2 - w^2 + 2 i sigma w)
            re = (wn - wi) * (wn + wi)
            im = 2.0 * sigma * wi
            den = re * re + im * im
            hr = re / den
            hi = -im / den
            cr = ai * math.cos(phi[i])
            ci = ai * math.sin(phi[i])
            ar = cr * hr - ci * hi
            ai_ = cr * hi + ci * hr
            coef[i, 0] = wi
            coef[i, 1] = ar
            coef[i, 2] = -ai_
            coef[i, 3] = REGULAR
    return coef


@njit(cache=True, inline='always')
def _beat_terms(w, sigma, delta, t, t_ref):
    """F = e^{i w t} E1(t - t_ref) and M = e^{i w t} e^{lambda (t - t_ref)} [s, -].

    E1 = expm1(lambda tau) / lambda with lambda = -sigma + i delta, evaluated without
    cancellation: Re expm1 = expm1(-sigma tau) cos(delta tau) - (1 - cos(delta tau)),
    the last term written as sin^2 / (1 + cos) when cos > 0.  Re[G F] is a
    particular solution for every t_ref (changing t_ref adds a homogeneous
    solution); it vanishes at t_ref, so referred to the start of a free flight it
    stays as small as the flight is short, and so do the bounds on it.
    """
    c = math.cos(w * t)
    s = math.sin(w * t)
    tau = t - t_ref
    em = 0.0 if sigma == 0.0 else math.expm1(-sigma * tau)
    if delta == 0.0:
        cy = 1.0
        sy = 0.0
    else:
        cy = math.cos(delta * tau)
        sy = math.sin(delta * tau)
    den = sigma * sigma + delta * delta
    if den == 0.0:
        e1 = complex(tau, 0.0)
    else:
        omc = sy * sy / (1.0 + cy) if cy > 0.0 else 1.0 - cy
        z = complex(em * cy - omc, (1.0 + em) * sy)
        e1 = z / complex(-sigma, delta)
    rot = complex(c, s)
    return rot * e1, (1.0 + em) * rot * complex(cy, sy)


@njit(cache=True, nogil=True)
def particular(coef, t):
    """x_p, x_p', x_p'' at absolute time t [s] (units m, m/s, m/s^2)."""
    return particular_ref(coef, t, 0.0)


@njit(cache=True, nogil=True)
def particular_ref(coef, t, t_ref):
    """x_p, x_p', x_p'' at t [s], beat tones referred to t_ref [s] (see _beat_terms)."""
    x = 0.0
    v = 0.0
    acc = 0.0
    for i in range(coef.shape[0]):
        w = coef[i, 0]
        if coef[i, 3] == REGULAR:
            c = math.cos(w * t)
            s = math.sin(w * t)
            f0 = coef[i, 1] * c + coef[i, 2] * s
            x += f0
            v += w * (coef[i, 2] * c - coef[i, 1] * s)
            acc -= w * w * f0
        else:
            f0, m = _beat_terms(w, coef[i, 4], coef[i, 5], t, t_ref)
            g = complex(coef[i, 1], coef[i, 2])
            iw = complex(0.0, w)
            mu = complex(-coef[i, 4], w + coef[i, 5])
            f1 = iw * f0 + m
            f2 = iw * f1 + mu * m
            x += (g * f0).real
            v += (g * f1).real
            acc += (g * f2).real
    return x, v, acc


@njit(cache=True, nogil=True)
def particular_jet(coef, t):
    """x_p and its first three derivatives at absolute time t [s].

    Returns
    -------
    x, v, acc, jerk : float
        [m, m/s, m/s^2, m/s^3].  One sine and cosine per regular tone, two
        pairs per beat tone: the event finder's per-step cost.
    """
    return particular_jet_ref(coef, t, 0.0)


@njit(cache=True, inline='always')
def particular_jet_ref(coef, t, t_ref):
    """:func:`particular_jet` with the beat tones referred to t_ref [s]."""
    x = 0.0
    v = 0.0
    acc = 0.0
    jerk = 0.0
    for i in range(coef.shape[0]):
        w = coef[i, 0]
        if coef[i, 3] == REGULAR:
            c = math.cos(w * t)
            s = math.sin(w * t)
            f0 = coef[i, 1] * c + coef[i, 2] * s
            f1 = w * (coef[i, 2] * c - coef[i, 1] * s)
            ww = w * w
            x += f0
            v += f1
            acc -= ww * f0
            jerk -= ww * f1
        else:
            f0, m = _beat_terms(w, coef[i, 4], coef[i, 5], t, t_ref)
            g = complex(coef[i, 1], coef[i, 2])
            iw = complex(0.0, w)
            mu = complex(-coef[i, 4], w + coef[i, 5])
            f1 = iw * f0 + m
            m1 = mu * m
            f2 = iw * f1 + m1
            f3 = iw * f2 + mu * m1
            x += (g * f0).real
            v += (g * f1).real
            acc += (g * f2).real
            jerk += (g * f3).real
    return x, v, acc, jerk


@njit(cache=True, nogil=True)
def particular_bound(coef, order, tmax):
    """Bound on |x_p^(order)| over t in [0, tmax] [m/s^order].

    Beat tones: |F^(n)| <= w^n |E1| + sum_{j<n} w^(n-1-j) |mu|^j |M| with |M| <= 1
    and |E1| <= min(t, 2 / |lambda|).  Referred to t_ref, the bound holds over
    [t_ref, t_ref + tmax].
    """
    total = 0.0
    for i in range(coef.shape[0]):
        w = coef[i, 0]
        if coef[i, 3] == REGULAR:
            total += w ** order * math.sqrt(coef[i, 1] ** 2 + coef[i, 2] ** 2)
        else:
            sg = coef[i, 4]
            dl = coef[i, 5]
            lam = math.sqrt(sg * sg + dl * dl)
            e1 = tmax if lam == 0.0 else min(tmax, 2.0 / lam)
            mu = math.sqrt(sg * sg + (w + dl) ** 2)
            s = w ** order * e1
            for j in range(order):
                s += w ** (order - 1 - j) * mu ** j
            total += math.sqrt(coef[i, 1] ** 2 + coef[i, 2] ** 2) * s
    return total


@njit(cache=True, nogil=True)
def forcing(w, a, phi, t):
    """Forcing per unit mass f(t) = sum a_i cos(w_i t + phi_i) and its derivative."""
    f = 0.0
    df = 0.0
    for i in range(w.shape[0]):
        arg = w[i] * t + phi[i]
        f += a[i] * math.cos(arg)
        df -= a[i] * w[i] * math.sin(arg)
    return f, df


@njit(cache=True, nogil=True)
def forcing_bound(w, a, order):
    """Bound on |f^(order)| for all t [m/s^(2+order)]."""
    total = 0.0
    for i in range(w.shape[0]):
        total += abs(a[i]) * w[i] ** order
    return total
