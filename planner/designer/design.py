"""The designer's public face: :func:`design_impacter` and :func:`design_pair`."""

from __future__ import annotations

import math
import numbers
import time
import warnings
from dataclasses import dataclass, replace

import numpy as np

from model import CONTACTS, Impacter, Slider, SolverWarning, simulate_slider
from model import devices as _d
from model.drive import POWER
from planner.core.rng import as_generator as _as_rng  # the one seed rule
from planner.designer.bounds import UM, DesignBounds
from planner.designer.budget import _as_budget
from planner.designer.problem import LONG_WINDOW_FACTOR, _Problem
from planner.designer.response import _band_and_margins
from planner.designer.result import DesignResult, PairDesign
from planner.designer.runs import Ensemble, _Tones, _u_grid
from planner.designer.search import _recheck, _search_and_recheck
from planner.core.separation import check_target

#: Default guard: silent within +-2% of each forbidden frequency, not just at it.  With
#: guard = 0 the optimiser parks forbidden frequencies in holes of a responding region
#: (found: a design silent at 6000 Hz that responds at 6000.5 Hz) [-].
GUARD = 0.02




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
                    forbidden_drives=(), max_mass_ratio=None, contact="paper",
                    robust_shift=None, target_drives=(), sensitivity=None,
                    speed_window=None, speed_x0_points=None, min_speed=None,
                    tone_window=0.0, direction=1.0, family=()):
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
    max_mass_ratio : float, optional
        Upper bound on m / M, the impacter's mass over the slider's [-] (None: no
        bound, the paper's problem).  Eq. (10) is the small-m/M limit of an impact.
    contact : {"paper", "two_body"}
        The contact law the slider is kicked by (:data:`model.CONTACTS`).  Under
        ``"two_body"`` a kick gives the slider 1 / (1 + q) of eq. (10)'s momentum,
        q = 2 (m/M) cos^2(theta), so the objective is r / (1 + q): a heavier impacter
        hits harder but pushes a lighter slider less than r alone says, and the
        designs no longer pile up at the area bound.  The predicted slider speed is
        simulated under this law too.
    robust_shift : float or callable, optional
        Robust design against fabrication: a relative shift s [-] in [0, 0.5), or a
        callable ``(area, width, length, gap) -> s`` for a shift that depends on the
        candidate's own geometry (the array planner passes k sigma of the natural
        frequency under the spec's ``fabrication`` tolerances, ``design.robust_k`` = k:
        :class:`planner.fabrication.tolerances.RobustShift`).  The design must meet the target and
        stay silent with its natural frequency scaled by 1 - s, 1 and 1 + s; it costs
        about three times the simulations.  None or 0: the nominal problem only.
    target_drives : sequence of model.Drive or Ensemble
        Multi-tone drives (the summed drives of the steps in which the impacter must
        move its slider together with others) under which it must respond too: the
        worst response counted by the objective is the least over its own tone and
        these, from every x0.  An off-resonant sum can hold an impacter off its wall
        from some initial states where its own tone alone would not.
    sensitivity : (float, float), optional
        Band (lo, hi) of the line-width sensitivity S = d ln nu_n / d(line width)
        [1/m] the design must lie in (:mod:`planner.designer.sensitivity`): the array
        planner's ``design.match_sensitivity``, so that a die-level line-width error
        moves every impacter of an array by one factor.  The search then solves the
        beam width (the area, when ``bounds.width`` fixes the width) for a target in
        the band instead of searching it.  None: no constraint.
    speed_window : float, optional
        Time over which the predicted slider speed is simulated [s] (default
        ``window``): an array plan passes its single-impacter step's length, over which
        its verification measures the speed.
    speed_x0_points : int, optional
        The predicted speed is the least from these many x0 over [-c, c] as well as the
        search's worst x0 (an array plan passes its verification's grid): a design can
        lock into an orbit that stops kicking after the design window from an x0 the
        window did not show as the worst.
    min_speed : float, optional
        The slowest predicted slider speed a design may have [m/s] (an array plan's
        ``verification.min_speed_mm_s``): a design predicted slower is infeasible, with
        the shortfall in ``shortfalls``.  None: no floor (the paper's problem).
    direction : float
        +1 for a forward pair, -1 for a backward one: the sense its kicks push the
        slider in, for the predicted speed (the substrate's vibration drives the slider
        too, and a kick adds to it in one half of the drive's cycle and opposes it in
        the other: the same design moves its slider at different speeds forward and
        backward).
    tone_window : float
        Relative half-width w of the design's tone window [-] (an array plan's
        ``design.tone_window_pct``): the design must respond from every x0 at
        ``frequency`` (1 - w) and (1 + w) too, and the objective's worst response is
        taken over the tone and both edges -- the paper's max-min over x0 extended over
        the tone, so that a tone moved by a measurement's error still drives it.  0:
        the tone alone (the paper's problem).

    family : sequence of ((A, w, l, c), frequency), optional
        Designs of the same spec at other tones [m, Hz]: each, scaled to ``frequency``
        (the same A, width or line-width sensitivity, nu_n / tone and gap over its
        linear amplitude at its tone), joins the first round's Sobol samples as a
        start of the annealing chains.  With matched sensitivities the designs of a spec
        are close to one family scaled in frequency, so a good neighbour is a good start;
        the search still explores as without it.

    Returns
    -------
    DesignResult
        ``feasible`` only if the design meets every constraint by its own prediction:
        it responds at ``frequency`` from every x0, is silent at every forbidden
        frequency and drive on the re-check grid and over the long re-check window, is
        predicted at least ``min_speed``, and lies within ``max_mass_ratio``, ``bounds``
        and ``sensitivity``; every miss is in ``shortfalls``, by how much.

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
    t_start = time.perf_counter()
    a = _checked_inputs(frequency, forbidden, process, environment, bounds, window, slider,
                        budget, x0_points, power, amplitude, seed, guard, impact_angle,
                        restitution, forbidden_drives, target_drives, contact,
                        max_mass_ratio, robust_shift, sensitivity, min_speed, tone_window)
    problem = _Problem(a.frequency, a.forbidden, a.factory, a.tones, a.bounds, a.window,
                       a.budget, a.guard, a.ensembles, mass_cap=a.mass_cap,
                       q_per_kg=a.q_per_kg, robust_shift=a.robust_shift,
                       target_ensembles=a.targets, sensitivity=a.sensitivity,
                       tone_window=a.tone_window)
    report = _progress_hook(progress)
    starts = [problem.z_of(g, f) for g, f in family]
    ev, chk, status, history, rounds = _search(problem, a.rng, a.budget, report, starts)
    return _result(a, problem, ev, chk, status, history, rounds, report, slider=a.slider,
                   speed_window=speed_window, speed_x0_points=speed_x0_points,
                   seed=seed, t_start=t_start, direction=direction)


@dataclass(frozen=True)
class _Inputs:
    """:func:`design_impacter`'s arguments, checked and converted (SI units)."""

    frequency: float
    forbidden: tuple
    window: float
    bounds: DesignBounds
    slider: Slider
    budget: object                 # planner.designer.budget.Budget
    budget_name: str
    tones: _Tones
    rng: np.random.Generator
    factory: object                # (A, w, l, c) -> model.Impacter
    guard: float
    ensembles: tuple
    targets: tuple
    contact: str
    mass_cap: float
    q_per_kg: float
    robust_shift: object           # callable or None
    sensitivity: tuple | None
    max_mass_ratio: float | None
    min_speed: float | None
    tone_window: float = 0.0


def _checked_inputs(frequency, forbidden, process, environment, bounds, window, slider,
                    budget, x0_points, power, amplitude, seed, guard, impact_angle,
                    restitution, forbidden_drives, target_drives, contact, max_mass_ratio,
                    robust_shift, sensitivity, min_speed=None, tone_window=0.0):
    """:class:`_Inputs` from :func:`design_impacter`'s arguments; ValueError naming the
    first bad one."""
    from planner.config import EnvironmentConfig, ProcessConfig, SliderConfig, build_slider

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
    # the same rule the assigner separates tones by (planner.core.separation)
    check_target(frequency, forbidden, guard)
    ensembles = tuple(e if isinstance(e, Ensemble) else Ensemble(e, f"drive {i}")
                      for i, e in enumerate(forbidden_drives))
    targets = tuple(e if isinstance(e, Ensemble) else Ensemble(e, f"target drive {i}")
                    for i, e in enumerate(target_drives))
    if contact not in CONTACTS:
        raise ValueError(f"contact must be one of {sorted(CONTACTS)}, {contact!r} was given")
    if max_mass_ratio is None:
        mass_cap = math.inf
    else:
        max_mass_ratio = float(max_mass_ratio)
        if not (math.isfinite(max_mass_ratio) and max_mass_ratio > 0):
            raise ValueError(f"max_mass_ratio must be finite and > 0, {max_mass_ratio!r} "
                             "was given")
        mass_cap = max_mass_ratio * slider.mass
    q_per_kg = (2.0 * math.cos(float(impact_angle)) ** 2 / slider.mass
                if contact == "two_body" else 0.0)
    if robust_shift is not None and not callable(robust_shift):
        shift = float(robust_shift)
        if not (math.isfinite(shift) and 0.0 <= shift < 0.5):
            raise ValueError(f"robust_shift must be in [0, 0.5), {robust_shift!r} was given")
        robust_shift = None if shift == 0.0 else (lambda geometry, s=shift: s)
    if sensitivity is not None:
        try:
            s_lo, s_hi = (float(v) for v in sensitivity)
        except (TypeError, ValueError):
            raise ValueError(f"sensitivity must be a (lo, hi) pair [1/m], {sensitivity!r} "
                             "was given") from None
        if not (math.isfinite(s_lo) and math.isfinite(s_hi) and 0.0 < s_lo <= s_hi):
            raise ValueError(f"sensitivity must satisfy 0 < lo <= hi (finite) [1/m], "
                             f"{sensitivity!r} was given")
        sensitivity = (s_lo, s_hi)
    if min_speed is not None:
        min_speed = float(min_speed)
        if not (math.isfinite(min_speed) and min_speed >= 0.0):
            raise ValueError(f"min_speed must be finite and >= 0 [m/s], {min_speed!r} was given")
    tone_window = float(tone_window)
    if not (math.isfinite(tone_window) and 0.0 <= tone_window < 0.1):
        raise ValueError(f"tone_window must be in [0, 0.1) [-], {tone_window!r} was given")
    for f in forbidden:
        # a forbidden tone inside the window would be one the design must answer
        if tone_window and abs(math.log(f / frequency)) <= tone_window:
            raise ValueError(f"the forbidden frequency {f:g} Hz lies inside the tone window "
                             f"of the target {frequency:g} Hz (tone_window {tone_window:g})")
    return _Inputs(frequency=frequency, forbidden=forbidden, window=window, bounds=bounds,
                   slider=slider, budget=budget, budget_name=budget_name, tones=tones, rng=rng,
                   factory=factory, guard=guard, ensembles=ensembles, targets=targets,
                   contact=contact, mass_cap=mass_cap, q_per_kg=q_per_kg,
                   robust_shift=robust_shift, sensitivity=sensitivity,
                   max_mass_ratio=max_mass_ratio, min_speed=min_speed,
                   tone_window=tone_window)


def _search(problem, rng, budget, report, family=()):
    """Search and re-check; returns (evaluation, re-check, status, history, rounds) of
    the design chosen: the first re-checked design that passes both checks, else the
    best on the fine grid, else the least violating ("infeasible")."""
    expected = (budget.initial + budget.chains * budget.anneal_steps
                + 12 * budget.sqp_maxiter + 10)
    count = [0]

    def tick():
        count[0] += 1
        if count[0] % 8 == 0:
            report(min(0.97, count[0] / expected))

    history = []          # (evaluation, re-check) of every archived design re-checked
    with problem.kernel_scope():
        rounds = _search_and_recheck(problem, rng, budget, tick, history, family)
    # the first re-checked design that passes both checks (the search stops there)
    chosen = next(((ev, c) for ev, c in history if c["fine_ok"] and c["long_ok"]), None)
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
    if status == "ok" and not chk["fine_ok"]:
        status = "infeasible"
    return ev, chk, status, history, rounds


def _result(a, problem, ev, chk, status, history, rounds, report, *, slider, speed_window,
            speed_x0_points, seed, t_start, direction=1.0):
    """The :class:`DesignResult` of the chosen design: band, margins, predicted slider
    speed (the only slider simulation), the checks and the message."""
    frequency, forbidden, window, budget, tones = (a.frequency, a.forbidden, a.window,
                                                   a.budget, a.tones)
    contact = a.contact
    imp = a.factory(*ev.geometry)
    # report: band, margins and slider speed (the only slider simulation)
    nu_n = imp.natural_frequency
    band, margins = _band_and_margins(imp, tones, frequency, forbidden,
                                      _u_grid(budget.forbidden_x0_points) * imp.gap, window, budget)
    worst_x0 = chk["worst_u"] * imp.gap
    starts = [min(worst_x0, imp.gap)]
    if speed_x0_points:
        starts += list(np.linspace(-imp.gap, imp.gap, int(speed_x0_points)))
    # the speed at the tone (the design's own prediction, its floor) and at its window's
    # edges (a tone re-planned from a measurement sits anywhere in the window, and a
    # slider's speed falls faster than the response towards the lower edge: friction
    # takes a fixed part of each kick); an array plan retries designs slow there
    edges = problem.window_tones
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SolverWarning)
        sign = 1.0 if direction >= 0 else -1.0
        speeds = [min(sign * simulate_slider(imp, slider, tones.drive(f), x0,
                                             duration=speed_window or window,
                                             contact=contact, direction=sign).mean_velocity
                      for x0 in starts)
                  for f in (frequency, *edges)]
    speed = speeds[0]
    checks = _checks(a, problem, ev, chk, history, rounds)
    if edges:
        checks["speed_at_tone_m_s"] = float(speeds[0])
        checks["speed_at_window_edges_m_s"] = [float(v) for v in speeds[1:]]
    short = shortfalls(a, chk, imp, float(speed), slider, checks)
    feasible = not short
    if not feasible:
        status = "infeasible"
    message = _message(a, chk, status, worst_x0, checks["violated_drives"], short)
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
        budget=a.budget_name, window_s=window, mass_ratio=imp.mass / slider.mass, contact=contact,
        shortfalls=short, tone_window=a.tone_window)


