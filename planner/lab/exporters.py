"""Drive files: write a :class:`~planner.synthesis.Waveform` for a player, read it back, verify it.

Formats (the :data:`EXPORTERS` registry, name -> :class:`Exporter`):

``wav``
    32-bit float WAV, samples as a fraction of full scale (for a sound card or DAQ).
``wav16``
    16-bit integer WAV, full scale = 32767.
``csv``
    Two columns, ``time_s,displacement_m``: the displacement itself, no scaling.
``arb``
    Keysight 33500/33600 text arbitrary-waveform file (``File Format:1.10``), one
    integer per line in -32767..32767.

Full scale is the waveform's continuous-time peak (not only the largest sample), so the
generator's reconstructed signal stays inside full scale: no sample is ever clipped.

Every file ``NAME`` gets a JSON sidecar ``NAME.json`` with the tone table (frequency,
amplitude, phase), sample rate, loop length, points, ``full_scale_m`` (the displacement at
full scale), ``volts_full_scale`` (the generator voltage at full scale, if the piezo's
um/V and the amplifier's gain are given), crest factor, the scale applied against the
piezo's limit, and warnings.  ``playback`` says how to play the file: ``loop`` (repeat
it for the step's burst) or ``once``: a gated burst (:class:`planner.synthesis.gating.Burst`),
whose sidecar also holds ``starts_s``, ``gates_s`` and ``ramp_s`` (every tone's
envelope).  Both are written atomically (temporary file, then
``os.replace``).  :func:`read_waveform` reads any format back in metres through its
sidecar; :func:`measure_tones` and :func:`verify_export` check that a file's spectrum
holds its tones and that its loop point is continuous.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import warnings as _warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from planner.synthesis.gating import Burst, burst_samples
from planner.synthesis import Waveform

#: Largest integer code of the 16-bit formats; the scale is symmetric, so -32768 is unused.
INT16_FULL_SCALE = 32767

#: Upper edge of a typical sound card's passband [Hz]: its anti-alias/reconstruction
#: filters and the analog stage are specified to 20 kHz.
SOUND_CARD_BAND_HZ = 20e3

#: Waveform memory of a Keysight 33500B [points]: 1 M standard; the MEM option gives 16 M
#: (pass ``memory_points=KEYSIGHT_33500B_OPTION_MEMORY``).
KEYSIGHT_33500B_MEMORY = 1_000_000
KEYSIGHT_33500B_OPTION_MEMORY = 16_000_000

#: Elements per block (tones x samples) when projecting onto the tones, to bound memory.
BLOCK_ELEMENTS = 1 << 22

#: Acceptance of :func:`verify_export`: relative amplitude and absolute phase [rad].
AMPLITUDE_RTOL = 1e-3
PHASE_ATOL = 1e-3


#: What a drive file's samples are (the exporters' ``signal``; a sidecar's ``signal``
#: for the amplifier input): the die's displacement [m], as without a drive chain ...
DISPLACEMENT = "displacement_m"
#: ... or, with a drive chain (issue 46), the amplifier's input [V].
AMPLIFIER_INPUT = "amplifier_input_v"
#: The CSV column of each signal.
CSV_COLUMNS = {DISPLACEMENT: "displacement_m", AMPLIFIER_INPUT: "input_v"}


class DriveWarning(UserWarning):
    """A drive file that a player may not reproduce faithfully."""


@dataclass(frozen=True)
class Exporter:
    """One file format: how to write and read it, and the usual player's limits.

    Attributes
    ----------
    write : callable
        ``write(path, waveform, full_scale_m, volts_full_scale, signal=DISPLACEMENT)
        -> dict`` writes the data file and returns format-specific sidecar fields;
        ``signal`` says what the samples are (:data:`DISPLACEMENT`: the die's
        displacement [m]; :data:`AMPLIFIER_INPUT`: a drive chain's amplifier input [V],
        whose ``full_scale_m`` is then in volts).
    read : callable
        ``read(path, sidecar) -> (samples [m], sample_rate [Hz])``.
    description : str
        One line for help texts.
    suffix : str
        The usual file extension.
    resolution : float
        Smallest step as a fraction of full scale [-] (quantisation).
    band_hz : float or None
        Upper edge of the usual player's passband [Hz]; tones above it are warned about.
    memory_points : int or None
        The usual instrument's waveform memory [points].
    default_sample_rate : float
        Sample rate the command line uses for this format [Hz].
    """

    write: Callable
    read: Callable
    description: str
    suffix: str
    resolution: float
    band_hz: float | None = None
    memory_points: int | None = None
    default_sample_rate: float = 200e3

    def __call__(self, path, waveform, full_scale_m, volts_full_scale=None,
                 signal=None):
        if signal is None or signal == DISPLACEMENT:
            return self.write(path, waveform, full_scale_m, volts_full_scale)
        return self.write(path, waveform, full_scale_m, volts_full_scale, signal=signal)


# --------------------------------------------------------------------------- formats


def _write_wav(dtype):
    def write(path, waveform, full_scale_m, volts_full_scale, signal=DISPLACEMENT):
        from scipy.io import wavfile

        rate = int(round(waveform.sample_rate))
        if rate != waveform.sample_rate:
            raise ValueError(f"sample_rate {waveform.sample_rate:g} Hz: WAV stores a whole "
                             f"number of samples per second")
        fraction = waveform.samples / full_scale_m
        if dtype == np.int16:
            data = np.rint(fraction * INT16_FULL_SCALE).astype(np.int16)
        else:
            data = fraction.astype(np.float32)
        with open(path, "wb") as fh:
            wavfile.write(fh, rate, data)
        return {"encoding": "int16, +-32767 = full scale" if dtype == np.int16
                else "float32, +-1.0 = full scale"}
    return write


def _read_wav(path, sidecar):
    from scipy.io import wavfile

    rate, data = wavfile.read(path)
    if data.dtype == np.int16:
        fraction = data.astype(float) / INT16_FULL_SCALE
    elif data.dtype == np.float32:
        fraction = data.astype(float)
    else:
        raise ValueError(f"{path}: WAV data type {data.dtype} is not one vibroplan writes")
    return fraction * full_scale_of(sidecar), float(rate)


def _write_csv(path, waveform, full_scale_m, volts_full_scale, signal=DISPLACEMENT):
    table = np.column_stack([waveform.times, waveform.samples])
    # the column says what the samples are, as the caller states it (a drive chain's
    # amplifier input in volts), never guessed from the scales
    column = CSV_COLUMNS[signal]
    np.savetxt(path, table, fmt=("%.12g", "%.12e"), delimiter=",",
               header=f"time_s,{column}", comments="")
    return {"columns": ["time_s", column]}


def _read_csv(path, sidecar):
    table = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    return table[:, 1].copy(), float(sidecar["sample_rate_hz"])


def _write_arb(path, waveform, full_scale_m, volts_full_scale, signal=DISPLACEMENT):
    # High/Low Level are the output at codes +-32767: volts when the piezo's um/V and the
    # amplifier's gain are known, otherwise the displacement at full scale in um.
    if volts_full_scale is not None:
        level, unit = volts_full_scale, "V"
    else:
        level, unit = full_scale_m * 1e6, "um"
    codes = np.rint(waveform.samples / full_scale_m * INT16_FULL_SCALE).astype(np.int64)
    header = [
        "File Format:1.10",
        "Checksum:0",
        "Channel Count:1",
        f"Sample Rate:{waveform.sample_rate:.6f}",
        f"High Level:{level:.6f}",
        f"Low Level:{-level:.6f}",
        'Data Type:"short"',
        f"Data Points:{len(codes)}",
        "Data:",
    ]
    # CRLF: the instruments' own files use Windows line ends
    with open(path, "w", newline="\r\n") as fh:
        fh.write("\n".join(header) + "\n")
        fh.write("\n".join(map(str, codes.tolist())) + "\n")
    return {"level_unit": unit, "high_level": level, "low_level": -level}


def _read_arb(path, sidecar):
    header = {}
    with open(path) as fh:
        for line in fh:
            line = line.strip()
            if line == "Data:":
                break
            key, _, value = line.partition(":")
            header[key.strip()] = value.strip()
        else:
            raise ValueError(f"{path}: no 'Data:' line; not a Keysight .arb file")
        codes = np.loadtxt(fh, dtype=np.int64, ndmin=1)
    if header.get("File Format") != "1.10":
        raise ValueError(f"{path}: File Format {header.get('File Format')!r}, expected 1.10")
    if int(header.get("Data Points", -1)) != len(codes):
        raise ValueError(f"{path}: Data Points {header.get('Data Points')} but {len(codes)} "
                         f"values follow")
    if np.any(np.abs(codes) > INT16_FULL_SCALE):
        raise ValueError(f"{path}: values outside -32767..32767")
    samples = codes.astype(float) / INT16_FULL_SCALE * full_scale_of(sidecar)
    return samples, float(header["Sample Rate"])


#: Format name -> :class:`Exporter`.  Add an entry to support another player.
EXPORTERS: dict[str, Exporter] = {
    "wav": Exporter(_write_wav(np.float32), _read_wav, "32-bit float WAV (sound card, DAQ)",
                    ".wav", resolution=2.0**-24, band_hz=SOUND_CARD_BAND_HZ,
                    default_sample_rate=192e3),
    "wav16": Exporter(_write_wav(np.int16), _read_wav, "16-bit integer WAV (sound card)",
                      ".int16.wav", resolution=1 / INT16_FULL_SCALE, band_hz=SOUND_CARD_BAND_HZ,
                      default_sample_rate=192e3),
    "csv": Exporter(_write_csv, _read_csv, "CSV time_s,displacement_m (any tool)", ".csv",
                    resolution=1e-11),
    "arb": Exporter(_write_arb, _read_arb, "Keysight 33500/33600 .arb text file", ".arb",
                    resolution=1 / INT16_FULL_SCALE, memory_points=KEYSIGHT_33500B_MEMORY),
}


def get_exporter(format) -> Exporter:
    """The registered :class:`Exporter` called ``format``; ValueError listing the names."""
    exporter = EXPORTERS.get(format) if isinstance(format, str) else None
    if exporter is None:
        raise ValueError(f"format must be one of {', '.join(EXPORTERS)}, {format!r} was given")
    return exporter


# --------------------------------------------------------------------------- export


def sidecar_path(path) -> Path:
    """The JSON sidecar of a drive file: ``NAME`` -> ``NAME.json``."""
    path = Path(path)
    return path.with_name(path.name + ".json")


def export(waveform: Waveform, path, format, *, um_per_v=None, amplifier_gain=None,
           band_hz=None, memory_points=None, die=None) -> Path:
    """Write a drive file and its JSON sidecar.

    Parameters
    ----------
    waveform : Waveform
        The drive (from :func:`planner.synthesize`).
    path : str or os.PathLike
        The data file; the sidecar is ``path + ".json"``.  Parent folders are created.
    format : str
        A name in :data:`EXPORTERS`: ``wav``, ``wav16``, ``csv`` or ``arb``.
    um_per_v : float, optional
        The piezo's displacement per volt [um/V]; with ``amplifier_gain`` it gives the
        generator voltage at full scale (the .arb file's levels, the sidecar's
        ``volts_full_scale``).
    amplifier_gain : float, optional
        Voltage gain of the piezo amplifier [V/V].
    band_hz : float, optional
        Upper edge of the player's passband [Hz]; default the format's (20 kHz for WAV).
    memory_points : int, optional
        The instrument's waveform memory [points]; default the format's (1 M for .arb,
        a Keysight 33500B; 16 M with its memory option).
    die : Waveform, optional
        With a drive chain (issue 46): ``waveform`` is then the amplifier input [V]
        and ``die`` the die's displacement [m] it gives, tone for tone.  The sidecar
        says so (``signal: amplifier_input_v``) and gives volts (``full_scale_v``,
        ``peak_v``, ``rms_v``, each tone's ``amplitude_v``) and, per tone, the die's
        ``die_amplitude_m`` and ``die_phase_rad`` and the transfer between them
        (``gain_m_per_v``, ``transfer_phase_rad``); ``volts_full_scale`` is the full
        scale itself.  ``um_per_v`` cannot be given with it.

    Returns
    -------
    Path
        The data file written.

    Warns
    -----
    DriveWarning
        For tones at or above Nyquist or above ``band_hz``, and for more points than
        ``memory_points``.  The same messages go into the sidecar's ``warnings``.
    """
    if not isinstance(waveform, Waveform):
        raise ValueError(f"waveform must be a Waveform, {type(waveform).__name__} was given")
    exporter = get_exporter(format)
    path = Path(path)
    volts_full_scale = None
    full_scale = max(float(waveform.peak), float(np.max(np.abs(waveform.samples))))
    if die is not None:
        if um_per_v is not None:
            raise ValueError("um_per_v cannot be given with die: the waveform is already "
                             "the amplifier input in volts")
        if len(die.frequencies) != len(waveform.frequencies):
            raise ValueError("die must have the input waveform's tones, one for one")
        um_per_v, gain = None, amplifier_gain
        amplifier_gain = None        # the volts are the input's: no piezo scale applies
    if (um_per_v is None) != (amplifier_gain is None):
        missing = "amplifier_gain" if amplifier_gain is None else "um_per_v"
        raise ValueError(f"{missing} is needed too: volts need both um_per_v and amplifier_gain")
    if um_per_v is not None:
        for name, value in (("um_per_v", um_per_v), ("amplifier_gain", amplifier_gain)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be positive and finite, {value!r} was given")
        volts_full_scale = full_scale / (um_per_v * 1e-6 * amplifier_gain)
    band = exporter.band_hz if band_hz is None else band_hz
    memory = exporter.memory_points if memory_points is None else memory_points
    new = _player_warnings(waveform, band, memory)
    for message in new:
        _warnings.warn(message, DriveWarning, stacklevel=2)

    path.parent.mkdir(parents=True, exist_ok=True)
    if die is not None:
        volts_full_scale, amplifier_gain = full_scale, gain
    signal = AMPLIFIER_INPUT if die is not None else DISPLACEMENT
    extra = _atomic_write(path, lambda tmp: exporter(tmp, waveform, full_scale, volts_full_scale,
                                                     signal))
    if die is not None:
        _input_sidecar(path, format, waveform, die, full_scale, amplifier_gain, new, extra)
        return path
    sidecar = {
        "format": format,
        "file": path.name,
        "tones": [
            {"frequency_hz": float(f), "amplitude_m": float(a), "phase_rad": float(p),
             "frequency_shift_hz": float(s)}
            for f, a, p, s in zip(waveform.frequencies, waveform.amplitudes, waveform.phases,
                                  waveform.frequency_shift)
        ],
        "sample_rate_hz": float(waveform.sample_rate),
        "loop_length_s": float(waveform.loop_length),
        "loop_points": waveform.loop_points,
        "points": len(waveform.samples),
        "full_scale_m": full_scale,
        "volts_full_scale": volts_full_scale,
        "um_per_v": um_per_v,
        "amplifier_gain": amplifier_gain,
        "peak_m": float(waveform.peak),
        "rms_m": float(waveform.rms),
        "crest_factor": float(waveform.crest_factor),
        "scale": float(waveform.scale),
        "playback": "once" if isinstance(waveform, Burst) else "loop",
        "warnings": list(waveform.warnings) + new,
        **(extra or {}),
    }
    _write_sidecar(path, sidecar, waveform)
    return path


def _input_sidecar(path, format, waveform, die, full_scale, amplifier_gain, new, extra):
    """The sidecar of a drive chain's file: the amplifier input in volts (:func:`export`
    with ``die``)."""
    gain = np.asarray(die.amplitudes) / np.asarray(waveform.amplitudes)
    turn = np.angle(np.exp(1j * (np.asarray(die.phases) - np.asarray(waveform.phases))))
    sidecar = {
        "format": format,
        "file": path.name,
        "signal": AMPLIFIER_INPUT,
        "tones": [
            {"frequency_hz": float(f), "amplitude_v": float(a), "phase_rad": float(p),
             "frequency_shift_hz": float(s), "die_amplitude_m": float(z),
             "die_phase_rad": float(q), "gain_m_per_v": float(g),
             "transfer_phase_rad": float(t)}
            for f, a, p, s, z, q, g, t in zip(waveform.frequencies, waveform.amplitudes,
                                              waveform.phases, waveform.frequency_shift,
                                              die.amplitudes, die.phases, gain, turn)
        ],
        "sample_rate_hz": float(waveform.sample_rate),
        "loop_length_s": float(waveform.loop_length),
        "loop_points": waveform.loop_points,
        "points": len(waveform.samples),
        "full_scale_v": full_scale,
        "volts_full_scale": full_scale,
        "amplifier_gain": amplifier_gain,
        "peak_v": float(waveform.peak),
        "rms_v": float(waveform.rms),
        "crest_factor": float(waveform.crest_factor),
        "die_peak_m": float(die.peak),
        "scale": float(waveform.scale),
        "playback": "once" if isinstance(waveform, Burst) else "loop",
        "warnings": list(waveform.warnings) + new,
        **(extra or {}),
    }
    _write_sidecar(path, sidecar, waveform)


def _write_sidecar(path, sidecar: dict, waveform) -> None:
    """Write ``sidecar`` beside ``path`` atomically, a burst's gates added (the
    displacement's sidecar and a drive chain's alike)."""
    if isinstance(waveform, Burst):
        sidecar["starts_s"] = [float(g) for g in waveform.starts_s]
        sidecar["gates_s"] = [float(g) for g in waveform.gates_s]
        sidecar["ramp_s"] = float(waveform.ramp_s)
    text = json.dumps(sidecar, indent=2) + "\n"
    _atomic_write(sidecar_path(path), lambda tmp: Path(tmp).write_text(text))


def full_scale_of(sidecar) -> float:
    """A drive file's full scale: [m] (``full_scale_m``), or [V] for a drive chain's
    amplifier input (``full_scale_v``)."""
    return sidecar["full_scale_v"] if "full_scale_v" in sidecar else sidecar["full_scale_m"]


def _player_warnings(waveform, band_hz, memory_points) -> list[str]:
    out = []
    f = np.asarray(waveform.frequencies)
    nyquist = waveform.sample_rate / 2
    above = f[f >= nyquist]
    if len(above):
        out.append(f"{len(above)} tone(s) at or above the Nyquist frequency {nyquist:g} Hz "
                   f"(highest {above.max():g} Hz): they alias")
    if band_hz is not None:
        above = f[(f > band_hz) & (f < nyquist)]
        if len(above):
            out.append(f"{len(above)} tone(s) above the player's {band_hz:g} Hz band "
                       f"(highest {above.max():g} Hz): expect them attenuated")
    if memory_points is not None and len(waveform.samples) > memory_points:
        out.append(f"{len(waveform.samples)} points exceed the instrument's memory of "
                   f"{memory_points} points: lower the sample rate or the loop length")
    return out


def _atomic_write(path: Path, write):
    """Call ``write(tmp)`` on a temporary file next to ``path``, then move it into place."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        result = write(tmp)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; give the file ordinary modes
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return result


