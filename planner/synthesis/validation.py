"""Argument checks of drive synthesis: each names the argument and the bad value."""

from __future__ import annotations

import math

import numpy as np


def _as_tone_array(values, name) -> np.ndarray:
    arr = np.atleast_1d(np.asarray(values, dtype=float))
    if arr.ndim != 1 or len(arr) == 0:
        raise ValueError(f"{name} must be a non-empty 1-D sequence, shape {arr.shape} was given")
    bad = np.nonzero(~np.isfinite(arr))[0]
    if len(bad):
        raise ValueError(f"{name}[{bad[0]}] must be finite, {arr[bad[0]]} was given")
    return arr


def _check_positive(arr, name):
    bad = np.nonzero(arr <= 0)[0]
    if len(bad):
        raise ValueError(f"{name}[{bad[0]}] must be positive, {arr[bad[0]]:g} was given")


def _positive_float(value, name) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, {value!r} was given") from None
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be positive and finite, {value!r} was given")
    return v


def _whole_samples(duration, fs) -> int:
    n = int(round(duration * fs))
    if n < 1 or abs(duration * fs - n) > 1e-6 * max(1.0, n):
        raise ValueError(f"duration must hold a whole number of samples at {fs:g} Hz, "
                         f"{duration!r} s holds {duration * fs:.6g}")
    return n