#: Relative slack of the bound checks of :func:`shortfalls`: the search clips to the
#: bounds and solves the beams to ~1e-12, so a design on a bound is inside [-].
BOUND_SLACK = 1e-9


def _shortfall(constraint, value, limit, unit, text):
    return {"constraint": constraint, "value": float(value), "limit": float(limit),
            "unit": unit, "text": text}


def shortfalls(a, chk, imp, speed, slider, checks):
    """Every constraint the chosen design misses by its own prediction, by how much.

    Returns
    -------
    tuple of dict
        ``{"constraint", "value", "limit", "unit", "text"}`` each; ``constraint`` is
        ``response`` (x0 of the re-check grid it does not respond from, out of all),
        ``silence`` (forbidden frequencies and drives it answers on the re-check grid),
        ``silence_long`` (the first frequency it answers within the long window),
        ``speed_floor``, ``mass_ratio``, ``bounds`` or ``sensitivity``.  Empty: feasible.
    """
    out = []
    frequency = a.frequency
    if not chk["r_min"] > 0:
        bad = int(np.asarray(chk["bad_target"]).size)
        under = checks.get("unanswered_target_drives") or []
        out.append(_shortfall("response", bad, 0, "x0",
                              f"does not respond at {frequency:g} Hz from {bad} of "
                              f"{chk['points']} x0 of the re-check grid"
                              + (" (under the summed drive " + ", ".join(map(repr, under))
                                 + " it plays in)" if under else "")))
    at = [f for f, r in zip(a.forbidden, chk["r_max"]) if r > 0]
    near = [f for f in checks.get("violated_tones_hz", ()) if f not in at]
    loud = [f"{f:g} Hz" for f in at]
    loud += [f"inside the guard band of {f:g} Hz" for f in near]
    loud += [f"the summed drive {label!r}" for label in checks["violated_drives"]]
    if loud or np.asarray(chk["bad_forbid"]).size:
        out.append(_shortfall("silence", len(loud), 0, "frequencies",
                              "responds " + (", ".join(loud) if loud else
                                             "inside the guard band of a forbidden frequency")))
    if chk["fine_ok"] and not chk["long_ok"]:
        out.append(_shortfall("silence_long", chk["long_violated_hz"] or math.nan, 0, "Hz",
                              f"responds at {chk['long_violated_hz']:g} Hz within the "
                              f"{LONG_WINDOW_FACTOR * a.window * 1e3:g} ms re-check window"))
    if a.min_speed is not None and not speed >= a.min_speed:
        out.append(_shortfall("speed_floor", speed, a.min_speed, "m/s",
                              f"its predicted slider speed {speed * 1e3:.3g} mm/s is below "
                              f"the floor {a.min_speed * 1e3:g} mm/s (by "
                              f"{(a.min_speed - speed) * 1e3:.3g} mm/s)"))
    ratio = imp.mass / slider.mass
    if a.max_mass_ratio is not None and ratio > a.max_mass_ratio * (1.0 + BOUND_SLACK):
        out.append(_shortfall("mass_ratio", ratio, a.max_mass_ratio, "-",
                              f"m/M {ratio:.4g} is above the cap {a.max_mass_ratio:g}"))
    g = imp.geometry
    for name, value, (lo, hi), scale, unit in (
            ("area", g.area, a.bounds.area, 1e12, "um^2"),
            ("width", g.width, a.bounds.width, 1e6, "um"),
            ("length", g.length, a.bounds.length, 1e6, "um"),
            ("gap", g.gap, a.bounds.gap, 1e6, "um")):
        if value < lo * (1.0 - BOUND_SLACK) or value > hi * (1.0 + BOUND_SLACK):
            limit = lo if value < lo else hi
            out.append(_shortfall("bounds", value, limit, name,
                                  f"its {name} {value * scale:.4g} {unit} is outside "
                                  f"[{lo * scale:g}, {hi * scale:g}] {unit}"))
    if a.sensitivity is not None:
        s = checks["line_width_sensitivity_per_um"] / UM
        lo, hi = a.sensitivity
        if s < lo * (1.0 - 1e-6) or s > hi * (1.0 + 1e-6):
            limit = lo if s < lo else hi
            out.append(_shortfall("sensitivity", s, limit, "1/m",
                                  f"its line-width sensitivity {s * UM:.4g}/um is outside "
                                  f"[{lo * UM:.4g}, {hi * UM:.4g}]/um"))
    return tuple(out)


