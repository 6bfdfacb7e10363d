"""The solver's public face: :func:`solve_bandwidth` and :func:`color_bandwidth`."""

from __future__ import annotations

import time
from typing import Hashable

import networkx as nx

from planner.coloring.bounds import _lower_bound
from planner.coloring.problem import _Problem, _check_graph
from planner.coloring.result import ColoringResult
from planner.coloring.strategies import STRATEGIES
from planner.coloring.verify import span, verify_coloring


def solve_bandwidth(graph: nx.Graph, separation: str = "sep", method="auto",
                    time_limit: float | None = None, seed=None) -> ColoringResult:
    """Colour a conflict graph so every edge's separation holds, with small span.

    Parameters
    ----------
    graph : networkx.Graph
        Conflict graph.  Self-loops are ignored (in the ``band`` format they
        are node weights).
    separation : str, default "sep"
        Edge attribute holding the required separation [channels], a
        non-negative integer; edges without it need 1 (plain colouring).
    method : str or callable, default "auto"
        A key of :data:`STRATEGIES` -- ``"dsatur"`` (greedy + tabu search),
        ``"milp"`` / ``"exact"`` (HiGHS MILP from the heuristic's span),
        ``"auto"`` (exact up to ``AUTO_EXACT_MAX_NODES`` vertices) -- or a
        callable ``f(graph, separation, time_limit, seed)`` returning a
        :class:`ColoringResult` or a ``{node: colour}`` dict.
    time_limit : float, optional
        Wall-clock budget [s]; default ``DEFAULT_EXACT_TIME_LIMIT`` for the
        exact strategy, ``DEFAULT_HEURISTIC_TIME_LIMIT`` for the heuristic.
        When it runs out the best colouring found is returned (never worse
        than the heuristic's), with ``optimal=False``.
    seed : int, numpy.random.Generator or None
        Seed of the heuristic's random tie-breaks and kicks (default 0).  The
        same input and seed give the same colouring unless a time limit stops
        a search early.

    Returns
    -------
    ColoringResult
        Colouring, span, proven lower bound, optimality flag, method, time.

    Raises
    ------
    ValueError
        A separation that is negative or not an integer (naming the edge), an
        unknown ``method``, a non-positive ``time_limit``, or a user strategy
        returning an invalid colouring.

    Notes
    -----
    The lower bound is the largest of: max separation + 1 over the edges, the
    exact span of every maximal clique of up to ``CLIQUE_EXACT_MAX`` vertices
    (branch and bound over colour orders), a Held-Karp bound on the shortest
    Hamiltonian path of larger cliques, and the MILP's dual bound.

    Examples
    --------
    >>> import networkx as nx
    >>> g = nx.Graph()
    >>> g.add_edge("a", "b", sep=3); g.add_edge("b", "c", sep=2); g.add_edge("a", "c", sep=1)
    >>> r = solve_bandwidth(g)  # a = 0, c = 1, b = 3
    >>> r.span, r.optimal
    (4, True)
    """
    _check_graph(graph, separation)
    func = STRATEGIES.get(method, method) if isinstance(method, Hashable) else method
    if not callable(func):
        raise ValueError(f"method must be one of {sorted(STRATEGIES)} or a callable, "
                         f"{method!r} was given")
    t0 = time.perf_counter()
    out = func(graph, separation, time_limit, seed)
    if not isinstance(out, (ColoringResult, dict)):
        raise ValueError(f"strategy {method!r} returned {type(out).__name__}, expected a "
                         f"ColoringResult or a dict")
    coloring = out.coloring if isinstance(out, ColoringResult) else out
    bad = verify_coloring(graph, coloring, separation)
    if bad:
        raise ValueError(f"strategy {method!r} returned an invalid colouring: {bad[0]}")
    if isinstance(out, ColoringResult):
        return out
    # a user strategy's plain colouring: shift to start at 0, bound it
    low = min(out.values(), default=0)
    coloring = {v: int(c) - low for v, c in out.items()}
    s = span(coloring)
    lower = _lower_bound(_Problem.from_graph(graph, separation), s)
    return ColoringResult(coloring, s, lower, s == lower,
                          getattr(func, "__name__", repr(func)),
                          time.perf_counter() - t0, "user strategy")


def color_bandwidth(graph: nx.Graph, separation: str = "sep", method="auto",
                    time_limit: float | None = None, seed=None) -> dict:
    """Bandwidth colouring of ``graph``: ``{node: colour}``.

    Same parameters as :func:`solve_bandwidth`, which also reports the span,
    the proven lower bound and whether the span is optimal.

    Parameters
    ----------
    graph : networkx.Graph
        Conflict graph; edge attribute ``separation`` gives the separation
        [channels] (default 1).
    separation : str, default "sep"
        Edge attribute name.
    method : str or callable, default "auto"
        Key of :data:`STRATEGIES` or a callable.
    time_limit : float, optional
        Wall-clock budget [s].
    seed : int, numpy.random.Generator or None
        Seed of the heuristic (default 0).

    Returns
    -------
    dict
        Node -> colour, non-negative ints with minimum 0.

    Examples
    --------
    >>> import networkx as nx
    >>> g = nx.path_graph(3)
    >>> nx.set_edge_attributes(g, 2, "sep")
    >>> c = color_bandwidth(g)
    >>> span(c), verify_coloring(g, c)
    (3, [])
    """
    return solve_bandwidth(graph, separation, method, time_limit, seed).coloring
