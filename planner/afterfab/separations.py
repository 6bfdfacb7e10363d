"""Silent bands and tone windows: when two as-built resonances can be told apart.

When are two resonances separable?
----------------------------------
The plan's ``manufacturability`` block gives every design its silent band (it answers a
tone from some x0 only within (nu - a, nu + b)) and its tone window (its tone may sit
anywhere in [t - lo, t + hi] and still drive it), and the re-plan keeps each tone's place
relative to its resonance, t = rho nu (rho = the designed tone over the designed nu_n).
Two impacters i below j are separable when some tone of i's window lies below j's silent
band and some tone of j's window above i's:

    nu_j >= max(rho_i nu_i - lo_i + a_j, (nu_i + b_i - hi_j) / rho_j) + margin,

the margin covering the trim's own error (:data:`MARGIN_SIGMAS` sigmas of
``trim.precision_pct`` on both).  This is the collision rule of
:mod:`planner.manufacturability`, solved for nu_j.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from planner.core.nodes import Node

#: Sigmas of the trim precision kept between two trimmed targets, on top of the
#: separation: a trimmed pair then stays separable on ~98 % of trims [-].
MARGIN_SIGMAS = 2.0

@dataclass(frozen=True)
class Separations:
    """What :func:`plan_trim` needs of each impacter, as arrays over impacters.

    Attributes
    ----------
    ids : tuple of str
    rho : ndarray
        Designed tone / designed natural frequency [-].
    below, above : ndarray
        Silent band reach below and above the resonance [Hz].
    lo, hi : ndarray
        Tone window reach below and above the tone [Hz].
    """

    ids: tuple
    rho: np.ndarray
    below: np.ndarray
    above: np.ndarray
    lo: np.ndarray
    hi: np.ndarray

    @classmethod
    def of(cls, ids, rho, separations) -> "Separations":
        """From the separations of plan.json's ``manufacturability.separation_hz`` (one
        dict per impacter of ``ids``), every silent band widened by
        :data:`planner.manufacturability.BAND_MARGIN`."""
        from planner.manufacturability import BAND_MARGIN

        widen = 1.0 + BAND_MARGIN
        return cls(tuple(ids), np.asarray(rho, dtype=float),
                   widen * np.array([s["silent_below"] for s in separations]),
                   widen * np.array([s["silent_above"] for s in separations]),
                   np.array([s["responds_below"] for s in separations]),
                   np.array([s["responds_above"] for s in separations]))

    @classmethod
    def from_plan(cls, data: dict) -> "Separations":
        """From a plan.json dict (its impacters and ``manufacturability`` block).

        Raises
        ------
        ValueError
            The plan has no ``manufacturability`` block (made before issue 25).
        """
        m = data.get("manufacturability")
        if not m or "separation_hz" not in m:
            raise ValueError("plan.json has no manufacturability.separation_hz (a plan made "
                             "before design for yield): re-plan it with this version")
        recs = sorted(data["impacters"], key=lambda r: r["id"])
        sep = m["separation_hz"]
        return cls.of([r["id"] for r in recs],
                      [r["frequency_hz"] / r["natural_frequency_hz"] for r in recs],
                      [sep[r["id"]] for r in recs])

    def needed(self, i: int, j: int, nu_i: float, precision: float = 0.0) -> float:
        """The lowest resonance [Hz] impacter ``j`` may have above impacter ``i`` at
        ``nu_i`` [Hz] and still be told apart from it (module notes); ``precision`` [-]
        adds the trim margin."""
        r_i, r_j = self.rho[i], self.rho[j]
        base = max(r_i * nu_i - self.lo[i] + self.below[j],
                   (nu_i + self.above[i] - self.hi[j]) / r_j)
        return base + MARGIN_SIGMAS * precision * math.sqrt(2.0) * base

    def separable(self, i: int, j: int, nu_i: float, nu_j: float) -> bool:
        """Whether ``i`` at ``nu_i`` and ``j`` at ``nu_j`` [Hz] can be told apart."""
        if nu_i > nu_j:
            i, j, nu_i, nu_j = j, i, nu_j, nu_i
        return nu_j >= self.needed(i, j, nu_i)


def separations_of(plan, settings) -> Separations:
    """The plan's :class:`planner.afterfab.separations.Separations`: its designs' silent bands and tone
    windows, from its ``manufacturability`` block, or, for a plan without one (made
    before it, or a re-plan from before re-plans carried it), measured now on its
    designs (a few seconds).

    Always the *designs'*: a chip is one chip whether its plan.json is the plan it was
    made by or a re-plan of it (whose impacters are as built and whose tones moved), so
    the separations, their tone ratios rho (designed tone / designed nu) and hence a
    re-plan's tones and a trim's targets are the same for both.  Measured now, each
    design is simulated at its designed tone, at the largest amplitude its tone plays in
    the plan's steps, as :func:`planner.planning.manufacture.assess` measured it.
    """
    from planner.fabrication.tolerances import NodeDesign, nominal_impacter
    from planner.manufacturability import measure_separation

    ids = tuple(sorted(r.id for r in plan.impacters))
    recs = {r.id: r for r in plan.impacters}
    tone = plan.design_frequency_hz or {r.id: r.frequency_hz for r in plan.impacters}
    block = (plan.manufacturability or {}).get("separation_hz")
    if block and set(block) >= set(ids):
        seps = [block[n] for n in ids]
    else:
        amps = _tone_amplitudes(plan)
        seps = []
        for n in ids:
            rec, g = recs[n], recs[n].geometry
            design = nominal_impacter(plan.spec, NodeDesign(
                n, rec.device, rec.direction, g.area_m2, g.width_m, g.length_m, g.gap_m,
                rec.impact_angle_rad, rec.restitution))
            seps.append(measure_separation(design, tone[n], tone_amplitude=amps.get(n),
                                           **settings.separation_kwargs()).to_dict())
    rho = np.array([tone[n] / plan.design_natural_frequency_hz[n] for n in ids])
    return Separations.of(ids, rho, seps)


def _tone_amplitudes(plan) -> dict:
    """Impacter id -> the largest amplitude [m] its tone plays at in the plan's steps
    (the steps that drive it; its tone the recorded one nearest its planned tone)."""
    out = {}
    for st in plan.steps:
        if not st.tones:
            continue
        freqs = np.array([t.frequency_hz for t in st.tones])
        for d, r in st.step.active_nodes():
            n = Node(d, r).text
            try:
                f = plan.impacter(n).frequency_hz
            except KeyError:
                continue
            k = int(np.argmin(np.abs(freqs - f)))
            out[n] = max(out.get(n, 0.0), float(st.tones[k].amplitude_m))
    return out


def remeasured(seps: Separations, ids, models: dict, tones: dict, settings) -> Separations:
    """``seps`` with the silent bands and tone windows of ``ids`` measured again, by
    simulation, on their as-built ``models`` (impacter id -> model) at ``tones`` (id ->
    tone [Hz]).

    The plan's separations were measured on the nominal designs; a trimmed impacter's
    model moved by up to the trim range (a few per cent), and at a band's edge the
    idle response is a grazing impact that such a move can bring a few per cent
    further out (measured: the close plan's A2.backward, trimmed 30 Hz up, answered a
    tone 304 Hz away once, outside its nominal band widened to 300 Hz).  About 0.1 s
    per impacter.
    """
    from planner.manufacturability import measure_separation

    ids = list(ids)
    rows = [seps.ids.index(n) for n in ids]
    # widened as the plan's are (Separations.of)
    fresh = Separations.of(ids, seps.rho[rows],
                           [measure_separation(models[n], tones[n],
                                               **settings.separation_kwargs()).to_dict()
                            for n in ids])
    out = {}
    for name in ("below", "above", "lo", "hi"):
        col = getattr(seps, name).copy()
        col[rows] = getattr(fresh, name)
        out[name] = col
    return dataclasses.replace(seps, **out)


