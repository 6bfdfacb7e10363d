"""Impacter design by the paper's max-min problem, eqs. (13)-(18).

For an impacter with target drive frequency nu and forbidden frequencies {nu_j}:

    maximise over p = (A, w, l, c)     min_{x0 in D} r(x0, p, nu)                 (13)
    subject to                         max_{x0 in D} r(x0, p, nu_j) = 0  for all j  (14)
                                       D = {x(t0) in [-c, c], v(t0) = 0}          (15), (18)
                                       p in P (bounds, (17) below)                (16), (17)

r is the response of eq. (12), computed by the exact event-driven simulator of
:mod:`model`; k, m and b follow from the geometry by eqs. (2)-(4) *as printed* (the
design variables really are geometry, see :mod:`model.devices` on the paper's
inconsistency).  Only impacter dynamics enter the objective, as the paper argues;
the slider is simulated once, for the report.

Public API
----------
:func:`design_impacter`, :func:`design_pair`, :func:`response_band`,
:func:`response_curves`, :func:`x0_grid`, :class:`DesignBounds`, :class:`DesignResult`,
:class:`PairDesign`, :data:`BUDGETS`.

Notes
-----
**Search coordinates.**  The annealer moves in z in [0, 1]^4, the normalised logarithms
of (A, w, nu_n, c); the beam length l is recovered from (A, w, nu_n) through eqs. (2)
and (4) (k = m (2 pi nu_n)^2 has exactly one root in l, since k falls and m grows with
l).  This is a smooth bijection of the paper's p, so the optimum is the same, but it
decouples the two things the response depends on: where the response curve sits
(nu_n and c set the dynamics per unit mass; b / 2m is nearly fixed by mu / (rho t d))
and how large it is (r is proportional to m).  A move in A at fixed nu_n leaves the
curve in place, which a random walk in (A, l) would almost never do.  nu_n is searched
in NATURAL_RATIO times nu; a proposal whose l would leave its bounds is projected onto
them (nu_n then follows from the clipped l).

**Constraint handling.**  The annealer minimises a tiered energy (feasibility first,
Deb's rule made scalar):

- a design that responds at a forbidden frequency from some x0 of the grid:
  E = 2 PENALTY + (fraction of x0 that respond at the first violated frequency);
- a feasible design that does not respond at nu from every x0:
  E = PENALTY + (fraction of x0 with r = 0);
- a feasible design that responds from every x0: E = -ln(r_min / 1 N).

PENALTY dwarfs any difference of ln r, so a chain that has found the feasible region
never leaves it, while the fractions give infeasible chains a slope towards
feasibility.  The SQP polish (SLSQP) minimises the same energy with the constraint
also passed explicitly (``-violation >= 0``); r is discontinuous (the paper's Fig. 9),
so its finite-difference gradients are only locally meaningful and its line search
is guarded by the cache: every point it evaluates joins the archive, and the best
feasible point seen, annealed or polished, wins.

**The x0 grid.**  D is sampled on a uniform grid of u = x0 / c in [-1, 1] (odd point
count, so -c, 0 and +c are nodes), plus points just inside the wall, and the target
response is refined by bisection wherever it jumps between neighbours (Fig. 9's
discontinuities, the paper's "bifurcations").  x0 = +c is evaluated at
c (1 - WALL_OFFSET): the limit x0 -> c from inside is the stricter case (from just
inside, a drive that presses on the wall at t0 produces counted chatter; a start
stuck on the wall produces none).  It also kept the designer clear of a solver fault
at x0 == gap exactly (spurious zero-time impacts of noise velocity when the net force
pulls away from the wall), fixed in the kernels since.

**Constraint checks are cheap.**  A forbidden frequency is checked with
``stop_at_first`` (a run stops at its first counted impact), frequencies are tried
nearest the target first with move-to-front on a violation, the check stops at the
first violated frequency, and every kernel call is cached by its inputs.  With the
"fast" budget only the ``active_forbidden`` most dangerous frequencies are checked
during the search; the final design is checked against all of them, and any that it
violates joins the active set for another search round (constraint generation).

**Re-checks.**  The best designs of the archive are re-checked on a grid about eight
times finer (with more refinement) and over a window LONG_WINDOW_FACTOR times longer;
the design reported is the best that passes both.  ``checks`` in the result says
how many designs passed on the optimiser's grid but failed a re-check.

References
----------
K. Saitou, D.-A. Wang, S. J. Wou, "Externally resonated linear microvibromotor for
microassembly", J. Microelectromech. Syst. 9(3), 2000, Section III-C.

Examples
--------
>>> from planner.designer import design_impacter
>>> res = design_impacter(6000.0, forbidden=(3000.0,), budget="fast", seed=1)  # doctest: +SKIP
>>> res.feasible, res.r_min_n > 0                                              # doctest: +SKIP
(True, True)
"""

from __future__ import annotations

import contextlib
import math
import numbers
import time
import warnings
from dataclasses import dataclass, field, replace

import numba
import numpy as np
from scipy import optimize, stats

from model import (
    Drive,
    Geometry,
    Impacter,
    Slider,
    SolverWarning,
    responses,
    simulate_slider,
    sweep,
)
from model import devices as _d
from model.drive import POWER

UM = 1e-6

# ---------------------------------------------------------------------------------
# tuning constants

#: Tier offset of the annealing energy; far above any difference of ln r [-].
PENALTY = 1.0e3
#: x0 = +c is simulated at c (1 - WALL_OFFSET): the limit from inside the gap, the
#: stricter case for (14) (see the module notes) [-].
WALL_OFFSET = 1e-9
#: Extra points just inside the wall, as fractions of c: a drive that presses on the
#: wall at t0 makes starts there chatter, in a zone that can be far thinner than the
#: grid step [-].
EDGE_FRACTIONS = (1.0 - 1e-2, 1.0 - 1e-4, 1.0 - 1e-6)
#: Neighbouring responses that differ by more than this fraction of the largest are
#: a jump (Fig. 9): the x0 interval between them is bisected [-].
JUMP_REL = 0.15
#: Search range of nu_n as a multiple of the target frequency.  The response of an
#: impact oscillator sits around and above nu_n (hardening, Fig. 9); the paper's
#: Table II designs sit at 0.68 and 0.97 times their targets [-].
NATURAL_RATIO = (0.4, 1.4)
#: Default guard: silent within +-2% of each forbidden frequency, not just at it.  With
#: guard = 0 the optimiser parks forbidden frequencies in holes of a responding region
#: (found: a design silent at 6000 Hz that responds at 6000.5 Hz) [-].
GUARD = 0.02
#: The long re-check window, as a multiple of the design window [-].
LONG_WINDOW_FACTOR = 10.0
#: Batches of fewer simulations than this run on one thread: each run takes tens of
#: microseconds, a parallel launch on a busy 2-core machine tens of milliseconds.
PARALLEL_MIN_RUNS = 512
#: Two designs closer than this in z (max norm) are one design in the archive [-].
ARCHIVE_SEPARATION = 0.02
#: The annealer adapts its step every this many moves towards ACCEPT_TARGET.
ADAPT_EVERY = 20
ACCEPT_TARGET = (0.2, 0.45)

