"""The drawing's primitives: polygons on masks, text labels, cells and their placements.

A :class:`Shape` is one polygon on one mask, a :class:`Cell` a named set of shapes,
labels and :class:`Placement` s of other cells (the GDSII model, without its file
format: :mod:`planner.layout.gds` writes it).  The helpers draw the rectangles, bars,
anchor cuts and dimple grids the cantilevers, sliders and guides are made of, in
metres, counter-clockwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planner.core.units import UM

#: Side of an anchor cut (ANCHOR1, ANCHOR2) [m], at least a line.
ANCHOR_CUT = 5.0 * UM
#: Side of a dimple [m] (at least a line) and the pitch of the dimple grids under
#: plates and sliders [m].
DIMPLE_SIDE = 3.0 * UM
DIMPLE_PITCH = 40.0 * UM


@dataclass(frozen=True)
class Shape:
    """One polygon on one mask.

    Attributes
    ----------
    layer : str
        Mask name, a key of :attr:`LayoutRules.layers`.
    points : ndarray, shape (n, 2)
        Vertices [m], counter-clockwise.
    """

    layer: str
    points: np.ndarray


@dataclass(frozen=True)
class Text:
    """A text label (no geometry): ``text`` at ``origin`` [m] on mask ``layer``."""

    text: str
    origin: tuple
    layer: str = "LABEL"


@dataclass(frozen=True)
class Placement:
    """An instance of cell ``cell``: reflected across x (``x_reflection``), rotated by
    ``rotation`` [rad], moved to ``origin`` [m], in that order (the GDSII order)."""

    cell: str
    origin: tuple = (0.0, 0.0)
    rotation: float = 0.0
    x_reflection: bool = False

    def apply(self, points) -> np.ndarray:
        """``points`` (n, 2) of the cell [m] in the parent's frame [m]."""
        p = np.array(points, dtype=float).reshape(-1, 2)
        if self.x_reflection:
            p[:, 1] = -p[:, 1]
        c, s = math.cos(self.rotation), math.sin(self.rotation)
        return p @ np.array([[c, s], [-s, c]]) + np.asarray(self.origin, dtype=float)


@dataclass(frozen=True)
class Cell:
    """A named cell: its own shapes and texts, and placements of other cells."""

    name: str
    shapes: tuple = ()
    texts: tuple = ()
    placements: tuple = ()


def rect(x0, y0, x1, y1) -> np.ndarray:
    """The rectangle (x0, y0)-(x1, y1) [m], counter-clockwise from (x0, y0)."""
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)


def bar(base, along, width, length) -> np.ndarray:
    """Rectangle ``width`` across and ``length`` along the unit vector ``along``, its
    base edge centred on ``base`` (counter-clockwise)."""
    a = np.asarray(along, dtype=float)
    n = np.array([a[1], -a[0]]) * (width / 2.0)
    b = np.asarray(base, dtype=float)
    return np.array([b - n, b + n, b + n + a * length, b - n + a * length])


def dimples(x0, y0, x1, y1, rules) -> list:
    """A grid of dimples inside the box, each at least the enclosure from its edges."""
    side = max(DIMPLE_SIDE, rules.min_line)
    inset = rules.anchor_enclosure + side / 2.0
    out = []
    spans = []
    for lo, hi in ((x0 + inset, x1 - inset), (y0 + inset, y1 - inset)):
        if hi < lo:
            return out
        n = int((hi - lo) // DIMPLE_PITCH) + 1
        start = (lo + hi) / 2.0 - (n - 1) * DIMPLE_PITCH / 2.0
        spans.append([start + i * DIMPLE_PITCH for i in range(n)])
    h = side / 2.0
    for y in spans[1]:
        for x in spans[0]:
            out.append(Shape("DIMPLE", rect(x - h, y - h, x + h, y + h)))
    return out


def polygon_area(points) -> float:
    """Area of a simple polygon [m^2] (the shoelace formula)."""
    x, y = points[:, 0], points[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def distinct(points) -> np.ndarray:
    """``points`` without vertices repeating their predecessor (cyclically)."""
    keep = np.any(np.abs(points - np.roll(points, 1, axis=0)) > 1e-15, axis=1)
    return points[keep]
