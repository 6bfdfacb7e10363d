"""Arbitrary-precision reference for the impacter: the same closed form, in mpmath.

The float solver (:mod:`model.kernels.impacter`) evaluates the closed-form solution of
eq. (1) between impacts in double precision and finds impacts by safe steps.  This
module evaluates the *same* closed form (same float parameters, converted exactly) in
``dps`` significant digits (50 by default) and finds impacts differently: by scanning
the closed form on a grid of ``samples_per_period`` points per shortest period (plus a
geometric grid just after the segment's start, where chatter flights are short),
bracketing every sign change of g = x - gap and every local maximum of g that reaches
the wall, and bisecting/secant-refining each bracket to the working precision.  So it
checks the float solver's arithmetic and its event logic, not just its consistency.

What it models is exactly what the float solver models: impact law (8); a chatter
sequence (impacts accumulating under a force pressing on the wall) is resolved impact
by impact until its remaining accumulation time is below ``chatter_time`` drive periods
(1e-20 by default, so the closed-form tail e v- / (1 - e) is exact to about that
relative size), then the impacter sticks until the net force pulls it off the wall.

It is slow (about 0.1-1 s per 3 ms run in pure Python) and meant for tests and
benchmarks; the float solver is what the product uses.

Examples
--------
>>> import model
>>> from model.mpref import reference
>>> imp = model.Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6).with_natural_frequency(5200)
>>> ref = reference(imp, model.Drive.tone(6200.0))
>>> ref.n_impacts
17
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mpmath
import numpy as np

from model.devices import Impacter
from model.drive import Drive

#: Working precision [significant digits].
DPS = 50
#: Grid points per shortest period of the problem when scanning for crossings.
SAMPLES_PER_PERIOD = 64
#: A chatter sequence whose remaining accumulation time is below this many drive
#: periods is summed in closed form (the tail's relative error is of this order).
#: Flights much shorter would rise less than the working precision resolves of x.
CHATTER_TIME = 1e-20
#: Cap on events, so that a reference run always ends.
MAX_EVENTS = 100_000


@dataclass(frozen=True)
class Reference:
    """An arbitrary-precision run.

    Attributes
    ----------
    times, velocities : list of mpf
        Event times [s] and v- [m/s]; a chatter tail's entry is its accumulation
        time and the sum of its remaining v-.
    kinds : list of str
        "impact" or "chatter" for each event.
    sum_v : mpf
        Sum of v- over every event but the first [m/s] (eq. 12 numerator over m).
    response : mpf
        r of eq. (12) [N].
    status : str
        "ok" or "event cap reached".
    """

    times: list
    velocities: list
    kinds: list
    sum_v: object
    response: object
    status: str

    @property
    def n_impacts(self):
        return sum(1 for k in self.kinds if k == "impact")

    def impact_arrays(self):
        """Impact times [s] and v- [m/s] as float arrays (chatter tails left out)."""
        sel = [i for i, k in enumerate(self.kinds) if k == "impact"]
        return (np.array([float(self.times[i]) for i in sel]),
                np.array([float(self.velocities[i]) for i in sel]))


class _ClosedForm:
    """x(t) = x_h(t - t_s) + x_p(t) in mpmath, for the current working precision."""

    def __init__(self, wn, sigma, w, a, phi):
        mp = mpmath.mp
        self.wn = mp.mpf(wn)
        self.sigma = mp.mpf(sigma)
        self.tones = []
        for wi, ai, phii in zip(w, a, phi):
            wi, ai, phii = mp.mpf(wi), mp.mpf(ai), mp.mpf(phii)
            if self.sigma == 0 and wi == self.wn:
                # exact resonance, undamped: the secular solution a t sin(w t + phi) / (2 w)
                self.tones.append(("secular", wi, ai / (2 * wi), phii, ai))
            else:
                h = 1 / mp.mpc(self.wn**2 - wi**2, 2 * self.sigma * wi)
                self.tones.append(("regular", wi, ai * mp.expj(phii) * h, phii, ai))
        s, wn_ = self.sigma, self.wn
        self.kappa = s**2 - wn_**2
        if s < wn_:
            self.regime, self.freq = "under", mp.sqrt(wn_**2 - s**2)
        elif s == wn_:
            self.regime, self.freq = "critical", mp.mpf(0)
        else:
            self.regime, self.freq = "over", mp.sqrt(s**2 - wn_**2)

    def particular(self, t):
        """x_p, x_p', x_p'' at absolute time t."""
        mp = mpmath.mp
        x = v = acc = mp.mpf(0)
        for kind, w, c, phi, _ in self.tones:
            if kind == "regular":
                z = c * mp.expj(w * t)
                x += z.real
                v += (1j * w * z).real
                acc += (-(w**2) * z).real
            else:
                sn, cs = mp.sin(w * t + phi), mp.cos(w * t + phi)
                x += c * t * sn
                v += c * sn + c * t * w * cs
                acc += 2 * c * w * cs - c * t * w**2 * sn
        return x, v, acc

    def basis(self, tau):
        """(EC, ES) and their first two derivatives at tau: EC(0) = 1, ES'(0) = 1."""
        mp = mpmath.mp
        s = self.sigma
        e = mp.exp(-s * tau)
        if self.regime == "under":
            f = self.freq
            c, sn = mp.cos(f * tau), mp.sin(f * tau)
            ec, es = e * c, e * sn / f
        elif self.regime == "critical":
            ec, es = e, tau * e
        else:
            f = self.freq
            ec, es = e * mp.cosh(f * tau), e * mp.sinh(f * tau) / f
        # EC(0) = 1, EC'(0) = -s, ES(0) = 0, ES'(0) = 1 (the float solver's basis), so
        # (EC, ES)' = (-s EC + kappa ES, EC - s ES) with kappa = s^2 - wn^2
        k = self.kappa
        ec1, es1 = -s * ec + k * es, ec - s * es
        ec2, es2 = -s * ec1 + k * es1, ec1 - s * es1
        return (ec, es), (ec1, es1), (ec2, es2)

    def forcing(self, t):
        mp = mpmath.mp
        return mp.fsum(a * mp.cos(w * t + phi) for _, w, _, phi, a in self.tones)

    def forcing_rate(self, t):
        mp = mpmath.mp
        return mp.fsum(-a * w * mp.sin(w * t + phi) for _, w, _, phi, a in self.tones)


