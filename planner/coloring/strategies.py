"""Interchangeable colouring strategies and their registry, :data:`STRATEGIES`.

A strategy is called as ``strategy(graph, separation, time_limit, seed)`` and
returns a :class:`~planner.coloring.ColoringResult` (or a plain
``{node: colour}`` dict); :func:`~planner.coloring.solve_bandwidth` resolves a
name with ``STRATEGIES.get(name, name)``, as networkx's ``greedy_color`` does.
"""

from __future__ import annotations

import math
import numbers
import time
from typing import Any, Callable

import networkx as nx
import numpy as np

from planner.coloring.heuristic import _as_rng, _heuristic
from planner.coloring.milp import _milp_component
from planner.coloring.problem import _Problem, _span_of
from planner.coloring.result import ColoringResult, _result

#: ``method="auto"`` runs the exact MILP up to this many vertices (GEOM
#: instances up to 60 vertices and the 5 x 5 array's 50 impacters fit), the
#: heuristic above it.
AUTO_EXACT_MAX_NODES = 80

#: Default wall-clock budget of the exact strategy [s].
DEFAULT_EXACT_TIME_LIMIT = 10.0

#: Default wall-clock budget of the heuristic strategy [s].  The search stops
#: earlier when it reaches the lower bound or its iteration budget.
DEFAULT_HEURISTIC_TIME_LIMIT = 5.0

#: Share of the exact strategy's budget given to its heuristic warm start, and
#: the scale of the heuristic's iteration caps there.  Up to
#: AUTO_EXACT_MAX_NODES vertices the MILP, not the heuristic, proves that a
#: span cannot be beaten, so a short warm start serves; on larger graphs the
#: MILP rarely improves on the heuristic within seconds (measured in
#: benchmarks/coloring.py), so the warm start gets the full search.
HEURISTIC_SHARE = 0.3
EXACT_HEURISTIC_EFFORT = 0.25
LARGE_HEURISTIC_SHARE = 0.5


def _check_time_limit(time_limit, default: float) -> float:
    if time_limit is None:
        return default
    if isinstance(time_limit, bool) or not isinstance(time_limit, numbers.Real) \
            or not time_limit > 0 or not math.isfinite(time_limit):
        raise ValueError(f"time_limit must be a positive number of seconds, {time_limit!r} "
                         f"was given")
    return float(time_limit)


def _strategy_dsatur(graph, separation="sep", time_limit=None, seed=None) -> ColoringResult:
    """DSATUR restarts + order search + iterated tabu search (heuristic; proves
    optimality only when it meets the clique lower bound)."""
    t0 = time.perf_counter()
    budget = _check_time_limit(time_limit, DEFAULT_HEURISTIC_TIME_LIMIT)
    problem = _Problem.from_graph(graph, separation)
    rng = _as_rng(seed)
    if problem.n == 0:
        return _result(problem, np.zeros(0, np.int64), 0, "dsatur", t0, "empty graph")
    colours, lower = _heuristic(problem, t0 + budget, rng)
    s = _span_of(colours)
    msg = ("span meets the clique lower bound" if s == lower
           else f"heuristic: span {s}, lower bound {lower} (gap not closed)")
    return _result(problem, colours, lower, "dsatur", t0, msg)


def _strategy_milp(graph, separation="sep", time_limit=None, seed=None) -> ColoringResult:
    """Heuristic warm start, clique bounds, then a MILP per connected component."""
    t0 = time.perf_counter()
    budget = _check_time_limit(time_limit, DEFAULT_EXACT_TIME_LIMIT)
    deadline = t0 + budget
    problem = _Problem.from_graph(graph, separation)
    rng = _as_rng(seed)
    if problem.n == 0:
        return _result(problem, np.zeros(0, np.int64), 0, "milp", t0, "empty graph")
    if problem.n <= AUTO_EXACT_MAX_NODES:
        share, effort = HEURISTIC_SHARE, EXACT_HEURISTIC_EFFORT
    else:
        share, effort = LARGE_HEURISTIC_SHARE, 1.0
    colours, lower = _heuristic(problem, t0 + share * budget, rng, effort)
    if _span_of(colours) == lower:
        return _result(problem, colours, lower, "milp", t0,
                       "heuristic span meets the clique lower bound")
    colours = colours.copy()
    comps = [sorted(c) for c in nx.connected_components(problem.index_graph())]
    # hardest component first: it sets the floor the others need not beat
    comps.sort(key=lambda c: -int(colours[c].max()))
    all_proven = True
    for comp in comps:
        if int(colours[comp].max()) + 1 <= lower:
            continue  # already within a proven bound
        left = deadline - time.perf_counter()
        if left <= 0.05:
            all_proven = False
            break
        got, comp_lower, proven = _milp_component(problem, comp, colours, lower, left)
        if got is not None:
            for v, c in got.items():
                colours[v] = c
        lower = max(lower, comp_lower)
        all_proven = all_proven and proven
    colours -= colours.min()
    s = _span_of(colours)
    if all_proven:
        lower = s
        msg = "proven optimal"
    else:
        msg = f"time limit: span {s}, lower bound {lower}"
    return _result(problem, colours, lower, "milp", t0, msg)


def _strategy_auto(graph, separation="sep", time_limit=None, seed=None) -> ColoringResult:
    """Exact up to AUTO_EXACT_MAX_NODES vertices, heuristic above."""
    if graph.number_of_nodes() <= AUTO_EXACT_MAX_NODES:
        return _strategy_milp(graph, separation, time_limit, seed)
    return _strategy_dsatur(graph, separation, time_limit, seed)


#: Colouring strategies by name.  A strategy is called as
#: ``strategy(graph, separation, time_limit, seed)`` and returns a
#: :class:`ColoringResult` or a plain ``{node: colour}`` dict.  Pass your own
#: callable as ``method`` to use another.
STRATEGIES: dict[str, Callable[..., Any]] = {
    "auto": _strategy_auto,
    "dsatur": _strategy_dsatur,
    "milp": _strategy_milp,
    "exact": _strategy_milp,
}
