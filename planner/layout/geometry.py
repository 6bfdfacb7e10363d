"""The chip as polygons: every designed impacter pair, slider and device of a plan (SI).

Pure geometry, no file format: :func:`build_chip` turns a plan's designs
(:class:`planner.fabrication.ChipDesign`) into :class:`Cell` s of :class:`Shape` s on
named masks, with placements, in metres; :mod:`planner.layout.gds` writes them.

The device (the paper's Fig. 3, one slider between two pairs of impacters)
--------------------------------------------------------------------------
Device frame: the slider's centre at the origin, its axis along +x (forward).

- **Slider**: a POLY1 rectangle of the device's ``slider.area_um2``, with DIMPLE bumps
  under it, held at both ends by POLY2 guides ("staples" crossing over it, landing on
  ANCHOR2 cuts beside it) that let it slide along x only; at least
  :data:`SLIDER_ASPECT` times as long as wide, longer when its guides must clear the
  impacters.
- **Impacter pair** (a model impacter is one of two identical cantilevers that strike
  the slider together): one cantilever above the slider, its mirror image below.
  Each moves along its own x axis, which meets the slider wall at the impact angle
  theta (Fig. 6); the forward pair strikes moving +x, the backward pair -x.
- **Cantilever** (own frame: x its motion towards the wall, y along its beams away
  from the slider): a plate (POLY1 + POLY2, thickness t, bonded by a
  POLY1_POLY2_VIA, dimples under it) whose corner nearest the wall is the tip, at the
  distance c from the wall along x.  Two V-beams (the double-V of Fig. 5(b)) hold
  it: each V is two POLY1 legs of width w and length l / 2 whose axes meet at the
  angle 2 phi (phi the process's ``beam_angle_deg``), starting from a joining member
  (POLY1 + POLY2, a block whose two roof faces meet the legs square) and landing at
  their far ends on anchor pads (POLY1 over an ANCHOR1 cut).  The two Vs are nested
  on the plate's axis: the first one's joining member sits on the plate's back edge,
  the second one's on a stem rising from it between the first V's legs, far enough
  up that its legs (parallel to the first V's) clear the first V's legs and pads.
  The plate, the joining members, the stem and any trim tabs make up the designed
  area A (eq. (2): "the planar area ... including the area of the joining member").
- **Trim tabs** (``trim: {direction: up}``): POLY1 + POLY2 fingers on the plate's rear
  edge (the side away from the wall), outlined on TRIM (:mod:`planner.layout.trim`).
- **Ground plane**: one POLY0 rectangle under the whole device.

Every space and size the drawing chooses is a named multiple of the process rules
(:class:`~planner.layout.rules.LayoutRules`), so only the designed beam width w and
the tip's space c sin(theta) can break a rule.  Every leg meets what it joins
square, so the layout has no acute corner for a width or space check to trip on.

Devices sit on the array's pitch, row A at the top: device (r, c) at
(c pitch, -r pitch).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planner.fabrication import ChipDesign, NodeDesign, nominal_impacter
from planner.layout.rules import LayoutRules
from planner.layout.trim import TrimPlan, tab_areas
from planner.units import UM

# Drawing constants: sizes [m] and multiples of the rules (min_line, min_space).
#: Side of an anchor cut (ANCHOR1, ANCHOR2) [m], at least a line.
ANCHOR_CUT = 5.0 * UM
#: Side of a dimple [m] (at least a line) and the pitch of the dimple grids under
#: plates and sliders [m].
DIMPLE_SIDE = 3.0 * UM
DIMPLE_PITCH = 40.0 * UM
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
#: Space between a moving structure and anything else, besides the swing of the
#: impacters on either side (2 c each) [min_space].
CLEARANCE = 2.0
#: Play between the slider and its guides' anchors [min_space].
GUIDE_PLAY = 1.0
#: Slider length beyond the outer edge of its guides [m].
SLIDER_END = 10.0 * UM
#: Least length over width of a slider [-]: longer when its impacters need the room.
SLIDER_ASPECT = 4.0
#: Margin of the POLY0 ground plane around everything else of a device [m].
GROUND_MARGIN = 10.0 * UM


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


@dataclass(frozen=True)
class ImpacterDrawing:
    """How one designed impacter pair was drawn (SI).

    Attributes
    ----------
    node : planner.fabrication.NodeDesign
        Its design: id, device, direction, A, w, l, c, theta.
    beam_angle : float
        phi [rad].
    frequency_hz, natural_frequency_hz : float
        Its drive tone and its natural frequency (plan.json) [Hz].
    plate : (float, float)
        The plate's sides along and across the motion [m].
    joints_area : float
        Area of its joining members and stem, part of A [m^2].
    tabs : tuple of float
        Areas of its trim tabs, in cutting order, part of A [m^2].
    contact_x : float
        Where its tips meet the slider walls, along the slider axis [m].
    """

    node: NodeDesign
    beam_angle: float
    frequency_hz: float
    natural_frequency_hz: float
    plate: tuple
    joints_area: float
    tabs: tuple
    contact_x: float


@dataclass(frozen=True)
class ChipLayout:
    """A plan's chip: cells leaves first, the top cell last.

    Attributes
    ----------
    cells : tuple of Cell
    top : str
        The top cell's name.
    pitch : float
        The array pitch [m].
    device_origins : dict
        Device id -> its origin on the chip [m], in device order.
    impacters : dict
        Impacter id -> :class:`ImpacterDrawing`, in plan order.
    sliders : dict
        Device id -> (length, width) of its slider [m].
    footprints : dict
        Device id -> (x0, y0, x1, y1), the box around its structures in its own frame
        [m] (the ground plane adds a margin).
    rules : LayoutRules
    trim : TrimPlan or None
    """

    cells: tuple
    top: str
    pitch: float
    device_origins: dict
    impacters: dict
    sliders: dict
    footprints: dict
    rules: LayoutRules
    trim: TrimPlan | None = None


#: The top cell's name.
TOP = "CHIP"
#: Cell name suffixes: one cantilever of a pair (``A1.forward.cantilever``), a
#: device's slider and guides (``A1.slider``).
CANTILEVER_SUFFIX = ".cantilever"
SLIDER_SUFFIX = ".slider"


def cantilever_cell_name(impacter_id: str) -> str:
    """The cell of one cantilever of an impacter pair (``A1.forward.cantilever``)."""
    return impacter_id + CANTILEVER_SUFFIX


def slider_cell_name(device: str) -> str:
    """The cell of a device's slider and guides (``A1.slider``)."""
    return device + SLIDER_SUFFIX


