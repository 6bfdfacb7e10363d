"""Design-rule check of a layout file with KLayout (``klayout.db``).

The checks, on the GDSII file as written (the chip flattened, each mask merged):

==========================  ===========================================================
``<MASK>.width``            every mask's lines at least ``min_line`` wide (Euclidean
                            metric; edges meeting at :data:`IGNORE_ANGLE` or more are
                            not measured against each other)
``<MASK>.space``            POLY0, POLY1, POLY2: structures at least ``min_space`` apart
``<CUT>.in.<MASK>``         every anchor cut inside POLY0 and its structural layer,
                            every via inside POLY1 and POLY2, every dimple inside
                            POLY1, by at least ``anchor_enclosure``
``device.pitch``            every device's structures inside its own pitch cell, a
                            space away from its neighbours'
==========================  ===========================================================

Each violation is named by the impacters and devices whose shapes it touches (the
cells ``<id>.cantilever`` and ``<device>.slider``), so that a designed quantity that
breaks a rule (a beam narrower than ``min_line``, a tip nearer its slider wall than
``min_space``) is reported by the impacter's id.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from planner.layout.geometry import CANTILEVER_SUFFIX, SLIDER_SUFFIX

#: Slack of every distance check [database units]: cells placed at 45 degrees snap
#: each vertex to the 1 nm grid, which may shave a nanometre off a line drawn exactly
#: at the rule.
TOLERANCE_DBU = 2
#: Edges meeting at this angle [deg] or more are not measured against each other.
#: KLayout's default is 90 (a rectangle's corner is no violation); cells placed at 45
#: degrees snap their right angles to the 1 nm grid, and a corner of 89.99 deg would
#: read as a zero width.  The layout draws no angle below 90 deg.
IGNORE_ANGLE = 89.0
#: Masks whose width is checked; masks whose spaces are checked.
WIDTH_MASKS = ("POLY0", "ANCHOR1", "DIMPLE", "POLY1", "POLY1_POLY2_VIA", "ANCHOR2", "POLY2")
SPACE_MASKS = ("POLY0", "POLY1", "POLY2")
#: (inner, outer): the inner mask must lie inside the outer one by the enclosure.
ENCLOSURES = (("ANCHOR1", "POLY0"), ("ANCHOR1", "POLY1"), ("ANCHOR2", "POLY0"),
              ("ANCHOR2", "POLY2"), ("POLY1_POLY2_VIA", "POLY1"),
              ("POLY1_POLY2_VIA", "POLY2"), ("DIMPLE", "POLY1"))
#: Masks of a device's structures for the pitch check (the ground plane may overlap).
PITCH_MASKS = ("ANCHOR1", "POLY1", "ANCHOR2", "POLY2")


@dataclass(frozen=True)
class Violation:
    """One place where a rule is broken.

    Attributes
    ----------
    rule : str
        E.g. ``POLY1.width``, ``ANCHOR1.in.POLY0``, ``device.pitch``.
    limit : float
        The rule's value [m].
    value : float
        What was measured there [m] (NaN for a shape missing its enclosure).
    box : tuple of float
        (x0, y0, x1, y1) of the violation on the chip [m].
    impacters, devices : tuple of str
        Whose shapes it touches.
    """

    rule: str
    limit: float
    value: float
    box: tuple
    impacters: tuple = ()
    devices: tuple = ()

    def to_dict(self) -> dict:
        um = 1e-6
        return {"rule": self.rule, "limit_um": self.limit / um,
                "value_um": None if math.isnan(self.value) else round(self.value / um, 4),
                "box_um": [round(v / um, 3) for v in self.box],
                "impacters": list(self.impacters), "devices": list(self.devices)}


@dataclass(frozen=True)
class DrcResult:
    """The check of one layout file.

    Attributes
    ----------
    rules : dict
        Rule name -> its value [m] (every rule checked).
    violations : tuple of Violation
    """

    rules: dict
    violations: tuple

    @property
    def clean(self) -> bool:
        return not self.violations

    @property
    def impacters(self) -> list:
        """Impacter ids in any violation, sorted."""
        return sorted({i for v in self.violations for i in v.impacters})

    @property
    def devices(self) -> list:
        """Device ids in any violation, sorted."""
        return sorted({d for v in self.violations for d in v.devices})

    def counts(self) -> dict:
        """Rule -> violations, rules in checking order."""
        out = {}
        for v in self.violations:
            out[v.rule] = out.get(v.rule, 0) + 1
        return out

    def to_dict(self) -> dict:
        return {"clean": self.clean,
                "rules_um": {k: v / 1e-6 for k, v in self.rules.items()},
                "counts": self.counts(), "impacters": self.impacters,
                "devices": self.devices,
                "violations": [v.to_dict() for v in self.violations]}


class _Components:
    """Every cantilever and slider instance of the chip: its id and its shapes on the
    chip, per mask, built on demand."""

    def __init__(self, kdb, layout, top, layer_index):
        self.kdb = kdb
        self.layer_index = layer_index
        self.items = []                     # (kind, id, cell, full transformation)
        suffixes = ((CANTILEVER_SUFFIX, "impacter"), (SLIDER_SUFFIX, "device"))
        it = top.begin_instances_rec()
        while not it.at_end():
            cell = it.inst_cell()
            for suffix, kind in suffixes:
                if cell.name.endswith(suffix):
                    self.items.append((kind, cell.name[:-len(suffix)], cell,
                                       it.trans() * it.inst_trans()))
            it.next()
        self._regions = {}

    def boxes(self):
        for i, (kind, ident, cell, trans) in enumerate(self.items):
            yield i, kind, ident, cell.bbox().transformed(trans)

    def region(self, i, mask):
        key = (i, mask)
        if key not in self._regions:
            kind, ident, cell, trans = self.items[i]
            li = self.layer_index.get(mask)
            self._regions[key] = (self.kdb.Region(cell.begin_shapes_rec(li)).transformed(trans)
                                  if li is not None else self.kdb.Region())
        return self._regions[key]

    def touching(self, masks, edges, box):
        """(impacter ids, device ids) whose shapes on ``masks`` touch ``edges``."""
        imps, devs = set(), set()
        for i, kind, ident, bbox in self.boxes():
            if not bbox.touches(box):
                continue
            if any(not self.region(i, m).interacting(edges).is_empty() for m in masks):
                (imps if kind == "impacter" else devs).add(ident)
        return tuple(sorted(imps)), tuple(sorted(devs))


def check(path: str | Path, rules, pitch: float) -> DrcResult:
    """Check a GDSII file against a process's rules.

    Parameters
    ----------
    path : str or Path
        The layout (:func:`planner.layout.gds.write_gds`).
    rules : planner.layout.rules.LayoutRules
    pitch : float
        The array pitch [m]: every top-level instance (a device) must keep its
        structures inside the square of this side around its origin.

    Returns
    -------
    DrcResult

    Raises
    ------
    ValueError
        The file has not exactly one top cell.
    """
    import klayout.db as kdb

    layout = kdb.Layout()
    layout.read(str(path))
    tops = layout.top_cells()
    if len(tops) != 1:
        raise ValueError(f"{path}: {len(tops)} top cells; expected one")
    top = tops[0]
    metre = layout.dbu * 1e-6                # one database unit [m]
    index = {}
    for name, (layer, datatype) in rules.layers.items():
        li = layout.find_layer(layer, datatype)
        if li is not None:
            index[name] = li
    merged = {}

    def region(name):
        if name not in merged:
            li = index.get(name)
            merged[name] = (kdb.Region(top.begin_shapes_rec(li)).merged() if li is not None
                            else kdb.Region())
        return merged[name]

    def dbu(length):
        return max(1, round(length / metre) - TOLERANCE_DBU)

    parts = _Components(kdb, layout, top, index)
    found, checked = [], {}

    def record(rule, limit, pairs, masks):
        checked[rule] = limit
        for ep in pairs.each():
            box = ep.bbox()
            edges = kdb.Edges([ep.first, ep.second])
            imps, devs = parts.touching(masks, edges, box)
            found.append(Violation(rule, limit, ep.distance() * metre,
                                   _box(box, metre), imps, devs))

    for mask in WIDTH_MASKS:
        record(f"{mask}.width", rules.min_line, region(mask).width_check(dbu(rules.min_line),
                                                          ignore_angle=IGNORE_ANGLE),
               (mask,))
    for mask in SPACE_MASKS:
        record(f"{mask}.space", rules.min_space,
               region(mask).space_check(dbu(rules.min_space), ignore_angle=IGNORE_ANGLE), (mask,))
    for inner, outer in ENCLOSURES:
        rule = f"{inner}.in.{outer}"
        record(rule, rules.anchor_enclosure,
               region(outer).enclosing_check(region(inner), dbu(rules.anchor_enclosure),
                                             ignore_angle=IGNORE_ANGLE),
               (inner, outer))
        for poly in region(inner).not_inside(region(outer)).each():
            box = poly.bbox()
            imps, devs = parts.touching((inner,), kdb.Edges(poly), box)
            found.append(Violation(rule, rules.anchor_enclosure, math.nan, _box(box, metre),
                                   imps, devs))
    checked["device.pitch"] = pitch
    found += _pitch(kdb, top, index, parts, pitch, rules.min_space, metre)
    return DrcResult(checked, tuple(found))


def _box(box, metre) -> tuple:
    return (box.left * metre, box.bottom * metre, box.right * metre, box.top * metre)


def _pitch(kdb, top, index, parts, pitch, space, metre) -> list:
    """Devices whose structures leave their pitch cell (less half a space each side).

    The boxes are those of the flattened shapes: a cell placed at 45 degrees has a
    hierarchical bounding box far larger than its shapes.
    """
    out = []
    half = (pitch - space) / 2.0 / metre

    def inside(box, allowed):
        return allowed.contains(box.p1) and allowed.contains(box.p2)

    for inst in top.each_inst():
        device = inst.cell.name
        trans = inst.cplx_trans
        shapes = kdb.Region()
        for mask in PITCH_MASKS:
            if mask in index:
                shapes += kdb.Region(inst.cell.begin_shapes_rec(index[mask])).transformed(trans)
        if shapes.is_empty():
            continue
        box = shapes.bbox()
        centre = trans.disp
        allowed = kdb.Box(round(centre.x - half), round(centre.y - half),
                          round(centre.x + half), round(centre.y + half))
        if inside(box, allowed):
            continue
        imps = set()
        for i, kind, ident, _ in parts.boxes():
            if kind == "impacter" and ident.split(".")[0] == device:
                own = kdb.Region()
                for mask in PITCH_MASKS:
                    own += parts.region(i, mask)
                if not inside(own.bbox(), allowed):
                    imps.add(ident)
        size = max(box.width(), box.height()) * metre
        out.append(Violation("device.pitch", pitch, size, _box(box, metre),
                             tuple(sorted(imps)), (device,)))
    return out