#: The paper's lower bounds (17): A >= 20 um^2, w >= 2 um, l >= 8 um, c >= 2 um [m^2, m].
PAPER_LOWER = (20.0 * UM**2, 2.0 * UM, 8.0 * UM, 2.0 * UM)
#: Default upper bounds [m^2, m]; see :class:`DesignBounds` for the reasons.
DEFAULT_UPPER = (5.0e4 * UM**2, 10.0 * UM, 1500.0 * UM, 10.0 * UM)


# ---------------------------------------------------------------------------------
# bounds, budgets, results


def _pair(name, value):
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a (lo, hi) pair, {value!r} was given") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and 0.0 < lo < hi):
        raise ValueError(f"{name} must satisfy 0 < lo < hi (finite), {value!r} was given")
    return lo, hi


@dataclass(frozen=True)
class DesignBounds:
    """Bounds of the design variables p = (A, w, l, c), SI units.

    Parameters
    ----------
    area : (float, float)
        A [m^2]; default (20 um^2, 5e4 um^2).
    width : (float, float)
        w [m]; default (2 um, 10 um).
    length : (float, float)
        l, total length of the two V-beam segments [m]; default (8 um, 1500 um).
    gap : (float, float)
        c [m]; default (2 um, 10 um).

    Notes
    -----
    The lower bounds are the paper's (17): the minimum feature of the MUMPs process
    (2 um) and the impacter geometry of its Fig. 6.

    The paper has no upper bounds, and without them (13) is unbounded: r is
    proportional to m, so a larger impacter tuned to the same nu_n responds more.
    The defaults come from the footprint of one device of an array at 1 mm pitch
    (``configs/array_5x5.yaml``), where a device holds a slider and two impacter
    pairs:

    - A <= 5e4 um^2: a mass of about 220 um x 220 um, so that four fit beside an
      8e4 um^2 slider; Table II's backward mass (45446 um^2) is just below it.
    - l <= 1500 um: each V-beam segment then spans about 725 um (phi = 15 deg), under
      the pitch; the paper's designs use 800 to 1250 um.
    - w <= 10 um: five times the minimum feature; wider beams only stiffen the
      impacter, which a longer beam then has to undo.
    - c <= 10 um: the slider's side-wall gap stays within a few drive amplitudes
      (Z0 = 1.27 um at 5 kHz); wider gaps need larger swings to respond at all.

    Examples
    --------
    >>> b = DesignBounds.from_spec(area_um2=(20, 3e4))
    >>> round(b.area[1] / 1e-12)
    30000
    """

    area: tuple[float, float] = (PAPER_LOWER[0], DEFAULT_UPPER[0])
    width: tuple[float, float] = (PAPER_LOWER[1], DEFAULT_UPPER[1])
    length: tuple[float, float] = (PAPER_LOWER[2], DEFAULT_UPPER[2])
    gap: tuple[float, float] = (PAPER_LOWER[3], DEFAULT_UPPER[3])

    def __post_init__(self):
        for name in ("area", "width", "length", "gap"):
            object.__setattr__(self, name, _pair(name, getattr(self, name)))

    @classmethod
    def from_spec(cls, area_um2=None, width_um=None, length_um=None, gap_um=None):
        """Bounds from config units (um^2, um); None keeps the default of that variable."""
        kwargs = {}
        for key, name, scale in (("area_um2", "area", UM**2), ("width_um", "width", UM),
                                 ("length_um", "length", UM), ("gap_um", "gap", UM)):
            value = locals()[key]
            if value is not None:
                lo, hi = _pair(key, value)
                kwargs[name] = (lo * scale, hi * scale)
        return cls(**kwargs)

    def as_dict(self):
        """Config-unit dict: ``{"area_um2": [lo, hi], ...}``."""
        return {"area_um2": [self.area[0] / UM**2, self.area[1] / UM**2],
                "width_um": [self.width[0] / UM, self.width[1] / UM],
                "length_um": [self.length[0] / UM, self.length[1] / UM],
                "gap_um": [self.gap[0] / UM, self.gap[1] / UM]}


@dataclass(frozen=True)
class Budget:
    """How hard the designer searches; named budgets are in :data:`BUDGETS`.

    Attributes
    ----------
    x0_points : int
        Uniform x0 grid of the optimiser's objective over [-c, c] (odd: -c, 0 and +c
        are nodes).
    forbidden_x0_points : int
        Uniform x0 grid of the optimiser's constraint checks (odd).
    refine_levels : int
        Bisection levels where the target response jumps between neighbours.
    initial : int
        Scrambled-Sobol samples that seed the annealing chains.
    chains : int
        Annealing chains, started from the best distinct initial samples.
    anneal_steps : int
        Moves per chain.
    t_start, t_end : float
        Geometric temperature schedule, in units of ln r.
    step : float
        Initial move size in z (adapted to the acceptance rate).
    sqp_maxiter : int
        SLSQP iterations of the polish (0: no polish).
    verify_x0_points, verify_refine_levels : int
        Grid and refinement of the re-check.
    rounds : int
        Search rounds: after the first, the x0 where a re-check failed join the
        optimiser's grids and the search resumes from the archive (exchange method).
    resume_steps : int
        Annealing moves per chain in a resumed round.
    archive : int
        Distinct feasible designs kept for the re-check.
    active_forbidden : int or None
        Forbidden frequencies checked during the search (the nearest to the target);
        None checks all.  The final design is always checked against all.
    margin_points : int
        Frequencies per side of each forbidden frequency scanned for its margin (the
        nearest responding one is then bisected).
    margin_tol : float
        Tolerance of the margins' bisection, relative to the forbidden frequency.
    guard_points : int
        Frequencies checked across each forbidden frequency's guard band (odd).
    escalations : int
        Further searches, each with 4x the samples and 2x the moves of the last, when a
        search finds no feasible design at all.
    area_face : float
        Share of the initial samples placed at the largest area (see ``_search``).
    violations_counted : int or None
        The constraint check of a candidate stops at this many violated frequencies
        (None: checks all): 1 is cheapest; more gives the annealer a slope towards
        feasibility when many frequencies are forbidden.
    """

    x0_points: int = 65
    forbidden_x0_points: int = 129
    refine_levels: int = 3
    initial: int = 128
    chains: int = 4
    anneal_steps: int = 1000
    t_start: float = 0.3
    t_end: float = 0.003
    step: float = 0.08
    sqp_maxiter: int = 20
    verify_x0_points: int = 1025
    verify_refine_levels: int = 5
    rounds: int = 4
    resume_steps: int = 150
    archive: int = 6
    active_forbidden: int | None = None
    margin_points: int = 48
    margin_tol: float = 1e-4
    guard_points: int = 5
    escalations: int = 1
    area_face: float = 0.25
    violations_counted: int | None = 1

    def __post_init__(self):
        for name in ("x0_points", "forbidden_x0_points", "verify_x0_points"):
            n = getattr(self, name)
            if n < 3 or n % 2 == 0:
                raise ValueError(f"{name} must be odd and >= 3, {n!r} was given")
        if self.verify_x0_points < max(self.x0_points, self.forbidden_x0_points):
            raise ValueError("verify_x0_points must be >= the optimiser's grids")
        for name in ("initial", "chains", "archive"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, {getattr(self, name)!r} was given")
        if not 0 < self.t_end <= self.t_start:
            raise ValueError("temperatures must satisfy 0 < t_end <= t_start")


#: Named budgets.  "full" (the CLI's default) meets the Table II check; "fast" is for
#: the array planner's ~50 designs (aim ~1 s each, up to ~50 forbidden frequencies).
BUDGETS = {
    "full": Budget(),
    "fast": Budget(x0_points=17, forbidden_x0_points=17, refine_levels=1, initial=16,
                   chains=1, anneal_steps=160, t_start=0.3, t_end=0.01, step=0.1,
                   sqp_maxiter=4, verify_x0_points=129, verify_refine_levels=3, rounds=3,
                   resume_steps=40, archive=3, active_forbidden=6, margin_points=8,
                   margin_tol=2e-3, guard_points=3, escalations=2, area_face=0.5,
                   violations_counted=3),
}


def _as_budget(budget, x0_points=None):
    b = BUDGETS.get(budget, budget) if isinstance(budget, str) else budget
    if not isinstance(b, Budget):
        raise ValueError(f"budget must be one of {sorted(BUDGETS)} or a Budget, "
                         f"{budget!r} was given")
    if x0_points is not None:
        n = int(x0_points)
        b = replace(b, x0_points=n, forbidden_x0_points=max(n, b.forbidden_x0_points),
                    verify_x0_points=max(b.verify_x0_points, 4 * (n - 1) + 1))
    return b


def _as_rng(seed):
    """The one place a ``seed`` (int, Generator or None) becomes a generator."""
    if isinstance(seed, np.random.Generator):
        return seed
    if seed is None:
        seed = 0
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral):
        raise ValueError(f"seed must be an int, a numpy Generator or None, {seed!r} was given")
    return np.random.default_rng(int(seed))


