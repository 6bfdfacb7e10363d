"""Line-width sensitivity of a design's natural frequency, and the geometry that matches it.

A lithographic line-width error dw moves every drawn edge by dw/2 outward: beams widen
to w + dw and the mass plate, a square of side sqrt(A), grows to (sqrt(A) + dw)^2; the
beam length l is set by the anchors and stays (:mod:`planner.fabrication.tolerances` builds
as-built chips by the same rule).  With eqs. (2) and (4),

    m = rho t A + 2 rho h w l = c_A A + c_wl w l,    k = K w^3 / l^3,

so the relative shift of nu_n = sqrt(k/m) / (2 pi) per unit of dw is

    S = d ln nu_n / d dw = (3 / w - (2 c_A sqrt(A) + c_wl l) / m) / 2     [1/m].

Beam-dominated mass gives S -> 1/w, plate-dominated S -> 3/(2w) - 1/sqrt(A).  Designs of
one array with equal S move by one common factor under a die-level line-width error
(which a re-plan absorbs by scaling every tone); unequal ones are reshuffled by it.

:class:`LineWidthModel` reads c_A, c_wl and K off the designer's impacter factory once
and then solves, in closed form plus one-dimensional roots, for the beam length that
gives a natural frequency and for the width (or area) that gives a sensitivity.
"""

from __future__ import annotations

import math

from scipy import optimize

#: Finite-difference step of the line width for :meth:`LineWidthModel.check` [m].
FD_STEP_M = 1e-10
#: Relative tolerance of the roots (length, width, area) [-].
XTOL_REL = 1e-12
#: Newton's method for the beam length: at most this many steps, stopping when a step
#: in ln l is below NEWTON_XTOL (the root is exact to rounding then) [-].
NEWTON_ITERATIONS = 60
NEWTON_XTOL = 1e-14


