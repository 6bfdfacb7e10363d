"""The drive chain: from the waveform's volts at the amplifier input to the die's
displacement (issue 46).

Between the waveform file and the die stand a generator, an amplifier and a piezo stack.
Their linear part is one complex transfer ``H(f)`` [m/V]: the die's displacement per
volt at the amplifier's input, measured (:class:`TableTransfer`, interpolated in log
frequency, refused outside the frequencies it covers) or modelled
(:class:`ModelTransfer`: a flat gain, second-order resonances, a first-order low-pass).
Their distortion is a polynomial of the die's displacement (:class:`Nonlinearity`,
``z = y + a2 y^2 + a3 y^3``), fitted to the 2nd and 3rd harmonics' levels at a stated
stroke; intermodulation follows from it.

A step designed for the die tones ``Z_i cos(2 pi f_i t + phi_i)`` is played as the input
tones ``V_i = Z_i / |H(f_i)|`` at phases ``phi_i - arg H(f_i)`` (:func:`input_tones`,
:func:`compensate`): the die then feels the designed tones.  SI units throughout: m, V,
Hz, rad.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from planner.synthesis.kernels import _cosine_sum
from planner.synthesis.peak import peak_of
from planner.synthesis.waveform import Waveform

#: Relative slack of a table's ends: a tone this close outside the measured range (by
#: float rounding of a frequency snapped to its loop) is still inside [-].
TABLE_END_RTOL = 1e-9


class ChainError(ValueError):
    """A tone the chain cannot deliver: outside its transfer's table, or beyond a
    voltage limit.  ``frequency_hz``: the tone [Hz]."""

    def __init__(self, message, frequency_hz=None):
        super().__init__(message)
        self.frequency_hz = frequency_hz


@dataclass(frozen=True)
class TableTransfer:
    """A measured transfer: ``H(f)`` [m/V] at the table's frequencies, between them
    interpolated linearly in log frequency (log gain and unwrapped phase), outside them
    refused.

    Attributes
    ----------
    frequency_hz : ndarray, shape (n,)
        Increasing [Hz].
    gain_m_per_v : ndarray, shape (n,)
        ``|H|`` [m/V], positive.
    phase_rad : ndarray, shape (n,)
        ``arg H`` [rad] (unwrapped on construction).
    source : str or None
        The CSV it was read from (messages only).
    """

    frequency_hz: np.ndarray
    gain_m_per_v: np.ndarray
    phase_rad: np.ndarray
    source: str | None = None

    def __post_init__(self):
        for name in ("frequency_hz", "gain_m_per_v", "phase_rad"):
            arr = np.array(getattr(self, name), dtype=float)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "phase_rad", np.unwrap(self.phase_rad))
        self.phase_rad.setflags(write=False)
        if len(self.frequency_hz) < 2 or np.any(np.diff(self.frequency_hz) <= 0):
            raise ValueError("a transfer table needs at least 2 increasing frequencies")

    @property
    def band_hz(self) -> tuple[float, float]:
        """The frequencies the table covers [Hz]."""
        return float(self.frequency_hz[0]), float(self.frequency_hz[-1])

    def response(self, frequency_hz) -> np.ndarray:
        """``H(f)`` [m/V], complex, the shape of ``frequency_hz`` [Hz].

        Raises
        ------
        ChainError
            A frequency outside the table, naming it and the table's range.
        """
        f = np.asarray(frequency_hz, dtype=float)
        lo, hi = self.band_hz
        out = (f < lo * (1 - TABLE_END_RTOL)) | (f > hi * (1 + TABLE_END_RTOL))
        if np.any(out):
            bad = float(f[out].flat[0])
            raise ChainError(f"{bad:.6g} Hz is outside the transfer table "
                             f"{'(' + self.source + ') ' if self.source else ''}"
                             f"({lo:g}-{hi:g} Hz): measure the chain there", bad)
        x = np.log(np.clip(f, lo, hi))
        lx = np.log(self.frequency_hz)
        gain = np.exp(np.interp(x, lx, np.log(self.gain_m_per_v)))
        phase = np.interp(x, lx, self.phase_rad)
        return gain * np.exp(1j * phase)


@dataclass(frozen=True)
class ModelTransfer:
    """A modelled transfer [m/V]:

        H(f) = g prod_k 1 / (1 - u_k^2 + j u_k / Q_k) / (1 + j f / f_lp),  u_k = f / f_k

    a flat gain ``g``, every resonance a second-order peak (1 far below it, ``Q_k`` at
    it, phase turning by 180 degrees across it, falling as ``1/u^2`` above it: a piezo
    stack's mode), and an optional first-order low-pass (the amplifier's bandwidth).

    Attributes
    ----------
    gain_m_per_v : float
        ``g`` [m/V].
    resonances : tuple of (float, float)
        ``(f_k [Hz], Q_k [-])``.
    low_pass_hz : float or None
        ``f_lp`` [Hz].
    """

    gain_m_per_v: float
    resonances: tuple = ()
    low_pass_hz: float | None = None

    band_hz = None

    def response(self, frequency_hz) -> np.ndarray:
        """``H(f)`` [m/V], complex, the shape of ``frequency_hz`` [Hz]."""
        f = np.asarray(frequency_hz, dtype=float)
        h = np.full(f.shape, complex(self.gain_m_per_v))
        for fr, q in self.resonances:
            u = f / fr
            h = h / (1.0 - u * u + 1j * u / q)
        if self.low_pass_hz is not None:
            h = h / (1.0 + 1j * f / self.low_pass_hz)
        return h


@dataclass(frozen=True)
class Nonlinearity:
    """The chain's distortion as a polynomial of the die's displacement:
    ``z = y + a2 y^2 + a3 y^3``, ``y`` the linear (transferred) displacement [m].

    Attributes
    ----------
    a2 : float
        [1/m].
    a3 : float
        [1/m^2].

    Notes
    -----
    For ``y = S cos(w t)`` the 2nd harmonic is ``a2 S^2 / 2`` and the 3rd ``a3 S^3 / 4``,
    so levels ``h2``, ``h3`` [dB below the fundamental] at the stroke ``S`` give
    ``a2 = 2 * 10^(h2/20) / S`` and ``a3 = 4 * 10^(h3/20) / S^2`` (:meth:`from_harmonics`).
    Tones played together give intermodulation products ``f_i +- f_j`` (from ``a2``) and
    ``2 f_i +- f_j``, ``f_i +- f_j +- f_k`` (from ``a3``).
    """

    a2: float = 0.0
    a3: float = 0.0

    @classmethod
    def from_harmonics(cls, harmonics_db: dict, stroke_m: float) -> Nonlinearity:
        """From ``{2: h2, 3: h3}`` [dB, < 0] at the stroke ``stroke_m`` [m]."""
        a2 = a3 = 0.0
        if 2 in harmonics_db:
            a2 = 2.0 * 10.0 ** (harmonics_db[2] / 20.0) / stroke_m
        if 3 in harmonics_db:
            a3 = 4.0 * 10.0 ** (harmonics_db[3] / 20.0) / stroke_m ** 2
        return cls(a2, a3)

    def harmonics_db(self, stroke_m: float) -> dict:
        """The 2nd and 3rd harmonics' levels [dB] at the stroke ``stroke_m`` [m]."""
        out = {}
        if self.a2:
            out[2] = 20.0 * math.log10(self.a2 * stroke_m / 2.0)
        if self.a3:
            out[3] = 20.0 * math.log10(self.a3 * stroke_m ** 2 / 4.0)
        return out

    def __call__(self, y):
        """``z`` [m] of the linear displacement ``y`` [m]."""
        y = np.asarray(y, dtype=float)
        return y + self.a2 * y * y + self.a3 * y * y * y


