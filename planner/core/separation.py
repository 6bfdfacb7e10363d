"""One rule for how far apart two tones must be, shared by the assigner and the designer.

The designer (:func:`planner.designer.design_impacter`) keeps every design silent across
a relative guard band around each forbidden frequency f_j, f_j (1 - g) ... f_j (1 + g)
(``design.guard``: the margin for model and fabrication error), and so it refuses a
target inside that band.  The assigner must therefore never give two impacters that
have to be told apart tones that close: for tones f_lo < f_hi that means
f_hi (1 - g) > f_lo, a fixed *ratio* -- a fixed number of channels on a log grid,
a number that grows with frequency on a linear grid (a 1 % guard is 400 Hz at 40 kHz,
600 Hz at 60 kHz).  The assigner also keeps them ``drive.guard.separation_channels``
apart (the response band, before designs exist).

Both are met by colouring on a *position grid* (:func:`position_grid`): a subset of
the channels in which any two positions ``separation`` or more apart are at least that
many channels apart *and* outside each other's guard band.  Where the guard is
narrower than ``separation`` channels (the whole band of the default 5 x 5 spec) the
positions are the channels; above that the positions thin out.  The number of
positions is what the band can hold, and what the capacity check counts.
"""

from __future__ import annotations

import math

import numpy as np


def in_guard_band(target_hz: float, forbidden_hz: float, guard: float) -> bool:
    """Whether ``target_hz`` lies in the guard band of ``forbidden_hz``.

    Parameters
    ----------
    target_hz : float
        A design's target frequency [Hz].
    forbidden_hz : float
        A frequency the design must be silent at [Hz].
    guard : float
        Relative half-width of the guard band [-].

    Returns
    -------
    bool
        ``forbidden_hz (1 - guard) <= target_hz <= forbidden_hz (1 + guard)``.
    """
    return forbidden_hz * (1.0 - guard) <= target_hz <= forbidden_hz * (1.0 + guard)


def check_target(target_hz: float, forbidden, guard: float) -> None:
    """Refuse a target inside the guard band of a forbidden frequency (the designer's
    entry check).

    Raises
    ------
    ValueError
        Naming the target, the forbidden frequency and the guard.
    """
    for f in forbidden:
        if in_guard_band(target_hz, f, guard):
            raise ValueError(f"the target {target_hz:g} Hz lies in the guard band of the "
                             f"forbidden frequency {f:g} Hz (guard {guard:g})")


def separated(f_a: float, f_b: float, guard: float) -> bool:
    """Whether two tones [Hz] may belong to impacters that must be told apart: neither
    lies in the other's guard band (relative half-width ``guard`` [-])."""
    return not (in_guard_band(f_a, f_b, guard) or in_guard_band(f_b, f_a, guard))


def position_grid(grid, separation: int, guard: float, allowed=None,
                  min_ratio=None) -> np.ndarray:
    """Channel indices of the positions a colouring with ``separation`` is laid out on.

    Parameters
    ----------
    grid : array_like
        Channel centre frequencies [Hz], increasing.
    separation : int
        The smallest separation of the colouring [positions] (``>= 1``).
    guard : float
        The designer's relative guard band [-].
    allowed : array_like of bool, shape (n_channels,), optional
        Channels a tone may take (the tones a design can serve,
        :mod:`planner.planning.reach`); default all.
    min_ratio : array_like, shape (n_channels,), optional
        The least ratio [-] between a channel's tone and the tone of the position
        ``separation`` below it (how far a design at that channel answers other tones,
        measured for the spec: :mod:`planner.planning.reach`); 1 imposes nothing.

    Returns
    -------
    ndarray of int
        Increasing channel indices, the first channel first.  Built bottom-up: each
        position is the next channel, or the first channel outside the guard band of
        the position ``separation`` below it if that is higher.  So any two positions
        ``separation`` or more apart are that many channels apart and
        :func:`separated` (the guard test is monotone in the ratio of the tones); and
        n tones pairwise ``separation`` apart fit iff (n - 1) separation + 1 positions
        exist, within a channel or so of the tightest packing.
    """
    grid = np.asarray(grid, dtype=float)
    separation = int(separation)
    if separation < 1:
        raise ValueError(f"separation must be >= 1, {separation!r} was given")
    guard = float(guard)
    if not (math.isfinite(guard) and 0.0 <= guard < 0.5):
        raise ValueError(f"guard must be in [0, 0.5), {guard!r} was given")
    if allowed is not None or min_ratio is not None:
        return _measured_positions(grid, separation, guard, allowed, min_ratio)
    if guard == 0.0:
        return np.arange(grid.size)
    pos = [0]
    n = grid.size
    while True:
        c = pos[-1] + 1
        if len(pos) >= separation:
            base = grid[pos[-separation]]
            # first channel strictly above base / (1 - guard), then the exact test
            c = max(c, int(np.searchsorted(grid, base / (1.0 - guard), side="right")) - 1)
            while c < n and not separated(base, grid[c], guard):
                c += 1
        if c >= n:
            break
        pos.append(c)
    return np.asarray(pos, dtype=np.int64)


def _measured_positions(grid, separation, guard, allowed, min_ratio):
    """:func:`position_grid` over the ``allowed`` channels, each position at least
    ``min_ratio`` (at the lower tone) above the one ``separation`` below it."""
    n = grid.size
    allowed = np.ones(n, dtype=bool) if allowed is None else np.asarray(allowed, dtype=bool)
    ratio = np.ones(n) if min_ratio is None else np.asarray(min_ratio, dtype=float)
    if allowed.shape != (n,) or ratio.shape != (n,):
        raise ValueError(f"allowed and min_ratio must have one entry per channel ({n})")
    pos = []
    for c in range(n):
        if not allowed[c]:
            continue
        if len(pos) >= separation:
            base = pos[-separation]
            if not (separated(grid[base], grid[c], guard)
                    and grid[c] >= grid[base] * ratio[base] * (1.0 - 1e-12)):
                continue
        pos.append(c)
    return np.asarray(pos, dtype=np.int64)


def guard_onset_hz(grid, separation: int, guard: float) -> float | None:
    """The lowest frequency [Hz] from which ``separation`` channels no longer clear the
    guard band (the positions thin out above it), or None if they do everywhere."""
    grid = np.asarray(grid, dtype=float)
    lo, hi = grid[:-separation], grid[separation:]
    inside = (((hi * (1.0 - guard) <= lo) & (lo <= hi * (1.0 + guard)))
              | ((lo * (1.0 - guard) <= hi) & (hi <= lo * (1.0 + guard))))
    if not inside.any():
        return None
    return float(lo[int(np.argmax(inside))])
