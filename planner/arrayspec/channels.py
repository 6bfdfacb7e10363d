"""The channel separation of a spec: how many channels keep two tones out of each
other's response band.  The channel grid itself (log, linear, or spaced by the
fabrication scatter) is :func:`planner.manufacturability.channel_grid`: a tolerance grid
needs the tolerance model, which reads the spec."""

from __future__ import annotations

import math

from planner.arrayspec.schema import ArraySpec


def separation_for_bandwidth(spec: ArraySpec, relative_halfwidth: float) -> int:
    """Channels needed between two tones so neither lies in the other's response band.

    On a log grid with channel ratio rho, tones k channels apart are rho^k apart; a band of
    relative half-width b around each needs rho^k >= (1 + b) / (1 - b).
    """
    lo, hi = spec.drive.band_hz
    n = spec.drive.channels.channel_count
    b = min(max(relative_halfwidth, 1e-6), 0.99)
    if spec.drive.channels.spacing == "log":
        rho = (hi / lo) ** (1.0 / (n - 1))
        return max(1, math.ceil(math.log((1 + b) / (1 - b)) / math.log(rho) - 1e-9))
    step = (hi - lo) / (n - 1)
    return max(1, math.ceil(2 * b * hi / step - 1e-9))