@dataclass(frozen=True)
class DriveChain:
    """What stands between the waveform file and the die.

    Attributes
    ----------
    transfer : TableTransfer or ModelTransfer
        ``H(f)`` [m/V].
    nonlinearity : Nonlinearity
        The distortion (zero: linear).
    max_input_v : float or None
        Largest peak at the amplifier's input [V].
    max_output_v : float or None
        Largest peak at the amplifier's output [V] (the input times ``amplifier_gain``).
    amplifier_gain : float or None
        [V/V].
    """

    transfer: object
    nonlinearity: Nonlinearity = Nonlinearity()
    max_input_v: float | None = None
    max_output_v: float | None = None
    amplifier_gain: float | None = None

    def response(self, frequency_hz) -> np.ndarray:
        """``H(f)`` [m/V] (:attr:`transfer`'s)."""
        return self.transfer.response(frequency_hz)

    @property
    def input_limit(self) -> tuple[float, str] | None:
        """(the tightest peak at the input [V], the spec's field that sets it), or None."""
        limits = []
        if self.max_input_v is not None:
            limits.append((float(self.max_input_v), "drive.chain.max_input_v"))
        if self.max_output_v is not None and self.amplifier_gain:
            limits.append((float(self.max_output_v) / float(self.amplifier_gain),
                           "drive.chain.max_output_v / drive.amplifier_gain"))
        return min(limits) if limits else None


