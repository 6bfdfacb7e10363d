"""Numba kernels of the bandwidth colouring: plain functions of int64 arrays.

The conflict graph enters in CSR form -- ``indptr`` (shape (n + 1,)), ``adj`` and
``adjsep`` (shape (2 m,), neighbour indices and their separations [channels]) --
and colourings as int64 vectors of channel indices.  Clique kernels take the
dense separation matrix of the clique.  Nothing here knows of networkx, SciPy or
the strategies that call these kernels.
"""

from __future__ import annotations

import numpy as np

# before the kernels are decorated: an installed copy caches outside site-packages
from model.numba_cache import cache_outside_installed_copy

cache_outside_installed_copy()

from numba import njit  # noqa: E402


# --------------------------------------------------------------------------
# Greedy colourings and local search
# --------------------------------------------------------------------------


@njit(cache=True, nogil=True)
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


@njit(cache=True, nogil=True)
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


@njit(cache=True, nogil=True)
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


@njit(cache=True, nogil=True)
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


@njit(cache=True, nogil=True)
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
