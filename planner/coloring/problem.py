"""The conflict graph in array form, and validation of the caller's graph."""

from __future__ import annotations

import math
import numbers

import networkx as nx
import numpy as np


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