def input_tones(transfer, frequencies, amplitudes, phases):
    """The input tones that give the die ``amplitudes`` [m] at ``phases`` [rad].

    Returns
    -------
    (amplitudes_v, phases_rad) : ndarray, shape (n_tones,) each
        ``Z_i / |H(f_i)|`` [V] and ``phi_i - arg H(f_i)`` wrapped to (-pi, pi] [rad].
    """
    h = transfer.response(np.asarray(frequencies, dtype=float))
    a = np.asarray(amplitudes, dtype=float) / np.abs(h)
    ph = np.angle(np.exp(1j * (np.asarray(phases, dtype=float) - np.angle(h))))
    return a, ph


def die_tones(transfer, frequencies, amplitudes_v, phases):
    """The die's tones [m], [rad] of input tones [V], [rad] (the inverse of
    :func:`input_tones`, the linear part of the chain only)."""
    h = transfer.response(np.asarray(frequencies, dtype=float))
    a = np.asarray(amplitudes_v, dtype=float) * np.abs(h)
    ph = np.angle(np.exp(1j * (np.asarray(phases, dtype=float) + np.angle(h))))
    return a, ph


def distort(cycles, amplitudes, phases, nonlinearity: Nonlinearity, floor: float):
    """The die's tones after the chain's distortion: the fundamentals (with the cubic
    term's share added) and every 2nd- and 3rd-order product (harmonics and
    intermodulation) stronger than ``floor``.

    Parameters
    ----------
    cycles : array_like of int, shape (n_tones,)
        Each tone's whole cycles per loop (a loop's grid: every product is on it too).
    amplitudes : array_like, shape (n_tones,)
        The linear die tones ``Y_i`` [m].
    phases : array_like, shape (n_tones,)
        [rad].
    nonlinearity : Nonlinearity
        ``z = y + a2 y^2 + a3 y^3``.
    floor : float
        Products weaker than this are left out [m] (the fundamentals never are).

    Returns
    -------
    (cycles, amplitudes, phases, is_product) : ndarrays, shape (n_out,)
        Sorted by frequency; ``is_product`` False for a fundamental's own line.

    Notes
    -----
    Exact for the polynomial: with ``y = sum_k S_k exp(j k w0 t)`` over the two-sided
    lines ``S_{+-k_i} = Y_i exp(+-j phi_i) / 2``, ``y^2`` and ``y^3`` are the line
    spectra's self-convolutions; the one-sided amplitude at ``k > 0`` is ``2 |Z_k|``.
    The DC term (a static offset of the die) is left out.
    """
    k = [int(c) for c in cycles]
    out = _distorted_lines(k, amplitudes, phases, nonlinearity)
    own = set(k)
    keep = sorted(c for c, z in out.items()
                  if c > 0 and (c in own or 2 * abs(z) >= floor))
    z = np.array([out[c] for c in keep], dtype=complex)
    return (np.array(keep, dtype=np.int64), 2 * np.abs(z), np.angle(z),
            np.array([c not in own for c in keep], dtype=bool))


#: The line grid of :func:`distort_tones` [Hz]: tones and products closer than this are
#: one line (a product's frequency is a sum of floats; its phase error over a stretch
#: of ms is ~1e-8 rad).
LINE_RESOLUTION_HZ = 1e-6


