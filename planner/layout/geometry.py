"""The chip as polygons: every designed impacter pair, slider and device of a plan (SI).

Pure geometry, no file format: :func:`build_chip` turns a plan's designs
(:class:`planner.fabrication.tolerances.ChipDesign`) into :class:`Cell` s of :class:`Shape` s on
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

The modules: :mod:`planner.layout.shapes` (polygons, cells, placements),
:mod:`planner.layout.cantilever` (one cantilever in its own frame) and this one (the
devices and the chip: where each cantilever goes, the slider and its guides).

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

from planner.fabrication.tolerances import ChipDesign, NodeDesign, nominal_impacter
from planner.layout.cantilever import Cantilever, cantilever
from planner.layout.rules import LayoutRules
from planner.layout.shapes import ANCHOR_CUT, Cell, Placement, Shape, Text, dimples, rect
from planner.layout.trim import TrimPlan, tab_areas
from planner.core.units import UM

# Drawing constants: sizes [m] and multiples of the rules (min_line, min_space).
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
class ImpacterDrawing:
    """How one designed impacter pair was drawn (SI).

    Attributes
    ----------
    node : planner.fabrication.tolerances.NodeDesign
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
    design : planner.fabrication.tolerances.ChipDesign
        The plan's designs (:func:`planner.fabrication.tolerances.design_from_plan`).
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
        A design that cannot be drawn (:func:`~planner.layout.cantilever.cantilever`),
        naming the impacter.
    """
    spec = design.spec
    phi = math.radians(spec.process.beam_angle_deg)
    by_device = {}
    for node in design.nodes:
        by_device.setdefault(node.device, []).append(node)
    cells, drawings, sliders, origins, footprints = [], {}, {}, {}, {}
    ids = spec.array.device_ids()
    pitch = spec.array.pitch_um * UM
    for device in design.devices:
        nodes = sorted(by_device[device], key=lambda n: n.direction != "forward")
        halves = {node.id: (node, _cantilever_of(node, design, phi, rules, trim))
                  for node in nodes}
        drawn = _device(device, halves, spec.slider_config(device).area_um2 * UM**2, phi,
                        frequencies, rules)
        cells += drawn.cells
        drawings.update(drawn.drawings)
        sliders[device] = drawn.slider
        footprints[device] = drawn.footprint
        r, c = ids.index(device) // spec.array.cols, ids.index(device) % spec.array.cols
        origins[device] = (c * pitch, -r * pitch)
    cells.append(Cell(name, texts=(Text(f"{spec.name}: {len(origins)} devices at "
                                        f"{spec.array.pitch_um:g} um pitch",
                                        (-pitch / 2.0, pitch / 2.0)),),
                      placements=tuple(Placement(d, o) for d, o in origins.items())))
    return ChipLayout(tuple(cells), name, pitch, origins, drawings, sliders, footprints,
                      rules, trim)


def _cantilever_of(node: NodeDesign, design: ChipDesign, phi, rules, trim) -> Cantilever:
    """The cantilever of the impacter pair ``node``, with its trim tabs if ``trim``."""
    spec, proc = design.spec, design.spec.process
    tabs = ()
    if trim is not None:
        imp = nominal_impacter(spec, node)
        tabs = tab_areas(imp.mass, proc.density_kg_m3, proc.mass_thickness_um * UM, trim)
    return cantilever(node.id, node.area, node.width, node.length, phi, node.impact_angle,
                      rules, tabs)


@dataclass(frozen=True)
class _Device:
    """One drawn device: its cells (slider, cantilevers, pairs, the device), its
    pairs' drawings, its slider's (length, width) [m] and its footprint [m]."""

    cells: list
    drawings: dict
    slider: tuple
    footprint: tuple


def _device(device, halves, slider_area, phi, frequencies, rules) -> _Device:
    """The cells of ``device``: its slider and guides, its impacter pairs ``halves``
    (id -> (node, cantilever)) placed around it, and the device with its ground plane.

    The pairs' structures keep a clearance off the device's middle beyond the swing of
    its impacters; the guides hold the slider beyond everything of the pairs near the
    walls; the slider of area ``slider_area`` [m^2] is as long as that needs.
    """
    line, space = rules.min_line, rules.min_space
    # contact points: each pair's structures a clearance off the device's middle
    swing = sum(2.0 * node.gap for node, _ in halves.values())
    clear = CLEARANCE * space + swing
    contact = _contacts(halves, clear)
    # guides at both ends, beyond everything of the pairs near the walls
    foot = max(ANCHOR_CUT, line) + 2.0 * rules.anchor_enclosure
    play = GUIDE_PLAY * space
    reach = _reach(halves, contact, clear, play + foot + clear)
    guide_x = max(reach + clear + foot / 2.0,
                  math.sqrt(slider_area * SLIDER_ASPECT) / 2.0 - foot / 2.0 - SLIDER_END)
    slider_len = 2.0 * (guide_x + foot / 2.0 + SLIDER_END)
    slider_w = slider_area / slider_len
    if slider_w < 4.0 * line:
        raise ValueError(f"device {device}: its slider of {slider_area / UM**2:.4g} um^2 "
                         f"would be {slider_len / UM:.4g} um long to reach past its "
                         f"impacters and only {slider_w / UM:.3g} um wide")
    slider_name = slider_cell_name(device)
    cells = [_slider_cell(slider_name, slider_len, slider_w, guide_x, foot, play, rules)]
    placements = [Placement(slider_name)]
    device_pts = [_points(cells[-1].shapes)]
    drawings = {}
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
    footprint = tuple(float(v) for v in (*pts.min(axis=0), *pts.max(axis=0)))
    lo, hi = pts.min(axis=0) - GROUND_MARGIN, pts.max(axis=0) + GROUND_MARGIN
    cells.append(Cell(device, shapes=(Shape("POLY0", rect(lo[0], lo[1], hi[0], hi[1])),),
                      texts=(Text(device, (0.0, 0.0)),), placements=tuple(placements)))
    return _Device(cells, drawings, (slider_len, slider_w), footprint)


def _contacts(halves, clear) -> dict:
    """Impacter id -> where its tips meet the slider walls along the slider axis [m]:
    its structures ``clear`` / 2 [m] off the device's middle."""
    contact = {}
    for nid, (node, half) in halves.items():
        probe = _place("", half.tip, node.direction, +1, node.impact_angle, node.gap,
                       0.0, 0.0)
        pts = _points(half.shapes, probe)
        if node.direction == "forward":
            contact[nid] = clear / 2.0 - pts[:, 0].min()
        else:
            contact[nid] = -clear / 2.0 - pts[:, 0].max()
    return contact


