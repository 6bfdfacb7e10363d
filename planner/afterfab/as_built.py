"""The as-built model of a measured chip: one builder for the re-plan, the trim and a
yield study.

A measured resonance is one number per impacter (per half), but the fabrication error
that moved it moved more than the stiffness: a line-width error dw widens the beams
(w + dw), grows the plate ((sqrt(A) + dw)^2: mass and squeeze-film damping) and closes
the gap (c - dw), as :mod:`planner.fabrication.tolerances` builds a sampled chip.  A model that
keeps the design's mass, damping and gap and only fits k to the resonance is not the
chip: near a design's tone window the difference decides (issue 37: 11 of 200 chips of
the default, re-planned from an exact measurement, failed only on their true models).

So the errors are inferred, then the chip rebuilt through eqs. (2)-(4):

1. **Each resonance's shift** y = ln(nu_measured / nu_design) is, to first order, s . e:
   the sensitivities s of :func:`planner.fabrication.tolerances.frequency_sensitivities` times the
   five errors e (line width, thickness, gap, Young's modulus, natural frequency) of that
   impacter, each the sum of a die part (shared by the chip), a device part (per
   impacter pair) and, for a pair measured half by half, a pair part per half.
2. **The errors' posterior mean** under the spec's ``fabrication:`` sigmas as Gaussian
   priors and the measurement's noise (:data:`DEFAULT_NOISE_PCT`, or the lab's): the die
   part from every impacter at once (matched sensitivities make it one common factor), by
   a Kalman update in covariance form; then each impacter's own part given it.  With
   line width the only tolerance, as in the default, every shift is a line-width error.
3. **Exact resonance**: along the direction the posterior moved the impacter, a 1-D root
   makes the rebuilt model's resonance the measured one (the measurement is the best
   knowledge of it; the prior only says how to split it into mass, stiffness, damping
   and gap).
4. **Sliders**: every slider takes the die's line-width and thickness parts (its own
   device part is not measured).
5. A measured quality factor sets the damping (b = m 2 pi nu_n / Q) and a measured gap
   the gap, overriding what the geometry gives.

Without fabrication tolerances (nothing to split the shift by) every shift is the
stiffness's: k from the measured resonance, the design's mass, damping and gap.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from scipy import optimize

import model
from planner.fabrication.tolerances import (
    ERRORS,
    ChipDesign,
    Tolerances,
    as_built_impacter,
    as_built_slider,
    frequency_sensitivities,
    nominal_impacter,
)

#: Relative sigma of a measured resonance when the lab gives none [%]: a swept
#: resonance fit to 1e-4 to 1e-3 (:mod:`planner.lab.calibrate`, 1-2 % noise).
DEFAULT_NOISE_PCT = 0.05
#: Bracket of the exact-resonance root, in units of the posterior's own step [-].
ROOT_BRACKET = 4.0


@dataclass(frozen=True)
class AsBuilt:
    """A measured chip's models.

    Attributes
    ----------
    impacters : dict
        Id -> :class:`model.Impacter`, or :class:`model.PairHalves` for a pair measured
        half by half.
    sliders : dict
        Device -> :class:`model.Slider`.
    errors : dict
        Id -> the inferred errors (``ERRORS`` order, their units) of the pair, or of each
        half ((a, b)).
    die : tuple of float
        The inferred die part of the errors.
    """

    impacters: dict
    sliders: dict
    errors: dict
    die: tuple

    def parameters(self) -> dict:
        """Id -> plan.json's ``as_built`` entry: natural frequency, stiffness, damping,
        gap, mass and the inferred errors (each half's too, where measured apart)."""
        out = {}
        for n, imp in self.impacters.items():
            parts = model.halves(imp)
            mean = symmetric(imp)
            rec = {"natural_frequency_hz": float(mean.natural_frequency),
                   "stiffness_n_per_m": float(mean.stiffness),
                   "damping_ns_per_m": float(mean.damping), "gap_m": float(mean.gap),
                   "mass_kg": float(mean.mass)}
            errs = self.errors[n]
            if len(parts) > 1:
                rec["halves"] = [
                    {"half": h, "natural_frequency_hz": float(p.natural_frequency),
                     "stiffness_n_per_m": float(p.stiffness),
                     "damping_ns_per_m": float(p.damping), "gap_m": float(p.gap),
                     "mass_kg": float(p.mass),
                     "errors": dict(zip(ERRORS, (float(x) for x in e)))}
                    for h, (p, _), e in zip("ab", parts, errs)]
            else:
                rec["errors"] = dict(zip(ERRORS, (float(x) for x in errs[0])))
            out[n] = rec
        return out


def symmetric(imp):
    """The symmetric pair standing for a pair of unequal halves (plan.json's impacter
    record of a pair measured half by half): their mean resonance and mass, mean
    damping and the wider gap (:attr:`model.PairHalves.gap`); a symmetric pair is
    itself."""
    if not isinstance(imp, model.PairHalves):
        return imp
    parts = [h for h, _ in model.halves(imp)]
    w = 2.0 * math.pi * float(imp.natural_frequency)
    m = float(imp.mass)
    return model.Impacter(m, m * w * w, float(np.mean([h.damping for h in parts])),
                          float(imp.gap), imp.a.impact_angle, imp.a.restitution)


def resonance_times(imp, ratio: float):
    """``imp`` (an impacter or a pair of halves) with its natural frequency times
    ``ratio``: the stiffness times ``ratio**2``, the mass, and so the kick each impact
    gives, kept (both halves alike)."""
    parts = [dataclasses.replace(h, stiffness=h.stiffness * ratio * ratio)
             for h, _ in model.halves(imp)]
    return parts[0] if len(parts) == 1 else model.pair_of(*parts)


def _variances(design: ChipDesign):
    """(die, device, pair) variances of the five errors (their units squared)."""
    return Tolerances.from_spec(design.spec.fabrication).variances()


def infer_errors(design: ChipDesign, measured: dict, noise_pct=DEFAULT_NOISE_PCT):
    """The posterior mean of each impacter's errors (see the module docstring).

    Parameters
    ----------
    design : planner.fabrication.tolerances.ChipDesign
        The chip's designs (:func:`planner.fabrication.tolerances.design_from_plan`).
    measured : dict
        Id -> :class:`~planner.afterfab.measurement.Measurement`; an impacter without
        one is not measured (its errors are the die's).
    noise_pct : float
        Relative sigma of a measured resonance [%].

    Returns
    -------
    (die, errors)
        ``die``: shape (5,); ``errors``: id -> list of one error vector per measured
        half (one for a pair measured whole or not measured).
    """
    var_die, var_dev, var_pair = _variances(design)
    spec = design.spec
    noise = (float(noise_pct) / 100.0) ** 2
    obs = []
    for node in design.nodes:
        s = frequency_sensitivities(spec, node, which=(var_die + var_dev + var_pair) > 0)
        nu0 = nominal_impacter(spec, node).natural_frequency
        m = measured.get(node.id)
        y = (np.array([math.log(f / nu0) for f in m.halves_hz]) if m is not None
             else np.zeros(0))
        h = y.size
        # y = 1 s.d + 1 s.e + s.p_h + noise: cov given d
        v = (float(s @ (var_dev * s)) * np.ones((h, h)) + float(s @ (var_pair * s)) * np.eye(h)
             + noise * np.eye(h))
        obs.append((node, s, y, v))
    # the die part: a Kalman update per impacter, in covariance form (a zero prior
    # variance stays zero)
    mean = np.zeros(len(ERRORS))
    cov = np.diag(var_die)
    for _, s, y, v in obs:
        if not y.size:
            continue
        hmat = np.outer(np.ones(y.size), s)
        gain = cov @ hmat.T @ np.linalg.inv(hmat @ cov @ hmat.T + v)
        mean = mean + gain @ (y - hmat @ mean)
        cov = cov - gain @ hmat @ cov
    errors = {}
    for node, s, y, v in obs:
        if not y.size:
            errors[node.id] = [mean.copy()]
            continue
        r = np.linalg.solve(v, y - (s @ mean) * np.ones(y.size))
        dev = (var_dev * s) * float(np.sum(r))
        errors[node.id] = [mean + dev + (var_pair * s) * float(r[k]) for k in range(y.size)]
    return mean, errors


def _exact(spec, node, err, target_hz, direction):
    """``err`` moved along ``direction`` until the rebuilt model's resonance is
    ``target_hz`` (a 1-D root; ``err`` unchanged when no such move exists nearby)."""
    if not np.any(direction):
        return err

    def miss(t):
        return math.log(as_built_impacter(spec, node, err + t * direction).natural_frequency
                        / target_hz)

    f0 = miss(0.0)
    if abs(f0) < 1e-13:
        return err
    slope = (miss(1e-3) - f0) / 1e-3
    if not math.isfinite(slope) or slope == 0.0:
        return err
    t0 = -f0 / slope
    lo, hi = sorted((0.0, ROOT_BRACKET * t0 if t0 else 1.0))
    lo -= abs(t0)
    hi += abs(t0)
    try:
        if miss(lo) * miss(hi) > 0:
            return err + t0 * direction
        t = optimize.brentq(miss, lo, hi, xtol=1e-15, rtol=1e-14, maxiter=200)
    except ValueError:      # a trial geometry that cannot be built: the linear step
        return err + t0 * direction
    return err + t * direction


def as_built(design: ChipDesign, measured: dict, *, noise_pct=DEFAULT_NOISE_PCT) -> AsBuilt:
    """The as-built models of a measured chip (see the module docstring).

    Parameters
    ----------
    design : planner.fabrication.tolerances.ChipDesign
        The chip's designs.
    measured : dict
        Id -> :class:`~planner.afterfab.measurement.Measurement` (quality factors and
        gaps where measured); an impacter without one keeps the die's errors.
    noise_pct : float
        Relative sigma of a measured resonance [%] (how far the prior may pull it).

    Returns
    -------
    AsBuilt
    """
    spec = design.spec
    var_die, var_dev, var_pair = _variances(design)
    if not np.any(var_die + var_dev + var_pair):
        return _stiffness_only(design, measured)
    die, errors = infer_errors(design, measured, noise_pct)
    impacters, out_errors = {}, {}
    for node in design.nodes:
        m = measured.get(node.id)
        parts, errs = [], []
        for k, err in enumerate(errors[node.id]):
            if m is not None:
                step = err - die
                # the exact resonance, moving the node's own part of the error (the die
                # part where the node has none: no device or pair sigma)
                direction = step if np.any(step) else (var_die + var_dev) * \
                    frequency_sensitivities(spec, node)
                err = _exact(spec, node, err, m.halves_hz[k], direction)
            imp = as_built_impacter(spec, node, err)
            if m is not None:
                imp = _measured_extras(imp, m.quality[k], m.gap_m[k], m.damping_ns_per_m)
            parts.append(imp)
            errs.append([float(x) for x in err])
        impacters[node.id] = parts[0] if len(parts) == 1 else model.pair_of(*parts)
        out_errors[node.id] = errs
    sliders = {d: as_built_slider(spec, d, float(die[0]), float(die[1])) for d in design.devices}
    return AsBuilt(impacters, sliders, out_errors, tuple(float(x) for x in die))


def _measured_extras(imp, quality, gap, damping):
    """``imp`` with a measured quality factor's damping (b = m 2 pi nu_n / Q), a known
    damping, or a measured gap."""
    if quality is None and gap is None and damping is None:
        return imp
    b = imp.damping
    if quality is not None:
        b = imp.mass * 2.0 * math.pi * imp.natural_frequency / float(quality)
    elif damping is not None:
        b = float(damping)
    return model.Impacter(imp.mass, imp.stiffness, b, float(gap) if gap else imp.gap,
                          imp.impact_angle, imp.restitution, imp.geometry)


def _stiffness_only(design: ChipDesign, measured: dict) -> AsBuilt:
    """Without tolerances: k from each measured resonance, the design's mass, damping
    and gap (and the design's sliders)."""
    spec = design.spec
    impacters, errors = {}, {}
    for node in design.nodes:
        base = nominal_impacter(spec, node)
        m = measured.get(node.id)
        parts = []
        for k, nu in enumerate(m.halves_hz if m is not None else (base.natural_frequency,)):
            w = 2.0 * math.pi * float(nu)
            imp = model.Impacter(base.mass, base.mass * w * w, base.damping, base.gap,
                                 base.impact_angle, base.restitution, base.geometry)
            if m is not None:
                imp = _measured_extras(imp, m.quality[k], m.gap_m[k], m.damping_ns_per_m)
            parts.append(imp)
        impacters[node.id] = parts[0] if len(parts) == 1 else model.pair_of(*parts)
        errors[node.id] = [[0.0] * len(ERRORS) for _ in parts]
    sliders = {d: as_built_slider(spec, d, 0.0, 0.0) for d in design.devices}
    return AsBuilt(impacters, sliders, errors, (0.0,) * len(ERRORS))
