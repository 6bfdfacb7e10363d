"""The substrate drive: a sum of tones zeta(t) = sum_i Z_i cos(2 pi f_i t + phi_i)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from model.devices import (
    MAX_AMPLITUDE,
    MIN_FREQUENCY,
    UNUSUAL_AMPLITUDE,
    UNUSUAL_FREQUENCY,
    UnitWarning,
    _positive,
)

#: The paper's power convention Z0^2 w^3 [m^2/s^3] (Section III-B, footnote 3).
POWER = 50.0


def amplitude_from_power(frequency, power=POWER):
    """Tone amplitude Z0 = sqrt(power / w^3) [m] at ``frequency`` [Hz].

    Parameters
    ----------
    frequency : float or array_like
        f [Hz], finite and > 0.
    power : float
        Z0^2 w^3 [m^2/s^3], finite and > 0.

    Raises
    ------
    ValueError
        Naming ``frequency`` or ``power`` if it is not finite and > 0 (a negative
        power would otherwise pass through sqrt as NaN and be blamed on the amplitude).

    >>> round(float(amplitude_from_power(5000.0)) * 1e6, 2)   # footnote 3: 1.27 um at 5 kHz
    1.27
    """
    try:
        f = np.asarray(frequency, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"frequency must be numbers, {frequency!r} was given") from None
    if not (np.all(np.isfinite(f)) and np.all(f > 0)):
        raise ValueError(f"frequency must be finite and > 0, {f.tolist()!r} was given")
    p = _positive("power", power)
    w = 2.0 * np.pi * f
    return np.sqrt(p / w**3)


def _vector(name, values, *, positive=False, nonnegative=False):
    try:
        arr = np.atleast_1d(np.asarray(values, dtype=float)).copy()
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be numbers, {values!r} was given") from None
    if arr.ndim != 1:
        raise ValueError(f"{name} must be one-dimensional, shape {arr.shape} was given")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, {arr.tolist()!r} was given")
    if positive and np.any(arr <= 0):
        raise ValueError(f"{name} must be > 0, {arr.tolist()!r} was given")
    if nonnegative and np.any(arr < 0):
        raise ValueError(f"{name} must be >= 0, {arr.tolist()!r} was given")
    arr.setflags(write=False)
    return arr


def _check_units(f, z):
    """Refuse tones impossible in Hz and m (a drive given in kHz or um); warn on unusual ones.

    A zero-amplitude tone (a drive switched off) may have any frequency.
    """
    live = z > 0
    slow = live & (f < MIN_FREQUENCY)
    if np.any(slow):
        raise ValueError(f"frequencies are in Hz: {f[slow].tolist()!r} Hz is below "
                         f"{MIN_FREQUENCY:g} Hz; was it given in kHz?")
    if np.any(z > MAX_AMPLITUDE):
        raise ValueError(f"amplitudes are in m: {z[z > MAX_AMPLITUDE].tolist()!r} m is above "
                         f"{MAX_AMPLITUDE * 1e3:g} mm of die displacement; was it given in um? "
                         "(a power convention at a very low frequency gives such amplitudes too)")
    if np.any(z > UNUSUAL_AMPLITUDE) or np.any(live & (f > UNUSUAL_FREQUENCY)):
        import warnings

        warnings.warn(f"unusual drive: tones up to {f.max():g} Hz and {z.max() * 1e6:g} um "
                      "(frequencies in Hz, amplitudes in m)", UnitWarning, stacklevel=4)


@dataclass(frozen=True, eq=False)
class Drive:
    """Substrate displacement along the slider axis, a sum of tones.

    zeta(t) = sum_i Z_i cos(2 pi f_i t + phi_i).  The impacter feels the inertial
    force m cos(theta) (-zeta''(t)) (eq. 5), the slider M (-zeta''(t)).

    Parameters
    ----------
    frequencies : array_like, shape (n,)
        f_i [Hz], > 0.
    amplitudes : array_like, shape (n,)
        Z_i [m], >= 0.
    phases : array_like, shape (n,), optional
        phi_i [rad]; zeros by default.

    Raises
    ------
    ValueError
        A tone below 10 Hz or above 1 cm (a drive in kHz or um); tones above 1 mm or
        10 MHz are warned of (:class:`model.devices.UnitWarning`).

    Examples
    --------
    >>> d = Drive.tone(5000.0)
    >>> round(float(d.amplitudes[0]) * 1e6, 2)
    1.27
    """

    frequencies: np.ndarray
    amplitudes: np.ndarray
    phases: np.ndarray | None = None

    def __post_init__(self):
        f = _vector("frequencies", self.frequencies, positive=True)
        z = _vector("amplitudes", self.amplitudes, nonnegative=True)
        p = np.zeros_like(f) if self.phases is None else _vector("phases", self.phases)
        if not (f.shape == z.shape == p.shape):
            raise ValueError("frequencies, amplitudes and phases must have the same length, "
                             f"got {f.size}, {z.size} and {p.size}")
        if p.flags.writeable:
            p.setflags(write=False)
        _check_units(f, z)
        object.__setattr__(self, "frequencies", f)
        object.__setattr__(self, "amplitudes", z)
        object.__setattr__(self, "phases", p)

    @classmethod
    def tone(cls, frequency, power=POWER, phase=0.0):
        """One tone at ``frequency`` [Hz] with Z0 = sqrt(power / w^3) [m].

        ``power`` [m^2/s^3] must be finite and > 0; a ValueError names it otherwise.
        """
        return cls([frequency], [float(amplitude_from_power(frequency, power))], [phase])

    @classmethod
    def from_power(cls, frequencies, power=POWER, phases=None):
        """Several tones, each with Z0^2 w^3 = power [m^2/s^3] (finite, > 0)."""
        f = _vector("frequencies", frequencies, positive=True)
        return cls(f, amplitude_from_power(f, power), phases)

    def __add__(self, other):
        if not isinstance(other, Drive):
            return NotImplemented
        return Drive(np.concatenate([self.frequencies, other.frequencies]),
                     np.concatenate([self.amplitudes, other.amplitudes]),
                     np.concatenate([self.phases, other.phases]))

    def __len__(self):
        return self.frequencies.size

    def __repr__(self):
        tones = ", ".join(f"{f:g} Hz x {z * 1e6:.3g} um" for f, z in
                          zip(self.frequencies, self.amplitudes))
        return f"Drive({tones})"

    @property
    def omegas(self):
        """Angular frequencies [rad/s]."""
        return 2.0 * math.pi * self.frequencies

    def acceleration_amplitudes(self):
        """w_i^2 Z_i, amplitudes of -zeta''(t) [m/s^2]."""
        return self.omegas**2 * self.amplitudes

    def displacement(self, t):
        """zeta(t) [m] at times ``t`` [s]."""
        t = np.asarray(t, dtype=float)
        arg = np.multiply.outer(t, self.omegas) + self.phases
        return np.cos(arg) @ self.amplitudes