class _Segment:
    """Free flight from (t_s, x_s, v_s)."""

    def __init__(self, cf, t_s, x_s, v_s):
        self.cf, self.t_s = cf, t_s
        xp, vp, _ = cf.particular(t_s)
        self.p = x_s - xp
        self.q = (v_s - vp) + cf.sigma * self.p

    def state(self, t):
        """x, x', x'' at t."""
        (ec, es), (ec1, es1), (ec2, es2) = self.cf.basis(t - self.t_s)
        xp, vp, ap = self.cf.particular(t)
        p, q = self.p, self.q
        return p * ec + q * es + xp, p * ec1 + q * es1 + vp, p * ec2 + q * es2 + ap


def _accel_bound(cf, seg, span, t_end):
    """Bound on |x''| over [t_s, t_s + span] of a segment [m/s^2].

    For every regime |EC| <= 1 and |ES| <= tau, and (EC, ES)' = (-s EC + k ES, EC - s ES),
    so |EC'| <= s + |k| tau, |ES'| <= 1 + s tau and the second derivatives follow.
    """
    s, k = cf.sigma, abs(cf.kappa)
    ec1, es1 = s + k * span, 1 + s * span
    ec2, es2 = s * ec1 + k * es1, ec1 + s * es1
    hom = abs(seg.p) * ec2 + abs(seg.q) * es2
    par = 0
    for kind, w, c, _, _ in cf.tones:
        par += abs(c) * w**2 if kind == "regular" else abs(c) * (2 * w + t_end * w**2)
    return (hom + par) * (1 + mpmath.mpf(10) ** (-20))


def _bracket_root(fun, lo, hi, f_lo, f_hi, tol):
    """Root of fun in (lo, hi] with fun(lo) < 0 <= fun(hi): Illinois + bisection.

    Keeps the bracket and returns its right end (fun >= 0 there) once it is
    narrower than tol.
    """
    side = 0
    while hi - lo > tol:
        # Illinois step, bisection when it stalls or leaves the bracket
        t = (lo * f_hi - hi * f_lo) / (f_hi - f_lo)
        if not (lo < t < hi) or side == 2 or side == -2:
            t = (lo + hi) / 2
            side = 0
        f_t = fun(t)
        if f_t >= 0:
            hi, f_hi = t, f_t
            f_lo = f_lo / 2 if side < 0 else f_lo
            side = side - 1 if side <= 0 else -1
        else:
            lo, f_lo = t, f_t
            f_hi = f_hi / 2 if side > 0 else f_hi
            side = side + 1 if side >= 0 else 1
    return hi


