"""Bandwidth colouring: integer channels with per-edge separations.

Every impacter of an array gets a drive channel (an integer colour).  Two
impacters joined by an edge of the conflict graph need channels at least
``sep`` apart, ``|c(u) - c(v)| >= sep(u, v)``, so that driving one never
resonates the other.  The *span* of a colouring is its largest colour plus one:
the number of channels the drive band must hold.  Minimising the span is the
bandwidth colouring problem (a generalisation of graph colouring, NP-hard);
the GEOM instances of Trick / Phan & Skiena are its standard benchmark.

Layout of this module

- numba kernels (``_*_kernel``): plain functions of int64 arrays -- the graph
  in CSR form (``indptr``, ``adj``, ``adjsep``) and colour vectors.  They know
  nothing of networkx and are documented with their array shapes.
- bounds: exact spans of small cliques (branch and bound over colour orders)
  and a Held-Karp (1-tree) bound on the shortest Hamiltonian path of large
  cliques.
- strategies, registered in :data:`STRATEGIES`: ``"dsatur"`` (DSATUR-style
  greedy restarts, a late-acceptance search over first-fit vertex orders, then
  iterated tabu search at decreasing spans), ``"milp"`` / ``"exact"``
  (scipy/HiGHS MILP below the heuristic's span) and ``"auto"``.
- the public API: :func:`solve_bandwidth`, :func:`color_bandwidth`,
  :func:`verify_coloring`, :func:`span`, :func:`read_band`.

Colours are channel indices (dimensionless integers, 0-based); nothing in this
module knows about hertz.  The caller maps channel ``k`` to a frequency.

References
----------
.. [1] M. A. Trick, "Computational series: Graph coloring and its
   generalizations", https://mat.gsia.cmu.edu/COLOR04/ (GEOM instances).
.. [2] X. Lai, Z. Lü, "Multistart iterated tabu search for bandwidth coloring
   problem", Computers & Operations Research 40 (2013) 1401-1409.
.. [3] E. Malaguti, P. Toth, "An evolutionary approach for bandwidth
   multicoloring problems", EJOR 189 (2008) 638-651.
"""

from __future__ import annotations

import math
import numbers
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Hashable, NamedTuple

import networkx as nx
import numpy as np
from numba import njit

__all__ = [
    "ColoringResult",
    "STRATEGIES",
    "Violation",
    "color_bandwidth",
    "read_band",
    "solve_bandwidth",
    "span",
    "verify_coloring",
]

# --------------------------------------------------------------------------
# Tuning constants
# --------------------------------------------------------------------------

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

#: Cliques up to this size get their exact span by branch and bound over colour
#: orders; larger ones a Held-Karp bound (and the exact span of a sub-clique).
CLIQUE_EXACT_MAX = 8

#: Stop enumerating maximal cliques after this many (geometric graphs have far
#: fewer; dense graphs would otherwise take exponential time).
CLIQUE_ENUM_LIMIT = 20_000

#: Subgradient steps of the Held-Karp 1-tree bound.
HELD_KARP_STEPS = 300

#: Default seed of every randomised step.
DEFAULT_SEED = 0


# --------------------------------------------------------------------------
# Kernels: int64 arrays only
# --------------------------------------------------------------------------


