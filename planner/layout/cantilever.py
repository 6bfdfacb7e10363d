"""One cantilever of an impacter pair, drawn in its own frame (SI).

The cantilever (x its motion towards the slider wall, y along its beams away from the
slider; see :mod:`planner.layout.geometry` for the device around it): a plate (POLY1 +
POLY2, bonded by a POLY1_POLY2_VIA, dimples under it) whose corner nearest the wall is
the tip, held by two nested V-beams (the double-V of the paper's Fig. 5(b)), each two
POLY1 legs of width w and length l / 2 at +-phi from the plate's axis, starting from a
joining member and landing on anchor pads; the second V stands on a stem rising from
the first one's joining member.  Optional trim tabs sit on the plate's rear edge.

:func:`cantilever` draws it in four steps: size the double V (:func:`_double_v`, the
stem widened until it is stiff enough), draw the legs, pads and anchor cuts
(:func:`_beams`), outline the joining members and the stem (:func:`_joints`), and give
the plate the rest of the designed area A with its tabs (:func:`_plate`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planner.layout.shapes import (
    ANCHOR_CUT,
    Shape,
    bar,
    dimples,
    distinct,
    polygon_area,
    rect,
)
from planner.core.units import UM

# Drawing constants: sizes [m] and multiples of the rules (min_line, min_space).
#: Space along a joining member's roof between the ridge and each leg [min_space]:
#: the two legs of a V start this far apart.
RIDGE_SPACE = 2.0
#: Space between a leg or pad of one V and the nearest leg, pad or joining member of
#: the other, and between the two pads of one V [min_space].
PAD_SPACE = 2.0
#: Space between neighbouring trim tabs [min_space]; widest tab [m].
TAB_SPACE = 2.0
TAB_WIDTH_MAX = 20.0 * UM
#: Largest compliance of the stem to the second V, relative to that V's (from eq.
#: (4)) [-]: the stem lowers the drawn k by at most about half of it.
STEM_COMPLIANCE = 0.002
#: Rounds of widening the stem (each moves the second V up, which lengthens it).
STEM_ROUNDS = 6


@dataclass(frozen=True)
class Cantilever:
    """One cantilever in its own frame, and where its tip is.

    Attributes
    ----------
    shapes : tuple of Shape
        Its polygons [m].
    tip : ndarray, shape (2,)
        The plate's corner nearest the slider wall [m].
    plate : (float, float)
        The plate's sides along and across the motion [m].
    joints_area : float
        Area of its joining members and stem, part of A [m^2].
    tabs : tuple of float
        Areas of its trim tabs, in cutting order, part of A [m^2].
    """

    shapes: tuple
    tip: np.ndarray
    plate: tuple
    joints_area: float
    tabs: tuple


@dataclass(frozen=True)
class _DoubleV:
    """The sizes of a double V [m] (``cp``, ``sp``: cos and sin of phi)."""

    cp: float
    sp: float
    leg: float          # one leg, l / 2
    pad: float          # an anchor pad's side
    wall: float         # a joining member's vertical sides
    gap: float          # the space between the two Vs' legs and pads
    stem: float         # the stem's width
    ridge: float        # along the roof from the ridge to a leg
    roof: float         # one roof face, ridge to eave
    ridge_y: float      # the ridge's height above the plate's back edge
    foot: float         # ridge to a leg's base centre, along the roof
    eave: float         # half the joining member's width
    rise: float         # how far the second V stands above the first


def cantilever(impacter_id, area, width, length, beam_angle, impact_angle, rules,
               tabs=()) -> Cantilever:
    """One cantilever of a pair in its own frame (see the module docstring).

    Parameters
    ----------
    impacter_id : str
        For error messages.
    area, width, length : float
        A [m^2], w [m], l [m] (the total length of the two legs of a V).
    beam_angle, impact_angle : float
        phi, theta [rad].
    rules : LayoutRules
    tabs : tuple of float
        Trim tab areas [m^2].

    Raises
    ------
    ValueError
        The design cannot be drawn: a plate too small for its joining members and
        tabs, or tabs that do not fit its rear edge, or structures nearer the slider
        wall than the tip.
    """
    if not 0.0 < beam_angle < math.pi / 2:
        raise ValueError(f"the double-V layout needs a beam angle in (0, 90) deg, "
                         f"{math.degrees(beam_angle):g} deg was given")
    v = _double_v(width, length, beam_angle, rules)
    # the stem rises between the first V's pads: their inner corners must clear it
    if (v.foot + v.leg * math.tan(beam_angle) - v.pad / 2.0) * v.cp < v.stem / 2.0 + v.gap:
        raise ValueError(f"impacter {impacter_id}: beams {length / UM:.4g} um long are too "
                         f"short for the double-V layout at a beam angle of "
                         f"{math.degrees(beam_angle):.3g} deg (the anchor pads of a V would "
                         "meet the stem between them)")
    shapes, roofs = _beams(v, width, rules)
    upper = _joints(v, roofs)
    tabs = tuple(float(a) for a in tabs)
    plate, side, depth = _plate(impacter_id, area, upper, tabs, v, rules)
    shapes += plate
    tip = np.array([side / 2.0, -depth])
    _check_tip(impacter_id, shapes, tip, impact_angle, rules.min_space)
    return Cantilever(tuple(shapes), tip, (side, depth), polygon_area(upper), tabs)


def _double_v(width, length, beam_angle, rules) -> _DoubleV:
    """The sizes of the double V of beams of width ``width`` and length ``length`` at
    ``beam_angle`` [rad], the stem widened until it is stiff enough."""
    line, space, enc = rules.min_line, rules.min_space, rules.anchor_enclosure
    cp, sp = math.cos(beam_angle), math.sin(beam_angle)
    leg = length / 2.0
    pad = max(max(ANCHOR_CUT, line) + 2.0 * enc, width + 2.0 * line)
    wall = max(2.0 * line, width)          # a joining member's vertical sides
    gap = PAD_SPACE * space
    # The stem to the second V carries its spring force: a beam of length `rise` and
    # width `stem` in series with that V, guided at its top (the V's two legs, at
    # +-phi, hold its joining member from turning).  It is made wide enough to add at
    # most STEM_COMPLIANCE to the V's compliance (eq. (4): one V is half of k), so that
    # the second V acts as drawn; a wider stem moves the legs apart and the V up, hence
    # the few rounds.
    stem = max(2.0 * line, width)
    k_v = 0.5 * (width / length) ** 3 * (4.0 / cp) * (2.0 / cp + 1.0)   # / (E h)
    for _ in range(STEM_ROUNDS):
        # along the roof from the ridge to a leg: the legs of a V start a space apart
        # and clear the stem by one
        ridge = max(RIDGE_SPACE * space, (stem / 2.0 + space) / cp)
        roof = ridge + width + line        # one roof face, ridge to eave
        ridge_y = wall + roof * sp
        foot = ridge + width / 2.0         # ridge to a leg's base centre, along the roof
        # The second V is the first moved up by `rise`, which moves everything of it by
        # rise sin(phi) across the first V's legs (towards the axis) and rise cos(phi)
        # along them.  Across: its legs must clear the first V's pads, and its joining
        # member (whose eaves reach `beyond` a leg's inner edge) the first V's legs and
        # pads (which reach (pad - w) / 2 inside the legs); along: its pads theirs.
        eave = roof * cp
        inner = (np.array([foot * cp, ridge_y - foot * sp])
                 - width / 2.0 * np.array([cp, -sp]))
        beyond = max(float((np.array(q) - inner) @ np.array([cp, -sp]))
                     for q in ((eave, 0.0), (eave, wall)))
        rise = max((gap + (width + pad) / 2.0) / sp,
                   (gap + beyond + (pad - width) / 2.0) / sp, (pad + gap) / cp)
        # a fixed-guided stem: k = E h stem^3 / rise^3
        need = (rise**3 * k_v / STEM_COMPLIANCE) ** (1.0 / 3.0)
        if need <= stem:
            break
        stem = need
    return _DoubleV(cp, sp, leg, pad, wall, gap, stem, ridge, roof, ridge_y, foot, eave, rise)


def _beams(v: _DoubleV, width, rules) -> tuple[list, list]:
    """The legs, anchor pads and anchor cuts of both Vs, and each V's roof corners
    (right leg outer, inner; left leg inner, outer) where its legs meet its joining
    member."""
    enc = rules.anchor_enclosure
    shapes = []
    roofs = []                             # per V: right leg (outer, inner), left (inner, outer)
    for level in (0.0, v.rise):
        corners = []
        for turn in (1.0, -1.0):           # the right leg, then the left one
            along = np.array([turn * v.sp, v.cp])
            base = np.array([turn * v.foot * v.cp, level + v.ridge_y - v.foot * v.sp])
            leg = bar(base, along, width, v.leg)
            shapes.append(Shape("POLY1", leg))
            # the pad's base edge runs through the leg's end corners and the roof
            # through its base corners: neighbours share their vertices exactly, so no
            # sliver opens between them when a rotated placement snaps to the grid
            p = bar(base + v.leg * along, along, v.pad, v.pad)
            shapes.append(Shape("POLY1", np.array([p[0], leg[3], leg[2], p[1], p[2], p[3]])))
            cut = v.pad - 2.0 * enc
            shapes.append(Shape("ANCHOR1", bar(base + (v.leg + enc) * along, along, cut, cut)))
            corners += [leg[1], leg[0]]
        roofs.append(corners)
    return shapes, roofs


def _joints(v: _DoubleV, roofs) -> np.ndarray:
    """The outline of the two joining members and the stem between them, right to left
    over the top, from the plate's back edge (y = 0) round to it again."""
    notch = v.ridge_y - v.stem / 2.0 * v.sp / v.cp
    eave, wall, rise, stem = v.eave, v.wall, v.rise, v.stem
    # right to left over the top: the first block, up the stem's right side, round the
    # second block, down the stem's left side onto the first block's left roof face
    return np.array(
        [[eave, 0.0], [eave, wall], *roofs[0][:2], [stem / 2.0, notch],
         [stem / 2.0, rise], [eave, rise], [eave, rise + wall], *roofs[1][:2],
         [0.0, rise + v.ridge_y], *roofs[1][2:], [-eave, rise + wall], [-eave, rise],
         [-stem / 2.0, rise], [-stem / 2.0, notch], *roofs[0][2:], [-eave, wall],
         [-eave, 0.0]], dtype=float)


