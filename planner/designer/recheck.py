"""Keep a finished design when some of its inputs change: :func:`recheck_design`.

An array plan that moves one impacter's tone changes the forbidden set of every other
impacter (the moved tone is forbidden to each of them), and a new phase draw of a
multi-tone step changes the summed drive every impacter idle in it must stay silent
under.  A design whose own tone did not move keeps its geometry if it passes the
designer's re-checks (:func:`planner.designer.search._recheck`: the fine x0 grid, the
guard band, the long window) against what changed; what did not change it already
passed, and the checks of different frequencies and drives are independent.  That
costs one re-check instead of a design, and leaves the design's speed, band and
margins to its unchanged tones as they were.
"""

from __future__ import annotations

import dataclasses
import time
import warnings

import numpy as np

from model import SolverWarning
from planner.designer.design import _checked_inputs, _message, shortfalls
from planner.designer.problem import _Problem
from planner.designer.response import _band_and_margins
from planner.designer.runs import Ensemble, _u_grid
from planner.designer.search import _recheck


def recheck_design(previous, frequency, forbidden=(), *, new_forbidden=(), forbidden_drives=(),
                   target_drives=(), min_speed=None, process=None, environment=None,
                   power=50.0, amplitude=None, bounds=None, window=3e-3, budget="fast",
                   slider=None, guard=0.02, impact_angle=None, restitution=None,
                   max_mass_ratio=None, contact="paper", robust_shift=None, sensitivity=None,
                   seed=0, x0_points=None, tone_window=0.0, **_ignored):
    """``previous`` (a feasible :class:`~planner.designer.DesignResult` for the same
    ``frequency``) with its inputs changed, re-checked where they changed.

    Parameters
    ----------
    previous : DesignResult
        A feasible design for ``frequency`` [Hz].
    frequency : float
        Its tone [Hz] (must equal ``previous.frequency_hz``).
    forbidden : sequence of float
        Every forbidden frequency now [Hz].
    new_forbidden : sequence of float
        Those of ``forbidden`` it was not checked at [Hz].
    forbidden_drives : sequence of Ensemble
        The summed drives it was not checked under (new or changed).
    target_drives : sequence of Ensemble
        Every summed drive it must move its slider under now (its response from every
        x0 is re-checked under them when any is given).
    min_speed, process, environment, power, amplitude, bounds, window, budget, slider,
    guard, impact_angle, restitution, max_mass_ratio, contact, robust_shift,
    sensitivity, seed, x0_points, tone_window :
        As :func:`planner.designer.design_impacter` (the design's own settings).

    Returns
    -------
    DesignResult
        The same geometry, ``forbidden_hz`` the new set, its margins and maxima at the
        new frequencies added, ``checks["kept_by_recheck"]`` True; ``feasible`` only if
        it passes every re-check (``shortfalls`` says which it misses).
    """
    t0 = time.perf_counter()
    if not previous.feasible:
        raise ValueError("only a feasible design can be kept by a re-check")
    if float(frequency) != float(previous.frequency_hz):
        raise ValueError(f"a re-check keeps the tone: {frequency!r} Hz was given for a design "
                         f"at {previous.frequency_hz!r} Hz")
    kw = dict(impact_angle=previous.impact_angle_rad if impact_angle is None else impact_angle,
              restitution=previous.restitution if restitution is None else restitution)
    a = _checked_inputs(frequency, tuple(new_forbidden), process, environment, bounds, window,
                        slider, budget, x0_points, power, amplitude, seed, guard,
                        kw["impact_angle"], kw["restitution"], forbidden_drives, target_drives,
                        contact, max_mass_ratio, robust_shift, sensitivity, min_speed,
                        tone_window)
    problem = _Problem(a.frequency, a.forbidden, a.factory, a.tones, a.bounds, a.window,
                       a.budget, a.guard, a.ensembles, mass_cap=a.mass_cap,
                       q_per_kg=a.q_per_kg, robust_shift=a.robust_shift,
                       target_ensembles=a.targets, sensitivity=a.sensitivity,
                       tone_window=a.tone_window)
    if a.targets:
        # the re-check counts the target drives in r_min
        problem.ensembles_in_search = True
    geometry = tuple(float(v) for v in (previous.geometry.area, previous.geometry.width,
                                        previous.geometry.length, previous.geometry.gap))
    with problem.kernel_scope():
        chk = _recheck(problem, geometry)
    imp = previous.impacter
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SolverWarning)
        if a.forbidden:
            _, new_margins = _band_and_margins(imp, a.tones, a.frequency, a.forbidden,
                                               _u_grid(a.budget.forbidden_x0_points) * imp.gap,
                                               a.window, a.budget)
        else:
            new_margins = []
    all_forbidden = tuple(sorted(float(f) for f in forbidden))
    old = {float(f): (float(r), float(m)) for f, r, m in
           zip(previous.forbidden_hz, previous.r_max_forbidden_n, previous.margins_hz)}
    new = {float(f): (float(r), float(m)) for f, r, m in
           zip(a.forbidden, chk["r_max"], new_margins)}
    missing = [f for f in all_forbidden if f not in old and f not in new]
    if missing:
        raise ValueError(f"forbidden frequencies {missing} are neither in the design nor "
                         "in new_forbidden")
    r_max = tuple(new.get(f, old.get(f))[0] for f in all_forbidden)
    margins = tuple(new.get(f, old.get(f))[1] for f in all_forbidden)
    violated = sorted({problem.check_hz[j].label for j in chk["violated"]
                       if isinstance(problem.check_hz[j], Ensemble)})
    tones = sorted({float(problem.forbidden[problem.owner[j]]) for j in chk["violated"]
                    if not isinstance(problem.check_hz[j], Ensemble) and problem.owner[j] >= 0})
    checks = {**previous.checks, "kept_by_recheck": True,
              "recheck_new_forbidden": len(a.forbidden),
              "recheck_new_drives": [e.label for e in a.ensembles],
              "fine_grid_passed": bool(chk["fine_ok"]),
              "long_window_passed": bool(chk["long_ok"]),
              "violated_drives": violated, "violated_tones_hz": tones}
    if not a.targets:
        # the response at the tone itself did not change: only the new checks count
        chk = {**chk, "r_min": previous.r_min_n, "worst_u": previous.worst_x0_m / imp.gap}
    speed = float(previous.predicted_slider_speed_m_s)
    short = shortfalls(dataclasses.replace(a, forbidden=all_forbidden),
                       {**chk, "r_max": list(r_max)}, imp, speed, a.slider, checks)
    status = "ok" if not short else "infeasible"
    message = _message(dataclasses.replace(a, forbidden=all_forbidden),
                       {**chk, "r_max": list(r_max)}, status, chk["worst_u"] * imp.gap,
                       violated, short)
    return dataclasses.replace(
        previous, forbidden_hz=all_forbidden, r_max_forbidden_n=r_max, margins_hz=margins,
        r_min_n=float(chk["r_min"]), worst_x0_m=float(chk["worst_u"] * imp.gap),
        feasible=not short, status=status, message=message, shortfalls=short, checks=checks,
        seconds=float(previous.seconds) + (time.perf_counter() - t0),
        evaluations=previous.evaluations, simulations=previous.simulations + problem.simulations)