@njit(cache=True)
def _dsatur_kernel(indptr, adj, adjsep, weight, tiebreak, mode, width):  # pragma: no cover - jit
    """DSATUR generalised to separations.

    Parameters
    ----------
    indptr : ndarray of int64, shape (n + 1,)
        CSR row pointers of the conflict graph.
    adj : ndarray of int64, shape (2 m,)
        Neighbour indices, row by row.
    adjsep : ndarray of int64, shape (2 m,)
        Separation of each adjacency entry [channels].
    weight : ndarray of int64, shape (n,)
        Weighted degree (sum of separations) of each vertex [channels].
    tiebreak : ndarray of float64, shape (n,)
        Last tie-break key; the larger wins.
    mode : int
        Saturation key: 0 = smallest feasible colour, then sum of separations
        to coloured neighbours; 1 = number of forbidden colours; 2 = sum of
        separations to coloured neighbours; 3 = the *lowest* smallest feasible
        colour (nearest neighbour: on a clique it builds the colour order as a
        short Hamiltonian path, where "most saturated first" jumps about).
    width : int
        Colour array width; must exceed every possible greedy colour.

    Returns
    -------
    colours : ndarray of int64, shape (n,)
        Each vertex gets the smallest colour compatible with its coloured
        neighbours, in DSATUR order.
    """
    n = indptr.shape[0] - 1
    colours = -np.ones(n, np.int64)
    forbid = np.zeros((n, width), np.int32)
    first = np.zeros(n, np.int64)
    satsum = np.zeros(n, np.int64)
    nforb = np.zeros(n, np.int64)
    for _ in range(n):
        best = -1
        k1 = 0
        k2 = 0
        k3 = 0
        k4 = 0.0
        for v in range(n):
            if colours[v] >= 0:
                continue
            if mode == 0:
                a = first[v]
                b = satsum[v]
            elif mode == 1:
                a = nforb[v]
                b = satsum[v]
            elif mode == 3:
                a = -first[v]
                b = satsum[v]
            else:
                a = satsum[v]
                b = first[v]
            c = weight[v]
            d = tiebreak[v]
            if (best < 0 or a > k1 or (a == k1 and (b > k2 or (b == k2 and (
                    c > k3 or (c == k3 and d > k4)))))):
                best = v
                k1 = a
                k2 = b
                k3 = c
                k4 = d
        col = first[best]
        colours[best] = col
        for idx in range(indptr[best], indptr[best + 1]):
            u = adj[idx]
            if colours[u] >= 0:
                continue
            s = adjsep[idx]
            satsum[u] += s
            lo = max(0, col - s + 1)
            hi = min(width, col + s)
            for k in range(lo, hi):
                if forbid[u, k] == 0:
                    nforb[u] += 1
                forbid[u, k] += 1
            while forbid[u, first[u]] > 0:
                first[u] += 1
    return colours


@njit(cache=True)
def _first_fit_kernel(indptr, adj, adjsep, order, width):  # pragma: no cover - jit
    """Greedy first fit in a given vertex order.

    Parameters
    ----------
    indptr, adj, adjsep : ndarray of int64
        The conflict graph in CSR form, as for :func:`_dsatur_kernel`.
    order : ndarray of int64, shape (n,)
        Vertices in the order they are coloured.
    width : int
        Colour array width; must exceed every possible greedy colour.

    Returns
    -------
    colours : ndarray of int64, shape (n,)

    Notes
    -----
    Fed the vertices in increasing order of an optimal colouring's colours,
    first fit gives every vertex a colour no larger than its optimal one
    (by induction: each earlier neighbour sits at or below its optimal colour,
    so the optimal colour is still free), so it never increases a span.
    """
    n = indptr.shape[0] - 1
    colours = -np.ones(n, np.int64)
    free = np.ones(width, np.bool_)
    for v in order:
        touched_lo = width
        touched_hi = 0
        for idx in range(indptr[v], indptr[v + 1]):
            u = adj[idx]
            cu = colours[u]
            if cu < 0:
                continue
            s = adjsep[idx]
            lo = max(0, cu - s + 1)
            hi = min(width, cu + s)
            for k in range(lo, hi):
                free[k] = False
            touched_lo = min(touched_lo, lo)
            touched_hi = max(touched_hi, hi)
        k = 0
        while not free[k]:
            k += 1
        colours[v] = k
        for j in range(touched_lo, touched_hi):
            free[j] = True
    return colours