def _plate(impacter_id, area, upper, tabs, v: _DoubleV, rules) -> tuple[list, float, float]:
    """The plate with the joining members ``upper`` on its back edge and the trim tabs
    ``tabs`` [m^2] on its rear edge, of total area ``area`` [m^2]: its shapes, side
    across the beams' axis and depth along it [m]."""
    line, enc = rules.min_line, rules.anchor_enclosure
    plate = area - polygon_area(upper) - sum(tabs)
    side = max(math.sqrt(max(plate, 0.0)), 2.0 * v.roof * v.cp)
    depth = plate / side
    if depth < 4.0 * line:
        raise ValueError(
            f"impacter {impacter_id}: its plate area {area / UM**2:.4g} um^2 is too small "
            f"to carry the joining members of its beams ({polygon_area(upper) / UM**2:.4g} um^2)"
            + (f" and {len(tabs)} trim tabs of {sum(tabs) / UM**2:.4g} um^2" if tabs else ""))
    outline = [[-side / 2.0, -depth], [side / 2.0, -depth], [side / 2.0, 0.0]]
    outline += list(upper) + [[-side / 2.0, 0.0]]
    trims = _tabs(impacter_id, tabs, side, depth, rules) if tabs else []
    for t in reversed(trims):              # down the rear edge, top tab first
        outline += [t[2], t[3], t[0], t[1]]
    outline = distinct(np.array(outline, dtype=float))
    shapes = [Shape("POLY1", outline), Shape("POLY2", outline)]
    shapes += [Shape("TRIM", t) for t in trims]
    if min(side, depth) > 2.0 * enc + line:
        shapes.append(Shape("POLY1_POLY2_VIA",
                            rect(-side / 2.0 + enc, -depth + enc, side / 2.0 - enc, -enc)))
    shapes += dimples(-side / 2.0, -depth, side / 2.0, 0.0, rules)
    return shapes, side, depth


