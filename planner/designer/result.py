"""What the designer returns: :class:`DesignResult` and :class:`PairDesign`."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from model import Geometry, Impacter


@dataclass(frozen=True)
class DesignResult:
    """A designed impacter and what the designer measured about it (SI units).

    Attributes
    ----------
    impacter : model.Impacter
        The design, with its ``geometry``.
    frequency_hz : float
        Target drive frequency nu [Hz].
    forbidden_hz : tuple of float
        Forbidden frequencies nu_j [Hz], as given (sorted).
    natural_frequency_hz, mass_kg, stiffness_n_per_m, damping_ns_per_m, gap_m,
    impact_angle_rad, restitution : float
        nu_n [Hz], m [kg], k [N/m], b [N s/m], c [m], theta [rad], e [-].
    geometry : model.Geometry
        A [m^2], w [m], l [m], c [m].
    worst_x0_m : float
        The x0 of D with the smallest response at nu, on the re-check grid [m].
    r_min_n : float
        min over x0 of r at nu, eq. (13), on the re-check grid [N].
    r_max_forbidden_n : tuple of float
        max over x0 of r at each forbidden frequency, on the re-check grid [N]
        (0 where the design is feasible).
    margins_hz : tuple of float
        Distance from each forbidden frequency to the nearest frequency where the
        design responds from some x0 of the optimiser's constraint grid [Hz] (0 if it
        responds there); scanned on both sides out to the target's distance, then
        bisected (``Budget.margin_points``, ``Budget.margin_tol``).
    predicted_slider_speed_m_s : float
        Mean slider speed over the window when driven at nu from the worst x0, under
        the ``contact`` law, in its direction [m/s]; with a tone window, ``checks``
        also has the speeds at its edges.
    mass_ratio : float
        m / M, impacter mass over slider mass [-] (eq. 10 holds for m/M << 1; it
        creates energy for m/M above about 1/3, see docs/contact.md).
    contact : str
        The contact law the design was made for (:data:`model.CONTACTS`).
    feasible : bool
        Responds at nu from every x0 and at no forbidden frequency from any x0, on
        the re-check grid over the design window.
    evaluations : int
        Distinct designs simulated.
    seconds : float
        Wall-clock time of the design [s].
    simulations : int
        Impacter runs simulated (cache misses).
    checks : dict
        The re-checks: grid sizes, long window [s], whether it passed each, and how
        many archived designs passed on the optimiser's grid but failed a re-check.
    response_band_hz : (float, float)
        Lowest and highest frequency near nu where the design responds [Hz] (nan if
        not measured).
    status : str
        "ok", or "infeasible" (the design misses a constraint: ``shortfalls`` says
        which; when the search found none that meets them all, the least violating is
        returned).
    message : str
    shortfalls : tuple of dict
        Every constraint the design misses by its own prediction, by how much
        (:func:`planner.designer.design.shortfalls`: ``constraint``, ``value``,
        ``limit``, ``unit``, ``text``); empty when ``feasible``.
    tone_window : float
        The relative half-width of the tone window it was made to answer from every x0
        [-] (0: its tone alone).
    """

    impacter: Impacter
    frequency_hz: float
    forbidden_hz: tuple
    natural_frequency_hz: float
    mass_kg: float
    stiffness_n_per_m: float
    damping_ns_per_m: float
    gap_m: float
    impact_angle_rad: float
    restitution: float
    geometry: Geometry
    worst_x0_m: float
    r_min_n: float
    r_max_forbidden_n: tuple
    margins_hz: tuple
    predicted_slider_speed_m_s: float
    feasible: bool
    evaluations: int
    seconds: float
    simulations: int = 0
    checks: dict = field(default_factory=dict)
    response_band_hz: tuple = (math.nan, math.nan)
    status: str = "ok"
    message: str = ""
    seed: int | None = None
    budget: str = "full"
    window_s: float = 3e-3
    mass_ratio: float = math.nan
    contact: str = "paper"
    shortfalls: tuple = ()
    tone_window: float = 0.0

    def to_dict(self):
        """JSON-safe dict with the plan's impacter keys (SI units, unit-suffixed)."""
        g = self.geometry

        def num(x):
            x = float(x)
            return x if math.isfinite(x) else None

        return {
            "frequency_hz": num(self.frequency_hz),
            "forbidden_hz": [num(f) for f in self.forbidden_hz],
            "mass_kg": num(self.mass_kg),
            "stiffness_n_per_m": num(self.stiffness_n_per_m),
            "damping_ns_per_m": num(self.damping_ns_per_m),
            "gap_m": num(self.gap_m),
            "impact_angle_rad": num(self.impact_angle_rad),
            "restitution": num(self.restitution),
            "natural_frequency_hz": num(self.natural_frequency_hz),
            "geometry": {"area_m2": num(g.area), "width_m": num(g.width),
                         "length_m": num(g.length), "gap_m": num(g.gap)},
            "worst_x0_m": num(self.worst_x0_m),
            "r_min_n": num(self.r_min_n),
            "r_max_forbidden_n": [num(r) for r in self.r_max_forbidden_n],
            "margins_hz": [num(m) for m in self.margins_hz],
            "response_band_hz": [num(f) for f in self.response_band_hz],
            "predicted_slider_speed_m_s": num(self.predicted_slider_speed_m_s),
            "mass_ratio": num(self.mass_ratio),
            "contact": self.contact,
            "feasible": bool(self.feasible),
            "shortfalls": [{k: (num(v) if isinstance(v, float) else v) for k, v in s.items()}
                           for s in self.shortfalls],
            "tone_window": num(self.tone_window),
            "status": self.status,
            "message": self.message,
            "checks": {k: (num(v) if isinstance(v, float) else v) for k, v in self.checks.items()},
            "evaluations": int(self.evaluations),
            "simulations": int(self.simulations),
            "seconds": num(self.seconds),
            "seed": self.seed,
            "budget": self.budget,
            "window_s": num(self.window_s),
        }


@dataclass(frozen=True)
class PairDesign:
    """The forward and backward designs of one device (:func:`design_pair`)."""

    forward: DesignResult
    backward: DesignResult
    seconds: float

    @property
    def feasible(self):
        return self.forward.feasible and self.backward.feasible

    def to_dict(self):
        """``{"forward": {...}, "backward": {...}}`` as :meth:`DesignResult.to_dict`."""
        return {"forward": self.forward.to_dict(), "backward": self.backward.to_dict()}
