"""The optimisation problem: geometry <-> search coordinates, cached simulations and
the tiered energy of the constraint handling (see the package notes)."""

from __future__ import annotations

import contextlib
import math
import warnings
from dataclasses import dataclass

import numba
import numpy as np

from model import SolverWarning, responses
from model.bounds import silence_bound
from planner.designer.runs import (
    PARALLEL_MIN_RUNS,
    Ensemble,
    _freq_key,
    _guard_offsets,
    _u_grid,
)
from planner.designer.sensitivity import LineWidthModel

#: Tier offset of the annealing energy; far above any difference of ln r [-].
PENALTY = 1.0e3
#: Neighbouring responses that differ by more than this fraction of the largest are
#: a jump (Fig. 9): the x0 interval between them is bisected [-].
JUMP_REL = 0.15
#: Search range of nu_n as a multiple of the target frequency.  The response of an
#: impact oscillator sits around and above nu_n (hardening, Fig. 9); the paper's
#: Table II designs sit at 0.68 and 0.97 times their targets [-].
NATURAL_RATIO = (0.4, 1.4)
#: The long re-check window, as a multiple of the design window [-].
LONG_WINDOW_FACTOR = 10.0
#: Answer a check of silence by :func:`model.bounds.silence_bound` where it proves r = 0
#: (from every x0, over any window) instead of simulating it; off only to compare.
SILENCE_BOUND = True
#: Two designs closer than this in z (max norm) are one design in the archive [-].
ARCHIVE_SEPARATION = 0.02
#: Search range of the gap c as a multiple kappa of the impacter's linear steady-state
#: amplitude X at its own tone (eq. 1 without the wall: X = Z0 r^2 / |1 - r^2 + 2 i zeta r|,
#: r = nu / nu_n).  Feasible designs need c below X (from rest the impacter must reach the
#: wall at its tone) and not far below it (a forbidden tone's amplitude is a fraction of
#: X, and the transient from x0 = +-c must not reach the wall): the feasible gaps of the
#: default plan, 4.5-51 kHz, lie at kappa = 0.60-0.65, a sliver of the absolute gap
#: range that moves with A and nu_n but not in kappa [-].
GAP_AMPLITUDE_RATIO = (0.3, 1.2)
#: A design projected onto the mass cap is aimed this far under it [-] ...
MASS_CAP_MARGIN = 1e-6
#: ... in at most this many fixed-point steps (each re-solves the beams).
MASS_CAP_ITERATIONS = 6


@dataclass
class _Eval:
    """One candidate's evaluation on the optimiser's grid."""

    z: np.ndarray
    geometry: tuple           # (A, w, l, c) [m^2, m, m, m]
    energy: float
    violation: float          # fraction of x0 responding at the first violated frequency
    violated_hz: float | None
    unresponsive: float       # fraction of x0 with r = 0 at the target
    r_min: float
    worst_u: float

    @property
    def feasible(self):
        return self.violation == 0.0 and self.r_min > 0.0


def natural_ratio(frequency, forbidden):
    """Search range of nu_n / nu: NATURAL_RATIO, narrowed when forbidden tones are near.

    A design that responds at nu but not at a forbidden nu_j a relative distance
    delta = |ln(nu_j / nu)| away has its resonance within a few delta of nu (the
    response band lies around nu_n, skewed upward by the hardening of the impacts).
    With the array's close neighbours (delta ~ 2 %) the feasible nu_n fill a sliver of
    NATURAL_RATIO that random sampling would rarely hit, so the range shrinks to
    [exp(-3 delta), exp(2 delta)] (never wider than NATURAL_RATIO).  For the paper's
    pair (delta = ln 2) this leaves NATURAL_RATIO unchanged.

    >>> natural_ratio(6000.0, [3000.0])
    (0.4, 1.4)
    """
    lo, hi = NATURAL_RATIO
    if len(forbidden):
        delta = min(abs(math.log(f / frequency)) for f in forbidden)
        lo, hi = max(lo, math.exp(-3.0 * delta)), min(hi, math.exp(2.0 * delta))
    return (lo, hi)


