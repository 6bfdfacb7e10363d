"""GDSII in and out (gdstk): a :class:`~planner.layout.geometry.ChipLayout` to a file, a
file to a :class:`gdstk.Library`.

The file's user unit is the micrometre and its database unit the nanometre (``unit
1e-6``, ``precision 1e-9``): the one place where the layout's metres become um.  Its
timestamp is fixed (:data:`TIMESTAMP`), so one plan gives one file, byte for byte.
"""

from __future__ import annotations

import datetime
from pathlib import Path

import numpy as np

from planner.core.units import UM

#: GDSII user unit [m] and database unit (precision) [m].
UNIT = UM
PRECISION = 1e-9
#: The modification and access time written into every file: a fixed date, so that
#: the same plan gives the same bytes.
TIMESTAMP = datetime.datetime(2000, 1, 1)
#: The GDSII library name.
LIBRARY = "VIBROPLAN"


def to_library(chip):
    """The :class:`gdstk.Library` of a chip layout (coordinates in um).

    Parameters
    ----------
    chip : planner.layout.geometry.ChipLayout

    Returns
    -------
    gdstk.Library
    """
    import gdstk

    layers = chip.rules.layers
    lib = gdstk.Library(LIBRARY, unit=UNIT, precision=PRECISION)
    made = {}
    for cell in chip.cells:
        out = gdstk.Cell(cell.name)
        for s in cell.shapes:
            layer, datatype = layers[s.layer]
            out.add(gdstk.Polygon(np.asarray(s.points) / UNIT, layer=layer, datatype=datatype))
        for t in cell.texts:
            layer, texttype = layers[t.layer]
            out.add(gdstk.Label(t.text, (t.origin[0] / UNIT, t.origin[1] / UNIT),
                                layer=layer, texttype=texttype))
        for p in cell.placements:
            out.add(gdstk.Reference(made[p.cell], (p.origin[0] / UNIT, p.origin[1] / UNIT),
                                    rotation=p.rotation, x_reflection=p.x_reflection))
        made[cell.name] = out
        lib.add(out)
    return lib


def write_gds(chip, path: str | Path) -> None:
    """Write ``chip`` to the GDSII file ``path`` (see the module docstring)."""
    to_library(chip).write_gds(str(path), timestamp=TIMESTAMP)


def read_gds(path: str | Path):
    """A GDSII file as a :class:`gdstk.Library` in its own user unit.

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        Not a GDSII file gdstk can read.
    """
    import gdstk

    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(2, "no such file", str(p))
    try:
        return gdstk.read_gds(str(p))
    except (RuntimeError, ValueError) as exc:
        raise ValueError(f"{p}: not a GDSII file gdstk can read ({exc})") from None
