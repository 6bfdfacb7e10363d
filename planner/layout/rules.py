"""The process's layout rules in SI units, and what they ask of the designer's bounds.

A spec's ``process`` section carries the rules of its fabrication process:
``min_line_um`` (the narrowest line of a structural layer), ``min_space_um`` (the
narrowest space between two structures of one layer) and ``anchor_enclosure_um`` (how
far a structural layer must reach beyond an anchor cut), with ``layers``, the GDSII
layer of every mask.  :class:`LayoutRules` holds them in SI for the layout and its
check; :func:`narrow_bounds` is how they reach the designer.

Two designed quantities meet a rule in the drawing:

- the beam width w is a POLY1 line: w >= min_line;
- the impacter's tip is a POLY1 corner at a distance c from its slider wall measured
  along the impacter's motion, which meets the wall at the impact angle theta (the
  paper's Fig. 6), so the drawn space between tip and wall is c sin(theta):
  c >= min_space / sin(theta).

Everything else the layout draws (anchors, joints, guides, tabs) is sized from the
rules themselves and meets them by construction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from planner.units import UM

#: The paper's minimum feature of the MUMPs process (Section III-C, the lower bounds
#: (17)) [m]: the line and space rule of a spec that sets neither.
PAPER_MIN_FEATURE = 2.0 * UM


class RuleBoundsError(ValueError):
    """A process rule no design inside the designer's bounds can meet.

    ``field`` is the spec field at fault, as a path tuple (``("process",
    "min_line_um")``), for a :class:`planner.errors.SpecError` with its YAML line.
    """

    def __init__(self, field: tuple, message: str):
        self.field = field
        super().__init__(message)


@dataclass(frozen=True)
class LayoutRules:
    """Design rules and layer map of a process, SI.

    Attributes
    ----------
    min_line : float
        Minimum line width of the structural layers [m].
    min_space : float
        Minimum space between two structures of one layer [m].
    anchor_enclosure : float
        How far POLY0, POLY1 and POLY2 reach beyond an anchor cut, and POLY1 and POLY2
        beyond a via or a dimple [m].
    layers : dict
        Mask name -> (GDSII layer, datatype).
    """

    min_line: float
    min_space: float
    anchor_enclosure: float
    layers: dict

    @classmethod
    def from_process(cls, process) -> "LayoutRules":
        """The rules of a :class:`planner.config.ProcessConfig`; unset line and space
        rules are the paper's minimum feature (:data:`PAPER_MIN_FEATURE`)."""
        line = process.min_line_um * UM if process.min_line_um is not None else PAPER_MIN_FEATURE
        space = (process.min_space_um * UM if process.min_space_um is not None
                 else PAPER_MIN_FEATURE)
        layers = {name: tuple(int(v) for v in getattr(process.layers, name))
                  for name in type(process.layers).model_fields}
        return cls(line, space, process.anchor_enclosure_um * UM, layers)


def narrow_bounds(bounds, process, impact_angles):
    """The designer's bounds narrowed so that every design inside them keeps the rules
    the spec sets.

    Parameters
    ----------
    bounds : planner.designer.DesignBounds
        The bounds from ``design.bounds`` (or the defaults).
    process : planner.config.ProcessConfig
        Only ``min_line_um`` and ``min_space_um`` count, and only when set: an unset
        rule leaves the bounds as they are (the paper's (17) already keeps w >= 2 um).
    impact_angles : iterable of float
        The impact angle theta of every impacter the bounds serve [rad]; the smallest
        sets the gap bound.

    Returns
    -------
    planner.designer.DesignBounds
        ``bounds`` itself when nothing narrows it.

    Raises
    ------
    RuleBoundsError
        A rule leaves no width or gap inside the bounds, naming the rule's field.

    Examples
    --------
    >>> import math
    >>> from planner.config import ProcessConfig
    >>> from planner.designer import DesignBounds
    >>> b = narrow_bounds(DesignBounds(), ProcessConfig(min_space_um=2.0), [math.pi / 4])
    >>> round(b.gap[0] / UM, 3)        # the tip clears the wall by c sin(45 deg) >= 2 um
    2.828
    """
    from dataclasses import replace

    width, gap = bounds.width, bounds.gap
    if process.min_line_um is not None:
        lo = max(width[0], process.min_line_um * UM)
        if lo >= width[1]:
            raise RuleBoundsError(
                ("process", "min_line_um"),
                f"{process.min_line_um:g} um leaves no beam width for the designer: the "
                f"beams may be at most {width[1] / UM:g} um wide (design.bounds.width_um)")
        width = (lo, width[1])
    if process.min_space_um is not None:
        sines = [math.sin(float(t)) for t in impact_angles]
        if not sines:
            raise ValueError("impact_angles is empty")
        sine = min(sines)
        if sine <= 0.0:
            raise RuleBoundsError(
                ("process", "min_space_um"),
                "an impacter with a 0 deg impact angle moves along its slider wall, so no "
                "gap keeps its tip a space away from it")
        lo = max(gap[0], process.min_space_um * UM / sine)
        if lo >= gap[1]:
            raise RuleBoundsError(
                ("process", "min_space_um"),
                f"{process.min_space_um:g} um leaves no gap for the designer: a tip at "
                f"impact angle {math.degrees(math.asin(sine)):g} deg clears its slider "
                f"wall by c sin(theta), so c must be at least {lo / UM:.3g} um, but "
                f"design.bounds.gap_um allows at most {gap[1] / UM:g} um")
        gap = (lo, gap[1])
    if width == bounds.width and gap == bounds.gap:
        return bounds
    return replace(bounds, width=width, gap=gap)
