"""Bounds of the design variables p = (A, w, l, c): the paper's (17), the documented upper
bounds, and what a process's layout rules ask of them (:func:`narrow_bounds`).

Two designed quantities meet a rule in the drawing (:mod:`planner.layout` draws them):

- the beam width w is a POLY1 line: w >= min_line;
- the impacter's tip is a POLY1 corner at a distance c from its slider wall measured
  along the impacter's motion, which meets the wall at the impact angle theta (the
  paper's Fig. 6), so the drawn space between tip and wall is c sin(theta):
  c >= min_space / sin(theta).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from planner.core.units import UM

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


class RuleBoundsError(ValueError):
    """A process rule no design inside the designer's bounds can meet.

    ``field`` is the spec field at fault, as a path tuple (``("process",
    "min_line_um")``), for a :class:`planner.core.errors.SpecError` with its YAML line.
    """

    def __init__(self, field: tuple, message: str):
        self.field = field
        super().__init__(message)


def narrow_bounds(bounds, process, impact_angles):
    """The designer's bounds narrowed so that every design inside them keeps the rules
    the spec sets.

    Parameters
    ----------
    bounds : DesignBounds
        The bounds from ``design.bounds`` (or the defaults).
    process : planner.config.ProcessConfig
        Only ``min_line_um`` and ``min_space_um`` count, and only when set: an unset
        rule leaves the bounds as they are (the paper's (17) already keeps w >= 2 um).
    impact_angles : iterable of float
        The impact angle theta of every impacter the bounds serve [rad]; the smallest
        sets the gap bound.

    Returns
    -------
    DesignBounds
        ``bounds`` itself when nothing narrows it.

    Raises
    ------
    RuleBoundsError
        A rule leaves no width or gap inside the bounds, naming the rule's field.

    Examples
    --------
    >>> import math
    >>> from planner.config import ProcessConfig
    >>> b = narrow_bounds(DesignBounds(), ProcessConfig(min_space_um=2.0), [math.pi / 4])
    >>> round(b.gap[0] / UM, 3)        # the tip clears the wall by c sin(45 deg) >= 2 um
    2.828
    """
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
