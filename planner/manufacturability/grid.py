"""Spec level, before any design: the scatter a tolerance model predicts, the channel grid
it sizes (``drive.channels.spacing: tolerance``, with the z margin of
:func:`planner.core.intervals.z_for`), and :func:`channel_grid`, the channel grid of every
spec (log, linear or tolerance)."""

from __future__ import annotations

import math

import numpy as np

from planner.assignment.assign import activity, plan_steps
from planner.fabrication.tolerances import ERRORS, NodeDesign, Tolerances, frequency_sensitivities
from planner.core.intervals import z_for
from planner.arrayspec import ArraySpec, LoadedSpec, resolve_steps

#: Die-level common shifts (sigmas) the channel grid keeps from the band's ends [-].
DIE_SHIFT_SIGMAS = 3.0
#: The reference beam of a matched array: its width [um] when the spec gives none, and
#: the beams' share of the mass assumed for the reference sensitivity (the default
#: plan's designs carry 1-31 % of their mass in the beams).
REFERENCE_WIDTH_UM = 5.0
REFERENCE_BEAM_MASS_FRACTION = 0.2


def sensitivity_target_per_um(design) -> float:
    """The array's common line-width sensitivity S* [1/um] of a ``design:`` section.

    ``design.sensitivity_per_um`` when given, else that of a beam of
    ``design.beam_width_um`` (or :data:`REFERENCE_WIDTH_UM`) carrying a plate of
    1 - :data:`REFERENCE_BEAM_MASS_FRACTION` of the mass
    (:func:`planner.designer.sensitivity.reference_sensitivity`).
    """
    from planner.designer.sensitivity import reference_sensitivity

    if design.sensitivity_per_um is not None:
        return float(design.sensitivity_per_um)
    width = design.beam_width_um if design.beam_width_um is not None else REFERENCE_WIDTH_UM
    return reference_sensitivity(width * 1e-6, REFERENCE_BEAM_MASS_FRACTION) * 1e-6


def predicted_sigmas(spec) -> tuple[np.ndarray, np.ndarray]:
    """Per-parameter sensitivities before any design: (s, spread), shape (5,) each.

    ``s`` [1/unit]: the line width's is the matched target S* (with
    ``design.match_sensitivity``), else that of the narrowest beam allowed (the worst
    case); the others, which do not depend on the geometry to first order (thickness
    and gap cancel in eqs. (2)-(4), E enters as sqrt), from a reference design.
    ``spread`` [1/unit]: how much two designs' sensitivities may differ (the matched
    band's full width, or the unmatched range), which turns a die-level error into a
    relative shift between them.
    """
    des = spec.design
    node = NodeDesign("reference", "A1", "forward", 3e-8, REFERENCE_WIDTH_UM * 1e-6, 4e-4,
                      4e-6, math.pi / 4, 0.5)
    s = frequency_sensitivities(spec, node)
    spread = np.zeros(len(ERRORS))
    if des.match_sensitivity:
        s[0] = sensitivity_target_per_um(des)
        spread[0] = 2.0 * des.sensitivity_tolerance * s[0]
    else:
        lo, hi = des.bounds.width_um or (2.0, 10.0)
        if des.beam_width_um is not None:
            lo = hi = des.beam_width_um
        # S lies between 1/w (beam mass) and 1.5/w (plate mass)
        s[0] = 1.5 / lo
        spread[0] = 1.5 / lo - 1.0 / hi
    return s, spread


def pair_sigma_rel(spec) -> float:
    """Relative standard deviation of the difference of two as-built resonances [-].

    sqrt(2 sum_i (s_i sigma_device_i)^2 + 2 sum_i (s_i sigma_pair_i)^2 + sum_i (spread_i
    sigma_die_i)^2 / 6): the device-level parts of two impacters are independent; the
    pair level moves each pair's mean and widens its band by about as much; a die-level
    error moves two designs apart by the difference of their sensitivities, uniform over
    the spread (variance spread^2 / 6 for the difference of two uniform draws on it).
    """
    tol = Tolerances.from_spec(spec.fabrication)
    s, spread = predicted_sigmas(spec)
    # the pair level: each node's mean moves by sigma / sqrt(2) and its band widens by
    # about as much again (half the halves' difference); counted as one more device sigma
    return float(math.sqrt(2.0 * np.sum((s * tol.device) ** 2)
                           + 2.0 * np.sum((s * tol.pair) ** 2)
                           + np.sum((spread * tol.die) ** 2) / 6.0))


