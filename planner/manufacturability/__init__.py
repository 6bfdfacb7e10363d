"""Manufacturability: will a fabricated chip's resonances still be told apart?

A plan verifies on the nominal chip.  A fabricated one has every natural frequency moved
by the process (:mod:`planner.fabrication.tolerances`): a die-level part shared by every impacter
and a device-level part of each.  The drive can follow a die that moved every resonance
by one factor (a re-plan measures the chip and scales the tones), but not two impacters
whose resonances came too close to be told apart.  This module predicts, in seconds and
without simulating chips, the fraction of chips on which that never happens -- the
*collision-free yield* -- and sizes the channel grid for it:

- :func:`sensitivities` (per design, d ln nu_n / d parameter through the as-built
  equations of :mod:`planner.fabrication.tolerances`);
- :func:`measure_separation` (per design, by simulation once): how far from its own
  resonance a tone must be for it to stay silent from every x0 at full power
  (``silent_beyond``), and how far its own tone may move and still drive it
  (``responds_within``);
- :func:`collision_free_yield`: a Monte Carlo of as-built resonances (10^4 chips in
  well under a second), first order in the errors, with its Wilson interval, the
  die-only and device-only yields, the closest-pair distribution and the pairs that
  limit it;
- :func:`tolerance_grid`: the channel grid of ``drive.channels.spacing: tolerance``, and
  :func:`channel_grid`, every spec's channel grid.

The collision rule
------------------
Impacter k has its resonance nu_k and tone t_k (the plan's), a silent band: it answers
tones in (nu_k - a_k, nu_k + b_k) from some x0 and none outside, and a tone window: its
tone may sit anywhere in [t_k - lo_k, t_k + hi_k] and still drive it.  On a chip every
resonance and tone moves by the impacter's as-built factor g_k = nu_k' / nu_k (a re-plan
keeps each tone's place relative to its resonance).  Two impacters i, j that must be
told apart *collide* when i's whole tone window lies in j's silent band, or j's in i's:
no tone then drives one without the other answering.  Before any design exists (the
channel grid, ``--dry-run``) every band is ``drive.channels.separation_hz`` wide on
either side of the tone and the windows are points.

Layout of this package (each module imports only those listed above it)

- :mod:`~planner.manufacturability.separation`: per design, once -- sensitivities and the
  separation (silent band, tone window) by simulation;
- :mod:`~planner.manufacturability.grid`: spec level, before any design -- predicted
  scatter, the tolerance channel grid, every spec's channel grid;
- :mod:`~planner.manufacturability.monte_carlo`: the collision-free yield.
"""

from __future__ import annotations

from planner.manufacturability.grid import (
    DIE_SHIFT_SIGMAS,
    channel_grid,
    REFERENCE_BEAM_MASS_FRACTION,
    REFERENCE_WIDTH_UM,
    die_shift_rel,
    pair_sigma_rel,
    predicted_sigmas,
    sensitivity_target_per_um,
    spec_tolerance_grid,
    told_apart_count,
    tolerance_grid,
    z_for,
)
from planner.manufacturability.monte_carlo import (
    CHIPS,
    LIMITING_PAIRS,
    MC_CELLS,
    YieldPrediction,
    collision_free_yield,
    predict_from_channels,
    prediction_lines,
)
from planner.manufacturability.separation import (
    BAND_MARGIN,
    EDGE_TOL_HZ,
    RESPONDS_FRACTION,
    SCAN_QUIET,
    SCAN_SPAN_REL,
    SCAN_STEP_MIN_HZ,
    SCAN_STEP_REL,
    Separation,
    measure_separation,
    sensitivities,
)

__all__ = [
    "sensitivities", "Separation", "measure_separation", "BAND_MARGIN", "EDGE_TOL_HZ",
    "RESPONDS_FRACTION", "SCAN_QUIET", "SCAN_SPAN_REL", "SCAN_STEP_MIN_HZ", "SCAN_STEP_REL",
    "predicted_sigmas", "pair_sigma_rel", "z_for", "tolerance_grid", "spec_tolerance_grid",
    "told_apart_count", "channel_grid", "die_shift_rel", "sensitivity_target_per_um", "DIE_SHIFT_SIGMAS",
    "REFERENCE_WIDTH_UM", "REFERENCE_BEAM_MASS_FRACTION",
    "YieldPrediction", "collision_free_yield", "predict_from_channels", "prediction_lines",
    "CHIPS", "LIMITING_PAIRS", "MC_CELLS",
]
