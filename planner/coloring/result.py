"""What a strategy returns: :class:`ColoringResult`."""

from __future__ import annotations

import time
from dataclasses import dataclass

from planner.coloring.problem import _span_of


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