def tolerance_grid(band_hz, separation_hz, sigma_rel, z, sub=1) -> np.ndarray:
    """Channel frequencies [Hz] spaced so that neighbours ``sub`` channels apart stay
    separable: f_{k+1} = f_k + (separation_hz + z sigma_rel f_k) / sub.

    Parameters
    ----------
    band_hz : (float, float)
        The band [Hz]; the grid starts at its bottom and ends at or below its top.
    separation_hz : float
        How close two resonances may be and still be told apart [Hz].
    sigma_rel : float
        Relative sigma of the difference of two as-built resonances [-]
        (:func:`pair_sigma_rel`).
    z : float
        Margin in sigmas (:func:`z_for`).
    sub : int
        Channels per separation (``drive.guard.separation_channels``): the colouring
        keeps tones that must be told apart ``sub`` channels apart.

    Returns
    -------
    ndarray, shape (n,)

    Examples
    --------
    >>> g = tolerance_grid((5000.0, 8000.0), 400.0, 0.008, 3.0)
    >>> [round(float(f)) for f in g[:3]], len(g)
    ([5000, 5520, 6052], 6)
    """
    lo, hi = (float(b) for b in band_hz)
    sub = max(int(sub), 1)
    if not (separation_hz > 0 and math.isfinite(separation_hz)):
        raise ValueError(f"separation_hz must be finite and > 0, {separation_hz!r} was given")
    factor = 1.0 + z * sigma_rel / sub
    step = separation_hz / sub
    # closed form of the recurrence: f_k + c = (f_0 + c) factor^k, c = step / (factor - 1)
    if factor > 1.0:
        c = step / (factor - 1.0)
        n = int(math.floor(math.log((hi + c) / (lo + c)) / math.log(factor) + 1e-12)) + 1
        return (lo + c) * factor ** np.arange(n) - c
    n = int(math.floor((hi - lo) / step + 1e-12)) + 1
    return lo + step * np.arange(n)


def told_apart_count(spec) -> int:
    """Impacters (channel groups) the spec's steps make distinct: the colouring's nodes."""
    loaded = LoadedSpec(spec, resolve_steps(spec), "<spec>")
    return max(len(set(activity(plan_steps(loaded, 0.01)).values())), 1)


def die_shift_rel(spec) -> float:
    """Relative sigma of the common shift a die-level error gives every resonance [-]:
    sqrt(sum_i (s_i sigma_die_i)^2), the predicted sensitivities."""
    s, _ = predicted_sigmas(spec)
    die = Tolerances.from_spec(spec.fabrication).die
    return float(math.sqrt(np.sum((s * die) ** 2)))


def spec_tolerance_grid(spec) -> np.ndarray:
    """The channel grid of a spec with ``drive.channels.spacing: tolerance`` [Hz].

    The channels keep :data:`DIE_SHIFT_SIGMAS` sigmas of the die-level common shift
    from either end of ``drive.band_hz``: a chip whose resonances all came out high
    (or low) is re-planned with every tone moved by that factor, which must still be
    in the band the piezo drives.
    """
    z = z_for(spec.fabrication.target_yield, told_apart_count(spec) - 1)
    lo, hi = spec.drive.band_hz
    m = 1.0 + DIE_SHIFT_SIGMAS * die_shift_rel(spec)
    return tolerance_grid((lo * m, hi / m), spec.drive.channels.resonance_separation_hz,
                          pair_sigma_rel(spec), z, spec.drive.guard.separation_channels)


def channel_grid(spec: ArraySpec) -> np.ndarray:
    """Channel centre frequencies [Hz] inside the band, ndarray shape (count,): a ``log``
    or ``linear`` grid of ``drive.channels.count`` channels, or the ``tolerance`` grid
    spaced by the fabrication scatter (:func:`spec_tolerance_grid`).

    >>> from planner.arrayspec import ArraySpec
    >>> g = channel_grid(ArraySpec.model_validate(
    ...     {"drive": {"band_hz": [5000, 20000], "channels": {"count": 3}}}))
    >>> [round(float(f)) for f in g]
    [5000, 10000, 20000]
    """
    if spec.drive.channels.spacing == "tolerance":
        return spec_tolerance_grid(spec)
    lo, hi = spec.drive.band_hz
    n = spec.drive.channels.channel_count
    if spec.drive.channels.spacing == "log":
        return np.geomspace(lo, hi, n)
    return np.linspace(lo, hi, n)