def _tabs(impacter_id, areas, side, depth, rules) -> list:
    """Trim tabs on the plate's rear edge (x = -side / 2), bottom up: rectangles
    (x0, y0), (x1, y0), (x1, y1), (x0, y1) with x1 on the edge."""
    line, space = rules.min_line, rules.min_space
    n = len(areas)
    gap = TAB_SPACE * space
    room = (depth - 2.0 * line - (n - 1) * gap) / n
    tab = min(TAB_WIDTH_MAX, room, min(areas) / (2.0 * line))
    if tab < 2.0 * line:
        raise ValueError(f"impacter {impacter_id}: {n} trim tabs do not fit the "
                         f"{depth / UM:.4g} um rear edge of its plate; ask for a coarser "
                         "trim.precision_pct or a smaller trim.range_pct")
    out = []
    y = -depth + line
    for a in areas:
        out.append(rect(-side / 2.0 - a / tab, y, -side / 2.0, y + tab))
        y += tab + gap
    return out


def _check_tip(impacter_id, shapes, tip, impact_angle, space):
    """The tip must be nearer the slider wall than anything else of the cantilever but
    the plate it is a corner of, by a space (in the cantilever's frame the wall's
    normal is (sin theta, -cos theta))."""
    normal = np.array([math.sin(impact_angle), -math.cos(impact_angle)])
    reach = float(tip @ normal)
    for s in shapes:
        if s.layer not in ("POLY1", "POLY2", "ANCHOR1"):
            continue
        if np.any(np.all(s.points == tip, axis=1)):
            continue                       # the plate: the tip is its corner
        if float(np.max(s.points @ normal)) > reach - space:
            raise ValueError(f"impacter {impacter_id}: at an impact angle of "
                             f"{math.degrees(impact_angle):.4g} deg its beams or anchors would "
                             "reach nearer the slider wall than its tip")
