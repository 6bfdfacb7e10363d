"""Numba kernels of the bandwidth colouring's cliques: the exact span of a small clique by
branch and bound over colour orders, an achievable span, and the Held-Karp lower bound.

Each takes the dense separation matrix ``w`` (int64, shape (k, k)) of one clique.
Nothing here knows of networkx, SciPy or the bounds that call these kernels.
"""

from __future__ import annotations

import numpy as np

# before the kernels are decorated: an installed copy caches outside site-packages
from model.numba_cache import cache_outside_installed_copy

cache_outside_installed_copy()

from numba import njit  # noqa: E402


# --------------------------------------------------------------------------
# Cliques: exact span, achievable span, Held-Karp bound
# --------------------------------------------------------------------------


@njit(cache=True, nogil=True)
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


@njit(cache=True, nogil=True)
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


@njit(cache=True, nogil=True)
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