@njit(cache=True)
def _order_search_kernel(indptr, adj, adjsep, order, n_iters, seed, history, width,
                         target):  # pragma: no cover - jit
    """Late-acceptance hill climbing over vertex orders decoded by first fit.

    A state is a vertex order; its colouring is first fit in that order
    (:func:`_first_fit_kernel`), which reaches every optimal colouring from
    some order.  Moves: move one vertex to another position, or reverse a
    segment (2-opt; on a clique with metric separations the problem is a
    shortest Hamiltonian path and these are its classic moves).  Cost:
    span, then the sum of colours (a gradient towards compact colourings on
    the span's plateaus).  A move is accepted when it is no worse than the
    current cost or than the cost ``history`` iterations ago (Burke & Bykov's
    late acceptance).

    Parameters
    ----------
    indptr, adj, adjsep : ndarray of int64
        The conflict graph in CSR form.
    order : ndarray of int64, shape (n,)
        Start order.
    n_iters : int
        Moves to try.
    seed : int
        Seed of numba's generator.
    history : int
        Late-acceptance list length.
    width : int
        Colour array width; must exceed every possible greedy colour.
    target : int
        Stop as soon as the span reaches this [channels].

    Returns
    -------
    best : ndarray of int64, shape (n,)
        The best order met.
    best_span : int
        Its first-fit span [channels].
    """
    np.random.seed(seed)
    n = order.shape[0]
    cur = order.copy()
    col = _first_fit_kernel(indptr, adj, adjsep, cur, width)
    scale = np.int64(n) * np.int64(width)
    cost = (col.max() + 1) * scale + col.sum()
    best = cur.copy()
    best_cost = cost
    hist = np.full(history, cost, np.int64)
    trial = np.empty(n, np.int64)
    if n < 3:
        return best, col.max() + 1
    for it in range(n_iters):
        i = np.random.randint(n)
        j = np.random.randint(n - 1)
        if j >= i:
            j += 1
        if np.random.randint(2) == 0:
            # move the vertex at position i to position j
            x = cur[i]
            if i < j:
                trial[:i] = cur[:i]
                trial[i:j] = cur[i + 1:j + 1]
                trial[j] = x
                trial[j + 1:] = cur[j + 1:]
            else:
                trial[:j] = cur[:j]
                trial[j] = x
                trial[j + 1:i + 1] = cur[j:i]
                trial[i + 1:] = cur[i + 1:]
        else:
            a = min(i, j)
            b = max(i, j)
            trial[:] = cur
            trial[a:b + 1] = cur[a:b + 1][::-1]
        col = _first_fit_kernel(indptr, adj, adjsep, trial, width)
        c = (col.max() + 1) * scale + col.sum()
        slot = it % history
        if c <= cost or c <= hist[slot]:
            cur[:] = trial
            cost = c
            if c < best_cost:
                best_cost = c
                best[:] = cur
                if best_cost // scale <= target:
                    break
        hist[slot] = cost
    return best, best_cost // scale


@njit(cache=True)
def _violation_table(indptr, adj, adjsep, colours, n_colours):  # pragma: no cover - jit
    """gamma[v, k]: total separation shortfall of vertex v if it had colour k.

    Parameters
    ----------
    indptr, adj, adjsep : ndarray of int64
        The conflict graph in CSR form.
    colours : ndarray of int64, shape (n,)
        Current colours, each in [0, n_colours).
    n_colours : int
        Number of colours K (the target span).

    Returns
    -------
    gamma : ndarray of int64, shape (n, n_colours)
        ``sum over neighbours u of max(0, sep(u, v) - |k - c(u)|)`` [channels].
    """
    n = indptr.shape[0] - 1
    gamma = np.zeros((n, n_colours), np.int64)
    for v in range(n):
        for idx in range(indptr[v], indptr[v + 1]):
            cu = colours[adj[idx]]
            s = adjsep[idx]
            for k in range(max(0, cu - s + 1), min(n_colours, cu + s)):
                gamma[v, k] += s - abs(k - cu)
    return gamma


