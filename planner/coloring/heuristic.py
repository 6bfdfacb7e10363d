"""The heuristic: DSATUR restarts, late-acceptance order search, iterated tabu search."""

from __future__ import annotations

import time

import numpy as np

from planner.coloring.bounds import _lower_bound
from planner.coloring.kernels import (
    _dsatur_kernel,
    _first_fit_kernel,
    _order_search_kernel,
    _tabu_kernel,
)
from planner.coloring.problem import _Problem, _span_of
from planner.core.rng import DEFAULT_SEED  # noqa: F401  (re-exported: None means seed 0)
from planner.core.rng import as_generator as _as_rng  # noqa: F401  (the one seed rule; strategies)

#: Tabu iterations without a better shortfall before an attempt is given up
#: (scaled by the number of vertices, with a floor).
TABU_STALL_PER_NODE = 2_000
TABU_STALL_MIN = 50_000

#: Tabu iterations before the search for one span is given up.  These caps,
#: not the clock, end the search on small graphs, so results are reproducible.
TABU_LEVEL_PER_NODE = 20_000
TABU_LEVEL_MIN = 300_000

#: Iterations per kernel call; the clock is read between calls.
TABU_CHUNK = 5_000

#: Tabu tenures tried in turn by successive attempts: (r, f) gives tenure =
#: random integer in [0, r] + f x (number of conflicting vertices), the
#: Galinier-Hao rule that Lai & Lu [2] carry over to bandwidth colouring.  No
#: single pair suits every instance (long tenures win on dense graphs with
#: many colours, short ones on distance-correlated separations), so the
#: attempts cycle through a portfolio.
TABU_TENURES = ((30, 2.0), (10, 1.0), (30, 3.0), (10, 0.6))

#: Fraction of the vertices recoloured at random when an attempt restarts
#: from the best state so far (iterated tabu search).
TABU_PERTURB_FRACTION = 0.1

#: Late-acceptance order search: moves per vertex (with a floor), moves per
#: kernel call, and the late-acceptance list length.
ORDER_SEARCH_PER_NODE = 200
ORDER_SEARCH_MIN = 20_000
ORDER_CHUNK = 10_000
ORDER_HISTORY = 500

#: Random tie-break orders tried by the greedy phase, on top of the
#: deterministic ones.
GREEDY_RANDOM_RESTARTS = 8



def _compact(problem: _Problem, colours: np.ndarray) -> np.ndarray:
    """First fit in increasing colour order: never a larger span (see kernel)."""
    order = np.lexsort((np.arange(problem.n), colours)).astype(np.int64)
    again = _first_fit_kernel(problem.indptr, problem.adj, problem.adjsep, order,
                              max(problem.width, _span_of(colours) + 1))
    return again if _span_of(again) <= _span_of(colours) else colours


def _greedy(problem: _Problem, rng: np.random.Generator) -> np.ndarray:
    """Best DSATUR colouring over saturation rules and tie-break orders."""
    n = problem.n
    tiebreaks = [-np.arange(n, dtype=float), np.arange(n, dtype=float)]
    tiebreaks += [rng.random(n) for _ in range(GREEDY_RANDOM_RESTARTS)]
    best = None
    for mode in (0, 1, 2, 3):
        for tb in tiebreaks:
            c = _dsatur_kernel(problem.indptr, problem.adj, problem.adjsep, problem.weight,
                               tb, mode, problem.width)
            c = _compact(problem, c)
            if best is None or _span_of(c) < _span_of(best):
                best = c
    return best


def _squeeze(problem: _Problem, colours: np.ndarray, n_colours: int) -> np.ndarray:
    """Move every vertex coloured >= n_colours to its least-conflicting colour.

    The vertices are placed one at a time, each against the vertices already
    in range, so later placements see earlier ones.
    """
    c = colours.copy()
    over = np.flatnonzero(c >= n_colours)
    pending = set(over.tolist())
    for v in over:
        row = np.zeros(n_colours, np.int64)
        for idx in range(problem.indptr[v], problem.indptr[v + 1]):
            u = int(problem.adj[idx])
            if u in pending:
                continue
            s = int(problem.adjsep[idx])
            k = np.arange(max(0, c[u] - s + 1), min(n_colours, c[u] + s))
            row[k] += s - np.abs(k - c[u])
        c[v] = int(np.argmin(row))
        pending.discard(int(v))
    return c


