"""The channel grid of a spec: the frequencies tones may take inside the band.

A ``log`` or ``linear`` grid of ``drive.channels.count`` channels, or a ``tolerance``
grid spaced by the fabrication scatter (:func:`planner.manufacturability.tolerance_grid`),
and the separation in channels that keeps two tones out of each other's response band.
"""

from __future__ import annotations

import math

from planner.spec.schema import ArraySpec


def channel_grid(spec: ArraySpec):
    """Channel centre frequencies [Hz] inside the band, ndarray shape (count,)."""
    import numpy as np

    if spec.drive.channels.spacing == "tolerance":
        from planner.manufacturability import spec_tolerance_grid

        return spec_tolerance_grid(spec)
    lo, hi = spec.drive.band_hz
    n = spec.drive.channels.channel_count
    if spec.drive.channels.spacing == "log":
        return np.geomspace(lo, hi, n)
    return np.linspace(lo, hi, n)


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
