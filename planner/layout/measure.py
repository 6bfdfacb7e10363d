"""The geometry round trip: every impacter's A, w, l and c measured on the GDSII polygons.

Nothing is read from labels or properties: the cells give the hierarchy (a device
cell per device id, in it a cell per impacter pair named by its id, in that two
placements of one cantilever cell, and the slider's cell), the polygons the numbers.

In a cantilever cell (its own frame):

- A = the total area of its POLY2 polygons (the plate, the joining members and any
  trim tabs are POLY1 + POLY2; nothing else is on POLY2);
- the beam legs are its POLY1 polygons that overlap no POLY2 and hold no ANCHOR1 cut;
  each is a rectangle: w = the distance between its long edges, its length = its area
  / w, and l = the mean length of a leg times two (a V is two legs);
- the beam angle phi = the mean angle between a leg and the beams' axis (the mean
  direction of the legs, each pointing away from the plate).

In the device frame (the placements applied), c = d / sin(theta): d the space
between the slider polygon (the largest POLY1 polygon of the slider's cell) and the
cantilever's nearest POLY1 vertex, theta the angle between that wall and the
cantilever's motion (perpendicular to its beams' axis).

:func:`round_trip` turns the measured geometry into natural frequencies through eqs.
(2)-(4) with the plan's process (:func:`planner.fabrication.tolerances.nominal_impacter`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planner.fabrication.tolerances import NodeDesign, nominal_impacter
from planner.layout.geometry import cantilever_cell_name, slider_cell_name
from planner.layout.shapes import polygon_area

#: Largest relative difference between the plan's natural frequency and the one the
#: measured geometry gives (the issue's round-trip criterion) [-].
ROUND_TRIP_RTOL = 0.005


@dataclass(frozen=True)
class MeasuredCantilever:
    """One placed cantilever as measured (SI).

    Attributes
    ----------
    area, width, length, gap : float
        A [m^2], w [m], l [m], c [m].
    beam_angle, impact_angle : float
        phi, theta [rad].
    legs : int
        Beam legs found (4 for a double-V cantilever).
    """

    area: float
    width: float
    length: float
    gap: float
    beam_angle: float
    impact_angle: float
    legs: int


@dataclass(frozen=True)
class MeasuredChip:
    """What the GDSII file holds.

    Attributes
    ----------
    top : str
        The top cell.
    devices : dict
        Device id -> its origin [m].
    impacters : dict
        Impacter id -> tuple of :class:`MeasuredCantilever` (one per placement).
    """

    top: str
    devices: dict
    impacters: dict


def _placed(points, ref) -> np.ndarray:
    """``points`` of the referenced cell in the referencing cell's frame (GDSII order:
    reflect across x, magnify, rotate, move)."""
    p = np.array(points, dtype=float).reshape(-1, 2)
    if ref.x_reflection:
        p[:, 1] = -p[:, 1]
    p = p * ref.magnification
    c, s = math.cos(ref.rotation), math.sin(ref.rotation)
    return p @ np.array([[c, s], [-s, c]]) + np.asarray(ref.origin, dtype=float)


def _refs(cell) -> dict:
    out = {}
    for ref in cell.references:
        name = ref.cell.name if hasattr(ref.cell, "name") else str(ref.cell)
        out.setdefault(name, []).append(ref)
    return out


def _layer(cell, layers, name):
    layer, datatype = layers[name]
    return [p for p in cell.polygons if p.layer == layer and p.datatype == datatype]


def _leg(points) -> tuple:
    """(width, length, unit direction) of a rectangular leg: its length the mean of its
    two long edges, its width its area over that (both averaging the 1 nm snapping of
    its four corners), its direction the long edges' mean."""
    edges = np.roll(points, -1, axis=0) - points
    lengths = np.hypot(edges[:, 0], edges[:, 1])
    k = int(np.argmax(lengths))
    opposite = (k + 2) % 4
    d = edges[k] / lengths[k] - edges[opposite] / lengths[opposite]
    length = 0.5 * float(lengths[k] + lengths[opposite])
    return polygon_area(points) / length, length, d / np.hypot(*d)