class _Problem:
    """Geometry <-> search coordinates, cached simulations and the tiered energy."""

    def __init__(self, frequency, forbidden, factory, tones, bounds, window, budget, guard,
                 ensembles=(), mass_cap=math.inf, q_per_kg=0.0, robust_shift=None,
                 target_ensembles=(), sensitivity=None, tone_window=0.0):
        self.frequency = frequency
        # the tone window: the design must respond, from every x0, at the tone moved by
        # -w and +w too (its tone moves with a measurement's error on a fabricated chip);
        # the objective's worst response is taken over the tone and both edges
        self.tone_window = float(tone_window)
        self.window_tones = (() if self.tone_window <= 0.0 else
                             (frequency * (1.0 - self.tone_window),
                              frequency * (1.0 + self.tone_window)))
        self._window_keys = {_freq_key(f) for f in self.window_tones}
        # eqs. (2), (4) in closed form: the beam length for a natural frequency and the
        # line-width sensitivity (planner.designer.sensitivity)
        self.line_width = LineWidthModel(factory)
        # (lo, hi) band of d ln nu_n / d(line width) [1/m] every design must lie in
        # (design.match_sensitivity), or None
        self.sensitivity = None if sensitivity is None else (float(sensitivity[0]),
                                                             float(sensitivity[1]))
        # summed drives of the multi-tone steps the design must move its slider in: the
        # response counted at the target is the least over its own tone and these
        self.target_ensembles = tuple(target_ensembles)
        # robust design: every check is made on the impacter with its natural frequency
        # scaled by 1, 1 - s and 1 + s, s = robust_shift(geometry) (k sigma of its own
        # fabrication scatter): the target must be met by all of them (the least
        # response counts) and the silence kept by all (the largest)
        self.robust_shift = robust_shift
        self.shifts = {}     # geometry -> s
        # m <= mass_cap [kg] (design.max_mass_ratio times the slider mass); and under the
        # two-body contact law a kick gives the slider only 1 / (1 + q) of what eq. (10)
        # says, q = 2 (m/M) cos^2(theta) = q_per_kg * m: the objective is r / (1 + q)
        self.mass_cap = float(mass_cap)
        self.q_per_kg = float(q_per_kg)
        self.forbidden = forbidden
        self.guard = float(guard)
        self.factory = factory
        self.tones = tones
        self.bounds = bounds
        self.window = window
        self.budget = budget
        # the frequencies checked for (14): every nu_j and points of its guard band,
        # in danger order (nearest the target in log frequency, centre first)
        offsets = _guard_offsets(guard, budget.guard_points)
        near = sorted(range(len(forbidden)), key=lambda j: abs(math.log(forbidden[j] / frequency)))
        # the summed drives of multi-tone steps come first: they are what fails when
        # every tone alone is harmless
        self.ensembles = tuple(ensembles)
        self.check_hz = list(self.ensembles) + [forbidden[j] * (1.0 + o) for j in near
                                                for o in offsets]
        self.owner = [-1] * len(self.ensembles) + [j for j in near for _ in offsets]
        self.order = list(range(len(self.check_hz)))
        k = budget.active_forbidden
        # checked during the search, with move-to-front on a violation
        self.active = list(self.order if k is None else
                           self.order[:len(self.ensembles) + k * len(offsets)])
        self.u = _u_grid(budget.x0_points)                # objective grid (u = x0 / c)
        self.u_forbid = _u_grid(budget.forbidden_x0_points)  # constraint grid
        self.u_long = np.zeros(0)     # constraint points checked over the long window
        ratio = natural_ratio(frequency, forbidden)
        area_hi = bounds.area[1]
        if math.isfinite(self.mass_cap):
            # the plate's mass alone (rho A t, eq. 2) must stay under the cap: no area
            # above that can be feasible, so the search does not look there
            a1, a2 = 1e-9, 2e-9
            per_area = (factory(a2, bounds.width[0], bounds.length[0], bounds.gap[0]).mass
                        - factory(a1, bounds.width[0], bounds.length[0], bounds.gap[0]).mass
                        ) / (a2 - a1)
            area_hi = min(area_hi, self.mass_cap / per_area)
            if area_hi <= bounds.area[0]:
                raise ValueError(
                    f"max_mass_ratio allows an impacter of at most {self.mass_cap * 1e12:.4g} "
                    f"ng, below the mass of the smallest area allowed ({bounds.area[0] * 1e12:g}"
                    " um^2): raise max_mass_ratio, lower the area bound or use a heavier slider")
        self.area_hi = area_hi
        # z[3] is ln kappa, the gap over the linear amplitude at the target
        # (GAP_AMPLITUDE_RATIO); the gap is then clipped to its bounds
        self.lo = np.log([bounds.area[0], bounds.width[0], ratio[0] * frequency,
                          GAP_AMPLITUDE_RATIO[0]])
        self.hi = np.log([area_hi, bounds.width[1], ratio[1] * frequency,
                          GAP_AMPLITUDE_RATIO[1]])
        # b = mu A / d (eq. 3) is linear in A: its coefficient, for the amplitude
        ref = factory(1e-9, bounds.width[0], bounds.length[0], bounds.gap[0])
        self.damping_per_area = ref.damping / 1e-9
        drive = tones.drive(frequency)
        self.tone_amplitude = float(drive.amplitudes[0])
        self.evals = {}      # geometry -> _Eval (on the current grids)
        self.runs = {}       # (geometry, f, window, stop, u bytes) -> (r, status)
        self.bound_cache = {}  # (geometry, f) -> proven silent by the closed-form bound
        self.bounded = 0     # checks the bound answered (no simulation)
        self.impacters = {}  # geometry -> model.Impacter (validation costs as much as a run)
        # whether the search's objective counts the target ensembles too: it starts
        # without them (on the default plan they lowered r_min in 2 of ~400 evaluations,
        # at ~400 us a run against ~50 us for the tone) and takes them in from the
        # first re-check in which they lower r_min; the re-checks always count them
        self.ensembles_in_search = False
        self.threads_full = numba.get_num_threads()
        self.threads_now = self.threads_full
        self.evaluations = 0
        self.simulations = 0
        self.faults = 0
        self.archive = []    # best distinct feasible evaluations, best first
        self.best_any = None

    # coordinates -------------------------------------------------------------------
    def length_for(self, area, width, nu_n):
        """l [m] with sqrt(k/m)/(2 pi) = nu_n by eqs. (2), (4), clipped to its bounds."""
        return self.line_width.length_for(area, width, nu_n, self.bounds.length)

    def geometry(self, z):
        """(A, w, l, c) and the z of the projected design.

        Without a sensitivity band z = (ln A, ln w, ln nu_n, ln c) scaled to [0, 1] and l
        follows from nu_n.  With one, z[1] is the target line-width sensitivity's place
        in the band (log scale) instead of the width: the width (or, when the width is
        fixed, the area) is solved for it at the candidate's A (or w) and nu_n.
        """
        z = np.clip(np.asarray(z, dtype=float), 0.0, 1.0)
        area, width, nu_n, kappa = np.exp(self.lo + z * (self.hi - self.lo))
        target = None
        if self.sensitivity is not None:
            s_lo, s_hi = self.sensitivity
            target = s_lo * (s_hi / s_lo) ** z[1] if s_hi > s_lo else s_lo
        area, width, length = self._shape(area, width, nu_n, target)
        area_free = self.sensitivity is None or self.bounds.width[0] < self.bounds.width[1]
        if area_free and self.line_width.mass(area, width, length) > self.mass_cap:
            area, width, length = self._onto_mass_cap(area, width, length, nu_n, target)
        amplitude = self.linear_amplitude(area, width, length)
        gap = min(max(kappa * amplitude, self.bounds.gap[0]), self.bounds.gap[1])
        imp = self.factory(area, width, length, gap)
        zz = z.copy()
        zz[0] = min(1.0, max(0.0, (math.log(area) - self.lo[0]) / (self.hi[0] - self.lo[0])))
        zz[2] = (math.log(imp.natural_frequency) - self.lo[2]) / (self.hi[2] - self.lo[2])
        zz[3] = min(1.0, max(0.0, (math.log(gap / amplitude) - self.lo[3])
                             / (self.hi[3] - self.lo[3])))
        if self.sensitivity is not None and self.sensitivity[1] > self.sensitivity[0]:
            s = self.line_width.sensitivity(area, width, length)
            zz[1] = min(1.0, max(0.0, math.log(s / self.sensitivity[0])
                                 / math.log(self.sensitivity[1] / self.sensitivity[0])))
        return (float(area), float(width), float(length), float(gap)), zz

    def z_of(self, geometry, frequency):
        """z of a design (A, w, l, c) made for the tone ``frequency`` [Hz], scaled to this
        problem's tone: the same A, width (or line-width sensitivity), nu_n / tone and gap
        over its linear amplitude at its tone (a member of the spec's design family,
        clipped into the search box)."""
        area, width, length, gap = (float(v) for v in geometry)
        nu_n = self.line_width.natural_frequency(area, width, length)
        kappa = gap / self.linear_amplitude(area, width, length, frequency)
        z = np.empty(4)
        z[0] = (math.log(area) - self.lo[0]) / (self.hi[0] - self.lo[0])
        if self.sensitivity is not None:
            s_lo, s_hi = self.sensitivity
            s = self.line_width.sensitivity(area, width, length)
            z[1] = (math.log(s / s_lo) / math.log(s_hi / s_lo)) if s_hi > s_lo else 0.0
        else:
            z[1] = ((math.log(width) - self.lo[1]) / (self.hi[1] - self.lo[1])
                    if self.hi[1] > self.lo[1] else 0.0)
        z[2] = ((math.log(nu_n / frequency * self.frequency) - self.lo[2])
                / (self.hi[2] - self.lo[2]))
        z[3] = (math.log(kappa) - self.lo[3]) / (self.hi[3] - self.lo[3])
        return np.clip(z, 0.0, 1.0)

    def _shape(self, area, width, nu_n, target):
        """(A, w, l) for natural frequency ``nu_n``: l from nu_n, or with a sensitivity
        ``target`` [1/m] the width (the area, when the width is fixed) solved for it."""
        if target is None:
            return area, width, self.length_for(area, width, nu_n)
        if self.bounds.width[0] < self.bounds.width[1]:
            width, length = self.line_width.width_for(area, nu_n, target,
                                                      self.bounds.width, self.bounds.length)
        else:
            area, length = self.line_width.area_for(width, nu_n, target,
                                                    (self.bounds.area[0], self.area_hi),
                                                    self.bounds.length)
        return area, width, length

    def _onto_mass_cap(self, area, width, length, nu_n, target):
        """(A, w, l) with the area lowered until m = c_A A + c_wl w l meets the mass cap.

        The plate-only bound ``area_hi`` leaves the beams' mass out, so the largest
        areas overshoot the cap, where the fastest designs sit (m/M at the cap: the
        heavier impacter kicks harder).  A projection onto the cap instead of a penalty
        keeps the search's largest-area samples (``Budget.area_face``) on that face.
        Fixed-point iteration on A, the beams re-solved each time (their mass is a
        small, slowly varying part of m); returned unchanged when it does not settle
        under the cap (the energy's penalty then applies).
        """
        lw = self.line_width
        goal = self.mass_cap * (1.0 - MASS_CAP_MARGIN)
        for _ in range(MASS_CAP_ITERATIONS):
            new_area = (goal - lw.c_wl * width * length) / lw.c_area
            if not (new_area >= self.bounds.area[0]):
                break
            area, width, length = self._shape(new_area, width, nu_n, target)
            if lw.mass(area, width, length) <= self.mass_cap:
                return area, width, length
        return area, width, length

    def linear_amplitude(self, area, width, length, frequency=None):
        """X [m]: steady-state amplitude of eq. (1) without the wall at the target tone
        (or at ``frequency`` [Hz]), for (A, w, l) by eqs. (2)-(4) in closed form."""
        lw = self.line_width
        m = lw.mass(area, width, length)
        k = lw.k_coef * (width / length) ** 3
        wn = math.sqrt(k / m)
        amplitude = self.tone_amplitude
        if frequency is None:
            frequency = self.frequency
        else:
            amplitude = float(self.tones.drive(frequency).amplitudes[0])
        r = 2.0 * math.pi * frequency / wn
        zeta = self.damping_per_area * area / (2.0 * m * wn)
        return amplitude * r * r / math.hypot(1.0 - r * r, 2.0 * zeta * r)

    def sensitivity_miss(self, geometry):
        """|ln(S / band)| of ``geometry``'s line-width sensitivity outside the band, 0 inside."""
        if self.sensitivity is None:
            return 0.0
        s = self.line_width.sensitivity(*geometry[:3])
        s_lo, s_hi = self.sensitivity
        # the roots are exact to ~1e-12: a design on the edge is inside
        if s < s_lo * (1.0 - 1e-9):
            return math.log(s_lo / s)
        if s > s_hi * (1.0 + 1e-9):
            return math.log(s / s_hi)
        return 0.0

    # simulations -------------------------------------------------------------------
    def impacter(self, geometry):
        imp = self.impacters.get(geometry)
        if imp is None:
            imp = self.impacters[geometry] = self.factory(*geometry)
        return imp

    def _threads_for(self, n_runs):
        """The thread policy of :func:`_kernel_threads`, switched only when it changes
        (the search makes tens of thousands of ~100 us calls)."""
        want = self.threads_full if n_runs >= PARALLEL_MIN_RUNS else 1
        if want != self.threads_now:
            numba.set_num_threads(want)
            self.threads_now = want

    @contextlib.contextmanager
    def kernel_scope(self):
        """Where the search runs: solver warnings off (status codes are counted in
        ``faults``) and the caller's numba thread count restored afterwards."""
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", SolverWarning)
                yield
        finally:
            if self.threads_now != self.threads_full:
                numba.set_num_threads(self.threads_full)
                self.threads_now = self.threads_full

    def runs_of(self, geometry, frequency, u, window, stop):
        """r [N] and status of one check from each u = x0 / c (cached; called inside
        :meth:`kernel_scope`)."""
        key = (geometry, _freq_key(frequency), float(window), bool(stop), u.tobytes())
        hit = self.runs.get(key)
        if hit is None and SILENCE_BOUND and not self._at_target(frequency) and self.bounded_silent(
                geometry, frequency):
            # a closed-form bound proves r = 0 from every x0 over any window: no runs
            hit = self.runs[key] = (np.zeros(u.size), np.zeros(u.size, dtype=np.int64))
        if hit is None:
            imp = self.impacter(geometry)
            self._threads_for(u.size)
            rs, statuses = [], []
            for scale in self.nu_scales(geometry):
                var = imp if scale == 1.0 else self.variant(geometry, scale)
                # arguments built here (x0 = u c, |u| <= 1, window > 0): no re-validation
                r, status = responses(var, self.tones.drive(frequency), u * var.gap,
                                      duration=window, stop_at_first=stop,
                                      return_status=True, check_input=False)
                self.simulations += u.size
                self.faults += int(np.count_nonzero(status))
                rs.append(r)
                statuses.append(status)
            if len(rs) == 1:
                hit = (rs[0], statuses[0])
            else:
                # at the target the variant that responds least counts (all must be
                # driven); anywhere else the one that responds most (all must be silent)
                target = self._at_target(frequency)
                hit = ((np.min(rs, axis=0) if target else np.max(rs, axis=0)),
                       np.max(statuses, axis=0))
            self.runs[key] = hit
        return hit

    def _at_target(self, frequency):
        """Whether ``frequency`` is the target, an edge of its window or a target
        ensemble (where the design must respond) rather than a check of silence."""
        return (any(frequency is e for e in self.target_ensembles)
                or (not isinstance(frequency, Ensemble)
                    and (_freq_key(frequency) == _freq_key(self.frequency)
                         or _freq_key(frequency) in self._window_keys)))

    def bounded_silent(self, geometry, frequency):
        """Whether :func:`model.bounds.silence_bound` proves ``geometry`` silent under
        ``frequency`` (a tone or an :class:`Ensemble`) for every natural-frequency
        variant it is checked for (cached; counted in ``bounded``)."""
        key = (geometry, _freq_key(frequency))
        hit = self.bound_cache.get(key)
        if hit is None:
            drive = frequency.drive if isinstance(frequency, Ensemble) else self.tones.drive(
                frequency)
            hit = all(
                silence_bound(self.impacter(geometry) if scale == 1.0
                              else self.variant(geometry, scale), drive).silent
                for scale in self.nu_scales(geometry))
            self.bound_cache[key] = hit
            self.bounded += int(hit)
        return hit

    def nu_scales(self, geometry):
        """Natural-frequency multipliers every check of ``geometry`` is made for."""
        if self.robust_shift is None:
            return (1.0,)
        s = self.shifts.get(geometry)
        if s is None:
            s = self.shifts[geometry] = float(self.robust_shift(geometry))
            if not (math.isfinite(s) and 0.0 <= s < 0.5):
                raise ValueError(f"robust shift must be in [0, 0.5), {s!r} for {geometry}")
        return (1.0,) if s == 0.0 else (1.0, 1.0 - s, 1.0 + s)

    def variant(self, geometry, scale):
        """The impacter of ``geometry`` with its natural frequency times ``scale``."""
        key = (geometry, scale)
        imp = self.impacters.get(key)
        if imp is None:
            base = self.impacter(geometry)
            imp = self.impacters[key] = base.with_natural_frequency(
                base.natural_frequency * scale)
        return imp

    def target(self, geometry, u, levels, window=None, ensembles=True):
        """(u, r) at the target frequency, refined by bisection where r jumps; r is the
        least of the tone's and its window edges' (``tone_window``), and with
        ``ensembles`` every target ensemble's too."""
        window = self.window if window is None else window
        u = np.asarray(u, dtype=float)
        r = self.runs_of(geometry, self.frequency, u, window, False)[0]
        for _ in range(levels):
            scale = float(np.max(r)) if r.size else 0.0
            jump = (np.abs(np.diff(r)) > JUMP_REL * scale) | ((r[:-1] > 0) != (r[1:] > 0))
            if not np.any(jump):
                break
            mids = 0.5 * (u[:-1] + u[1:])[jump]
            r_new = self.runs_of(geometry, self.frequency, mids, window, False)[0]
            u = np.concatenate([u, mids])
            r = np.concatenate([r, r_new])
            order = np.argsort(u, kind="stable")
            u, r = u[order], r[order]
        for f in self.window_tones:
            # the tone anywhere in its window: the edges must drive it from every x0 too
            r = np.minimum(r, self.runs_of(geometry, f, u, window, False)[0])
        for ens in (self.target_ensembles if ensembles else ()):
            # the slider must move under the step's summed drive from every x0 too
            r = np.minimum(r, self.runs_of(geometry, ens, u, window, False)[0])
        return u, r

    def violation(self, geometry, u, window, indices, count=1):
        """How badly (14) fails, and the first violated check (index), or (0, None).

        Checks frequencies in the order given, each on the x0 grid u with
        ``stop_at_first``, and stops after ``count`` violated ones (None: checks all).
        The measure is (violations found - 1) + the fraction of x0 responding at the
        first: in (0, 1] with count=1, larger the more frequencies respond.
        """
        if u.size == 0:
            return 0.0, None
        first, frac, found = None, 0.0, 0
        for j in indices:
            r, status = self.runs_of(geometry, self.check_hz[j], u, window, True)
            hit = r > 0
            if np.any(hit):
                if first is None:
                    first, frac = j, float(np.mean(hit))
                found += 1
                if count is not None and found >= count:
                    break
        if first is None:
            return 0.0, None
        return found - 1 + frac, first

    def add_points(self, u_target=(), u_forbid=(), u_long=()):
        """Exchange step: grow the grids by the x0 where a re-check failed."""
        self.u = np.unique(np.concatenate([self.u, np.asarray(u_target, dtype=float)]))
        self.u_forbid = np.unique(np.concatenate([self.u_forbid,
                                                  np.asarray(u_forbid, dtype=float)]))
        self.u_long = np.unique(np.concatenate([self.u_long, np.asarray(u_long, dtype=float)]))
        self.evals = {}          # energies on the old grids no longer hold
        self.archive = []
        self.best_any = None

    # energy --------------------------------------------------------------------------
    def evaluate(self, z):
        geometry, zz = self.geometry(z)
        ev = self.evals.get(geometry)
        if ev is not None:
            return ev
        self.evaluations += 1
        mass = self.impacter(geometry).mass
        miss = self.sensitivity_miss(geometry)
        if miss > 0.0:
            # no width (area) within the bounds reaches the sensitivity band here: worse
            # than any violation of (14), graded so the search walks back into the band
            ev = _Eval(zz, geometry, 3 * PENALTY + miss, 1.0, None, 0.0, 0.0, math.nan)
            self.evals[geometry] = ev
            self._remember(ev)
            return ev
        if mass > self.mass_cap:
            # over the mass cap (the beams' mass pushed it there): worse than any
            # violation of (14), graded so that the search walks back under the cap
            ev = _Eval(zz, geometry, 3 * PENALTY + math.log(mass / self.mass_cap), 1.0, None,
                       0.0, 0.0, math.nan)
            self.evals[geometry] = ev
            self._remember(ev)
            return ev
        frac, j = self.violation(geometry, self.u_forbid, self.window, self.active,
                                 self.budget.violations_counted)
        if j is None:
            frac, j = self.violation(geometry, self.u_long, LONG_WINDOW_FACTOR * self.window,
                                     self.active)
        if j is not None:
            # move-to-front: the frequency that just failed is the likeliest next time
            self.active.remove(j)
            self.active.insert(0, j)
            ev = _Eval(zz, geometry, 2 * PENALTY + frac, frac, float(self.check_hz[j]), 0.0,
                       0.0, math.nan)
        else:
            u, r = self.target(geometry, self.u, self.budget.refine_levels,
                               ensembles=self.ensembles_in_search)
            i = int(np.argmin(r))
            zero = float(np.mean(r <= 0))
            energy = (PENALTY + zero if zero > 0 else
                      -math.log(float(r[i])) + math.log1p(self.q_per_kg * mass))
            ev = _Eval(zz, geometry, energy, 0.0, None, zero, float(r[i]), float(u[i]))
        self.evals[geometry] = ev
        self._remember(ev)
        return ev

    def _remember(self, ev):
        if self.best_any is None or ev.energy < self.best_any.energy:
            self.best_any = ev
        if not ev.feasible:
            return
        for k, other in enumerate(self.archive):
            if np.max(np.abs(other.z - ev.z)) < ARCHIVE_SEPARATION:
                if ev.energy < other.energy:
                    self.archive[k] = ev
                    self.archive.sort(key=lambda e: e.energy)
                return
        self.archive.append(ev)
        self.archive.sort(key=lambda e: e.energy)
        del self.archive[self.budget.archive:]