@dataclass(frozen=True)
class DesignResult:
    """A designed impacter and what the designer measured about it (SI units).

    Attributes
    ----------
    impacter : model.Impacter
        The design, with its ``geometry``.
    frequency_hz : float
        Target drive frequency nu [Hz].
    forbidden_hz : tuple of float
        Forbidden frequencies nu_j [Hz], as given (sorted).
    natural_frequency_hz, mass_kg, stiffness_n_per_m, damping_ns_per_m, gap_m,
    impact_angle_rad, restitution : float
        nu_n [Hz], m [kg], k [N/m], b [N s/m], c [m], theta [rad], e [-].
    geometry : model.Geometry
        A [m^2], w [m], l [m], c [m].
    worst_x0_m : float
        The x0 of D with the smallest response at nu, on the re-check grid [m].
    r_min_n : float
        min over x0 of r at nu, eq. (13), on the re-check grid [N].
    r_max_forbidden_n : tuple of float
        max over x0 of r at each forbidden frequency, on the re-check grid [N]
        (0 where the design is feasible).
    margins_hz : tuple of float
        Distance from each forbidden frequency to the nearest frequency where the
        design responds from some x0 of the optimiser's constraint grid [Hz] (0 if it
        responds there); scanned on both sides out to the target's distance, then
        bisected (``Budget.margin_points``, ``Budget.margin_tol``).
    predicted_slider_speed_m_s : float
        Mean slider speed over the window when driven at nu from the worst x0 [m/s].
    feasible : bool
        Responds at nu from every x0 and at no forbidden frequency from any x0, on
        the re-check grid over the design window.
    evaluations : int
        Distinct designs simulated.
    seconds : float
        Wall-clock time of the design [s].
    simulations : int
        Impacter runs simulated (cache misses).
    checks : dict
        The re-checks: grid sizes, long window [s], whether it passed each, and how
        many archived designs passed on the optimiser's grid but failed a re-check.
    response_band_hz : (float, float)
        Lowest and highest frequency near nu where the design responds [Hz] (nan if
        not measured).
    status : str
        "ok", or "infeasible" (no design met the constraints; the least violating is
        returned).
    message : str
    """

    impacter: Impacter
    frequency_hz: float
    forbidden_hz: tuple
    natural_frequency_hz: float
    mass_kg: float
    stiffness_n_per_m: float
    damping_ns_per_m: float
    gap_m: float
    impact_angle_rad: float
    restitution: float
    geometry: Geometry
    worst_x0_m: float
    r_min_n: float
    r_max_forbidden_n: tuple
    margins_hz: tuple
    predicted_slider_speed_m_s: float
    feasible: bool
    evaluations: int
    seconds: float
    simulations: int = 0
    checks: dict = field(default_factory=dict)
    response_band_hz: tuple = (math.nan, math.nan)
    status: str = "ok"
    message: str = ""
    seed: int | None = None
    budget: str = "full"
    window_s: float = 3e-3

    def to_dict(self):
        """JSON-safe dict with the plan's impacter keys (SI units, unit-suffixed)."""
        g = self.geometry

        def num(x):
            x = float(x)
            return x if math.isfinite(x) else None

        return {
            "frequency_hz": num(self.frequency_hz),
            "forbidden_hz": [num(f) for f in self.forbidden_hz],
            "mass_kg": num(self.mass_kg),
            "stiffness_n_per_m": num(self.stiffness_n_per_m),
            "damping_ns_per_m": num(self.damping_ns_per_m),
            "gap_m": num(self.gap_m),
            "impact_angle_rad": num(self.impact_angle_rad),
            "restitution": num(self.restitution),
            "natural_frequency_hz": num(self.natural_frequency_hz),
            "geometry": {"area_m2": num(g.area), "width_m": num(g.width),
                         "length_m": num(g.length), "gap_m": num(g.gap)},
            "worst_x0_m": num(self.worst_x0_m),
            "r_min_n": num(self.r_min_n),
            "r_max_forbidden_n": [num(r) for r in self.r_max_forbidden_n],
            "margins_hz": [num(m) for m in self.margins_hz],
            "response_band_hz": [num(f) for f in self.response_band_hz],
            "predicted_slider_speed_m_s": num(self.predicted_slider_speed_m_s),
            "feasible": bool(self.feasible),
            "status": self.status,
            "message": self.message,
            "checks": {k: (num(v) if isinstance(v, float) else v) for k, v in self.checks.items()},
            "evaluations": int(self.evaluations),
            "simulations": int(self.simulations),
            "seconds": num(self.seconds),
            "seed": self.seed,
            "budget": self.budget,
            "window_s": num(self.window_s),
        }


@dataclass(frozen=True)
class PairDesign:
    """The forward and backward designs of one device (:func:`design_pair`)."""

    forward: DesignResult
    backward: DesignResult
    seconds: float

    @property
    def feasible(self):
        return self.forward.feasible and self.backward.feasible

    def to_dict(self):
        """``{"forward": {...}, "backward": {...}}`` as :meth:`DesignResult.to_dict`."""
        return {"forward": self.forward.to_dict(), "backward": self.backward.to_dict()}


# ---------------------------------------------------------------------------------
# the drive convention and kernel calls


@dataclass(frozen=True, eq=False)
class Ensemble:
    """A forbidden drive of several tones: a step's summed drive in which the design is idle.

    Off-resonant responses to the tones of a step add up, so a design silent under
    each tone alone can still hit its slider under their sum; the array planner
    passes every multi-tone step in which an impacter must be idle as one of these.

    Attributes
    ----------
    drive : model.Drive
        The summed drive, amplitudes and phases as synthesised.
    label : str
        Name for reports (the step).
    """

    drive: Drive
    label: str = "ensemble"

    def __float__(self):          # for sorting and reports: the lowest tone
        return float(np.min(self.drive.frequencies))

    def __repr__(self):
        return f"Ensemble({self.label!r}, {self.drive.frequencies.size} tones)"


