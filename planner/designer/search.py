"""The search: Sobol seeding, annealing chains, SQP polish, and the re-checks that
drive the exchange method."""

from __future__ import annotations

import math
import warnings
from dataclasses import replace

import numpy as np

from planner.designer.problem import LONG_WINDOW_FACTOR
from planner.designer.runs import Ensemble, _u_grid

#: Points of the dense scan of a near forbidden tone's guard band at the re-check: the
#: search checks only ``Budget.guard_points`` of them, and a design can answer between
#: them (found: silent at 5236 and 5337 Hz, answering at 5260 Hz; a fabricated chip moves
#: the tone there) [-].
GUARD_SCAN_POINTS = 13
#: Forbidden tones within this log distance of the target get the dense scan [-].
GUARD_SCAN_NEAR = 0.2
#: The annealer adapts its step every this many moves towards ACCEPT_TARGET.
ADAPT_EVERY = 20
ACCEPT_TARGET = (0.2, 0.45)


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
    # SciPy's optimize and stats are imported where they are used: a plan read from
    # the design cache runs no search and spares their import (~0.6 s)
    from scipy import optimize

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


def _search(problem, rng, budget, tick, starts=None, family=()):
    """Annealing chains and the SQP polish.

    The first round seeds its chains with scrambled-Sobol samples, and the ``family``
    (z of designs of the same spec at other tones, scaled to this one) beside them; a
    resumed round (``starts``: z of the previous round's archive) re-evaluates those on
    the grown grids and anneals shorter chains from them.
    """
    if starts is None:
        from scipy.stats import qmc

        samples = qmc.Sobol(4, scramble=True, seed=rng).random(budget.initial)
        # a share of the samples on the face A = A_max: r grows with m, and the damping
        # b / 2m = mu A / (2 d m) is largest when the plate outweighs the beams, which
        # narrows the response band (air); both favour the largest area
        if budget.area_face > 0:
            k = max(1, round(1.0 / budget.area_face))
            samples[k - 1::k, 0] = 1.0
        pool = [problem.evaluate(z) for z in samples]
        pool += [problem.evaluate(z) for z in family]
        steps = budget.anneal_steps
        if family and budget.family_steps is not None:
            # started from the spec's family, a chain needs a short local walk
            steps = budget.family_steps
    else:
        pool = [problem.evaluate(z) for z in starts]
        steps = budget.resume_steps
    for _ in pool:
        tick()
    for s in _distinct(pool, budget.chains):
        _anneal(problem, s, rng, steps, budget, tick)
    if problem.archive:
        _polish(problem, problem.archive[0], budget, tick)


def _recheck(problem, geometry):
    """Fine-grid and long-window checks of one design against every forbidden frequency.

    On the fine grid: r_min at the target (refined where it jumps), r_max at every
    forbidden frequency and silence across its guard band; over the long window:
    silence at every forbidden frequency and across its guard band.  Returns a dict with the u where a check
    failed (for the exchange step) and the check indices violated.
    """
    b = problem.budget
    u_fine = _u_grid(b.verify_x0_points)
    u, r = problem.target(geometry, u_fine, b.verify_refine_levels)
    i = int(np.argmin(r))
    if problem.target_ensembles and not problem.ensembles_in_search:
        # the tone's runs are cached: free.  Where a target ensemble lowers r_min, the
        # search counts the ensembles from now on
        if float(r[i]) < float(np.min(problem.target(geometry, u_fine, b.verify_refine_levels,
                                                      ensembles=False)[1])):
            problem.ensembles_in_search = True
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
    # the guard bands of the near forbidden tones, densely: a frequency that answers
    # joins the checks (the exchange method then keeps the search away from it)
    if problem.guard > 0:
        checked = {float(c) for c in problem.check_hz if not isinstance(c, Ensemble)}
        for owner, f in enumerate(problem.forbidden):
            if abs(math.log(f / problem.frequency)) > GUARD_SCAN_NEAR:
                continue
            for fs in f * (1.0 + problem.guard * np.linspace(-1.0, 1.0, GUARD_SCAN_POINTS)):
                fs = float(fs)
                if fs in checked:
                    continue
                rf = problem.runs_of(geometry, fs, u_fine, problem.window, True)[0]
                if np.any(rf > 0):
                    problem.check_hz.append(fs)
                    problem.owner.append(owner)
                    problem.order.append(len(problem.check_hz) - 1)
                    checked.add(fs)
                    bad_forbid.append(u_fine[rf > 0])
                    violated.append(len(problem.check_hz) - 1)
    long_window = LONG_WINDOW_FACTOR * problem.window
    bad_long, long_hz = [], None
    for j, f in enumerate(problem.check_hz):
        # every check over the long window, the guard band's points too: a fabricated
        # chip moves a neighbour's tone anywhere in the guard band, where it then plays
        # for a whole step (an idle design silent there over the short window answered
        # over a 10 ms step on 20 % of chips)
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


def _search_and_recheck(problem, rng, budget, tick, history, family=()):
    """Search; re-check the archive on a finer grid and a longer window; where every
    archived design fails, add the failing x0 (and any forbidden frequency the search
    skipped) to the optimiser's problem and resume (exchange method).

    ``family``: z of related designs the first round's chains may start from.  Appends
    (evaluation, re-check) of every re-checked design to ``history`` and stops at the
    first that passes both checks.  Returns the number of rounds run.
    """
    starts = None
    for round_ in range(budget.rounds):
        _search(problem, rng, budget, tick, starts, family if round_ == 0 else ())
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