@njit(cache=True)
def _tabu_kernel(indptr, adj, adjsep, colours, tabu, it0, n_iters, n_colours, seed,
                 tenure_random, tenure_factor):  # pragma: no cover - jit
    """Tabu search for a colouring with colours in [0, n_colours) and no conflict.

    Minimises the total separation shortfall f = sum over edges of
    max(0, sep - |c(u) - c(v)|) by one-vertex recolourings of conflicting
    vertices (the neighbourhood of Lai & Lu [2]), with a tabu list on
    (vertex, old colour) pairs and the aspiration criterion "better than the
    best so far".

    Parameters
    ----------
    indptr, adj, adjsep : ndarray of int64
        The conflict graph in CSR form.
    colours : ndarray of int64, shape (n,)
        Start state; updated in place to the state after the last iteration.
    tabu : ndarray of int64, shape (n, n_colours)
        Iteration until which each (vertex, colour) move is tabu; updated in
        place so that a search can continue over several calls.
    it0 : int
        Iteration counter at entry.
    n_iters : int
        Iterations to run at most.
    n_colours : int
        Number of colours K.
    seed : int
        Seed of numba's generator for tie-breaks and tenures.
    tenure_random, tenure_factor : int, float
        Tenure = randint(0, tenure_random) + tenure_factor * conflicting vertices.

    Returns
    -------
    best_f : int
        Smallest shortfall met [channels]; 0 means a valid colouring.
    best : ndarray of int64, shape (n,)
        The state with ``best_f``.
    it : int
        Iteration counter at exit.
    """
    np.random.seed(seed)
    n = indptr.shape[0] - 1
    gamma = _violation_table(indptr, adj, adjsep, colours, n_colours)
    f = 0
    for v in range(n):
        f += gamma[v, colours[v]]
    f //= 2
    best_f = f
    best = colours.copy()
    it = it0
    end = it0 + n_iters
    big = np.int64(1) << 62
    while it < end and best_f > 0:
        best_delta = big
        count = 0
        mv = -1
        mk = -1
        nconf = 0
        for v in range(n):
            g0 = gamma[v, colours[v]]
            if g0 == 0:
                continue
            nconf += 1
            cv = colours[v]
            for k in range(n_colours):
                if k == cv:
                    continue
                d = gamma[v, k] - g0
                if tabu[v, k] > it and f + d >= best_f:
                    continue
                if d < best_delta:
                    best_delta = d
                    mv = v
                    mk = k
                    count = 1
                elif d == best_delta:
                    count += 1
                    if np.random.randint(count) == 0:
                        mv = v
                        mk = k
        if mv < 0:
            # every move is tabu: take a random recolouring of a conflicting vertex
            pick = np.random.randint(nconf)
            for v in range(n):
                if gamma[v, colours[v]] > 0:
                    if pick == 0:
                        mv = v
                        break
                    pick -= 1
            mk = np.random.randint(n_colours - 1)
            if mk >= colours[mv]:
                mk += 1
            best_delta = gamma[mv, mk] - gamma[mv, colours[mv]]
        old = colours[mv]
        for idx in range(indptr[mv], indptr[mv + 1]):
            u = adj[idx]
            s = adjsep[idx]
            for k in range(max(0, old - s + 1), min(n_colours, old + s)):
                gamma[u, k] -= s - abs(k - old)
            for k in range(max(0, mk - s + 1), min(n_colours, mk + s)):
                gamma[u, k] += s - abs(k - mk)
        colours[mv] = mk
        f += best_delta
        tabu[mv, old] = it + np.random.randint(tenure_random + 1) + int(tenure_factor * nconf)
        it += 1
        if f < best_f:
            best_f = f
            best[:] = colours
    return best_f, best, it


@njit(cache=True)
def _clique_span_kernel(w, best):  # pragma: no cover - jit
    """Exact span of a clique with separations, by branch and bound.

    Parameters
    ----------
    w : ndarray of int64, shape (k, k)
        Symmetric separations between the clique's vertices [channels].
    best : int
        A span known to be achievable (or larger); only smaller ones are
        searched for.

    Returns
    -------
    span : int
        The smallest span of the clique alone (``best`` if none is smaller).

    Notes
    -----
    In a clique all colours differ, so a colouring is a colour order plus
    gaps; for a fixed order, placing every vertex as low as its already placed
    neighbours allow is optimal.  The search enumerates orders depth first
    and prunes with the lowest colours the placed vertices leave to the others,
    which must also be pairwise at least the clique's smallest separation apart.
    """
    k = w.shape[0]
    if k == 0:
        return 0
    gmin = w[0, 1] if k > 1 else 0
    for i in range(k):
        for j in range(i + 1, k):
            if w[i, j] < gmin:
                gmin = w[i, j]
    order = np.empty(k, np.int64)
    col = np.empty(k, np.int64)
    top = np.empty(k, np.int64)  # highest colour among the first d+1 placed
    used = np.zeros(k, np.bool_)
    nxt = np.zeros(k + 1, np.int64)
    d = 0
    while d >= 0:
        if nxt[d] >= k:
            d -= 1
            if d >= 0:
                used[order[d]] = False
                nxt[d] += 1
            continue
        t = nxt[d]
        if used[t]:
            nxt[d] += 1
            continue
        c = 0
        for j in range(d):
            cj = col[j] + w[order[j], t]
            if cj > c:
                c = cj
        hi = c if d == 0 else max(c, top[d - 1])
        remaining = k - d - 1
        bound = hi + 1
        if remaining > 0:
            # f[u]: lowest colour the placed vertices allow u.  The vertices
            # with f >= f_(i) (the i-th smallest) need distinct slots >= gmin
            # apart from f_(i) up, so the top is >= f_(i) + (their count - 1) gmin.
            f = np.empty(remaining, np.int64)
            r = 0
            for u in range(k):
                if used[u] or u == t:
                    continue
                fu = c + w[t, u]
                for j in range(d):
                    fj = col[j] + w[order[j], u]
                    if fj > fu:
                        fu = fj
                f[r] = fu
                r += 1
            f = np.sort(f)
            for i in range(remaining):
                b2 = f[i] + 1 + (remaining - 1 - i) * gmin
                if b2 > bound:
                    bound = b2
        if bound >= best:
            nxt[d] += 1
            continue
        if remaining == 0:
            best = hi + 1
            nxt[d] += 1
            continue
        order[d] = t
        col[d] = c
        top[d] = hi
        used[t] = True
        d += 1
        nxt[d] = 0
    return best


