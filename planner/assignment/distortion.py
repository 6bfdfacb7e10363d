"""Which of the guard rules' products matter, at a drive chain's stated distortion
(issue 46): the assigner keeps apart the tones whose products can move an idle impacter,
not those whose products are too weak to.

A product of playing tones that lands in an idle impacter's band
(:func:`planner.assignment.assign.guard_violations`) is a force on that impacter only
as far as the chain distorts.  With ``drive.chain``'s nonlinearity ``z = y + a2 y^2 +
a3 y^3`` (:class:`planner.synthesis.chain.Nonlinearity`) each product has an amplitude
at the die, from its source tones' amplitudes at the spec's convention (an upper bound:
the acceleration and input limits only lower them):

    n f_i (n = 2, 3)         a2 Y_i^2 / 2,  a3 Y_i^3 / 4
    f_i + f_j, |f_i - f_j|   a2 Y_i Y_j
    2 f_i - f_j              3/4 a3 Y_i^2 Y_j
    f_i + f_j - f_k          3/2 a3 Y_i Y_j Y_k
    f_i / n                  0 (a polynomial makes no subharmonic)

It can move the idle impacter when the closed-form silence bound
(:func:`model.bounds.silence_bound`) cannot prove a reference impacter silent under it
played exactly at the reference's resonance, the worst place in the band (a product
inside the guard band is at most there).  The reference is the design the idle
impacter's own design would start from: the member of the spec's design family (the
reach probes' designs, :attr:`planner.planning.reach.Reach.family`) nearest its tone in
log frequency, its resonance scaled with the tone.  Without a family (an assignment
before any reach: ``vibroplan assign``) every product with an amplitude counts, as
every product counted before the chain was known.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

import model
from model.bounds import silence_bound
from planner.config import ImpacterConfig, build_impacter
from planner.core.units import UM

#: The product amplitudes the threshold is bisected between [m] ...
THRESHOLD_LOW_M = 1e-13
#: ... and the steps of the bisection in log amplitude (2^-30 of the decade span).
THRESHOLD_STEPS = 30


@dataclasses.dataclass
class ProductRule:
    """What a guard rule's product is at the die, and whether it can move its impacter.

    Attributes
    ----------
    nonlinearity : planner.synthesis.chain.Nonlinearity
        The chain's distortion.
    tone_amplitude : callable
        ``tone_amplitude(frequency_hz) -> amplitude [m]`` of a tone at the spec's
        convention.
    reference : callable
        ``reference(node, tone_hz) -> model.Impacter or None``: the impacter a product
        at ``node`` idle on ``tone_hz`` is judged on (None: every product with an
        amplitude counts).
    """

    nonlinearity: object
    tone_amplitude: object
    reference: object
    _thresholds: dict = dataclasses.field(default_factory=dict)

    def amplitude(self, kind, product_hz, sources) -> float:
        """The product's amplitude at the die [m] (the module's table)."""
        nl = self.nonlinearity
        y = [float(self.tone_amplitude(f)) for f in sources]
        if kind == "harmonic":
            f = sources[0]
            n = product_hz / f
            if abs(n - 2.0) < 1e-6:
                return abs(nl.a2) * y[0] ** 2 / 2.0
            if abs(n - 3.0) < 1e-6:
                return abs(nl.a3) * y[0] ** 3 / 4.0
            return 0.0                                   # f / n
        if len(sources) == 2:
            if kind == SECOND_ORDER:
                return abs(nl.a2) * y[0] * y[1]
            return 0.75 * abs(nl.a3) * y[0] ** 2 * y[1]
        return 1.5 * abs(nl.a3) * y[0] * y[1] * y[2]

    def threshold(self, node, tone_hz) -> float:
        """The smallest amplitude [m] of a product at the reference impacter's resonance
        that the silence bound cannot prove silent (0: no reference, every product
        counts)."""
        key = (node, round(float(tone_hz), 6))
        if key not in self._thresholds:
            self._thresholds[key] = self._bisect(node, tone_hz)
        return self._thresholds[key]

    def _bisect(self, node, tone_hz):
        imp = self.reference(node, tone_hz)
        if imp is None:
            return 0.0
        nu = float(imp.natural_frequency)

        def silent(a):
            return bool(silence_bound(imp, model.Drive([nu], [a], [0.0])))

        lo, hi = math.log(THRESHOLD_LOW_M), math.log(float(imp.gap))
        if not silent(math.exp(lo)):
            return 0.0
        if silent(math.exp(hi)):
            return math.exp(hi)
        for _ in range(THRESHOLD_STEPS):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if silent(math.exp(mid)) else (lo, mid)
        return math.exp(hi)

    def judge(self, violation):
        """``violation`` with its ``amplitude_m`` and whether it ``moves`` its impacter."""
        a = self.amplitude(violation.kind, violation.product_hz, violation.sources)
        moves = a > 0.0 and a >= self.threshold(violation.node, violation.node_hz)
        return dataclasses.replace(violation, amplitude_m=a, moves=bool(moves))


#: The kind of a 2nd-order intermodulation product (f_i + f_j, |f_i - f_j|), which only
#: a chain's a2 makes (the guard rules without a chain do not look for it).
SECOND_ORDER = "intermodulation (2nd order)"


def product_rule(settings, reach=None):
    """The :class:`ProductRule` of ``settings``' drive chain, or None without a chain
    that distorts (the assignment is then exactly as without a chain).

    ``reach``: the spec's measured reach, whose design family gives the reference
    impacters (None or no family: every product with an amplitude counts)."""
    chain = getattr(settings, "chain", None)
    if chain is None or not (chain.nonlinearity.a2 or chain.nonlinearity.a3):
        return None
    family = tuple(getattr(reach, "family", ()) or ())

    def tone_amplitude(f):
        if settings.amplitude_m is not None:
            return settings.amplitude_m
        return float(model.amplitude_from_power(np.asarray([f]), settings.power_m2_s3)[0])

    def reference(node, tone_hz):
        if not family or node not in settings.impacters:
            return None
        (area, width, length, gap), tone = min(
            family, key=lambda d: (abs(math.log(d[1] / tone_hz)), d[1]))
        imp = settings.impacters[node]
        cfg = ImpacterConfig(area_um2=area / UM ** 2, width_um=width / UM,
                             length_um=length / UM, gap_um=gap / UM,
                             impact_angle_deg=math.degrees(imp.impact_angle_rad),
                             restitution=imp.restitution)
        built = build_impacter(cfg, imp.process, settings.environment)
        # the family member scaled to the idle tone, as a design there starts
        return built.with_natural_frequency(float(built.natural_frequency) * tone_hz / tone)

    return ProductRule(chain.nonlinearity, tone_amplitude, reference)


__all__ = ["ProductRule", "SECOND_ORDER", "product_rule"]