def _rect(x0, y0, x1, y1) -> np.ndarray:
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)


def _bar(base, along, width, length) -> np.ndarray:
    """Rectangle ``width`` across and ``length`` along the unit vector ``along``, its
    base edge centred on ``base`` (counter-clockwise)."""
    a = np.asarray(along, dtype=float)
    n = np.array([a[1], -a[0]]) * (width / 2.0)
    b = np.asarray(base, dtype=float)
    return np.array([b - n, b + n, b + n + a * length, b - n + a * length])


def _dimples(x0, y0, x1, y1, rules) -> list:
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
            out.append(Shape("DIMPLE", _rect(x - h, y - h, x + h, y + h)))
    return out


@dataclass(frozen=True)
class _Cantilever:
    """One cantilever in its own frame, and where its tip is."""

    shapes: tuple
    tip: np.ndarray
    plate: tuple
    joints_area: float
    tabs: tuple


def cantilever(impacter_id, area, width, length, beam_angle, impact_angle, rules,
               tabs=()) -> _Cantilever:
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
    line, space, enc = rules.min_line, rules.min_space, rules.anchor_enclosure
    if not 0.0 < beam_angle < math.pi / 2:
        raise ValueError(f"the double-V layout needs a beam angle in (0, 90) deg, "
                         f"{math.degrees(beam_angle):g} deg was given")
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
    # the stem rises between the first V's pads: their inner corners must clear it
    if (foot + leg * math.tan(beam_angle) - pad / 2.0) * cp < stem / 2.0 + gap:
        raise ValueError(f"impacter {impacter_id}: beams {length / UM:.4g} um long are too "
                         f"short for the double-V layout at a beam angle of "
                         f"{math.degrees(beam_angle):.3g} deg (the anchor pads of a V would "
                         "meet the stem between them)")
    shapes = []
    roofs = []                             # per V: right leg (outer, inner), left (inner, outer)
    for level in (0.0, rise):
        corners = []
        for turn in (1.0, -1.0):           # the right leg, then the left one
            along = np.array([turn * sp, cp])
            base = np.array([turn * foot * cp, level + ridge_y - foot * sp])
            bar = _bar(base, along, width, leg)
            shapes.append(Shape("POLY1", bar))
            # the pad's base edge runs through the leg's end corners and the roof
            # through its base corners: neighbours share their vertices exactly, so no
            # sliver opens between them when a rotated placement snaps to the grid
            p = _bar(base + leg * along, along, pad, pad)
            shapes.append(Shape("POLY1", np.array([p[0], bar[3], bar[2], p[1], p[2], p[3]])))
            cut = pad - 2.0 * enc
            shapes.append(Shape("ANCHOR1", _bar(base + (leg + enc) * along, along, cut, cut)))
            corners += [bar[1], bar[0]]
        roofs.append(corners)
    notch = ridge_y - stem / 2.0 * sp / cp
    # right to left over the top: the first block, up the stem's right side, round the
    # second block, down the stem's left side onto the first block's left roof face
    upper = np.array(
        [[eave, 0.0], [eave, wall], *roofs[0][:2], [stem / 2.0, notch],
         [stem / 2.0, rise], [eave, rise], [eave, rise + wall], *roofs[1][:2],
         [0.0, rise + ridge_y], *roofs[1][2:], [-eave, rise + wall], [-eave, rise],
         [-stem / 2.0, rise], [-stem / 2.0, notch], *roofs[0][2:], [-eave, wall],
         [-eave, 0.0]], dtype=float)
    tabs = tuple(float(a) for a in tabs)
    plate = area - polygon_area(upper) - sum(tabs)
    side = max(math.sqrt(max(plate, 0.0)), 2.0 * roof * cp)
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
    outline = _distinct(np.array(outline, dtype=float))
    shapes += [Shape("POLY1", outline), Shape("POLY2", outline)]
    shapes += [Shape("TRIM", t) for t in trims]
    if min(side, depth) > 2.0 * enc + line:
        shapes.append(Shape("POLY1_POLY2_VIA",
                            _rect(-side / 2.0 + enc, -depth + enc, side / 2.0 - enc, -enc)))
    shapes += _dimples(-side / 2.0, -depth, side / 2.0, 0.0, rules)
    tip = np.array([side / 2.0, -depth])
    _check_tip(impacter_id, shapes, tip, impact_angle, space)
    return _Cantilever(tuple(shapes), tip, (side, depth), polygon_area(upper), tabs)