def _cantilever(cell, layers, unit):
    """(A, w, l, phi, legs, beam axis unit vector) of a cantilever cell, SI."""
    import gdstk

    mass = _layer(cell, layers, "POLY2")
    if not mass:
        raise ValueError(f"cell {cell.name}: no POLY2 plate")
    area = sum(p.area() for p in mass) * unit**2
    centre = sum(p.area() * np.mean(p.points, axis=0) for p in mass) / sum(p.area() for p in mass)
    cuts = np.concatenate([p.points for p in _layer(cell, layers, "ANCHOR1")] or
                          [np.zeros((0, 2))])
    legs = []
    for p in _layer(cell, layers, "POLY1"):
        if len(p.points) != 4:
            continue
        if len(cuts) and any(gdstk.inside(cuts, [p])):
            continue                       # an anchor pad
        # the plate, a joining member or a tab (a leg only touches a joining member:
        # their shared edge, snapped to the 1 nm grid, may overlap by a sliver)
        if sum(q.area() for q in gdstk.boolean(p, mass, "and")) > 0.5 * p.area():
            continue
        w, length, d = _leg(p.points)
        base = p.points[np.argmin(np.hypot(*(p.points - centre).T))]
        if (np.mean(p.points, axis=0) - base) @ d < 0:
            d = -d                         # from the plate outwards
        legs.append((w * unit, length * unit, d))
    if not legs:
        raise ValueError(f"cell {cell.name}: no beam legs (POLY1 outside the plate and "
                         "the anchor pads)")
    axis = np.sum([d for _, _, d in legs], axis=0)
    axis = axis / np.hypot(*axis)
    phi = float(np.mean([math.acos(min(1.0, abs(float(d @ axis)))) for _, _, d in legs]))
    width = float(np.mean([w for w, _, _ in legs]))
    length = 2.0 * float(np.mean([leg for _, leg, _ in legs]))
    return area, width, length, phi, len(legs), axis


def _gap(vertices, axis, wall) -> tuple:
    """(c, theta) of a placed cantilever: its POLY1 ``vertices`` and beam ``axis`` in
    the device frame, ``wall`` the slider polygon there."""
    x, y = wall[:, 0], wall[:, 1]
    ccw = float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) > 0
    best = None
    for a, b in zip(wall, np.roll(wall, -1, axis=0)):
        e = b - a
        e = e / np.hypot(*e)
        outward = np.array([e[1], -e[0]]) if ccw else np.array([-e[1], e[0]])
        # distance of every vertex to the edge segment
        t = np.clip((vertices - a) @ e, 0.0, float(np.hypot(*(b - a))))
        near = float(np.min(np.hypot(*(vertices - (a + t[:, None] * e)).T)))
        if best is None or near < best[0]:
            best = (near, a, outward)
    _, a, outward = best
    space = float(np.min((vertices - a) @ outward))
    motion = np.array([-axis[1], axis[0]])
    sine = abs(float(motion @ outward))
    if sine <= 0.0:
        raise ValueError("a cantilever moves parallel to its slider wall")
    return space / sine, math.asin(min(1.0, sine))


