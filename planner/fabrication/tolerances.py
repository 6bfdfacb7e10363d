"""Fabrication tolerances -> sampled as-built chips (the spec's ``fabrication:`` section).

A *chip* is one fabricated copy of a plan's array: every designed impacter pair and
every slider rebuilt from its design geometry through the designer's own equations
(eqs. (2)-(4) of the paper, :meth:`model.Impacter.from_geometry`) after the geometry and
the process constants have been moved by sampled fabrication errors.

How each error moves the design (all errors normal, mean 0, sigma from the spec):

==========================  ============================================================
``line_width_um`` dw [um]   every drawn edge moves dw/2 outward: beam width w + dw,
                            impacter-to-wall gap c - dw (the space between two edges),
                            mass plate of area A taken as a square of side sqrt(A):
                            (sqrt(A) + dw)^2; slider plate likewise.  The beam length l
                            is set by the anchor positions and does not move.
``thickness_um`` dt [um]    structural layer thickness: beam height h + dt, mass and
                            slider thickness t (h + dt) / h (the same deposited layers).
``gap_um`` dc [um]          an extra gap error on top of the line width's: c - dw + dc.
``youngs_modulus_pct`` [%]  E (1 + dE/100): k of eq. (4) scales with it.
``natural_frequency_pct``   a direct scatter of the natural frequency (residual stress,
  [%]                       anchor compliance, model error): k (1 + dnu/100)^2, so that
                            sqrt(k/m) moves by dnu percent.
==========================  ============================================================

Mass (2) and damping (3) follow the moved A, w, t and h; k (4) the moved w, h and E.

Each error is the sum of a per-die draw (one per chip, shared by every device) and a
per-device draw, taken once per *impacter pair* (a node: device + direction); the slider
of each device gets its own independent line-width and thickness draw.  With a ``pair``
sigma, each of the two cantilevers of a pair gets a further draw of its own, and the
node becomes a :class:`model.PairHalves` (two oscillators striking the same slider);
without one, the two halves are identical and the node is the symmetric
:class:`model.Impacter` of the paper.

A chip whose errors make a dimension non-physical (a gap closed, a beam or layer of
zero width or thickness) cannot be built; its nodes are reported as ``unbuildable``.

Draws are made in a fixed order from standard normals, whatever the sigmas (a zero
sigma multiplies its draw by 0), so one chip seed gives the same normals at every
``--sigma-scale``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from model import Impacter, Slider, pair_of
from planner.arrayspec import ArraySpec, FabricationSpec

UM = 1e-6
#: The five errors, in the order of their draws (columns of the normal arrays).
ERRORS = ("line_width_um", "thickness_um", "gap_um", "youngs_modulus_pct",
          "natural_frequency_pct")
#: The unit of each error of :data:`ERRORS`: a chip's errors, their sigmas
#: (:class:`Tolerances`) and the sensitivities d ln nu_n / d e
#: (:func:`frequency_sensitivities`, per um and per %) all count in these, so that a
#: sensitivity times an error is a relative shift [-] (plan.json's keys carry them).
ERROR_UNITS = ("um", "um", "um", "%", "%")


@dataclass(frozen=True, eq=False)
class Tolerances:
    """The fabrication tolerance model as numbers: one sigma per error and level.

    The spec's ``fabrication:`` section (:class:`planner.arrayspec.FabricationSpec`, a
    pydantic model with a field per error) turned once, by :meth:`from_spec`, into the
    arrays every computation with the tolerances reads: a sampled chip
    (:func:`sample_chip`), an impacter's frequency sigma
    (:func:`natural_frequency_sigma`), the predicted scatter and the collision-free
    yield (:mod:`planner.manufacturability`).  A plan's settings carry it
    (``Settings.tolerances``).

    Attributes
    ----------
    die : ndarray, shape (5,)
        Sigma of the per-die part of each error of :data:`ERRORS`, in that order, each
        in its unit (:data:`ERROR_UNITS`: um, um, um, %, %).
    device : ndarray, shape (5,)
        Sigma of the per-device part (one draw per impacter pair and per slider), same
        order and units.
    pair : ndarray, shape (5,)
        Sigma of each half's own error of a pair, same order and units.

    Notes
    -----
    The units are the errors' own, not SI: they are the coordinates in which a chip is
    built (:func:`as_built_impacter`) and in which the sensitivities are measured and recorded
    (plan.json's ``manufacturability.sensitivity``, per um and per %), so the sums
    s_i sigma_i need no conversion and give the plan's numbers to the last bit.

    Examples
    --------
    >>> from planner.arrayspec import FabricationSpec
    >>> t = Tolerances.from_spec(FabricationSpec.model_validate(
    ...     {"line_width_um": {"die": 0.05, "device": 0.02}}))
    >>> [float(x) for x in t.die], t.zero
    ([0.05, 0.0, 0.0, 0.0, 0.0], False)
    """

    die: np.ndarray
    device: np.ndarray
    pair: np.ndarray

    #: the unit of each entry (:data:`ERROR_UNITS`)
    units = ERROR_UNITS

    def __post_init__(self):
        for name in ("die", "device", "pair"):
            a = np.array(getattr(self, name), dtype=float)
            if a.shape != (len(ERRORS),) or not np.all(np.isfinite(a)) or np.any(a < 0):
                raise ValueError(f"{name} must be {len(ERRORS)} finite sigmas >= 0 (in "
                                 f"ERRORS order), {getattr(self, name)!r} was given")
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    @classmethod
    def from_spec(cls, fab: FabricationSpec) -> "Tolerances":
        """The sigmas of a spec's ``fabrication:`` section (``fab.<error>.die`` and so on)."""
        return cls(*(np.array([getattr(getattr(fab, k), level) for k in ERRORS])
                     for level in ("die", "device", "pair")))

    @property
    def zero(self) -> bool:
        """No error at all: every sigma 0."""
        return not (np.any(self.die) or np.any(self.device) or np.any(self.pair))

    def scaled(self, scale: float) -> "Tolerances":
        """Every sigma times ``scale`` [-] (a yield study's ``--sigma-scale``)."""
        return Tolerances(self.die * scale, self.device * scale, self.pair * scale)

    def variances(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(die, device, pair) variances, shape (5,) each, the units squared."""
        return self.die ** 2, self.device ** 2, self.pair ** 2

    def __eq__(self, other):
        if not isinstance(other, Tolerances):
            return NotImplemented
        return all(np.array_equal(getattr(self, k), getattr(other, k))
                   for k in ("die", "device", "pair"))

    __hash__ = None

    def __repr__(self):
        return (f"Tolerances(die={self.die.tolist()}, device={self.device.tolist()}, "
                f"pair={self.pair.tolist()})")


def _as_tolerances(fab) -> Tolerances:
    """``fab`` itself when a :class:`Tolerances`, else :meth:`Tolerances.from_spec` of a
    spec's ``fabrication:`` section."""
    return fab if isinstance(fab, Tolerances) else Tolerances.from_spec(fab)


@dataclass(frozen=True)
class NodeDesign:
    """One designed impacter pair of a plan (SI).

    ``stiffness_scale``, ``mass_scale``, ``damping_scale``, ``damping_shift`` [N s/m]
    and ``gap_shift`` [m] carry a re-planned plan's as-built model: what the chip's
    models are against what its geometry gives (1, 1, 1, 0 and 0 for a plan; the damping
    as a shift only where the geometry gives none, in vacuum).  A chip's errors act on the geometry as for a plan,
    and the as-built differences on top, so the chip without errors is the as-built one.
    """

    id: str
    device: str
    direction: str
    area: float
    width: float
    length: float
    gap: float
    impact_angle: float
    restitution: float
    stiffness_scale: float = 1.0
    damping_scale: float = 1.0
    damping_shift: float = 0.0
    gap_shift: float = 0.0
    mass_scale: float = 1.0


@dataclass(frozen=True)
class ChipDesign:
    """What a chip is built from: the plan's nominal designs and process constants."""

    spec: ArraySpec
    nodes: tuple[NodeDesign, ...]
    devices: tuple[str, ...]

    @property
    def node_ids(self) -> list[str]:
        return [n.id for n in self.nodes]


def design_from_plan(record) -> ChipDesign:
    """The nominal designs of a plan (a :class:`planner.planfile.reader.PlanRecord`,
    whose reader has checked that its m, k and b follow from its geometry by these
    equations); for a re-planned plan, its as-built models (see :class:`NodeDesign`).
    """
    spec = record.spec
    nodes = []
    for rec in record.impacters:
        g = rec.geometry
        node = NodeDesign(rec.id, rec.device, rec.direction, g.area_m2, g.width_m,
                          g.length_m, g.gap_m, rec.impact_angle_rad, rec.restitution)
        if record.replanned:
            built = nominal_impacter(spec, node)
            damped = built.damping > 0
            node = replace(node, stiffness_scale=rec.stiffness_n_per_m / built.stiffness,
                           mass_scale=rec.mass_kg / built.mass,
                           damping_scale=rec.damping_ns_per_m / built.damping if damped else 1.0,
                           damping_shift=0.0 if damped else rec.damping_ns_per_m,
                           gap_shift=rec.gap_m - built.gap)
        nodes.append(node)
    devices = tuple(sorted({n.device for n in nodes}, key=lambda d: (d[0], int(d[1:]))))
    return ChipDesign(spec, tuple(nodes), devices)


def nominal_impacter(spec: ArraySpec, node: NodeDesign) -> Impacter:
    """The impacter pair ``node`` describes, without fabrication error: its geometry
    through eqs. (2)-(4) on the spec's process and environment (what plan.json records
    for a designed node)."""
    return as_built_impacter(spec, node, np.zeros(len(ERRORS)))


def as_built_impacter(spec: ArraySpec, node: NodeDesign, err) -> Impacter:
    """As-built impacter pair; ``err`` = the five errors in :data:`ERRORS` order (um, %)."""
    dw, dt, dc, de, dnu = (float(e) for e in err)
    p = spec.process
    h0 = p.beam_height_um * UM
    h = h0 + dt * UM
    side = math.sqrt(node.area) + dw * UM
    imp = Impacter.from_geometry(
        side * side if side > 0 else -1.0, node.width + dw * UM, node.length,
        node.gap - dw * UM + dc * UM,
        thickness=p.mass_thickness_um * UM * h / h0, beam_height=h,
        density=p.density_kg_m3, youngs_modulus=p.youngs_modulus_gpa * 1e9 * (1 + de / 100),
        viscosity=spec.environment.viscosity_mpa_s * 1e-3,
        substrate_gap=p.substrate_gap_um * UM, beam_angle=math.radians(p.beam_angle_deg),
        impact_angle=node.impact_angle, restitution=node.restitution)
    if dnu != 0.0:
        f = 1 + dnu / 100
        if f <= 0:
            raise ValueError("natural frequency scaled to <= 0")
        imp = Impacter(imp.mass, imp.stiffness * f * f, imp.damping, imp.gap,
                       imp.impact_angle, imp.restitution, imp.geometry)
    if (node.stiffness_scale, node.mass_scale, node.damping_scale, node.damping_shift,
            node.gap_shift) != (1.0, 1.0, 1.0, 0.0, 0.0):
        gap = imp.gap + node.gap_shift
        if gap <= 0:
            raise ValueError("gap closed")
        imp = Impacter(imp.mass * node.mass_scale, imp.stiffness * node.stiffness_scale,
                       imp.damping * node.damping_scale + node.damping_shift, gap,
                       imp.impact_angle, imp.restitution, imp.geometry)
    return imp


def as_built_slider(spec: ArraySpec, device: str, dw: float, dt: float) -> Slider:
    cfg = spec.slider_config(device)
    p = spec.process
    t0 = (cfg.thickness_um if cfg.thickness_um is not None else p.slider_thickness_um) * UM
    h0 = p.beam_height_um * UM
    side = math.sqrt(cfg.area_um2) * UM + dw * UM
    return Slider.from_geometry(
        side * side if side > 0 else -1.0, t0 * (h0 + dt * UM) / h0,
        density=p.density_kg_m3, viscosity=spec.environment.viscosity_mpa_s * 1e-3,
        substrate_gap=p.substrate_gap_um * UM, static_friction=cfg.static_friction_un * UM,
        dynamic_friction=cfg.dynamic_friction_un * UM)


@dataclass
class Chip:
    """One sampled chip: as-built impacters (node id -> Impacter), sliders (device ->
    Slider), the nodes and devices that could not be built, and the sampled errors."""

    impacters: dict
    sliders: dict
    unbuildable: list
    errors: dict


def sample_chip(design: ChipDesign, fab: Tolerances | FabricationSpec,
                rng: np.random.Generator, scale: float = 1.0,
                line_width_offsets: dict | None = None) -> Chip:
    """Draw one chip from ``rng``.

    Parameters
    ----------
    design : ChipDesign
        The plan's nominal designs (:func:`design_from_plan`).
    fab : Tolerances or planner.arrayspec.FabricationSpec
        The tolerance model (a spec's section is read by :meth:`Tolerances.from_spec`).
    rng : numpy.random.Generator
        The chip's own generator (seeded from the run's seed and the chip's index).
    scale : float
        Multiplies every sigma [-], >= 0.
    line_width_offsets : dict, optional
        Device id -> a line width [um] added to every impacter pair and the slider of
        that device: where the die sat on its wafer
        (:func:`planner.fabrication.wafer.line_width_offsets`); None adds nothing, and the draws
        are the same either way.

    Returns
    -------
    Chip
    """
    if not (math.isfinite(scale) and scale >= 0):
        raise ValueError(f"scale must be finite and >= 0, {scale!r} was given")
    tol = _as_tolerances(fab).scaled(scale)
    sd_die, sd_dev, sd_pair = tol.die, tol.device, tol.pair
    # fixed draw order: die, then every node, then every slider (line width, thickness),
    # then every half of every node (drawn last, so that the earlier draws are those of
    # a chip without the pair level)
    z_die = rng.standard_normal(len(ERRORS))
    z_nodes = rng.standard_normal((len(design.nodes), len(ERRORS)))
    z_sliders = rng.standard_normal((len(design.devices), 2))
    z_halves = rng.standard_normal((len(design.nodes), 2, len(ERRORS)))
    die = sd_die * z_die
    impacters, sliders, bad, errors = {}, {}, [], {}
    for node, z, zh in zip(design.nodes, z_nodes, z_halves):
        err = die + sd_dev * z
        if line_width_offsets is not None:
            err[0] += line_width_offsets[node.device]
        errors[node.id] = [float(e) for e in err]
        try:
            if np.any(sd_pair > 0):
                # two halves, each the pair's error plus its own mismatch
                a, b = (as_built_impacter(design.spec, node, err + sd_pair * zk) for zk in zh)
                impacters[node.id] = pair_of(a, b)
            else:
                impacters[node.id] = as_built_impacter(design.spec, node, err)
        except ValueError:
            bad.append(node.id)
    for dev, z in zip(design.devices, z_sliders):
        dw = die[0] + sd_dev[0] * z[0]
        if line_width_offsets is not None:
            dw += line_width_offsets[dev]
        dt = die[1] + sd_dev[1] * z[1]
        try:
            sliders[dev] = as_built_slider(design.spec, dev, dw, dt)
        except ValueError:
            bad.append(dev)
    return Chip(impacters, sliders, bad, errors)


#: Finite-difference step of each error source (um, um, um, %, %) for the sensitivity
#: of the natural frequency: small against any tolerance, large against rounding.
_FD_STEP = np.array([1e-4, 1e-4, 1e-4, 1e-3, 1e-3])


def frequency_sensitivities(spec: ArraySpec, node: NodeDesign, which=None) -> np.ndarray:
    """d ln nu_n / d e_i of an impacter pair for each error source, shape (5,).

    Units per :data:`ERRORS` entry: 1/um (line width, thickness, gap), 1/% (Young's
    modulus, natural frequency).  Central differences through the same as-built
    equations a sampled chip is built with (:func:`sample_chip`), so they are what a
    chip does to first order.  ``which`` (booleans, shape (5,)) computes only those
    entries (the others are 0).

    Examples
    --------
    >>> from planner.arrayspec import ArraySpec
    >>> node = NodeDesign("A1.forward", "A1", "forward", 3e-8, 5e-6, 4e-4, 4e-6, 0.785, 0.5)
    >>> [round(float(x), 4) for x in frequency_sensitivities(ArraySpec(), node)]
    [0.2876, 0.0, 0.0, 0.005, 0.01]
    """
    out = np.zeros(len(ERRORS))
    for i, h in enumerate(_FD_STEP):
        if which is not None and not which[i]:
            continue
        up, down = np.zeros(len(ERRORS)), np.zeros(len(ERRORS))
        up[i], down[i] = h, -h
        out[i] = (math.log(as_built_impacter(spec, node, up).natural_frequency)
                  - math.log(as_built_impacter(spec, node, down).natural_frequency)) / (2 * h)
    # thickness and gap cancel exactly in eqs. (2)-(4); keep their round-off out
    out[np.abs(out) < 1e-9] = 0.0
    return out


def natural_frequency_sigma(spec: ArraySpec, node: NodeDesign,
                            fab: Tolerances | FabricationSpec) -> float:
    """Relative standard deviation of an impacter's natural frequency [-] under ``fab``
    (:class:`Tolerances`, or a spec's section).

    First order: sum over the error sources of (d ln nu_n / d e_i)^2 (sigma_die_i^2 +
    sigma_device_i^2), the sensitivities from :func:`frequency_sensitivities`.  A
    line-width error of 0.05 um on a 4.6 um beam moves nu_n by about 1.6 %.
    """
    var_die, var_dev, _ = _as_tolerances(fab).variances()
    var = var_die + var_dev
    s = frequency_sensitivities(spec, node, which=var > 0)
    return math.sqrt(float(np.sum(s * s * var)))


@dataclass(frozen=True)
class RobustShift:
    """``design.robust``: k sigma of a candidate's own natural frequency, for the designer.

    Called by :func:`planner.designer.design_impacter` with a candidate geometry
    ``(area, width, length, gap)`` [m^2, m, m, m]; returns k times its relative
    natural-frequency sigma under the spec's fabrication tolerances
    (:func:`natural_frequency_sigma`), capped below 0.5.  Picklable, so it travels to
    the design worker processes.
    """

    spec: ArraySpec
    k: float
    impact_angle: float
    restitution: float

    def __call__(self, geometry) -> float:
        area, width, length, gap = geometry
        node = NodeDesign("candidate", "A1", "forward", area, width, length, gap,
                          self.impact_angle, self.restitution)
        s = self.k * natural_frequency_sigma(self.spec, node, self.spec.fabrication)
        return min(s, 0.45)