class LineWidthModel:
    """Eqs. (2) and (4) as m = c_A A + c_wl w l and k = K w^3 / l^3, read off ``factory``.

    Parameters
    ----------
    factory : callable
        ``(area, width, length, gap) -> model.Impacter`` by eqs. (2)-(4) (the designer's
        factory, with the process constants bound).

    Examples
    --------
    >>> from planner.designer.design import _impacter_factory
    >>> from planner.config import ProcessConfig, EnvironmentConfig
    >>> import math
    >>> f = _impacter_factory(ProcessConfig(), EnvironmentConfig(), math.pi / 4, 0.5)
    >>> lw = LineWidthModel(f)
    >>> round(lw.sensitivity(3e-8, 5e-6, 4e-4) * 1e-6, 4)   # per um
    0.2876
    """

    def __init__(self, factory):
        a = factory(1e-9, 4e-6, 4e-4, 1e-6)
        b = factory(2e-9, 4e-6, 4e-4, 1e-6)
        c = factory(1e-9, 8e-6, 4e-4, 1e-6)
        self.c_area = (b.mass - a.mass) / 1e-9                    # rho t [kg/m^2]
        self.c_wl = (c.mass - a.mass) / (4e-6 * 4e-4)             # 2 rho h [kg/m^3]
        self.k_coef = a.stiffness * (4e-4 / 4e-6) ** 3            # K [N/m]
        self.factory = factory

    def mass(self, area, width, length):
        """m of eq. (2) [kg]."""
        return self.c_area * area + self.c_wl * width * length

    def natural_frequency(self, area, width, length):
        """nu_n [Hz] by eqs. (2) and (4)."""
        k = self.k_coef * (width / length) ** 3
        return math.sqrt(k / self.mass(area, width, length)) / (2.0 * math.pi)

    def sensitivity(self, area, width, length):
        """S = d ln nu_n / d(line width) [1/m] at (A, w, l) [m^2, m, m]."""
        dm = 2.0 * self.c_area * math.sqrt(area) + self.c_wl * length
        return 0.5 * (3.0 / width - dm / self.mass(area, width, length))

    def check(self, area, width, length):
        """S by central differences through ``factory`` itself [1/m] (for tests)."""
        h = FD_STEP_M

        def nu(dw):
            side = math.sqrt(area) + dw
            return self.factory(side * side, width + dw, length, 1e-6).natural_frequency

        return (math.log(nu(h)) - math.log(nu(-h))) / (2.0 * h)

    def length_for(self, area, width, nu_n, bounds):
        """l [m] with natural frequency ``nu_n`` [Hz], clipped to ``bounds`` (lo, hi) [m].

        K w^3 / l^3 = (c_A A + c_wl w l) (2 pi nu_n)^2 is solved for y = ln l by Newton's
        method from the beams-massless root (an upper bound: the beams only add mass),
        safeguarded by bisection; f(y) is strictly decreasing, so the root is unique.
        The designer calls this tens of thousands of times per design (inside the
        width and area solves), where a bracketing solver costs ~10x more.
        """
        l_lo, l_hi = bounds
        w2 = (2.0 * math.pi * nu_n) ** 2
        log_kk = math.log(self.k_coef * width ** 3)
        beam = self.c_wl * width

        def f(y):
            return log_kk - 3.0 * y - math.log((self.c_area * area + beam * math.exp(y)) * w2)

        lo, hi = math.log(l_lo), math.log(l_hi)
        if f(lo) <= 0.0:
            return l_lo
        if f(hi) >= 0.0:
            return l_hi
        y = min(hi, (log_kk - math.log(self.c_area * area * w2)) / 3.0)
        for _ in range(NEWTON_ITERATIONS):
            fy = f(y)
            if fy > 0.0:
                lo = y
            elif fy < 0.0:
                hi = y
            else:
                break
            ell = math.exp(y)
            slope = -3.0 - beam * ell / (self.c_area * area + beam * ell)
            step = fy / slope
            y_new = y - step
            if not lo < y_new < hi:
                y_new = 0.5 * (lo + hi)          # bisection keeps the bracket
            if abs(y_new - y) <= NEWTON_XTOL:
                y = y_new
                break
            y = y_new
        return math.exp(y)

    def _solve(self, g, lo, hi):
        """Root of g on [lo, hi] (log coordinates), or the end nearer to one."""
        g_lo, g_hi = g(math.log(lo)), g(math.log(hi))
        if g_lo == 0.0:
            return lo
        if g_hi == 0.0 or (g_lo > 0) == (g_hi > 0):
            return lo if abs(g_lo) < abs(g_hi) else hi
        return math.exp(optimize.brentq(g, math.log(lo), math.log(hi),
                                        xtol=XTOL_REL, rtol=XTOL_REL))

    def _length_at(self, area, width, target):
        """The beam length [m] that gives (A, w) the sensitivity ``target`` [1/m]: eq. for S
        solved for l, closed form (S = target is linear in l at fixed A, w):

            l = (3 c_A A - 2 c_A w (S A + sqrt(A))) / (2 c_wl w (S w - 1)).

        Not positive when no length reaches it (S w <= 1 is below the beam-only limit).
        """
        den = 2.0 * self.c_wl * width * (target * width - 1.0)
        num = 3.0 * self.c_area * area - 2.0 * self.c_area * width * (target * area
                                                                      + math.sqrt(area))
        return num / den if den > 0 else -1.0

    def _solve_pair(self, free, fixed_value, nu_n, target, bounds, length_bounds, on_width):
        """Root in the free variable (w, or A when ``on_width`` is False) of nu_n at the
        sensitivity ``target``, l following in closed form; None when the bracket has no
        sign change with l inside its bounds (then :meth:`_nested` decides)."""
        l_lo, l_hi = length_bounds
        w2 = (2.0 * math.pi * nu_n) ** 2

        def parts(log_x):
            x = math.exp(log_x)
            a, w = (fixed_value, x) if on_width else (x, fixed_value)
            return a, w, self._length_at(a, w, target)

        def g(log_x):
            a, w, ll = parts(log_x)
            return (math.log(self.k_coef * w ** 3 / ll ** 3)
                    - math.log(self.mass(a, w, ll) * w2))

        if on_width:
            # l(w) falls from +inf at w = 1/S to 0: the widths whose l lies inside its
            # bounds form one interval, [w(l_hi), w(l_lo)], in closed form
            w_lo = max(bounds[0], self._width_at(fixed_value, target, l_hi))
            w_hi = min(bounds[1], self._width_at(fixed_value, target, l_lo))
            if not w_lo < w_hi:
                return None
            bounds = (w_lo, w_hi)
        lo, hi = (math.log(b) for b in bounds)
        ends = [parts(lo)[2], parts(hi)[2]]
        # the narrowed ends sit on the length bounds to rounding
        tol = 1e-9
        if not all(l_lo * (1 - tol) <= ll <= l_hi * (1 + tol) for ll in ends):
            return None
        g_lo, g_hi = g(lo), g(hi)
        if g_lo == 0.0:
            x = lo
        elif g_hi == 0.0:
            x = hi
        elif (g_lo > 0) == (g_hi > 0):
            return None
        else:
            x = optimize.brentq(g, lo, hi, xtol=XTOL_REL, rtol=XTOL_REL)
        a, w, ll = parts(x)
        return a, w, min(max(ll, l_lo), l_hi)

    def _width_at(self, area, target, length):
        """The width [m] at which ``length`` gives (A, w, l) the sensitivity ``target``:
        :meth:`_length_at` inverted, the positive root of

            2 c_wl l S w^2 + (2 c_A (S A + sqrt(A)) - 2 c_wl l) w - 3 c_A A = 0.
        """
        qa = 2.0 * self.c_wl * length * target
        qb = 2.0 * self.c_area * (target * area + math.sqrt(area)) - 2.0 * self.c_wl * length
        qc = -3.0 * self.c_area * area
        root = math.sqrt(qb * qb - 4.0 * qa * qc)
        # the form without cancellation for either sign of qb
        return (-qb + root) / (2.0 * qa) if qb < 0 else -2.0 * qc / (qb + root)

    def width_for(self, area, nu_n, target, width_bounds, length_bounds):
        """(w, l) [m] with natural frequency ``nu_n`` and sensitivity ``target`` [1/m],
        w within ``width_bounds``; the nearer bound when no width in them reaches it."""
        if width_bounds[0] < width_bounds[1]:
            hit = self._solve_pair("w", area, nu_n, target, width_bounds, length_bounds,
                                   True)
            if hit is not None:
                return hit[1], hit[2]

        def g(log_w):
            w = math.exp(log_w)
            return math.log(self.sensitivity(area, w, self.length_for(area, w, nu_n,
                                                                         length_bounds))
                            / target)

        w = self._solve(g, *width_bounds)
        return w, self.length_for(area, w, nu_n, length_bounds)

    def area_for(self, width, nu_n, target, area_bounds, length_bounds):
        """(A, l) [m^2, m] with natural frequency ``nu_n`` and sensitivity ``target``
        [1/m] at the fixed width ``width``, A within ``area_bounds``; the nearer bound
        when no area in them reaches it."""
        if area_bounds[0] < area_bounds[1]:
            hit = self._solve_pair("A", width, nu_n, target, area_bounds, length_bounds,
                                   False)
            if hit is not None:
                return hit[0], hit[2]

        def g(log_a):
            a = math.exp(log_a)
            return math.log(self.sensitivity(a, width, self.length_for(a, width, nu_n,
                                                                         length_bounds))
                            / target)

        a = self._solve(g, *area_bounds)
        return a, self.length_for(a, width, nu_n, length_bounds)


def reference_sensitivity(width, beam_mass_fraction):
    """S [1/m] of a beam of width ``width`` [m] carrying a plate that makes
    ``1 - beam_mass_fraction`` of the mass, the plate's own edge term neglected:
    (3 - beam_mass_fraction) / (2 w).

    >>> round(reference_sensitivity(5e-6, 0.2) * 1e-6, 3)
    0.28
    """
    return (3.0 - beam_mass_fraction) / (2.0 * width)