@njit(cache=True)
def _clique_greedy_span_kernel(w):  # pragma: no cover - jit
    """A span achievable on a clique: best nearest-neighbour colour order.

    Parameters
    ----------
    w : ndarray of int64, shape (k, k)
        Symmetric separations among the clique's vertices [channels].

    Returns
    -------
    span : int
        Smallest span over the k start vertices, each vertex then placed
        next whose lowest allowed colour is smallest [channels].  An upper
        bound on the clique's exact span: cliques whose upper bound cannot
        beat the current lower bound need no exact search.
    """
    k = w.shape[0]
    best = np.int64(1) << 62
    col = np.empty(k, np.int64)
    used = np.zeros(k, np.bool_)
    low = np.empty(k, np.int64)
    for start in range(k):
        used[:] = False
        low[:] = 0
        top = 0
        t = start
        for step in range(k):
            c = low[t]
            col[t] = c
            used[t] = True
            if c > top:
                top = c
            nxt = -1
            for u in range(k):
                if used[u]:
                    continue
                if c + w[t, u] > low[u]:
                    low[u] = c + w[t, u]
                if nxt < 0 or low[u] < low[nxt]:
                    nxt = u
            t = nxt
        if top + 1 < best:
            best = top + 1
    return best


# --------------------------------------------------------------------------
# The problem in array form
# --------------------------------------------------------------------------