def _tabu_descent(problem: _Problem, start: np.ndarray, lower: int, deadline: float,
                  rng: np.random.Generator, effort: float = 1.0) -> tuple[np.ndarray, int]:
    """Lower the span one channel at a time with tabu search; stop at ``lower``.

    At each target span the search runs a series of attempts (iterated tabu
    search): the first starts from the last valid colouring with its top
    colour squeezed out, the later ones from the best state so far with a
    random kick, or from a random colouring.  An attempt ends after
    ``stall`` iterations without a better shortfall; a target is abandoned
    after ``effort * TABU_LEVEL_PER_NODE * n`` iterations.

    Returns the best valid colouring and the number of tabu iterations spent.
    """
    best = start
    total = 0
    n = problem.n
    stall = int(effort * max(TABU_STALL_MIN, TABU_STALL_PER_NODE * n))
    level_cap = int(effort * max(TABU_LEVEL_MIN, TABU_LEVEL_PER_NODE * n))
    n_kick = max(1, int(round(TABU_PERTURB_FRACTION * n)))
    while _span_of(best) > lower and time.perf_counter() < deadline:
        k = _span_of(best) - 1
        found = None
        level_f = None
        level_state = None
        spent = 0
        attempt = 0
        while found is None and spent < level_cap and time.perf_counter() < deadline:
            if attempt == 0:
                colours = _squeeze(problem, best, k)
            elif attempt % 3 == 0:
                colours = rng.integers(0, k, size=n).astype(np.int64)
            else:
                colours = level_state.copy()
                kick = rng.choice(n, size=n_kick, replace=False)
                colours[kick] = rng.integers(0, k, size=n_kick)
            tenure_random, tenure_factor = TABU_TENURES[attempt % len(TABU_TENURES)]
            attempt += 1
            tabu = np.zeros((n, k), np.int64)
            it = 0
            attempt_f = problem.shortfall(colours)
            since = 0
            while since < stall and spent < level_cap and time.perf_counter() < deadline:
                chunk = int(min(TABU_CHUNK, level_cap - spent))
                seed = int(rng.integers(2**31 - 1))
                f, state, it_end = _tabu_kernel(problem.indptr, problem.adj, problem.adjsep,
                                                colours, tabu, it, chunk, k, seed,
                                                tenure_random, tenure_factor)
                spent += it_end - it
                it = it_end
                if level_f is None or f < level_f:
                    level_f = f
                    level_state = state.copy()
                if f == 0:
                    found = state
                    break
                if f < attempt_f:
                    attempt_f = f
                    since = 0
                else:
                    since += chunk
        total += spent
        if found is None:
            break
        best = _compact(problem, found)
    return best, total


def _order_descent(problem: _Problem, colours: np.ndarray, lower: int, deadline: float,
                   rng: np.random.Generator, effort: float = 1.0) -> np.ndarray:
    """Late-acceptance search over first-fit orders, from ``colours``' order."""
    order = np.lexsort((np.arange(problem.n), colours)).astype(np.int64)
    best = colours
    budget = int(effort * max(ORDER_SEARCH_MIN, ORDER_SEARCH_PER_NODE * problem.n))
    spent = 0
    while spent < budget and _span_of(best) > lower and time.perf_counter() < deadline:
        chunk = int(min(ORDER_CHUNK, budget - spent))
        order, s = _order_search_kernel(problem.indptr, problem.adj, problem.adjsep, order,
                                        chunk, int(rng.integers(2**31 - 1)), ORDER_HISTORY,
                                        problem.width, lower)
        spent += chunk
        if s < _span_of(best):
            best = _first_fit_kernel(problem.indptr, problem.adj, problem.adjsep, order,
                                     problem.width)
    return best


def _heuristic(problem: _Problem, deadline: float, rng,
               effort: float = 1.0) -> tuple[np.ndarray, int]:
    """DSATUR restarts, late-acceptance order search, then tabu descent.

    Each phase runs only while the span is above the clique lower bound, and
    all stop at ``deadline`` (a ``time.perf_counter()`` value).  ``effort``
    scales the search phases' iteration caps.  Returns the colouring and the
    clique lower bound.
    """
    colours = _greedy(problem, rng)
    lower = _lower_bound(problem, _span_of(colours))
    if _span_of(colours) > lower:
        colours = _order_descent(problem, colours, lower, deadline, rng, effort)
    if _span_of(colours) > lower:
        colours, _ = _tabu_descent(problem, colours, lower, deadline, rng, effort)
    colours = colours - colours.min()
    return colours, lower