def _first_crossing(value, slope, t_s, t_end, s_min, grid, tol):
    """First t in (t_s, t_end] where value(t) >= 0, or None.

    value(t) < 0 just after t_s is assumed for t_s < t < t_s + s_min (the caller
    proves it).  Samples at t_s + s_min 2^k (geometric, up to one grid step), then
    every grid step; a sign change, or a local maximum (slope + to -) whose value
    reaches 0, brackets the first crossing.
    """
    mp = mpmath.mp
    pts = []
    s = s_min
    while s < grid:
        pts.append(t_s + s)
        s *= 2
    n = int(mp.ceil((t_end - t_s) / grid))
    pts.extend(t_s + grid * k for k in range(1, n + 1))
    pts = [min(t, t_end) for t in pts]
    prev_t, prev_v, prev_d = None, None, None
    for t in pts:
        val, der = value(t), slope(t)
        if val >= 0:
            if prev_t is None:
                # the caller's s_min guarantee: below s_min the value is < 0
                lo = t_s + s_min / 2
                v_lo = value(lo)
                if not v_lo < 0:
                    raise RuntimeError(f"reference: value {v_lo} >= 0 at t_s + s_min / 2 = {lo}"
                                       f" (t_s = {t_s}, s_min = {s_min}, first sample {val})")
                return _bracket_root(value, lo, t, v_lo, val, tol)
            return _bracket_root(value, prev_t, t, prev_v, val, tol)
        if prev_t is not None and prev_d > 0 and der < 0:
            # a local maximum inside: does it reach the wall? (grazing)
            t_max = _bracket_root(lambda u: -slope(u), prev_t, t, -prev_d, -der, tol)
            v_max = value(t_max)
            if v_max >= 0:
                return _bracket_root(value, prev_t, t_max, prev_v, v_max, tol)
        prev_t, prev_v, prev_d = t, val, der
        if t >= t_end:
            break
    return None


def free_maximum(impacter, drive, x0=0.0, v0=0.0, duration=3e-3, *, dps=DPS,
                 samples_per_period=SAMPLES_PER_PERIOD):
    """Highest interior local maximum of the motion without a wall, to ``dps`` digits.

    Used to build grazing tests: with the wall at this height (plus or minus a
    hair) the trajectory touches it tangentially (or just passes it).

    Returns
    -------
    t_max, x_max : mpf or None
        Time [s] and height [m] of the highest local maximum in (0, duration);
        None when x has no interior maximum.
    """
    w = drive.omegas
    a = math.cos(impacter.impact_angle) * drive.acceleration_amplitudes()
    with mpmath.workdps(dps):
        mp = mpmath.mp
        cf = _ClosedForm(impacter.omega_n, impacter.sigma, w, a, drive.phases)
        seg = _Segment(cf, mp.mpf(0), mp.mpf(x0), mp.mpf(v0))
        t_end = mp.mpf(duration)
        grid = 2 * mp.pi / max([cf.wn] + [mp.mpf(x) for x in w]) / samples_per_period
        tol = t_end * mp.mpf(10) ** (-(mp.dps - 3))
        best = (None, None)
        prev_t, prev_d = None, None
        n = int(mp.ceil(t_end / grid))
        for k in range(n + 1):
            t = min(grid * k, t_end)
            d = seg.state(t)[1]
            if prev_t is not None and prev_d > 0 and d <= 0:
                t_m = _bracket_root(lambda u: -seg.state(u)[1], prev_t, t, -prev_d, -d, tol)
                if t_m < t_end:
                    x_m = seg.state(t_m)[0]
                    if best[1] is None or x_m > best[1]:
                        best = (t_m, x_m)
            prev_t, prev_d = t, d
        return best


def reference(impacter, drive, x0=0.0, v0=0.0, duration=3e-3, *, dps=DPS,
              samples_per_period=SAMPLES_PER_PERIOD, chatter_time=CHATTER_TIME,
              max_events=MAX_EVENTS):
    """Run the impacter in ``dps``-digit arithmetic; see the module docstring.

    Parameters
    ----------
    impacter : Impacter
    drive : Drive
    x0, v0 : float
        Initial position [m] (<= gap) and velocity [m/s].
    duration : float
        [s].
    dps : int
        Significant digits.
    samples_per_period : int
        Scan density [1/period] of the shortest period (drive or natural).
    chatter_time : float
        Chatter tails shorter than this many shortest periods are summed.
    max_events : int
        Cap on events.

    Returns
    -------
    Reference
    """
    if not isinstance(impacter, Impacter):
        raise ValueError(f"impacter must be a model.Impacter, {type(impacter).__name__} was given")
    if not isinstance(drive, Drive):
        raise ValueError(f"drive must be a model.Drive, {type(drive).__name__} was given")
    if not (math.isfinite(x0) and x0 <= impacter.gap):
        raise ValueError(f"x0 must be finite and <= the gap, {x0!r} was given")
    # the same float parameters as the float solver (model.impacter.impacter_forcing)
    w = drive.omegas
    a = math.cos(impacter.impact_angle) * drive.acceleration_amplitudes()
    phi = drive.phases
    with mpmath.workdps(dps):
        return _run(impacter, w, a, phi, float(x0), float(v0), float(duration),
                    samples_per_period, chatter_time, max_events)