# --------------------------------------------------------------------------- reading back


def read_sidecar(path) -> dict:
    """The JSON sidecar of drive file ``path`` (FileNotFoundError naming it if missing)."""
    side = sidecar_path(path)
    if not side.exists():
        raise FileNotFoundError(f"{side}: the sidecar of {Path(path).name} is missing; it holds "
                                f"the file's scale")
    return json.loads(side.read_text())


def read_waveform(path) -> tuple[np.ndarray, float]:
    """Read a drive file back as displacement.

    Parameters
    ----------
    path : str or os.PathLike
        A file written by :func:`export`, with its sidecar next to it.

    Returns
    -------
    samples : ndarray, shape (n_samples,)
        Displacement [m] (the file's values times the sidecar's ``full_scale_m``), or
        for a drive chain's file the amplifier input [V] (``full_scale_v``).
    sample_rate : float
        [Hz].
    """
    sidecar = read_sidecar(path)
    return get_exporter(sidecar["format"]).read(Path(path), sidecar)


def measure_tones(samples, sample_rate, frequencies) -> tuple[np.ndarray, np.ndarray]:
    """Amplitudes and phases of given tones in a record, by least-squares projection.

    Parameters
    ----------
    samples : array_like, shape (n_samples,)
        The record, ``x_n`` at ``t = n / sample_rate``.
    sample_rate : float
        [Hz].
    frequencies : array_like, shape (n_tones,)
        Tone frequencies [Hz], distinct, between 0 and Nyquist (exclusive).

    Returns
    -------
    amplitudes : ndarray, shape (n_tones,)
        In the units of ``samples``.
    phases : ndarray, shape (n_tones,)
        At ``t = 0`` [rad], in (-pi, pi].

    Notes
    -----
    Fits ``x_n = sum_i p_i cos(w_i n) + q_i sin(w_i n)`` by least squares, with the normal
    matrix in closed form (geometric sums), so ``A = hypot(p, q)``, ``phi = atan2(-q, p)``.
    Over whole loops the tones are orthogonal and this is exactly the DFT at each
    frequency; over a part of a loop it still separates them.
    """
    x = np.asarray(samples, dtype=float)
    f = np.atleast_1d(np.asarray(frequencies, dtype=float))
    n_pts, n_tones = len(x), len(f)
    nu = f / float(sample_rate)                       # cycles per sample
    rhs_c = np.zeros(n_tones)
    rhs_s = np.zeros(n_tones)
    block = max(1, BLOCK_ELEMENTS // n_tones)
    for start in range(0, n_pts, block):
        n = np.arange(start, min(n_pts, start + block), dtype=float)
        arg = 2 * np.pi * np.mod(np.outer(nu, n), 1.0)   # reduced first: exact phase
        rhs_c += np.cos(arg) @ x[start:start + len(n)]
        rhs_s += np.sin(arg) @ x[start:start + len(n)]
    s_minus = _geometric_sum(nu[:, None] - nu[None, :], n_pts)
    s_plus = _geometric_sum(nu[:, None] + nu[None, :], n_pts)
    cc = 0.5 * (s_minus.real + s_plus.real)
    ss = 0.5 * (s_minus.real - s_plus.real)
    cs = 0.5 * (s_plus.imag - s_minus.imag)          # sum cos(a n) sin(b n), [a, b]
    gram = np.block([[cc, cs], [cs.T, ss]])
    coef = np.linalg.lstsq(gram, np.concatenate([rhs_c, rhs_s]), rcond=None)[0]
    p, q = coef[:n_tones], coef[n_tones:]
    return np.hypot(p, q), np.arctan2(-q, p)


def _geometric_sum(cycles_per_sample, n_pts):
    """``sum_{n<N} exp(2j pi nu n)`` for an array of ``nu`` [cycles/sample]."""
    nu = np.mod(cycles_per_sample + 0.5, 1.0) - 0.5   # the sum depends on nu mod 1
    theta = 2 * np.pi * nu
    total = 2 * np.pi * np.mod(cycles_per_sample * n_pts, 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        value = (1 - np.exp(1j * total)) / (1 - np.exp(1j * theta))
    return np.where(np.abs(nu) < 1e-12, complex(n_pts), value)


@dataclass(frozen=True)
class Verification:
    """What :func:`verify_export` found in a drive file.

    Attributes
    ----------
    amplitude_error : float
        Largest relative amplitude error of a tone [-].
    phase_error : float
        Largest phase error of a tone [rad].
    loop_jump : float
        ``|x[0] - x[-1]|``, the step across the loop point [m].
    loop_bound : float
        Largest step a continuous signal can make in one sample, plus quantisation [m].
    whole_cycles : bool
        Every tone makes a whole number of cycles in the file.
    ok : bool
        All four within tolerance.
    sample_error : float or None
        A burst (``playback: once``): the largest difference of a sample from the
        burst's exact sum [m], against ``sample_bound`` (the format's quantisation);
        its ``loop_jump`` is then the displacement at its first and last samples,
        which must be 0 within a code, and ``amplitude_error`` and ``phase_error``
        are 0 (the tones have envelopes; the samples are checked instead).  None for
        a loop.
    sample_bound : float or None
        [m].
    """

    amplitude_error: float
    phase_error: float
    loop_jump: float
    loop_bound: float
    whole_cycles: bool
    ok: bool
    sample_error: float | None = None
    sample_bound: float | None = None

    def __str__(self):
        if self.sample_error is not None:
            return (f"{'ok' if self.ok else 'FAILED'}: burst samples within "
                    f"{self.sample_error * 1e9:.3g} nm of its gated tones (bound "
                    f"{self.sample_bound * 1e9:.3g} nm), ends at "
                    f"{self.loop_jump * 1e9:.3g} nm")
        return (f"{'ok' if self.ok else 'FAILED'}: amplitudes within "
                f"{self.amplitude_error * 100:.2g} %, phases within "
                f"{self.phase_error * 1e3:.2g} mrad, loop jump {self.loop_jump * 1e9:.3g} nm "
                f"(bound {self.loop_bound * 1e9:.3g} nm), "
                f"{'whole' if self.whole_cycles else 'NOT whole'} cycles")


def verify_export(path, *, amplitude_rtol=AMPLITUDE_RTOL, phase_atol=PHASE_ATOL) -> Verification:
    """Read a drive file back and check it against its sidecar's tone table.

    Parameters
    ----------
    path : str or os.PathLike
        A file written by :func:`export`.
    amplitude_rtol : float, optional
        Allowed relative amplitude error [-] (0.1 %).
    phase_atol : float, optional
        Allowed phase error [rad] (1 mrad).

    Returns
    -------
    Verification

    Notes
    -----
    A 16-bit file's error per sample is at most half a code, ``FS / 65534``; the projection
    averages it, so a tone's error is at most ``FS / 32767`` relative to the tone's own
    amplitude in the worst case (all errors aligned) and about ``sqrt(2 / N)`` times that
    for the rounding noise of N points.  The loop point is continuous if the step from the
    last sample to the first (by periodic extension) is no larger than any step a signal of
    these tones can make in one sample, ``sum_i 2 pi f_i A_i / fs``, plus one code.
    """
    sidecar = read_sidecar(path)
    samples, rate = read_waveform(path)
    f = np.array([t["frequency_hz"] for t in sidecar["tones"]])
    a = np.array([t["amplitude_v" if "amplitude_v" in t else "amplitude_m"]
                  for t in sidecar["tones"]])
    ph = np.array([t["phase_rad"] for t in sidecar["tones"]])
    if sidecar.get("playback") == "once":
        return _verify_burst(sidecar, samples, rate, f, a, ph)
    a_meas, ph_meas = measure_tones(samples, rate, f)
    amplitude_error = float(np.max(np.abs(a_meas / a - 1)))
    phase_error = float(np.max(np.abs(np.angle(np.exp(1j * (ph_meas - ph))))))
    resolution = get_exporter(sidecar["format"]).resolution * full_scale_of(sidecar)
    loop_bound = float(np.sum(2 * np.pi * f * a)) / rate + 2 * resolution
    loop_jump = float(abs(samples[0] - samples[-1]))
    cycles = f * len(samples) / rate
    whole = bool(np.all(np.abs(cycles - np.rint(cycles)) < 1e-6))
    ok = (amplitude_error <= amplitude_rtol and phase_error <= phase_atol
          and loop_jump <= loop_bound and whole)
    return Verification(amplitude_error, phase_error, loop_jump, loop_bound, whole, ok)


def _verify_burst(sidecar, samples, rate, f, a, ph) -> Verification:
    """:func:`verify_export` of a gated burst: every sample against the exact sum of
    its gated tones (:func:`planner.synthesis.gating.burst_samples`), within half a code of
    rounding plus the float32 WAV's relative precision; first and last samples at 0."""
    resolution = get_exporter(sidecar["format"]).resolution * full_scale_of(sidecar)
    exact = burst_samples(f, a, ph, sidecar["starts_s"], sidecar["gates_s"], sidecar["ramp_s"],
                          np.arange(len(samples)) / rate)
    error = float(np.max(np.abs(samples - exact)))
    bound = resolution
    ends = float(max(abs(samples[0]), abs(samples[-1])))
    ok = error <= bound and ends <= bound
    return Verification(0.0, 0.0, ends, bound, True, ok, sample_error=error,
                        sample_bound=bound)


__all__ = ["EXPORTERS", "Exporter", "DriveWarning", "export", "get_exporter", "read_waveform",
           "read_sidecar", "sidecar_path", "measure_tones", "verify_export", "Verification",
           "full_scale_of", "DISPLACEMENT", "AMPLIFIER_INPUT"]