def polygon_area(points) -> float:
    """Area of a simple polygon [m^2] (the shoelace formula)."""
    x, y = points[:, 0], points[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def _distinct(points) -> np.ndarray:
    """``points`` without vertices repeating their predecessor (cyclically)."""
    keep = np.any(np.abs(points - np.roll(points, 1, axis=0)) > 1e-15, axis=1)
    return points[keep]


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
        out.append(_rect(-side / 2.0 - a / tab, y, -side / 2.0, y + tab))
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


def _orientation(direction: str, side: int, theta: float) -> tuple:
    """(rotation [rad], x_reflection) taking a cantilever's frame to the device frame:
    x to its motion (cos theta, -sin theta) for forward above the slider (side +1),
    mirrored for below (side -1) and for backward; y away from the slider."""
    if direction == "forward":
        return (-theta, False) if side > 0 else (theta, True)
    return (math.pi + theta, True) if side > 0 else (math.pi - theta, False)


def _place(cell, tip, direction, side, theta, gap, contact_x, wall_y) -> Placement:
    """The placement of a cantilever whose tip is ``gap`` from the wall at ``wall_y``
    (signed: the wall on this side), along its motion, aimed at ``contact_x``."""
    rotation, mirror = _orientation(direction, side, theta)
    sgn = 1.0 if direction == "forward" else -1.0
    tip_at = np.array([contact_x - sgn * gap * math.cos(theta),
                       wall_y + side * gap * math.sin(theta)])
    origin = tip_at - Placement(cell, (0.0, 0.0), rotation, mirror).apply(tip)[0]
    return Placement(cell, (float(origin[0]), float(origin[1])), rotation, mirror)


def _points(shapes, placement=None, layers=("POLY1", "POLY2", "ANCHOR1")) -> np.ndarray:
    pts = [s.points for s in shapes if s.layer in layers]
    pts = np.concatenate(pts) if pts else np.zeros((0, 2))
    return placement.apply(pts) if placement is not None else pts


def _x_extent_below(shapes, placement, height) -> tuple:
    """(min x, max x) [m] of the placed shapes' parts below ``height`` (y <= height)."""
    xs = []
    for s in shapes:
        if s.layer not in ("POLY1", "POLY2"):
            continue
        p = placement.apply(s.points)
        q = np.roll(p, -1, axis=0)
        xs += list(p[p[:, 1] <= height, 0])
        cross = (p[:, 1] - height) * (q[:, 1] - height) < 0
        t = (height - p[cross, 1]) / (q[cross, 1] - p[cross, 1])
        xs += list(p[cross, 0] + t * (q[cross, 0] - p[cross, 0]))
    return (min(xs), max(xs)) if xs else (math.inf, -math.inf)


def build_chip(design: ChipDesign, frequencies: dict, rules: LayoutRules,
               trim: TrimPlan | None = None, name: str = TOP) -> ChipLayout:
    """The chip of a plan: one cell per impacter pair, slider and device (SI).

    Parameters
    ----------
    design : planner.fabrication.ChipDesign
        The plan's designs (:func:`planner.fabrication.design_from_plan`).
    frequencies : dict
        Impacter id -> (drive tone, natural frequency) [Hz], for the labels.
    rules : LayoutRules
    trim : TrimPlan, optional
        Draw trim tabs (``direction: up``).
    name : str
        The top cell's name.

    Returns
    -------
    ChipLayout

    Raises
    ------
    ValueError
        A design that cannot be drawn (:func:`cantilever`), naming the impacter.
    """
    spec = design.spec
    proc = spec.process
    phi = math.radians(proc.beam_angle_deg)
    line, space = rules.min_line, rules.min_space
    by_device = {}
    for node in design.nodes:
        by_device.setdefault(node.device, []).append(node)
    cells, drawings, sliders, origins, footprints = [], {}, {}, {}, {}
    ids = spec.array.device_ids()
    for device in design.devices:
        nodes = sorted(by_device[device], key=lambda n: n.direction != "forward")
        halves = {}
        for node in nodes:
            tabs = ()
            if trim is not None:
                imp = nominal_impacter(spec, node)
                tabs = tab_areas(imp.mass, proc.density_kg_m3, proc.mass_thickness_um * UM,
                                 trim)
            half = cantilever(node.id, node.area, node.width, node.length, phi,
                              node.impact_angle, rules, tabs)
            halves[node.id] = (node, half)
        # contact points: each pair's structures a clearance off the device's middle
        swing = sum(2.0 * n.gap for n in nodes)
        clear = CLEARANCE * space + swing
        contact, extent = {}, {}
        for nid, (node, half) in halves.items():
            probe = _place("", half.tip, node.direction, +1, node.impact_angle, node.gap,
                           0.0, 0.0)
            pts = _points(half.shapes, probe)
            if node.direction == "forward":
                contact[nid] = clear / 2.0 - pts[:, 0].min()
            else:
                contact[nid] = -clear / 2.0 - pts[:, 0].max()
        # guides at both ends, beyond everything of the pairs near the walls
        foot = max(ANCHOR_CUT, line) + 2.0 * rules.anchor_enclosure
        play = GUIDE_PLAY * space
        band = play + foot + clear
        reach = clear / 2.0
        for nid, (node, half) in halves.items():
            probe = _place("", half.tip, node.direction, +1, node.impact_angle, node.gap,
                           contact[nid], 0.0)
            lo, hi = _x_extent_below(half.shapes, probe, band)
            reach = max(reach, hi if node.direction == "forward" else -lo)
        slider_area = spec.slider_config(device).area_um2 * UM**2
        guide_x = max(reach + clear + foot / 2.0,
                      math.sqrt(slider_area * SLIDER_ASPECT) / 2.0 - foot / 2.0 - SLIDER_END)
        slider_len = 2.0 * (guide_x + foot / 2.0 + SLIDER_END)
        slider_w = slider_area / slider_len
        if slider_w < 4.0 * line:
            raise ValueError(f"device {device}: its slider of {slider_area / UM**2:.4g} um^2 "
                             f"would be {slider_len / UM:.4g} um long to reach past its "
                             f"impacters and only {slider_w / UM:.3g} um wide")
        sliders[device] = (slider_len, slider_w)
        slider_name = slider_cell_name(device)
        cells.append(_slider_cell(slider_name, slider_len, slider_w, guide_x, foot, play,
                                  rules))
        placements = [Placement(slider_name)]
        device_pts = [_points(cells[-1].shapes)]
        for nid, (node, half) in halves.items():
            cname = cantilever_cell_name(nid)
            cells.append(Cell(cname, half.shapes))
            pair = [_place(cname, half.tip, node.direction, side, node.impact_angle,
                           node.gap, contact[nid], side * slider_w / 2.0) for side in (1, -1)]
            device_pts += [_points(half.shapes, p) for p in pair]
            centre = pair[0].apply(np.array([[0.0, -half.plate[1] / 2.0]]))[0]
            f, nu = frequencies[nid]
            cells.append(Cell(nid, texts=(Text(f"{nid} {f:.0f} Hz (nu_n {nu:.0f} Hz)",
                                               (float(centre[0]), float(centre[1]))),),
                              placements=tuple(pair)))
            placements.append(Placement(nid))
            drawings[nid] = ImpacterDrawing(node, phi, float(f), float(nu), half.plate,
                                            half.joints_area, half.tabs, contact[nid])
        pts = np.concatenate(device_pts)
        footprints[device] = tuple(float(v) for v in (*pts.min(axis=0), *pts.max(axis=0)))
        lo, hi = pts.min(axis=0) - GROUND_MARGIN, pts.max(axis=0) + GROUND_MARGIN
        cells.append(Cell(device, shapes=(Shape("POLY0", _rect(lo[0], lo[1], hi[0], hi[1])),),
                          texts=(Text(device, (0.0, 0.0)),), placements=tuple(placements)))
        r, c = ids.index(device) // spec.array.cols, ids.index(device) % spec.array.cols
        pitch = spec.array.pitch_um * UM
        origins[device] = (c * pitch, -r * pitch)
    pitch = spec.array.pitch_um * UM
    cells.append(Cell(name, texts=(Text(f"{spec.name}: {len(origins)} devices at "
                                        f"{spec.array.pitch_um:g} um pitch",
                                        (-pitch / 2.0, pitch / 2.0)),),
                      placements=tuple(Placement(d, o) for d, o in origins.items())))
    return ChipLayout(tuple(cells), name, pitch, origins, drawings, sliders, footprints,
                      rules, trim)


def _slider_cell(name, length, width, guide_x, foot, play, rules) -> Cell:
    """The slider (POLY1, dimples) and its two guides (POLY2 staples on ANCHOR2)."""
    shapes = [Shape("POLY1", _rect(-length / 2.0, -width / 2.0, length / 2.0, width / 2.0))]
    shapes += _dimples(-length / 2.0, -width / 2.0, length / 2.0, width / 2.0, rules)
    reach = width / 2.0 + play + foot
    cut = foot - 2.0 * rules.anchor_enclosure
    for x in (-guide_x, guide_x):
        shapes.append(Shape("POLY2", _rect(x - foot / 2.0, -reach, x + foot / 2.0, reach)))
        for y in (-1.0, 1.0):
            yc = y * (width / 2.0 + play + foot / 2.0)
            shapes.append(Shape("ANCHOR2", _rect(x - cut / 2.0, yc - cut / 2.0,
                                                 x + cut / 2.0, yc + cut / 2.0)))
    return Cell(name, tuple(shapes))