def _checks(a, problem, ev, chk, history, rounds):
    """DesignResult.checks: grids, re-check outcomes, rounds, faults, violated drives."""
    window, sensitivity, robust_shift = a.window, a.sensitivity, a.robust_shift
    rejected = sum(1 for _, c in history if not c["fine_ok"])
    rejected_long = sum(1 for _, c in history if c["fine_ok"] and not c["long_ok"])
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
        # the forbidden tones whose guard band (or the tone itself) it answers, on the
        # re-check grid or over the long window
        "violated_tones_hz": sorted({float(problem.forbidden[problem.owner[j]])
                                     for j in chk["violated"]
                                     if not isinstance(problem.check_hz[j], Ensemble)
                                     and problem.owner[j] >= 0}),
        # the summed drives it must move its slider under (a multi-tone step it plays
        # in) from some x0 of the re-check grid it does not respond under
        "unanswered_target_drives": _unanswered(problem, ev.geometry),
    }
    if sensitivity is not None:
        checks["line_width_sensitivity_per_um"] = (
            problem.line_width.sensitivity(*ev.geometry[:3]) * UM)
        checks["sensitivity_band_per_um"] = [sensitivity[0] * UM, sensitivity[1] * UM]
    if robust_shift is not None:
        checks["robust_natural_frequency_scales"] = list(problem.nu_scales(ev.geometry))
    return checks