def response_alone(design, *, process=None, environment=None, power=50.0, amplitude=None,
                   bounds=None, window=3e-3, budget=None, slider=None, guard=0.02,
                   impact_angle=None, restitution=None, max_mass_ratio=None, contact="paper",
                   sensitivity=None, seed=0, x0_points=None, tone_window=0.0, **_ignored):
    """Where ``design`` (a :class:`~planner.designer.DesignResult`) does not respond to
    its own tone, and to its tone window's edges, *alone*: the designer's response
    check (its fine x0 grid, refined where r jumps) without the summed drives it plays
    in.

    An array planner asks this of a design that misses only its response under a
    multi-tone step's summed drive over the designer's short window: whether the tone
    itself drives it from every x0 (then the step's own simulation, over its whole
    burst, can settle the summed drive; :func:`planner.planning.verify.confirm_responses`).

    Parameters
    ----------
    design : DesignResult
        Any design, feasible or not; its own budget is used unless ``budget`` is given.
    process, environment, power, amplitude, bounds, window, budget, slider, guard,
    impact_angle, restitution, max_mass_ratio, contact, sensitivity, seed, x0_points,
    tone_window :
        As :func:`planner.designer.design_impacter` (the design's own settings).

    Returns
    -------
    (missed, points) : (int, int)
        The x0 of the re-check grid from which it does not respond, and the grid's size.
    """
    kw = dict(impact_angle=design.impact_angle_rad if impact_angle is None else impact_angle,
              restitution=design.restitution if restitution is None else restitution)
    a = _checked_inputs(float(design.frequency_hz), (), process, environment, bounds, window,
                        slider, design.budget if budget is None else budget, x0_points, power,
                        amplitude, seed, guard, kw["impact_angle"], kw["restitution"], (), (),
                        contact, max_mass_ratio, None, sensitivity, None, tone_window)
    problem = _Problem(a.frequency, (), a.factory, a.tones, a.bounds, a.window, a.budget,
                       a.guard, (), mass_cap=a.mass_cap, q_per_kg=a.q_per_kg,
                       tone_window=a.tone_window)
    geometry = tuple(float(v) for v in (design.geometry.area, design.geometry.width,
                                        design.geometry.length, design.geometry.gap))
    b = a.budget
    with problem.kernel_scope():
        u, r = problem.target(geometry, _u_grid(b.verify_x0_points), b.verify_refine_levels,
                              ensembles=False)
    return int(np.count_nonzero(r <= 0)), int(u.size)