def distort_tones(frequencies, amplitudes, phases, nonlinearity: Nonlinearity,
                  floor: float):
    """:func:`distort` of constant tones at any frequencies (not on a loop's grid: a
    gated burst's stretch, :meth:`planner.synthesis.gating.Burst.program`), exact for
    the polynomial over the stretch, with its phases at the stretch's start.

    Parameters
    ----------
    frequencies : array_like, shape (n_tones,)
        [Hz], positive.
    amplitudes, phases, nonlinearity, floor :
        As :func:`distort`'s.

    Returns
    -------
    (frequencies, amplitudes, phases, is_product) : ndarrays, shape (n_out,)
        [Hz], [m], [rad]; sorted by frequency; a tone's own line keeps its frequency.
    """
    f = np.asarray(frequencies, dtype=float)
    keys = [int(round(x / LINE_RESOLUTION_HZ)) for x in f]
    out = _distorted_lines(keys, amplitudes, phases, nonlinearity)
    exact = dict(zip(keys, f))
    own = set(keys)
    keep = sorted(c for c, z in out.items()
                  if c > 0 and (c in own or 2 * abs(z) >= floor))
    z = np.array([out[c] for c in keep], dtype=complex)
    freqs = np.array([exact.get(c, c * LINE_RESOLUTION_HZ) for c in keep], dtype=float)
    return (freqs, 2 * np.abs(z), np.angle(z),
            np.array([c not in own for c in keep], dtype=bool))


def _distorted_lines(keys, amplitudes, phases, nonlinearity):
    """The two-sided line spectrum {line: complex} of ``z = y + a2 y^2 + a3 y^3`` for
    ``y`` the tones on integer ``keys`` (see :func:`distort`'s notes)."""
    spec = {}
    for c, a, p in zip(keys, amplitudes, phases):
        z = 0.5 * float(a) * complex(math.cos(p), math.sin(p))
        spec[c] = spec.get(c, 0j) + z
        spec[-c] = spec.get(-c, 0j) + z.conjugate()
    out = dict(spec)
    if nonlinearity.a2 or nonlinearity.a3:
        sq = _convolve(spec, spec)
        if nonlinearity.a2:
            for c, z in sq.items():
                out[c] = out.get(c, 0j) + nonlinearity.a2 * z
        if nonlinearity.a3:
            for c, z in _convolve(sq, spec).items():
                out[c] = out.get(c, 0j) + nonlinearity.a3 * z
    return out


def _convolve(a, b):
    """The line spectrum of the product of two signals given as {line: complex}."""
    out = {}
    for ka, za in a.items():
        for kb, zb in b.items():
            c = ka + kb
            out[c] = out.get(c, 0j) + za * zb
    return out


def compensate(waveform: Waveform, transfer) -> Waveform:
    """The amplifier input [V] that plays ``waveform`` (the die's displacement [m]).

    Every tone divided by the transfer at its frequency (:func:`input_tones`); the same
    loop, samples, continuous peak, rms and crest factor recomputed for the input.
    ``scale`` and the warnings are kept (they are the die's), with one added that says
    what the samples are.

    Raises
    ------
    ChainError
        A tone outside a table transfer's range.
    """
    a, ph = input_tones(transfer, waveform.frequencies, waveform.amplitudes,
                        waveform.phases)
    cycles = np.rint(waveform.frequencies * waveform.loop_length).astype(np.int64)
    n = waveform.loop_points
    loop = _cosine_sum(cycles, n, a, ph)
    n_loops = max(1, len(waveform.samples) // n)
    samples = np.tile(loop, n_loops) if n_loops > 1 else loop
    peak = max(peak_of(cycles, a, ph), float(np.max(np.abs(samples)))) if len(a) else 0.0
    rms = math.sqrt(float(np.sum(a ** 2)) / 2.0)
    return dataclasses.replace(
        waveform, samples=samples, amplitudes=a, phases=ph, peak=peak, rms=rms,
        crest_factor=peak / rms if rms > 0 else 0.0,
        warnings=waveform.warnings + ("the samples are the amplifier input [V]: every "
                                      "tone divided by the chain's transfer",))


__all__ = ["ChainError", "DriveChain", "ModelTransfer", "Nonlinearity", "TableTransfer",
           "compensate", "die_tones", "distort", "distort_tones", "input_tones"]