def _run(imp, w, a, phi, x0, v0, duration, samples_per_period, chatter_time, max_events):
    mp = mpmath.mp
    cf = _ClosedForm(imp.omega_n, imp.sigma, w, a, phi)
    gap, e = mp.mpf(imp.gap), mp.mpf(imp.restitution)
    wn2, sigma = cf.wn**2, cf.sigma
    t_end = mp.mpf(duration)
    wmax = max([cf.wn] + [mp.mpf(x) for x in w])
    period = 2 * mp.pi / wmax
    grid = period / samples_per_period
    tol = t_end * mp.mpf(10) ** (-(mp.dps - 3))

    def net_force(t):  # per unit mass, at rest on the wall
        return cf.forcing(t) - wn2 * gap

    times, vels, kinds = [], [], []
    sum_v = mp.mpf(0)
    t, x, v = mp.mpf(0), mp.mpf(x0), mp.mpf(v0)
    stuck = x == gap and v == 0 and net_force(t) >= 0
    status = "ok"
    while t < t_end:
        if len(times) >= max_events:
            status = "event cap reached"
            break
        if stuck and net_force(t) < 0:
            stuck = False  # pulled off at once
        if stuck:
            # stuck until the net force pulls the impacter off the wall
            t_rel = _first_crossing(lambda u: -net_force(u), lambda u: -cf.forcing_rate(u),
                                    t, t_end, grid * mp.mpf(2) ** -60, grid, tol)
            if t_rel is None:
                break
            t, x, v, stuck = t_rel, gap, mp.mpf(0), False
            continue
        seg = _Segment(cf, t, x, v)
        g0 = x - gap
        if g0 < 0:
            order = 0
        elif v < 0:
            order = 1
        else:
            order = 2  # at rest on the wall, see below
        t_s = t

        def value(u, seg=seg, order=order, t_s=t_s):
            return (seg.state(u)[0] - gap) / (u - t_s) ** order

        def slope(u, seg=seg):
            return seg.state(u)[1]

        # below s_min no crossing is possible: g <= g0 + v s + M s^2 / 2
        m2 = _accel_bound(cf, seg, grid, t_end)
        if order == 0:
            s_min = min(grid, -g0 / (abs(v) + mp.sqrt(m2 * -g0)))
        elif order == 1:
            s_min = min(grid, -v / m2)
        else:
            # at rest on the wall with x'' = F <= 0 and x''' = J = f' - 2 sigma F:
            # g = F s^2 / 2 + J s^3 / 6 + O(s^4), negative for small s when F < 0, or
            # when F = 0 (a release) and J < 0.  Start where g is resolved at the
            # working precision, and before a positive J could turn it.
            force = net_force(t_s)
            jerk = cf.forcing_rate(t_s) - 2 * sigma * force
            resolved = abs(gap) * mp.mpf(10) ** (12 - mp.dps)
            cands = []
            if force < 0:
                cands.append(mp.sqrt(2 * resolved / -force))
            if jerk < 0:
                cands.append(mp.cbrt(6 * resolved / -jerk))
            if not cands:
                raise RuntimeError(f"reference: leaving the wall at t = {t_s} with force "
                                   f"{force} and jerk {jerk} >= 0")
            s_min = min(cands + [grid / 2])
            if jerk > 0:
                s_min = min(s_min, -force / jerk)
        t_hit = _first_crossing(value, slope, t_s, t_end, s_min, grid, tol)
        if t_hit is None:
            break
        vminus = seg.state(t_hit)[1]
        if vminus <= 0:
            # reached the wall at zero speed (grazing at rest): stick or leave
            t, x, v = t_hit, gap, mp.mpf(0)
            stuck = net_force(t) >= 0
            if not stuck:
                t = t + tol
            continue
        times.append(t_hit)
        vels.append(vminus)
        kinds.append("impact")
        if len(times) >= 2:
            sum_v += vminus
        t, x, v = t_hit, gap, -e * vminus
        acc_wall = net_force(t) - 2 * sigma * v
        if e == 0:
            v = mp.mpf(0)
            stuck = net_force(t) >= 0
            continue
        if acc_wall > 0 and e < 1:
            t_acc = 2 * e * vminus / (acc_wall * (1 - e))
            if t_acc < chatter_time * period:
                tail = vminus * e / (1 - e)
                times.append(t + t_acc)
                vels.append(tail)
                kinds.append("chatter")
                sum_v += tail
                t, x, v, stuck = t + t_acc, gap, mp.mpf(0), True
    response = mp.mpf(imp.mass) * sum_v / t_end
    return Reference(times, vels, kinds, sum_v, response, status)