class _Problem:
    """A conflict graph in index form: vertices 0..n-1, each edge once (u < v).

    Attributes
    ----------
    nodes : list
        Graph nodes; vertex i is ``nodes[i]``.
    eu, ev, es : ndarray of int64, shape (m,)
        Edge endpoints (eu < ev) and separations (>= 1) [channels].
    indptr, adj, adjsep : ndarray of int64
        CSR adjacency, shapes (n + 1,), (2 m,), (2 m,).
    """

    def __init__(self, nodes, edges: dict[tuple[int, int], int]):
        self.nodes = nodes
        self.n = len(nodes)
        keys = sorted(edges)
        self.eu = np.array([a for a, _ in keys], np.int64)
        self.ev = np.array([b for _, b in keys], np.int64)
        self.es = np.array([edges[k] for k in keys], np.int64)
        self.m = len(keys)
        src = np.concatenate([self.eu, self.ev])
        dst = np.concatenate([self.ev, self.eu])
        sep = np.concatenate([self.es, self.es])
        order = np.lexsort((dst, src))
        self.adj = dst[order].astype(np.int64)
        self.adjsep = sep[order].astype(np.int64)
        counts = np.bincount(src, minlength=self.n) if self.m else np.zeros(self.n, np.int64)
        self.indptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        self.weight = np.zeros(self.n, np.int64)
        if self.m:
            np.add.at(self.weight, self.eu, self.es)
            np.add.at(self.weight, self.ev, self.es)
        # no greedy colour can exceed sum over neighbours of (2 sep - 1)
        per_vertex = np.zeros(self.n, np.int64)
        if self.m:
            np.add.at(per_vertex, self.eu, 2 * self.es - 1)
            np.add.at(per_vertex, self.ev, 2 * self.es - 1)
        self.width = int(per_vertex.max(initial=0)) + 2

    @classmethod
    def from_graph(cls, graph, separation: str) -> "_Problem":
        _check_graph(graph, separation)
        nodes = list(graph.nodes)
        index = {node: i for i, node in enumerate(nodes)}
        edges: dict[tuple[int, int], int] = {}
        for u, v, value in graph.edges(data=separation, default=1):
            s = _check_separation(value, u, v, separation)
            if u == v or s == 0:
                continue  # self-loops are node weights; sep 0 constrains nothing
            a, b = index[u], index[v]
            key = (a, b) if a < b else (b, a)
            edges[key] = max(s, edges.get(key, 0))
        return cls(nodes, edges)

    def sep_matrix(self, members) -> np.ndarray:
        """Separations among ``members`` (0 off the graph), shape (k, k)."""
        members = list(members)
        pos = {v: i for i, v in enumerate(members)}
        w = np.zeros((len(members), len(members)), np.int64)
        for v in members:
            for idx in range(self.indptr[v], self.indptr[v + 1]):
                u = int(self.adj[idx])
                if u in pos:
                    w[pos[v], pos[u]] = self.adjsep[idx]
        return w

    def index_graph(self) -> nx.Graph:
        """The graph on vertex indices 0..n-1, without separations."""
        g = nx.Graph()
        g.add_nodes_from(range(self.n))
        g.add_edges_from(zip(self.eu.tolist(), self.ev.tolist()))
        return g

    def to_dict(self, colours) -> dict:
        return {node: int(c) for node, c in zip(self.nodes, colours)}

    def shortfall(self, colours) -> int:
        """Total separation shortfall of an index colouring [channels]."""
        if self.m == 0:
            return 0
        gap = np.abs(colours[self.eu] - colours[self.ev])
        return int(np.maximum(0, self.es - gap).sum())


def _check_graph(graph, separation) -> None:
    if not isinstance(graph, nx.Graph):
        raise ValueError(f"graph must be a networkx graph, {type(graph).__name__} was given")
    if not isinstance(separation, str):
        raise ValueError(f"separation must be an edge attribute name, {separation!r} was given")


def _check_separation(value, u, v, separation) -> int:
    bad = isinstance(value, bool) or not isinstance(value, numbers.Real)
    if not bad and not isinstance(value, numbers.Integral):
        bad = not (math.isfinite(value) and float(value).is_integer())
    if bad:
        raise ValueError(
            f"edge ({u!r}, {v!r}): separation {separation!r} must be a non-negative "
            f"integer, {value!r} was given")
    s = int(value)
    if s < 0:
        raise ValueError(
            f"edge ({u!r}, {v!r}): separation {separation!r} must be a non-negative "
            f"integer, {value!r} was given")
    return s


def _span_of(colours) -> int:
    return int(colours.max()) + 1 if len(colours) else 0


# --------------------------------------------------------------------------
# Lower bounds
# --------------------------------------------------------------------------