def _freq_key(frequency):
    return frequency if isinstance(frequency, Ensemble) else float(frequency)


@dataclass(frozen=True)
class _Tones:
    """One tone per frequency: Z0^2 w^3 = power, or a fixed amplitude [m]."""

    power: float = POWER
    amplitude: float | None = None

    def __post_init__(self):
        p = float(self.power)
        if not (math.isfinite(p) and p > 0):
            raise ValueError(f"power must be finite and > 0, {self.power!r} was given")
        object.__setattr__(self, "power", p)
        if self.amplitude is not None:
            a = float(self.amplitude)
            if not (math.isfinite(a) and a > 0):
                raise ValueError(f"amplitude must be finite and > 0, {self.amplitude!r} was given")
            object.__setattr__(self, "amplitude", a)

    # Drive objects already built, by frequency (validation costs more than a short run)
    built: dict = field(default_factory=dict, compare=False, repr=False)

    def drive(self, frequency):
        if isinstance(frequency, Ensemble):
            return frequency.drive
        d = self.built.get(frequency)
        if d is None:
            d = (Drive.tone(frequency, self.power) if self.amplitude is None
                 else Drive([frequency], [self.amplitude]))
            self.built[frequency] = d
        return d


@contextlib.contextmanager
def _kernel_threads(n_runs):
    """Run small batches on one thread (see PARALLEL_MIN_RUNS); restore afterwards."""
    if n_runs >= PARALLEL_MIN_RUNS:
        yield
        return
    prev = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(prev)


def _runs(impacter, tones, frequency, x0s, window, stop_at_first):
    """r [N] and status codes of one tone from each x0 (one batch kernel call)."""
    with _kernel_threads(len(x0s)), warnings.catch_warnings():
        warnings.simplefilter("ignore", SolverWarning)
        return responses(impacter, tones.drive(frequency), x0s, duration=window,
                         stop_at_first=stop_at_first, return_status=True)


def _responds(impacter, tones, frequencies, x0s, window):
    """Whether some x0 responds at each frequency, shape (n_freq,) of bool.

    One parallel sweep for the power convention; one batch per tone otherwise.
    A run that ends on a cap counts as responding if it recorded a counted impact.
    """
    frequencies = np.asarray(frequencies, dtype=float)
    if frequencies.size == 0:
        return np.zeros(0, dtype=bool)
    if tones.amplitude is None:
        with _kernel_threads(frequencies.size * len(x0s)), warnings.catch_warnings():
            warnings.simplefilter("ignore", SolverWarning)
            r = sweep(impacter, frequencies, x0s, tones.power, window, stop_at_first=True)
        return np.any(r > 0, axis=1)
    return np.array([np.any(_runs(impacter, tones, f, x0s, window, True)[0] > 0)
                     for f in frequencies])


def _u_grid(n):
    """x0 / c on [-1, 1]: n uniform nodes with +1 just inside the wall, and edge points."""
    u = np.linspace(-1.0, 1.0, n)
    u[-1] = 1.0 - WALL_OFFSET
    return np.unique(np.concatenate([u, EDGE_FRACTIONS]))


def _guard_offsets(guard, points):
    """Relative offsets of the checked frequencies in a guard band, centre first."""
    if guard == 0.0 or points <= 1:
        return [0.0]
    k = np.linspace(-1.0, 1.0, points if points % 2 else points + 1)
    ks = sorted(k, key=lambda v: (abs(v) != 1.0, abs(v) != 0.0, abs(v), v))
    ks.remove(0.0)
    return [0.0] + [guard * float(v) for v in ks]


def x0_grid(gap, points=33):
    """The designer's sampling of D = {x0 in [-c, c], v0 = 0}: x0 values [m].

    ``points`` uniform nodes over [-c, c] (odd, so -c, 0 and +c are nodes), +c taken
    at c (1 - WALL_OFFSET), and the points c EDGE_FRACTIONS just inside the wall.

    Parameters
    ----------
    gap : float
        c [m].
    points : int
        Uniform nodes.

    Returns
    -------
    ndarray, shape (n,)
        Sorted initial positions [m].

    Examples
    --------
    >>> x = x0_grid(2e-6, 5)
    >>> float(x[0]), float(x[2]), x.size
    (-2e-06, 0.0, 8)
    """
    return _u_grid(int(points)) * float(gap)


def _default_x0s(impacter, n=33):
    return x0_grid(impacter.gap, n)


# ---------------------------------------------------------------------------------
# response band and curves


def _bisect_edge(impacter, tones, x0s, window, f_in, f_out, tol):
    """Boundary between a responding f_in and a silent f_out, on the f_in side [Hz]."""
    while abs(f_out - f_in) > tol:
        mid = 0.5 * (f_in + f_out)
        if _responds(impacter, tones, [mid], x0s, window)[0]:
            f_in = mid
        else:
            f_out = mid
    return f_in


def response_band(impacter, x0s=None, power=POWER, window=3e-3, f_lo=None, f_hi=None, *,
                  amplitude=None, points=96, tol_hz=None):
    """The frequency band where an impacter responds from some initial state.

    Parameters
    ----------
    impacter : model.Impacter
    x0s : array_like, shape (n_x0,), optional
        Initial positions [m] (v0 = 0); default: the designer's grid over [-c, c]
        (33 uniform points, +c just inside the wall, and points near the wall).
    power : float
        Z0^2 w^3 of each tone [m^2/s^3] (ignored with ``amplitude``).
    window : float
        Simulated time t_f - t_0 [s].
    f_lo, f_hi : float, optional
        Scanned range [Hz]; default 0.5 and 2 times the natural frequency.
    amplitude : float, optional
        Fixed tone amplitude Z0 [m] instead of the power convention.
    points : int
        Uniform scan points in [f_lo, f_hi]; both edges are then bisected.
    tol_hz : float, optional
        Edge tolerance [Hz]; default 1e-4 of the natural frequency.

    Returns
    -------
    lo_hz, hi_hz : float
        The lowest and highest frequency in [f_lo, f_hi] at which some x0 gives a
        counted impact (eq. 12, r > 0) [Hz]; (nan, nan) if none.  The band is the
        hull: isolated responding frequencies inside it are included.

    Examples
    --------
    >>> from model import Impacter
    >>> imp = Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6).with_natural_frequency(5200)
    >>> lo, hi = response_band(imp, f_lo=4000, f_hi=9000)       # doctest: +SKIP
    """
    if not isinstance(impacter, Impacter):
        raise ValueError(f"impacter must be a model.Impacter, {type(impacter).__name__} was given")
    tones = _Tones(power, amplitude)
    nu_n = impacter.natural_frequency
    f_lo = 0.5 * nu_n if f_lo is None else float(f_lo)
    f_hi = 2.0 * nu_n if f_hi is None else float(f_hi)
    if not (0 < f_lo < f_hi and math.isfinite(f_hi)):
        raise ValueError(f"need 0 < f_lo < f_hi, got f_lo={f_lo!r}, f_hi={f_hi!r}")
    if int(points) < 2:
        raise ValueError(f"points must be >= 2, {points!r} was given")
    tol = 1e-4 * nu_n if tol_hz is None else float(tol_hz)
    x0s = _default_x0s(impacter) if x0s is None else np.asarray(x0s, dtype=float)
    window = float(window)
    freqs = np.linspace(f_lo, f_hi, int(points))
    hit = _responds(impacter, tones, freqs, x0s, window)
    idx = np.flatnonzero(hit)
    if idx.size == 0:
        return math.nan, math.nan
    i, j = idx[0], idx[-1]
    lo = freqs[i] if i == 0 else _bisect_edge(impacter, tones, x0s, window, freqs[i],
                                              freqs[i - 1], tol)
    hi = freqs[j] if j == freqs.size - 1 else _bisect_edge(impacter, tones, x0s, window,
                                                           freqs[j], freqs[j + 1], tol)
    return float(lo), float(hi)


