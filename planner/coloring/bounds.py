"""Lower bounds on the optimal span: exact spans of small cliques, Held-Karp on large ones."""

from __future__ import annotations

import math

import networkx as nx
import numpy as np

from planner.coloring.cliques import (
    _clique_greedy_span_kernel,
    _clique_span_kernel,
    _held_karp_kernel,
)
from planner.coloring.problem import _Problem

#: Cliques up to this size get their exact span by branch and bound over colour
#: orders; larger ones a Held-Karp bound (and the exact span of a sub-clique).
CLIQUE_EXACT_MAX = 8

#: Stop enumerating maximal cliques after this many (geometric graphs have far
#: fewer; dense graphs would otherwise take exponential time).
CLIQUE_ENUM_LIMIT = 20_000

#: Subgradient steps of the Held-Karp 1-tree bound.
HELD_KARP_STEPS = 300


def _clique_bound(problem: _Problem, clique, cap: int) -> int:
    """Lower bound on the span any colouring needs on ``clique``.

    ``cap`` is a span known to be achievable; the exact search looks only
    below it, so the result never exceeds ``cap``.
    """
    k = len(clique)
    w = problem.sep_matrix(clique)
    if k <= CLIQUE_EXACT_MAX:
        return int(_clique_span_kernel(w, cap))
    # consecutive vertices in colour order are >= their separation apart
    path = _held_karp_kernel(w, HELD_KARP_STEPS)
    bound = int(math.ceil(path - 1e-6)) + 1
    # and the heaviest sub-clique's exact span
    strongest = np.argsort(-w.sum(axis=1), kind="stable")[:CLIQUE_EXACT_MAX]
    sub = w[np.ix_(strongest, strongest)]
    return min(cap, max(bound, int(_clique_span_kernel(sub, cap))))


def _lower_bound(problem: _Problem, cap: int) -> int:
    """Lower bound on the optimal span [channels], never above ``cap``.

    The largest of: max separation + 1 (an edge is a 2-clique) and, over the
    maximal cliques, :func:`_clique_bound`.  ``cap`` is an achievable span
    (the heuristic's), which the bound cannot exceed and which stops the
    search early.
    """
    if problem.n == 0:
        return 0
    if problem.m == 0:
        return 1
    best = int(problem.es.max()) + 1
    cliques = []
    for count, q in enumerate(nx.find_cliques(problem.index_graph())):
        if count >= CLIQUE_ENUM_LIMIT:
            break
        if len(q) >= 3:
            cliques.append(sorted(q))
    # a clique can raise the bound only if its achievable span exceeds it:
    # try the cliques with the largest achievable spans first, stop at the
    # first that cannot
    ub = [int(_clique_greedy_span_kernel(problem.sep_matrix(q))) for q in cliques]
    for j in np.argsort(-np.array(ub, dtype=np.int64), kind="stable"):
        if ub[j] <= best:
            break
        q = cliques[j]
        best = max(best, _clique_bound(problem, q, min(cap, ub[j])))
        if best >= cap:
            break
    return min(best, cap)