@njit(cache=True)
def _held_karp_kernel(w, steps):  # pragma: no cover - jit
    """Lagrangian (1-tree) lower bound on the shortest Hamiltonian path.

    Parameters
    ----------
    w : ndarray of int64, shape (k, k)
        Symmetric edge costs (separations) [channels].
    steps : int
        Subgradient steps.

    Returns
    -------
    bound : float
        A lower bound on the cheapest path through all k vertices [channels].

    Notes
    -----
    The path becomes a tour by adding a vertex joined at cost 0 to all; the
    1-tree rooted there is a minimum spanning tree of the k vertices plus
    the extra vertex's two cheapest links, under node potentials pi that a
    subgradient method tunes (Held & Karp, 1970): bound = 1-tree cost - 2 sum pi.
    """
    k = w.shape[0]
    if k < 2:
        return 0.0
    pi = np.zeros(k)
    best = -np.inf
    mean = 0.0
    for i in range(k):
        for j in range(k):
            mean += w[i, j]
    step = 0.1 * mean / (k * (k - 1))
    dist = np.empty(k)
    parent = np.empty(k, np.int64)
    in_tree = np.empty(k, np.bool_)
    deg = np.empty(k, np.int64)
    for _ in range(steps):
        in_tree[:] = False
        deg[:] = 0
        in_tree[0] = True
        for j in range(k):
            dist[j] = w[0, j] + pi[0] + pi[j]
            parent[j] = 0
        total = 0.0
        for _ in range(k - 1):
            j = -1
            for u in range(k):
                if not in_tree[u] and (j < 0 or dist[u] < dist[j]):
                    j = u
            total += dist[j]
            deg[j] += 1
            deg[parent[j]] += 1
            in_tree[j] = True
            for u in range(k):
                if not in_tree[u]:
                    cu = w[j, u] + pi[j] + pi[u]
                    if cu < dist[u]:
                        dist[u] = cu
                        parent[u] = j
        # the extra vertex links to the two vertices of smallest potential
        a = 0 if pi[0] <= pi[1] else 1
        b = 1 - a
        for u in range(2, k):
            if pi[u] < pi[a]:
                b = a
                a = u
            elif pi[u] < pi[b]:
                b = u
        total += pi[a] + pi[b]
        deg[a] += 1
        deg[b] += 1
        value = total - 2.0 * pi.sum()
        if value > best:
            best = value
        done = True
        for u in range(k):
            if deg[u] != 2:
                done = False
            pi[u] += step * (deg[u] - 2)
        if done:
            break
        step *= 0.98
    return best


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


# --------------------------------------------------------------------------
# Heuristic
# --------------------------------------------------------------------------


def _as_rng(seed) -> np.random.Generator:
    """The one place a ``seed`` (int, Generator or None) becomes a generator."""
    if isinstance(seed, np.random.Generator):
        return seed
    if seed is None:
        seed = DEFAULT_SEED
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral):
        raise ValueError(f"seed must be an int, a numpy Generator or None, {seed!r} was given")
    return np.random.default_rng(int(seed))


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


# --------------------------------------------------------------------------
# Exact MILP
# --------------------------------------------------------------------------



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


# --------------------------------------------------------------------------
# Results and strategies
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class ColoringResult:
    """A bandwidth colouring and what is known about its quality.

    Attributes
    ----------
    coloring : dict
        Node -> colour (channel index, int >= 0; the smallest used is 0).
    span : int
        Largest colour + 1 [channels].
    lower_bound : int
        Proven lower bound on the optimal span [channels].
    optimal : bool
        True when ``span`` is proven optimal (``span == lower_bound``).
    method : str
        Strategy that produced the colouring (``"dsatur"``, ``"milp"``, or a
        user callable's name).
    seconds : float
        Wall-clock time [s].
    message : str
        How the search ended, in words.
    """

    coloring: dict
    span: int
    lower_bound: int
    optimal: bool
    method: str
    seconds: float
    message: str = ""


def _result(problem, colours, lower, method, t0, message) -> ColoringResult:
    s = _span_of(colours)
    return ColoringResult(problem.to_dict(colours), s, lower, s == lower, method,
                          time.perf_counter() - t0, message)


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


# --------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------


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


class Violation(NamedTuple):
    """One broken requirement of a colouring.

    ``v`` is None for a vertex-level problem (missing or invalid colour);
    otherwise ``required`` is the separation and ``actual`` the colour gap
    [channels].
    """

    u: Any
    v: Any
    required: Any
    actual: Any

    def __str__(self) -> str:
        if self.v is None:
            return f"node {self.u!r}: colour {self.actual!r} ({self.required})"
        return (f"edge ({self.u!r}, {self.v!r}): colours {self.actual} apart, "
                f"separation {self.required} required")