def measure(lib, layers: dict) -> MeasuredChip:
    """Measure every impacter of a GDSII library written by :mod:`planner.layout.gds`.

    Parameters
    ----------
    lib : gdstk.Library
    layers : dict
        Mask name -> (layer, datatype).

    Returns
    -------
    MeasuredChip

    Raises
    ------
    ValueError
        The library has not one top cell, or a device lacks its slider, or a
        cantilever lacks its plate or legs.
    """
    unit = lib.unit
    tops = lib.top_level()
    if len(tops) != 1:
        raise ValueError(f"the layout has {len(tops)} top cells; expected one")
    top = tops[0]
    cells = {c.name: c for c in lib.cells}
    devices, impacters, shapes = {}, {}, {}
    for device, refs in _refs(top).items():
        devices[device] = tuple(float(v) * unit for v in refs[0].origin)
        dev = cells[device]
        inside = _refs(dev)
        sliders = inside.get(slider_cell_name(device))
        if not sliders:
            raise ValueError(f"device {device}: no slider cell {slider_cell_name(device)}")
        slider = max(_layer(cells[slider_cell_name(device)], layers, "POLY1"),
                     key=lambda p: p.area())
        wall = _placed(slider.points, sliders[0]) * unit
        for pair in (f"{device}.forward", f"{device}.backward"):
            if pair not in inside:
                continue
            name = cantilever_cell_name(pair)
            if name not in shapes:
                shapes[name] = _cantilever(cells[name], layers, unit)
            area, width, length, phi, n_legs, axis = shapes[name]
            own = np.concatenate([p.points for p in _layer(cells[name], layers, "POLY1")])
            out = []
            for ref in _refs(cells[pair]).get(name, []):
                # the pair cell sits at the device's origin: its frame is the device's
                to_device = inside[pair][0]
                vertices = _placed(_placed(own, ref), to_device) * unit
                turned = (_placed(np.array([[0.0, 0.0], axis]), ref)
                          - _placed(np.zeros((1, 2)), ref))
                turned = (_placed(turned, to_device) - _placed(np.zeros((1, 2)), to_device))
                direction = turned[1] - turned[0]
                gap, theta = _gap(vertices, direction / np.hypot(*direction), wall)
                out.append(MeasuredCantilever(area, width, length, gap, phi, theta, n_legs))
            impacters[pair] = tuple(out)
    return MeasuredChip(top.name, devices, impacters)


def round_trip(spec, design, measured: MeasuredChip) -> list:
    """Plan against layout, one row per designed impacter (SI, frequencies in Hz).

    Parameters
    ----------
    spec : planner.arrayspec.ArraySpec
        The plan's spec (its process and environment make eqs. (2)-(4)).
    design : planner.fabrication.tolerances.ChipDesign
        The plan's designs.
    measured : MeasuredChip

    Returns
    -------
    list of dict
        ``id``, the plan's and the layout's ``area_m2``, ``width_m``, ``length_m``,
        ``gap_m`` (``*_plan``, ``*_layout``), ``natural_frequency_hz_plan``,
        ``natural_frequency_hz_layout``, their relative difference ``error`` [-], the
        ``cantilevers`` found and the largest relative difference between them
        (``spread``), ``passed`` (error within :data:`ROUND_TRIP_RTOL` and two
        cantilevers).
    """
    rows = []
    for node in design.nodes:
        found = measured.impacters.get(node.id, ())
        row = {"id": node.id, "cantilevers": len(found)}
        nu_plan = nominal_impacter(spec, node).natural_frequency
        keys = (("area_m2", "area"), ("width_m", "width"), ("length_m", "length"),
                ("gap_m", "gap"))
        for key, attr in keys:
            row[f"{key}_plan"] = getattr(node, attr)
        if not found:
            row.update({f"{k}_layout": math.nan for k, _ in keys},
                       natural_frequency_hz_plan=nu_plan, natural_frequency_hz_layout=math.nan,
                       error=math.inf, spread=math.nan, passed=False)
            rows.append(row)
            continue
        means = {attr: float(np.mean([getattr(m, attr) for m in found])) for _, attr in keys}
        spread = max(abs(getattr(m, attr) - means[attr]) / means[attr]
                     for m in found for _, attr in keys)
        for key, attr in keys:
            row[f"{key}_layout"] = means[attr]
        drawn = NodeDesign(node.id, node.device, node.direction, means["area"], means["width"],
                           means["length"], means["gap"], node.impact_angle, node.restitution)
        nu = nominal_impacter(spec, drawn).natural_frequency
        error = nu / nu_plan - 1.0
        row.update(natural_frequency_hz_plan=nu_plan, natural_frequency_hz_layout=nu,
                   error=error, spread=spread, beam_angle_rad=found[0].beam_angle,
                   impact_angle_rad=float(np.mean([m.impact_angle for m in found])),
                   passed=abs(error) <= ROUND_TRIP_RTOL and len(found) == 2)
        rows.append(row)
    return rows
