"""Bandwidth colouring: integer channels with per-edge separations.

Every impacter of an array gets a drive channel (an integer colour).  Two
impacters joined by an edge of the conflict graph need channels at least
``sep`` apart, ``|c(u) - c(v)| >= sep(u, v)``, so that driving one never
resonates the other.  The *span* of a colouring is its largest colour plus one:
the number of channels the drive band must hold.  Minimising the span is the
bandwidth colouring problem (a generalisation of graph colouring, NP-hard);
the GEOM instances of Trick / Phan & Skiena are its standard benchmark.

Layout of this package (each module imports only those listed above it)

- :mod:`~planner.coloring.kernels`: numba kernels (``_*_kernel``), plain
  functions of int64 arrays -- the graph in CSR form (``indptr``, ``adj``,
  ``adjsep``) and colour vectors.  They know nothing of networkx and are
  documented with their array shapes.  :mod:`~planner.coloring.cliques`: the
  clique kernels (exact span, achievable span, Held-Karp), of a dense separation
  matrix.
- :mod:`~planner.coloring.problem`: ``_Problem``, the networkx graph turned
  into those arrays once, with the validation of the caller's graph.
- :mod:`~planner.coloring.bounds`: exact spans of small cliques (branch and
  bound over colour orders) and a Held-Karp (1-tree) bound on the shortest
  Hamiltonian path of large cliques.
- :mod:`~planner.coloring.heuristic`: DSATUR-style greedy restarts, a
  late-acceptance search over first-fit vertex orders, then iterated tabu
  search at decreasing spans.
- :mod:`~planner.coloring.milp`: the exact step, a scipy/HiGHS MILP per
  connected component below the heuristic's span.
- :mod:`~planner.coloring.result`: :class:`ColoringResult`.
- :mod:`~planner.coloring.strategies`: the strategies, registered in
  :data:`STRATEGIES`: ``"dsatur"`` (the heuristic), ``"milp"`` / ``"exact"``
  (heuristic warm start, then the MILP) and ``"auto"``.
- :mod:`~planner.coloring.verify`: :func:`verify_coloring` and :func:`span`,
  an independent checker that shares no code with the solvers.
- :mod:`~planner.coloring.band_file`: :func:`read_band`, the GEOM file format.
- :mod:`~planner.coloring.solve`: the public API, :func:`solve_bandwidth` and
  :func:`color_bandwidth`.

Colours are channel indices (dimensionless integers, 0-based); nothing in this
package knows about hertz.  The caller maps channel ``k`` to a frequency.

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

from planner.coloring.band_file import read_band
from planner.coloring.result import ColoringResult
from planner.coloring.solve import color_bandwidth, solve_bandwidth
from planner.coloring.strategies import STRATEGIES
from planner.coloring.verify import Violation, span, verify_coloring


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
