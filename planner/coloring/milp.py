"""The exact step: a HiGHS MILP (scipy.optimize.milp) per connected component."""

from __future__ import annotations

import math

import numpy as np

from planner.coloring.problem import _Problem


def _milp_component(problem: _Problem, members: list[int], start: np.ndarray, floor: int,
                    time_limit: float):
    """Minimise one connected component's span with HiGHS, below its current span.

    Parameters
    ----------
    problem : _Problem
        The whole graph.
    members : list of int
        The component's vertices.
    start : ndarray of int64, shape (n,)
        A valid colouring (the heuristic's); its span on ``members`` is the
        incumbent U.
    floor : int
        Spans below this need no search (another component or a bound already
        forces it): the model's span variable starts at ``floor``.
    time_limit : float
        HiGHS time limit [s].

    Returns
    -------
    colours : dict int -> int or None
        A better colouring of the component, or None.
    lower : int
        Proven lower bound on the component's span, raised to ``floor``.
    proven : bool
        True when the returned (or incumbent) span is proven optimal.
    """
    from scipy.optimize import Bounds, LinearConstraint, milp
    from scipy.sparse import coo_array

    incumbent = int(start[members].max()) + 1
    target = incumbent - 1  # search spans <= target only
    if target < floor:
        return None, floor, True
    cmax = target - 1  # largest colour allowed
    local = np.full(problem.n, -1, np.int64)
    local[members] = np.arange(len(members))
    keep = local[problem.eu] >= 0
    eu, ev, es = local[problem.eu[keep]], local[problem.ev[keep]], problem.es[keep]
    n, m = len(members), len(es)
    # variables: colours c_0..c_{n-1}, max colour z, order o_e (1: c_v >= c_u + s)
    iz = n
    io = n + 1 + np.arange(m)
    nvar = n + 1 + m
    big = cmax + es  # makes the constraint of the order not chosen vacuous
    e2 = 2 * np.arange(m)
    rows = np.concatenate([e2, e2, e2, e2 + 1, e2 + 1, e2 + 1,
                           2 * m + np.arange(n), 2 * m + np.arange(n)])
    cols = np.concatenate([eu, ev, io, ev, eu, io, np.arange(n), np.full(n, iz)])
    ones = np.ones(m)
    vals = np.concatenate([ones, -ones, big, ones, -ones, -big, np.ones(n), -np.ones(n)])
    # c_u - c_v + M o >= s  and  c_v - c_u - M o >= s - M ;  c_v - z <= 0
    lo = np.concatenate([np.column_stack([es, es - big]).ravel(), np.full(n, -np.inf)])
    hi = np.concatenate([np.full(2 * m, np.inf), np.zeros(n)])
    a = coo_array((vals.astype(float), (rows, cols)), shape=(2 * m + n, nvar)).tocsr()
    lb = np.zeros(nvar)
    ub = np.ones(nvar)
    ub[:n] = cmax
    lb[iz] = floor - 1
    ub[iz] = cmax
    # reversal symmetry (c -> z - c) flips every order variable: fix one,
    # on the edge of largest separation
    if m:
        lb[io[int(np.argmax(es))]] = 1.0
    cost = np.zeros(nvar)
    cost[iz] = 1.0
    res = milp(cost, integrality=np.ones(nvar), bounds=Bounds(lb, ub),
               constraints=LinearConstraint(a, lo, hi),
               options={"time_limit": max(0.05, time_limit), "disp": False,
                        "mip_rel_gap": 0.0})
    if res.status == 2:  # infeasible: nothing below the incumbent
        return None, incumbent, True
    dual = getattr(res, "mip_dual_bound", None)
    lower = floor
    if dual is not None and np.isfinite(dual):
        lower = max(floor, int(math.ceil(dual - 1e-6)) + 1)
    if res.x is None:
        return None, lower, False
    colours = np.rint(res.x[:n]).astype(np.int64)
    got = {members[i]: int(colours[i]) for i in range(n)}
    proven = res.status == 0
    if proven:
        lower = max(lower, int(colours.max()) + 1)
    return got, lower, proven
