"""The process's layout rules in SI units.

A spec's ``process`` section carries the rules of its fabrication process:
``min_line_um`` (the narrowest line of a structural layer), ``min_space_um`` (the
narrowest space between two structures of one layer) and ``anchor_enclosure_um`` (how
far a structural layer must reach beyond an anchor cut), with ``layers``, the GDSII
layer of every mask.  :class:`LayoutRules` holds them in SI for the layout and its
check; :func:`planner.designer.bounds.narrow_bounds` is how they reach the designer
(the beam width w >= min_line, the tip's distance c >= min_space / sin(theta) from its
slider wall).  Everything else the layout draws (anchors, joints, guides, tabs) is sized
from the rules themselves and meets them by construction.
"""

from __future__ import annotations

from dataclasses import dataclass

from planner.core.units import UM

#: The paper's minimum feature of the MUMPs process (Section III-C, the lower bounds
#: (17)) [m]: the line and space rule of a spec that sets neither.
PAPER_MIN_FEATURE = 2.0 * UM


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
