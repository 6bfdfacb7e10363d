"""Bounds of the design variables p = (A, w, l, c): the paper's (17) and the documented upper bounds."""

from __future__ import annotations

import math
from dataclasses import dataclass

from planner.units import UM

#: The paper's lower bounds (17): A >= 20 um^2, w >= 2 um, l >= 8 um, c >= 2 um [m^2, m].
PAPER_LOWER = (20.0 * UM**2, 2.0 * UM, 8.0 * UM, 2.0 * UM)
#: Default upper bounds [m^2, m]; see :class:`DesignBounds` for the reasons.
DEFAULT_UPPER = (5.0e4 * UM**2, 10.0 * UM, 1500.0 * UM, 10.0 * UM)


def _pair(name, value):
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a (lo, hi) pair, {value!r} was given") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and 0.0 < lo <= hi):
        raise ValueError(f"{name} must satisfy 0 < lo <= hi (finite; lo = hi fixes it), "
                         f"{value!r} was given")
    return lo, hi


@dataclass(frozen=True)
class DesignBounds:
    """Bounds of the design variables p = (A, w, l, c), SI units.

    Parameters
    ----------
    area : (float, float)
        A [m^2]; default (20 um^2, 5e4 um^2).
    width : (float, float)
        w [m]; default (2 um, 10 um).
    length : (float, float)
        l, total length of the two V-beam segments [m]; default (8 um, 1500 um).
    gap : (float, float)
        c [m]; default (2 um, 10 um).

    Notes
    -----
    The lower bounds are the paper's (17): the minimum feature of the MUMPs process
    (2 um) and the impacter geometry of its Fig. 6.

    The paper has no upper bounds, and without them (13) is unbounded: r is
    proportional to m, so a larger impacter tuned to the same nu_n responds more.
    The defaults come from the footprint of one device of an array at 1 mm pitch
    (``configs/array_5x5.yaml``), where a device holds a slider and two impacter
    pairs:

    - A <= 5e4 um^2: a mass of about 220 um x 220 um, so that four fit beside an
      8e4 um^2 slider; Table II's backward mass (45446 um^2) is just below it.
    - l <= 1500 um: each V-beam segment then spans about 725 um (phi = 15 deg), under
      the pitch; the paper's designs use 800 to 1250 um.
    - w <= 10 um: five times the minimum feature; wider beams only stiffen the
      impacter, which a longer beam then has to undo.
    - c <= 10 um: the slider's side-wall gap stays within a few drive amplitudes
      (Z0 = 1.27 um at 5 kHz); wider gaps need larger swings to respond at all.

    Examples
    --------
    >>> b = DesignBounds.from_spec(area_um2=(20, 3e4))
    >>> round(b.area[1] / 1e-12)
    30000
    """

    area: tuple[float, float] = (PAPER_LOWER[0], DEFAULT_UPPER[0])
    width: tuple[float, float] = (PAPER_LOWER[1], DEFAULT_UPPER[1])
    length: tuple[float, float] = (PAPER_LOWER[2], DEFAULT_UPPER[2])
    gap: tuple[float, float] = (PAPER_LOWER[3], DEFAULT_UPPER[3])

    def __post_init__(self):
        for name in ("area", "width", "length", "gap"):
            object.__setattr__(self, name, _pair(name, getattr(self, name)))

    @classmethod
    def from_spec(cls, area_um2=None, width_um=None, length_um=None, gap_um=None):
        """Bounds from config units (um^2, um); None keeps the default of that variable."""
        kwargs = {}
        for key, name, scale in (("area_um2", "area", UM**2), ("width_um", "width", UM),
                                 ("length_um", "length", UM), ("gap_um", "gap", UM)):
            value = locals()[key]
            if value is not None:
                lo, hi = _pair(key, value)
                kwargs[name] = (lo * scale, hi * scale)
        return cls(**kwargs)

    def as_dict(self):
        """Config-unit dict: ``{"area_um2": [lo, hi], ...}``."""
        return {"area_um2": [self.area[0] / UM**2, self.area[1] / UM**2],
                "width_um": [self.width[0] / UM, self.width[1] / UM],
                "length_um": [self.length[0] / UM, self.length[1] / UM],
                "gap_um": [self.gap[0] / UM, self.gap[1] / UM]}