def _reach(halves, contact, clear, band) -> float:
    """How far along the slider axis [m] the pairs' structures reach within ``band``
    [m] of the slider's wall (where the guides go), at least ``clear`` / 2."""
    reach = clear / 2.0
    for nid, (node, half) in halves.items():
        probe = _place("", half.tip, node.direction, +1, node.impact_angle, node.gap,
                       contact[nid], 0.0)
        lo, hi = _x_extent_below(half.shapes, probe, band)
        reach = max(reach, hi if node.direction == "forward" else -lo)
    return reach


def _slider_cell(name, length, width, guide_x, foot, play, rules) -> Cell:
    """The slider (POLY1, dimples) and its two guides (POLY2 staples on ANCHOR2)."""
    shapes = [Shape("POLY1", rect(-length / 2.0, -width / 2.0, length / 2.0, width / 2.0))]
    shapes += dimples(-length / 2.0, -width / 2.0, length / 2.0, width / 2.0, rules)
    reach = width / 2.0 + play + foot
    cut = foot - 2.0 * rules.anchor_enclosure
    for x in (-guide_x, guide_x):
        shapes.append(Shape("POLY2", rect(x - foot / 2.0, -reach, x + foot / 2.0, reach)))
        for y in (-1.0, 1.0):
            yc = y * (width / 2.0 + play + foot / 2.0)
            shapes.append(Shape("ANCHOR2", rect(x - cut / 2.0, yc - cut / 2.0,
                                                 x + cut / 2.0, yc + cut / 2.0)))
    return Cell(name, tuple(shapes))