def response_curves(impacter, frequencies, x0s=None, power=POWER, window=3e-3, *,
                    amplitude=None):
    """min and max over x0 of r (eq. 12) at each frequency, for Fig. 10 [N].

    Parameters
    ----------
    impacter : model.Impacter
    frequencies : array_like, shape (n_freq,)
        [Hz].
    x0s : array_like, shape (n_x0,), optional
        [m]; default the designer's grid over [-c, c].

    Returns
    -------
    r_min, r_max : ndarray, shape (n_freq,)
        [N].
    """
    tones = _Tones(power, amplitude)
    f = np.asarray(frequencies, dtype=float)
    x0s = _default_x0s(impacter) if x0s is None else np.asarray(x0s, dtype=float)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SolverWarning)
        if tones.amplitude is None:
            r = sweep(impacter, f, x0s, tones.power, window)
        else:
            r = np.array([_runs(impacter, tones, fi, x0s, window, False)[0] for fi in f])
    return r.min(axis=1), r.max(axis=1)


# ---------------------------------------------------------------------------------
# the problem


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
                 ensembles=()):
        self.frequency = frequency
        self.forbidden = forbidden
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
        self.lo = np.log([bounds.area[0], bounds.width[0], ratio[0] * frequency,
                          bounds.gap[0]])
        self.hi = np.log([bounds.area[1], bounds.width[1], ratio[1] * frequency,
                          bounds.gap[1]])
        self.evals = {}      # geometry -> _Eval (on the current grids)
        self.runs = {}       # (geometry, f, window, stop, u bytes) -> (r, status)
        self.impacters = {}  # geometry -> model.Impacter (validation costs as much as a run)
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
        l_lo, l_hi = self.bounds.length
        # m = m0 + m1 l (eq. 2) and k = K l^-3 (eq. 4 at fixed w), read off the model
        a = self.factory(area, width, l_lo, 1e-6)  # any gap: m and k do not depend on it
        b = self.factory(area, width, l_hi, 1e-6)
        m1 = (b.mass - a.mass) / (l_hi - l_lo)
        m0 = a.mass - m1 * l_lo
        kk = a.stiffness * l_lo**3
        w2 = (2.0 * math.pi * nu_n) ** 2

        def f(log_l):
            ll = math.exp(log_l)
            return math.log(kk / ll**3) - math.log((m0 + m1 * ll) * w2)

        f_lo, f_hi = f(math.log(l_lo)), f(math.log(l_hi))
        if f_lo <= 0.0:
            return l_lo
        if f_hi >= 0.0:
            return l_hi
        return math.exp(optimize.brentq(f, math.log(l_lo), math.log(l_hi), xtol=1e-13))

    def geometry(self, z):
        """(A, w, l, c) and the z of the projected design."""
        z = np.clip(np.asarray(z, dtype=float), 0.0, 1.0)
        area, width, nu_n, gap = np.exp(self.lo + z * (self.hi - self.lo))
        length = self.length_for(area, width, nu_n)
        imp = self.factory(area, width, length, gap)
        zz = z.copy()
        zz[2] = (math.log(imp.natural_frequency) - self.lo[2]) / (self.hi[2] - self.lo[2])
        return (float(area), float(width), float(length), float(gap)), zz

    def z_of(self, geometry):
        area, width, length, gap = geometry
        nu_n = self.factory(area, width, length, gap).natural_frequency
        v = np.log([area, width, nu_n, gap])
        return (v - self.lo) / (self.hi - self.lo)

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
        if hit is None:
            imp = self.impacter(geometry)
            self._threads_for(u.size)
            # arguments built here (x0 = u c with |u| <= 1, window > 0): no re-validation
            r, status = responses(imp, self.tones.drive(frequency), u * imp.gap,
                                  duration=window, stop_at_first=stop, return_status=True,
                                  check_input=False)
            self.simulations += u.size
            self.faults += int(np.count_nonzero(status))
            hit = self.runs[key] = (r, status)
        return hit

    def target(self, geometry, u, levels, window=None):
        """(u, r) at the target frequency, refined by bisection where r jumps."""
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
            u, r = self.target(geometry, self.u, self.budget.refine_levels)
            i = int(np.argmin(r))
            zero = float(np.mean(r <= 0))
            energy = PENALTY + zero if zero > 0 else -math.log(float(r[i]))
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


# ---------------------------------------------------------------------------------
# search: Sobol seeding, annealing chains, SQP polish


def _reflect(z):
    z = np.mod(z, 2.0)
    return np.where(z > 1.0, 2.0 - z, z)


def _anneal(problem, start, rng, steps, budget, tick):
    """One simulated-annealing chain from ``start`` (an _Eval); returns the chain's best."""
    cur = best = start
    step = budget.step
    accepted = 0
    ratio = budget.t_end / budget.t_start
    for k in range(steps):
        temp = budget.t_start * ratio ** (k / max(steps - 1, 1))
        cand = problem.evaluate(_reflect(cur.z + step * rng.standard_normal(cur.z.size)))
        delta = cand.energy - cur.energy
        if delta <= 0.0 or rng.random() < math.exp(-delta / temp):
            cur = cand
            accepted += 1
            if cur.energy < best.energy:
                best = cur
        if (k + 1) % ADAPT_EVERY == 0:
            rate = accepted / ADAPT_EVERY
            if rate < ACCEPT_TARGET[0]:
                step = max(step / 1.5, 1e-3)
            elif rate > ACCEPT_TARGET[1]:
                step = min(step * 1.5, 0.5)
            accepted = 0
        tick()
    return best


def _polish(problem, start, budget, tick):
    """SLSQP from ``start``; every point it evaluates joins the archive."""
    if budget.sqp_maxiter <= 0 or not start.feasible:
        return

    def energy(z):
        tick()
        return problem.evaluate(z).energy

    def feasible(z):
        return -problem.evaluate(z).violation

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        optimize.minimize(energy, start.z, method="SLSQP", bounds=[(0.0, 1.0)] * start.z.size,
                          constraints=[{"type": "ineq", "fun": feasible}],
                          options={"maxiter": budget.sqp_maxiter, "ftol": 1e-7, "eps": 2e-3})


def _distinct(evals, count, separation=0.1):
    """Up to ``count`` evaluations, best first, at least ``separation`` apart in z."""
    out = []
    for ev in sorted(evals, key=lambda e: e.energy):
        if all(np.max(np.abs(ev.z - o.z)) >= separation for o in out):
            out.append(ev)
        if len(out) == count:
            break
    return out