def _unanswered(problem, geometry):
    """Labels of the target ensembles under which ``geometry`` does not respond from
    some x0 of the re-check grid (runs the re-check made: cached)."""
    if not problem.target_ensembles:
        return []
    u = _u_grid(problem.budget.verify_x0_points)
    with problem.kernel_scope():
        return sorted(e.label for e in problem.target_ensembles
                      if np.any(problem.runs_of(geometry, e, u, problem.window, False)[0] <= 0))


def _message(a, chk, status, worst_x0, violated_drives, short=()):
    """DesignResult.message: what was met, or every constraint the design misses."""
    frequency, forbidden, window = a.frequency, a.forbidden, a.window
    if short:
        # the search found no design passing the re-check grid: the least violating
        head = ("no design met the constraints within the bounds and budget; the least "
                "violating design is returned: " if not chk["fine_ok"] else "infeasible: ")
        return head + "; ".join(s["text"] for s in short)
    if status == "ok":
        message = (f"feasible: r_min = {chk['r_min']:.4g} N at x0 = {worst_x0 / UM:.4g} um; "
                   f"silent at {len(forbidden)} forbidden frequencies on {chk['points']} x0")
        if not chk["long_ok"]:
            message += (f"; responds at {chk['long_violated_hz']:g} Hz within the "
                        f"{LONG_WINDOW_FACTOR * window * 1e3:g} ms re-check window")
    else:
        bad = [f"{f:g} Hz (r_max {r:.3g} N)" for f, r in zip(forbidden, chk["r_max"]) if r > 0]
        bad += [f"the summed drive {label!r}" for label in violated_drives]
        message = ("no design met the constraints within the bounds and budget; the least "
                   "violating design is returned: "
                   + (f"responds at {', '.join(bad)}" if bad else "")
                   + ("" if chk["r_min"] > 0 else
                      (", and " if bad else "")
                      + f"does not respond at {frequency:g} Hz from every x0"))
    return message


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