def verify_coloring(graph: nx.Graph, coloring: dict, separation: str = "sep") -> list:
    """All the ways ``coloring`` breaks the bandwidth-colouring rules.

    An independent checker (it shares no code with the solvers): every node
    needs an integer colour >= 0, and every non-loop edge ``|c(u) - c(v)| >=
    sep(u, v)`` (sep 1 when the attribute is missing).

    Parameters
    ----------
    graph : networkx.Graph
        Conflict graph.
    coloring : dict
        Node -> colour.
    separation : str, default "sep"
        Edge attribute holding the separation [channels].

    Returns
    -------
    list of Violation
        Empty when the colouring is valid.

    Examples
    --------
    >>> import networkx as nx
    >>> g = nx.Graph([(1, 2, {"sep": 3})])
    >>> verify_coloring(g, {1: 0, 2: 3}), len(verify_coloring(g, {1: 0, 2: 2}))
    ([], 1)
    """
    out = []
    for node in graph.nodes:
        c = coloring.get(node)
        if c is None:
            out.append(Violation(node, None, "no colour", c))
        elif isinstance(c, bool) or not isinstance(c, numbers.Integral) or c < 0:
            out.append(Violation(node, None, "not a non-negative integer", c))
    for u, v, s in graph.edges(data=separation, default=1):
        if u == v:
            continue
        cu, cv = coloring.get(u), coloring.get(v)
        if not (isinstance(cu, numbers.Integral) and isinstance(cv, numbers.Integral)):
            continue
        if abs(int(cu) - int(cv)) < s:
            out.append(Violation(u, v, s, abs(int(cu) - int(cv))))
    return out


def span(coloring: dict) -> int:
    """Largest colour + 1 [channels]; 0 for an empty colouring.

    Examples
    --------
    >>> span({"a": 0, "b": 4})
    5
    """
    return max(coloring.values()) + 1 if coloring else 0


def read_band(path) -> nx.Graph:
    """Read a bandwidth-colouring instance in the DIMACS-like ``band`` format.

    Lines: ``c ...`` comments, ``p band V E`` (once, before any edge),
    ``e i j d`` an edge with separation ``d`` between 1-based vertices ``i``
    and ``j``, ``n i w`` a node weight.  Self-loops ``e i i w`` and ``n``
    lines are node weights of the multicolouring variant and are ignored.
    ``E`` counts every ``e`` line, self-loops included (as in the GEOM files).

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Returns
    -------
    networkx.Graph
        Nodes 1..V (ints); edge attribute ``"sep"`` [channels].  A repeated
        edge keeps its largest separation.

    Raises
    ------
    ValueError
        A malformed file, naming the line number.
    FileNotFoundError
        ``path`` does not exist.
    """
    path = Path(path)
    graph = None
    declared = 0
    n_edges = 0
    with path.open(encoding="utf-8", errors="replace") as fh:
        for lineno, raw in enumerate(fh, start=1):
            parts = raw.split()
            if not parts or parts[0].startswith("c"):
                continue

            def fail(why):
                raise ValueError(f"{path.name}: line {lineno}: {why}: {raw.strip()!r}")

            def ints(tokens):
                try:
                    return [int(t) for t in tokens]
                except ValueError:
                    fail("expected integers")

            kind = parts[0]
            if kind == "p":
                if graph is not None:
                    fail("second 'p' line")
                if len(parts) != 4 or parts[1] not in ("band", "edge", "col"):
                    fail("expected 'p band <vertices> <edges>'")
                n, declared = ints(parts[2:])
                if n < 0 or declared < 0:
                    fail("negative count")
                graph = nx.Graph()
                graph.add_nodes_from(range(1, n + 1))
            elif kind == "e":
                if graph is None:
                    fail("edge before the 'p' line")
                if len(parts) not in (3, 4):
                    fail("expected 'e <i> <j> <separation>'")
                i, j, *rest = ints(parts[1:])
                d = rest[0] if rest else 1
                n = graph.number_of_nodes()
                if not (1 <= i <= n and 1 <= j <= n):
                    fail(f"vertex out of range 1..{n}")
                if d < 0:
                    fail("negative separation")
                n_edges += 1
                if i == j:
                    continue
                if graph.has_edge(i, j):
                    d = max(d, graph[i][j]["sep"])
                graph.add_edge(i, j, sep=d)
            elif kind == "n":
                if graph is None:
                    fail("node line before the 'p' line")
                if len(parts) != 3:
                    fail("expected 'n <i> <weight>'")
                i, _ = ints(parts[1:])
                if not 1 <= i <= graph.number_of_nodes():
                    fail(f"vertex out of range 1..{graph.number_of_nodes()}")
            else:
                fail(f"unknown line type {kind!r}")
    if graph is None:
        raise ValueError(f"{path.name}: no 'p band <vertices> <edges>' line")
    if n_edges != declared:
        raise ValueError(f"{path.name}: the 'p' line declares {declared} edges, the file "
                         f"has {n_edges} 'e' lines")
    return graph