def _search(problem, rng, budget, tick, starts=None):
    """Annealing chains and the SQP polish.

    The first round seeds its chains with scrambled-Sobol samples; a resumed round
    (``starts``: z of the previous round's archive) re-evaluates those on the grown
    grids and anneals shorter chains from them.
    """
    if starts is None:
        samples = stats.qmc.Sobol(4, scramble=True, seed=rng).random(budget.initial)
        # a share of the samples on the face A = A_max: r grows with m, and the damping
        # b / 2m = mu A / (2 d m) is largest when the plate outweighs the beams, which
        # narrows the response band (air); both favour the largest area
        if budget.area_face > 0:
            k = max(1, round(1.0 / budget.area_face))
            samples[k - 1::k, 0] = 1.0
        pool = [problem.evaluate(z) for z in samples]
        steps = budget.anneal_steps
    else:
        pool = [problem.evaluate(z) for z in starts]
        steps = budget.resume_steps
    for _ in pool:
        tick()
    for s in _distinct(pool, budget.chains):
        _anneal(problem, s, rng, steps, budget, tick)
    if problem.archive:
        _polish(problem, problem.archive[0], budget, tick)


# ---------------------------------------------------------------------------------
# re-check and report


def _recheck(problem, geometry):
    """Fine-grid and long-window checks of one design against every forbidden frequency.

    On the fine grid: r_min at the target (refined where it jumps), r_max at every
    forbidden frequency and silence across its guard band; over the long window:
    silence at every forbidden frequency.  Returns a dict with the u where a check
    failed (for the exchange step) and the check indices violated.
    """
    b = problem.budget
    u_fine = _u_grid(b.verify_x0_points)
    u, r = problem.target(geometry, u_fine, b.verify_refine_levels)
    i = int(np.argmin(r))
    r_max = []
    for f in problem.forbidden:
        rf = problem.runs_of(geometry, f, u_fine, problem.window, False)[0]
        r_max.append(float(np.max(rf)))
    bad_forbid, violated = [], []
    for j, f in enumerate(problem.check_hz):
        rf = problem.runs_of(geometry, f, u_fine, problem.window, True)[0]
        if np.any(rf > 0):
            bad_forbid.append(u_fine[rf > 0])
            violated.append(j)
    long_window = LONG_WINDOW_FACTOR * problem.window
    bad_long, long_hz = [], None
    for j, f in enumerate(problem.check_hz):
        if problem.check_hz[j] not in problem.forbidden and not isinstance(f, Ensemble):
            continue   # the long window is checked at the forbidden frequencies themselves
        rl = problem.runs_of(geometry, f, u_fine, long_window, True)[0]
        if np.any(rl > 0):
            bad_long.append(u_fine[rl > 0])
            violated.append(j)
            long_hz = float(f) if long_hz is None else long_hz
    fine_ok = not bad_forbid and float(r[i]) > 0
    return {"r_min": float(r[i]), "worst_u": float(u[i]), "r_max": r_max,
            "fine_ok": fine_ok, "long_ok": not bad_long, "points": int(u.size),
            "long_violated_hz": long_hz, "violated": sorted(set(violated)),
            "bad_target": u[r <= 0],
            "bad_forbid": np.concatenate(bad_forbid) if bad_forbid else np.zeros(0),
            "bad_long": np.concatenate(bad_long) if bad_long else np.zeros(0)}


def _sparse(u, count=8):
    """At most ``count`` of the sorted points u, spread over their range."""
    u = np.unique(u)
    if u.size <= count:
        return u
    return u[np.linspace(0, u.size - 1, count).round().astype(int)]


def _band_and_margins(impacter, tones, frequency, forbidden, x0s, window, budget):
    """The response band around the target and each forbidden frequency's margin.

    One scan serves both, so they agree: ``8 margin_points`` frequencies over 0.5x the
    lowest to 1.5x the highest of the target, nu_n and the forbidden frequencies,
    plus ``margin_points`` on each side of every nu_j out to |nu - nu_j| (the target
    responds, so no margin is larger).  The band's edges and, for each nu_j, the
    nearest responding scan frequency (on either side; both when within a scan step
    of each other) are then bisected to ``margin_tol`` times the frequency.

    Returns
    -------
    band : (float, float)
        Lowest and highest responding frequency of the scan range [Hz] (nan if none).
    margins : list of float
        [Hz]; 0 where the design responds at nu_j itself.
    """
    points = budget.margin_points
    span = [frequency, impacter.natural_frequency] + list(forbidden)
    grids = [np.linspace(0.5 * min(span), 1.5 * max(span), 8 * points), [frequency],
             list(forbidden)]
    for f in forbidden:
        k = np.arange(1, points + 1) * (abs(frequency - f) / points)
        grids += [f + k, f - k]
    scan = np.unique(np.concatenate([np.asarray(g, dtype=float) for g in grids]))
    scan = scan[scan > 0]
    hit = _responds(impacter, tones, scan, x0s, window)

    def edge(i, toward):
        """Bisect between responding scan[i] and its neighbour in direction ``toward``."""
        j = i + toward
        if j < 0 or j >= scan.size:
            return float(scan[i])
        return _bisect_edge(impacter, tones, x0s, window, scan[i], scan[j],
                            budget.margin_tol * scan[i])

    idx = np.flatnonzero(hit)
    if idx.size == 0:
        return (math.nan, math.nan), [abs(frequency - f) for f in forbidden]
    band = (edge(idx[0], -1), edge(idx[-1], +1))
    margins = []
    for f in forbidden:
        i0 = int(np.searchsorted(scan, f))          # scan[i0] == f
        if hit[i0]:
            margins.append(0.0)
            continue
        below, above = idx[idx < i0], idx[idx > i0]
        cands = []
        if below.size:
            cands.append((f - scan[below[-1]], below[-1], +1))
        if above.size:
            cands.append((scan[above[0]] - f, above[0], -1))
        nearest = min(c[0] for c in cands)
        best = abs(frequency - f)
        for dist, i, toward in cands:
            # the edge lies between scan[i] and its neighbour towards nu_j
            if dist - abs(scan[i] - scan[i + toward]) <= nearest:
                best = min(best, abs(edge(i, toward) - f))
        margins.append(float(best))
    return band, margins


def _search_and_recheck(problem, rng, budget, tick, history):
    """Search; re-check the archive on a finer grid and a longer window; where every
    archived design fails, add the failing x0 (and any forbidden frequency the search
    skipped) to the optimiser's problem and resume (exchange method).

    Appends (evaluation, re-check) of every re-checked design to ``history`` and stops
    at the first that passes both checks.  Returns the number of rounds run.
    """
    starts = None
    for round_ in range(budget.rounds):
        _search(problem, rng, budget, tick, starts)
        if starts is None:
            # no feasible design on the optimiser's grid: the feasible region may be
            # small (a narrow band of (nu_n, c)); search again with more samples
            for k in range(budget.escalations):
                if problem.archive:
                    break
                grown = replace(budget, initial=budget.initial * 4 ** (k + 1),
                                anneal_steps=budget.anneal_steps * 2 ** (k + 1))
                _search(problem, rng, grown, tick)
        checked = []
        for ev in problem.archive:          # best first; the first that passes wins
            chk = _recheck(problem, ev.geometry)
            checked.append((ev, chk))
            if chk["fine_ok"] and chk["long_ok"]:
                break
        history += checked
        if not checked or (checked[-1][1]["fine_ok"] and checked[-1][1]["long_ok"]):
            break
        for _, c in checked:
            for j in c["violated"]:
                if j not in problem.active:
                    problem.active.append(j)
        starts = [ev.z for ev, _ in checked]
        problem.add_points(
            u_target=np.concatenate([_sparse(c["bad_target"]) for _, c in checked]),
            u_forbid=np.concatenate([_sparse(c["bad_forbid"]) for _, c in checked]),
            u_long=np.concatenate([_sparse(c["bad_long"]) for _, c in checked]))
    return round_ + 1


