"""Validation of the simulation APIs' arguments, shared by the impacter and slider APIs.

Each check names the argument and the bad value in a ``ValueError`` (the house rule for
input at a public entry point).  Units are SI throughout.
"""

from __future__ import annotations

import math

import numpy as np

from model.devices import Impacter, Slider
from model.drive import Drive

#: Samples of a trajectory requested with ``trajectory=True``.
TRAJECTORY_SAMPLES = 2001


def check_float(name, value):
    """``value`` as a finite float, or a ValueError naming ``name``."""
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, {value!r} was given")
    return value


def check_state(impacter, x0, v0, duration):
    """An impacter's initial position [m], velocity [m/s] and a run's duration [s]."""
    x0 = check_float("x0", x0)
    v0 = check_float("v0", v0)
    duration = check_float("duration", duration)
    if duration <= 0:
        raise ValueError(f"duration must be > 0, {duration!r} was given")
    if x0 > impacter.gap:
        raise ValueError(f"x0 must be <= the gap {impacter.gap!r} m (the wall), {x0!r} was given")
    return x0, v0, duration


def check_impacter(impacter):
    """A ValueError unless ``impacter`` is a :class:`model.Impacter`."""
    if not isinstance(impacter, Impacter):
        raise ValueError(f"impacter must be a model.Impacter, {type(impacter).__name__} was given")


def check_slider(slider):
    """A ValueError unless ``slider`` is a :class:`model.Slider`."""
    if not isinstance(slider, Slider):
        raise ValueError(f"slider must be a model.Slider, {type(slider).__name__} was given")


def check_drive(drive):
    """A ValueError unless ``drive`` is a :class:`model.Drive`."""
    if not isinstance(drive, Drive):
        raise ValueError(f"drive must be a model.Drive, {type(drive).__name__} was given")


def sample_times(trajectory, duration):
    """The sample times [s] a ``trajectory=`` argument asks for (empty for none).

    True: :data:`TRAJECTORY_SAMPLES` evenly spaced over [0, duration]; an int n: n of
    them; an array: those times, sorted and finite.
    """
    if trajectory is None or trajectory is False:
        return np.empty(0)
    if trajectory is True:
        return np.linspace(0.0, duration, TRAJECTORY_SAMPLES)
    if isinstance(trajectory, (int, np.integer)):
        if trajectory < 2:
            raise ValueError(f"trajectory must be >= 2 samples, {trajectory!r} was given")
        return np.linspace(0.0, duration, int(trajectory))
    t = np.asarray(trajectory, dtype=float)
    if t.ndim != 1 or np.any(np.diff(t) < 0) or not np.all(np.isfinite(t)):
        raise ValueError("trajectory times must be a sorted one-dimensional array of finite times")
    return t
