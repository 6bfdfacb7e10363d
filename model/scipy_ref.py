"""Independent references by SciPy's DOP853: the impacter and the slider as an ODE user
would integrate them.

The product's solvers (:mod:`model.kernels.impacter`, :mod:`model.kernels.slider`) use
closed forms between events and bounds that cannot step over one.  These references
share none of that code: they integrate the equations of motion with
:func:`scipy.integrate.solve_ivp` (DOP853, rtol 1e-12), locate events with its event
functions, and restart at each one.  They are slow (about a second per 10 ms of a
25-tone drive) and meant for tests and benchmarks.

- :func:`impacts`: the impacter against its wall, eq. (1) with impact law (8)
  (v+ = -e v-), restarted at each impact.  Event location sees a crossing only where
  x - gap changes sign between two of the integrator's steps (or ``max_step`` apart): a
  grazing impact shorter than the step is missed, which the product's solver must not
  do (``max_step`` small enough finds it).  No chatter: a run stops at the first impact
  slower than ``min_speed`` (a sequence accumulating in finite time cannot be stepped).
- :func:`slider_motion`: the slider's stick-slip (eqs. 6-7) between kicks under the
  drive's base acceleration, the slips by DOP853 with a stop (v = 0) by event location,
  a release from stick (|f| > F_s / M) found on a grid of ``grid_per_period`` points
  per period of the highest tone and refined by Brent's method, and the kicks applied at
  their times by either contact law, restated from docs/contact.md.

Examples
--------
>>> import model
>>> from model import scipy_ref
>>> imp = model.Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6).with_natural_frequency(5200)
>>> t, v = scipy_ref.impacts(imp, model.Drive.tone(6200.0), 3e-3)
>>> t.size == model.simulate(imp, model.Drive.tone(6200.0)).n_impacts
True
"""

from __future__ import annotations

import numpy as np

from model.impacter import impacter_forcing

#: DOP853's relative tolerance in every reference run [-].
RTOL = 1e-12


def impacts(impacter, drive, duration, x0=0.0, v0=0.0, *, max_step=np.inf, min_speed=1e-9):
    """Impact times [s] and speeds v- [m/s] of ``impacter`` under ``drive`` from (x0, v0).

    DOP853 with event location on x = gap, restarted at each impact with v+ = -e v-;
    ``max_step`` [s] bounds the integrator's step (a graze shorter than it may be
    missed).  Stops at an impact slower than ``min_speed`` [m/s] (chatter)."""
    from scipy.integrate import solve_ivp

    w, a, phi = impacter_forcing(impacter, drive)
    wn2, s2, gap, e = impacter.omega_n ** 2, 2 * impacter.sigma, impacter.gap, impacter.restitution

    def rhs(t, y):
        return [y[1], float(np.sum(a * np.cos(w * t + phi))) - s2 * y[1] - wn2 * y[0]]

    def wall(t, y):
        return y[0] - gap
    wall.terminal, wall.direction = True, 1
    t, y, times, speeds = 0.0, [x0, v0], [], []
    while t < duration:
        sol = solve_ivp(rhs, (t, duration), y, method="DOP853", rtol=RTOL, atol=1e-22,
                        events=wall, max_step=max_step)
        if sol.status != 1:
            break
        te, ye = sol.t_events[0][0], sol.y_events[0][0]
        if ye[1] < min_speed:
            break
        times.append(te)
        speeds.append(ye[1])
        t, y = te, [gap, -e * ye[1]]
    return np.array(times), np.array(speeds)


def _two_body(V, v, s, g, c, e):
    """docs/contact.md: dV = s (1 + e) g u / (1 + g c), u = v- - s V- c; none if u <= 0."""
    u = v - s * V * c
    return s * (1 + e) * g * u / (1 + g * c) if u > 0 else 0.0


def _kicked(V, kicks, j, contact):
    """The slider's velocity after kick ``j`` of ``kicks`` (a :class:`model.Kicks`)."""
    c = np.cos(kicks.impact_angle[j])
    s, e = kicks.direction[j], kicks.restitution[j]
    g = 2 * kicks.mass_ratio[j] * c
    if contact == "paper":
        return V + s * (1 + e) * g * kicks.velocities[j]
    if not kicks.chatter[j]:
        return V + _two_body(V, kicks.velocities[j], s, g, c, e)
    vk = kicks.velocities[j] * (1 - e)          # a tail: v-_k = S (1 - e) e^(k-1)
    while vk > 1e-17 * kicks.velocities[j]:
        dv = _two_body(V, vk, s, g, c, e)
        if dv == 0.0:
            break
        V, vk = V + dv, vk * e
    return V


def slider_motion(slider, drive, kicks, duration, contact="two_body", *, z0=0.0, v0=0.0,
                  grid_per_period=60):
    """The slider's position [m] and velocity [m/s] at ``duration`` [s] from (z0, v0),
    kicked by ``kicks`` (a :class:`model.Kicks`) under ``drive``'s base acceleration."""
    from scipy.integrate import solve_ivp
    from scipy.optimize import brentq

    beta = slider.damping / slider.mass
    fs, fd = slider.static_friction / slider.mass, slider.dynamic_friction / slider.mass
    w, a, phi = drive.omegas, drive.acceleration_amplitudes(), np.asarray(drive.phases)
    per_s = grid_per_period * float(np.max(drive.frequencies))

    def f(t):
        return float(np.sum(a * np.cos(w * t + phi)))

    def slip(t, t_end, z, v):
        s = np.sign(v)

        def stop(t, y):
            return y[1]
        stop.terminal, stop.direction = True, -s
        sol = solve_ivp(lambda t, y: [y[1], f(t) - beta * y[1] - s * fd], (t, t_end), [z, v],
                        method="DOP853", rtol=RTOL, atol=1e-18, events=stop)
        if sol.status == 1:
            return sol.t_events[0][0], sol.y_events[0][0][0], 0.0
        return t_end, sol.y[0, -1], sol.y[1, -1]

    def released(t, t_end):
        ts = np.linspace(t, t_end, int(np.ceil((t_end - t) * per_s)) + 2)
        over = np.nonzero(np.abs(np.cos(np.outer(ts, w) + phi) @ a) > fs)[0]
        if over.size == 0:
            return None
        i = over[0]
        return t if i == 0 else brentq(lambda s: abs(f(s)) - fs, ts[i - 1], ts[i], xtol=1e-16)

    order = np.argsort(kicks.times, kind="stable")
    t, z, v = 0.0, z0, v0
    for j in list(order) + [None]:
        t_next = duration if j is None else min(kicks.times[j], duration)
        while t < t_next:
            if v == 0.0:
                t_go = released(t, t_next)
                if t_go is None:
                    break
                t, v = t_go, np.sign(f(t_go)) * 1e-300      # starts to slip with f
            t, z, v = slip(t, t_next, z, v)
            if v == 0.0 and abs(f(t)) > fs:
                v = np.sign(f(t)) * 1e-300                   # stopped, but f slips it on
        t = t_next
        if j is None or kicks.times[j] > duration:
            break
        v = _kicked(v, kicks, j, contact)
    return z, v