def _impacter_factory(process, environment, impact_angle, restitution):
    """(A, w, l, c) [SI] -> model.Impacter by eqs. (2)-(4), with the process constants."""
    kwargs = dict(
        thickness=process.mass_thickness_um * UM, beam_height=process.beam_height_um * UM,
        density=process.density_kg_m3, youngs_modulus=process.youngs_modulus_gpa * 1e9,
        viscosity=environment.viscosity_mpa_s * 1e-3,
        substrate_gap=process.substrate_gap_um * UM,
        beam_angle=math.radians(process.beam_angle_deg),
        impact_angle=impact_angle, restitution=restitution)

    def factory(area, width, length, gap):
        return Impacter.from_geometry(area, width, length, gap, **kwargs)

    return factory


def _progress_hook(progress):
    """callable(fraction in [0, 1]) from a callable, a tqdm bar or None."""
    if progress is None:
        return lambda fraction: None
    if callable(progress) and not hasattr(progress, "update"):
        return progress

    def bar(fraction):
        target = int(round(min(1.0, max(0.0, fraction)) * (progress.total or 1)))
        if target > progress.n:
            progress.update(target - progress.n)   # tqdm throttles the redraws

    return bar


def design_impacter(frequency, forbidden=(), *, process=None, environment=None, power=POWER,
                    amplitude=None, bounds=None, window=3e-3, seed=0, budget="full",
                    slider=None, progress=None, x0_points=None, guard=GUARD,
                    impact_angle=_d.IMPACT_ANGLE, restitution=_d.RESTITUTION,
                    forbidden_drives=()):
    """Design one impacter by the paper's max-min problem, eqs. (13)-(18).

    Maximise the worst response over initial positions at ``frequency`` subject to
    no response at any forbidden frequency from any initial position, over the
    geometry p = (A, w, l, c) within ``bounds``: Sobol seeding and simulated
    annealing for the global search, SLSQP for the local polish (as in the paper),
    then re-checks on a finer x0 grid and a 10x longer window.  See the module
    docstring for the search coordinates, the constraint handling and the caching.

    Parameters
    ----------
    frequency : float
        Target drive frequency nu [Hz].
    forbidden : sequence of float
        Frequencies nu_j at which the design must not respond [Hz] (the paper has one;
        an array has many).
    process : planner.config.ProcessConfig, optional
        Process constants; default the paper's (Table I, Section III-B).
    environment : planner.config.EnvironmentConfig, optional
        Viscosity mu; default vacuum (10 mTorr, mu = 0).
    power : float
        Drive convention Z0^2 w^3 of every tone [m^2/s^3]; 50 in the paper.
    amplitude : float, optional
        A fixed tone amplitude Z0 [m] instead of the power convention.
    bounds : DesignBounds, optional
        Bounds of p; default the paper's lower bounds (17) and the documented upper
        bounds of :class:`DesignBounds`.
    window : float
        t_f - t_0 of eq. (12) [s]; the paper's 3 ms.
    seed : int, numpy Generator or None
        Same seed, same design.
    budget : {"full", "fast"} or Budget
        Search effort, see :data:`BUDGETS`.
    slider : model.Slider, optional
        For the predicted slider speed; default an 8e4 um^2 Poly1 slider (Table I
        friction, the environment's viscosity).
    progress : callable(fraction) or tqdm bar, optional
        Called as the search advances.
    x0_points : int, optional
        Overrides the budget's optimiser x0 grid (odd).
    guard : float
        Relative half-width of the band around each forbidden frequency in which the
        design must also be silent [-]: (14) is checked at nu_j (1 + guard k), k in
        [-1, 1] (``Budget.guard_points`` values).  0 is the paper's (14) exactly.
    impact_angle : float
        theta [rad].
    restitution : float
        e [-].
    forbidden_drives : sequence of model.Drive or Ensemble
        Multi-tone drives (the summed drives of the steps in which the impacter must be
        idle) under which the design must also be silent, from every x0, over the
        window and the long re-check window; checked before the single tones.

    Returns
    -------
    DesignResult

    Notes
    -----
    (13) max_p min_{x0 in D} r(x0, p, nu);  (14) s.t. max_{x0 in D} r(x0, p, nu_j) = 0;
    (17) A >= 20 um^2, w >= 2 um, l >= 8 um, c >= 2 um;  (18) D = {-c <= x(t0) <= c,
    v(t0) = 0}.  r is eq. (12) with k, m, b from eqs. (2)-(4) as printed.

    In vacuum (mu = 0, the default environment) the problem is usually infeasible: an
    undamped impacter released from x0 = -c swings back to +c by itself, and the drive
    brings it to the wall again within the window at almost any frequency.  The result
    then has ``status == "infeasible"`` and a message saying where it responds; the
    paper's optimisation example (Table II) is in air.

    Examples
    --------
    >>> res = design_impacter(6000.0, (3000.0,), budget="fast")   # doctest: +SKIP
    >>> res.to_dict()["geometry"]                                 # doctest: +SKIP
    {'area_m2': ..., 'width_m': ..., 'length_m': ..., 'gap_m': ...}
    """
    from planner.config import EnvironmentConfig, ProcessConfig, SliderConfig, build_slider

    t_start = time.perf_counter()
    frequency = float(frequency)
    if not (math.isfinite(frequency) and frequency > 0):
        raise ValueError(f"frequency must be finite and > 0, {frequency!r} was given")
    forbidden = tuple(sorted(float(f) for f in forbidden))
    for f in forbidden:
        if not (math.isfinite(f) and f > 0):
            raise ValueError(f"forbidden frequencies must be finite and > 0, {f!r} was given")
        if f == frequency:
            raise ValueError(f"forbidden frequency {f!r} equals the target frequency")
    window = float(window)
    if not (math.isfinite(window) and window > 0):
        raise ValueError(f"window must be finite and > 0, {window!r} was given")
    process = ProcessConfig() if process is None else process
    environment = EnvironmentConfig() if environment is None else environment
    if not isinstance(process, ProcessConfig):
        raise ValueError(f"process must be a ProcessConfig, {type(process).__name__} was given")
    if not isinstance(environment, EnvironmentConfig):
        raise ValueError("environment must be an EnvironmentConfig, "
                         f"{type(environment).__name__} was given")
    bounds = DesignBounds() if bounds is None else bounds
    if not isinstance(bounds, DesignBounds):
        raise ValueError(f"bounds must be a DesignBounds, {type(bounds).__name__} was given")
    if slider is None:
        slider = build_slider(SliderConfig(), process, environment)
    elif isinstance(slider, SliderConfig):
        slider = build_slider(slider, process, environment)
    if not isinstance(slider, Slider):
        raise ValueError(f"slider must be a model.Slider or SliderConfig, {type(slider).__name__} "
                         "was given")
    budget_name = budget if isinstance(budget, str) else "custom"
    budget = _as_budget(budget, x0_points)
    tones = _Tones(power, amplitude)
    rng = _as_rng(seed)
    factory = _impacter_factory(process, environment, float(impact_angle), float(restitution))
    guard = float(guard)
    if not (math.isfinite(guard) and 0.0 <= guard < 0.5):
        raise ValueError(f"guard must be in [0, 0.5), {guard!r} was given")
    for f in forbidden:
        if f * (1.0 - guard) <= frequency <= f * (1.0 + guard):
            raise ValueError(f"the target {frequency:g} Hz lies in the guard band of the "
                             f"forbidden frequency {f:g} Hz (guard {guard:g})")
    ensembles = tuple(e if isinstance(e, Ensemble) else Ensemble(e, f"drive {i}")
                      for i, e in enumerate(forbidden_drives))
    problem = _Problem(frequency, forbidden, factory, tones, bounds, window, budget, guard,
                       ensembles)

    report = _progress_hook(progress)
    expected = (budget.initial + budget.chains * budget.anneal_steps
                + 12 * budget.sqp_maxiter + 10)
    count = [0]

    def tick():
        count[0] += 1
        if count[0] % 8 == 0:
            report(min(0.97, count[0] / expected))

    history = []          # (evaluation, re-check) of every archived design re-checked
    with problem.kernel_scope():
        rounds = _search_and_recheck(problem, rng, budget, tick, history)
    # the first re-checked design that passes both checks (the search stops there)
    chosen = next(((ev, c) for ev, c in history if c["fine_ok"] and c["long_ok"]), None)
    rejected = sum(1 for _, c in history if not c["fine_ok"])
    rejected_long = sum(1 for _, c in history if c["fine_ok"] and not c["long_ok"])
    status = "ok"
    if chosen is None:
        fine = [(ev, c) for ev, c in history if c["fine_ok"]]
        if fine:      # passes the fine grid but responds within the long window
            chosen = max(fine, key=lambda p: p[1]["r_min"])
        elif history:
            chosen = history[0]
            status = "infeasible"
        else:
            ev = problem.best_any
            with problem.kernel_scope():
                chosen = (ev, _recheck(problem, ev.geometry))
            status = "infeasible"
    ev, chk = chosen
    imp = factory(*ev.geometry)
    feasible = bool(chk["fine_ok"])
    if status == "ok" and not feasible:
        status = "infeasible"

    # report: band, margins and slider speed (the only slider simulation)
    nu_n = imp.natural_frequency
    band, margins = _band_and_margins(imp, tones, frequency, forbidden,
                                      _u_grid(budget.forbidden_x0_points) * imp.gap, window, budget)
    worst_x0 = chk["worst_u"] * imp.gap
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SolverWarning)
        speed = simulate_slider(imp, slider, tones.drive(frequency), min(worst_x0, imp.gap),
                                duration=window).mean_velocity
    checks = {
        "optimizer_x0_points": int(problem.u.size),
        "optimizer_forbidden_x0_points": int(problem.u_forbid.size),
        "optimizer_long_window_x0_points": int(problem.u_long.size),
        "forbidden_checked_during_search": len(problem.active),
        "recheck_x0_points": int(chk["points"]),
        "long_window_s": LONG_WINDOW_FACTOR * window,
        "fine_grid_passed": bool(chk["fine_ok"]),
        "long_window_passed": bool(chk["long_ok"]),
        "coarse_only_designs": int(rejected),
        "short_window_only_designs": int(rejected_long),
        "rounds": int(rounds),
        "solver_faults": int(problem.faults),
        # the forbidden drives (Ensemble labels) the returned design responds under, on
        # the re-check grid or its long window: what an array planner must move away
        "violated_drives": sorted({problem.check_hz[j].label for j in chk["violated"]
                                   if isinstance(problem.check_hz[j], Ensemble)}),
    }
    if status == "ok":
        message = (f"feasible: r_min = {chk['r_min']:.4g} N at x0 = {worst_x0 / UM:.4g} um; "
                   f"silent at {len(forbidden)} forbidden frequencies on {chk['points']} x0")
        if not chk["long_ok"]:
            message += (f"; responds at {chk['long_violated_hz']:g} Hz within the "
                        f"{LONG_WINDOW_FACTOR * window * 1e3:g} ms re-check window")
    else:
        bad = [f"{f:g} Hz (r_max {r:.3g} N)" for f, r in zip(forbidden, chk["r_max"]) if r > 0]
        bad += [f"the summed drive {label!r}" for label in checks["violated_drives"]]
        message = ("no design met the constraints within the bounds and budget; the least "
                   "violating design is returned: "
                   + (f"responds at {', '.join(bad)}" if bad else "")
                   + ("" if chk["r_min"] > 0 else
                      (", and " if bad else "")
                      + f"does not respond at {frequency:g} Hz from every x0"))
    report(1.0)
    return DesignResult(
        impacter=imp, frequency_hz=frequency, forbidden_hz=forbidden,
        natural_frequency_hz=nu_n, mass_kg=imp.mass, stiffness_n_per_m=imp.stiffness,
        damping_ns_per_m=imp.damping, gap_m=imp.gap, impact_angle_rad=imp.impact_angle,
        restitution=imp.restitution, geometry=imp.geometry, worst_x0_m=worst_x0,
        r_min_n=chk["r_min"], r_max_forbidden_n=tuple(chk["r_max"]), margins_hz=tuple(margins),
        predicted_slider_speed_m_s=float(speed), feasible=feasible,
        evaluations=problem.evaluations, seconds=time.perf_counter() - t_start,
        simulations=problem.simulations, checks=checks, response_band_hz=band, status=status,
        message=message, seed=seed if isinstance(seed, numbers.Integral) else None,
        budget=budget_name, window_s=window)


