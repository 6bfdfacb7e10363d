"""An independent checker of colourings: :func:`verify_coloring`, :func:`span`.

It shares no code with the solvers, so a solver bug cannot hide in it.
"""

from __future__ import annotations

import numbers
from typing import Any, NamedTuple

import networkx as nx


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
