"""Reader of the DIMACS-like ``band`` format of the GEOM instances: :func:`read_band`."""

from __future__ import annotations

from pathlib import Path

import networkx as nx


#: Memory of one vertex and one edge of the graph and the colouring's arrays [bytes]:
#: networkx keeps a dict per vertex and two dict entries per edge (upper estimates).
NODE_BYTES = 1024
EDGE_BYTES = 512


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
    from planner.files import read_input
    from planner.runtime.limits import check_memory

    path = Path(path)
    graph = None
    declared = 0
    n_edges = 0
    text = read_input(path).decode("utf-8", errors="replace")
    for lineno, raw in enumerate(text.splitlines(), start=1):
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
            check_memory(n * NODE_BYTES + declared * EDGE_BYTES,
                         f"{path.name}: line {lineno}: a graph of {n} vertices and "
                         f"{declared} edges")
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