def design_pair(forward_hz, backward_hz, *, seed=0, progress=None, **kw):
    """Design the forward and backward impacters of one device (Table II).

    The forward impacter targets ``forward_hz`` with ``backward_hz`` forbidden, and
    vice versa; each gets its own seed spawned from ``seed``.  Other keywords go to
    :func:`design_impacter`.

    Returns
    -------
    PairDesign
        ``.forward``, ``.backward`` (:class:`DesignResult`) and ``.seconds``.

    Examples
    --------
    >>> pair = design_pair(6000.0, 3000.0)            # doctest: +SKIP
    >>> sorted(pair.to_dict())                        # doctest: +SKIP
    ['backward', 'forward']
    """
    t0 = time.perf_counter()
    forward_hz, backward_hz = float(forward_hz), float(backward_hz)
    if forward_hz == backward_hz:
        raise ValueError(f"forward and backward frequencies must differ, both are {forward_hz!r}")
    if isinstance(seed, np.random.Generator):
        seeds = seed.spawn(2)
    else:
        base = 0 if seed is None else seed
        if isinstance(base, bool) or not isinstance(base, numbers.Integral):
            raise ValueError(f"seed must be an int, a numpy Generator or None, {seed!r} was given")
        seeds = [int(s.generate_state(1)[0]) for s in np.random.SeedSequence(int(base)).spawn(2)]
    report = _progress_hook(progress)
    fwd = design_impacter(forward_hz, (backward_hz,), seed=seeds[0],
                          progress=lambda f: report(0.5 * f), **kw)
    bwd = design_impacter(backward_hz, (forward_hz,), seed=seeds[1],
                          progress=lambda f: report(0.5 + 0.5 * f), **kw)
    if isinstance(seed, numbers.Integral):
        fwd = replace(fwd, seed=int(seed))
        bwd = replace(bwd, seed=int(seed))
    return PairDesign(fwd, bwd, time.perf_counter() - t0)
