"""The lab's drive-chain sweep: read it, fit the chain, write the ``drive.chain`` block
(``vibroplan calibrate --chain``, issue 46).

SWEEP.csv has one row per played tone (blank lines and ``#`` comments skipped):

``frequency_hz``
    the tone [Hz];
``input_v``
    its amplitude at the amplifier's input [V] (half the peak-to-peak);
``displacement_um``
    the substrate's measured displacement amplitude at that frequency [um];
``phase_deg``
    the displacement's phase against the input [deg] (a lag is negative);
``harmonic2_um``, ``harmonic3_um`` (optional)
    the displacement's 2nd and 3rd harmonic amplitudes [um] (blank: not measured).

:func:`fit_sweep` fits it (:func:`planner.synthesis.chain_fit.fit_chain`): the measured
transfer as a table, the resonances found in it (frequency and Q), and the harmonics'
levels at the sweep's largest stroke.  :func:`write_chain` writes the table (the CSV a
spec's ``transfer:`` names) and the YAML block a spec can take.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from planner.lab.csv_files import csv_number, read_csv_rows, row_values
from planner.synthesis.chain_fit import ChainFit, fit_chain, harmonic_levels
from planner.core.units import UM

REQUIRED = ("frequency_hz", "input_v", "displacement_um", "phase_deg")
OPTIONAL = ("harmonic2_um", "harmonic3_um")
#: Largest input amplitude a row may give [V]: beyond it, no generator (a typo, mV?).
MAX_INPUT_V = 1e4


@dataclass(frozen=True)
class ChainSweep:
    """A read sweep (SI): ``frequency_hz`` [Hz], ``input_v`` [V], ``displacement_m`` [m],
    ``phase_rad`` [rad], ``harmonics_m``: order -> (row indices, amplitudes [m])."""

    frequency_hz: np.ndarray
    input_v: np.ndarray
    displacement_m: np.ndarray
    phase_rad: np.ndarray
    harmonics_m: dict
    source: str

    @property
    def response(self) -> np.ndarray:
        """The measured transfer [m/V] of every row."""
        return self.displacement_m / self.input_v * np.exp(1j * self.phase_rad)


@dataclass(frozen=True)
class ChainCalibration:
    """What ``calibrate --chain`` found: the fit, the harmonics' levels [dB] at the
    stroke ``stroke_m`` [m] (order -> level) and the sweep's frequency range."""

    fit: ChainFit
    harmonics_db: dict
    stroke_m: float
    sweep: ChainSweep


def read_chain_sweep(path) -> ChainSweep:
    """Read SWEEP.csv (see the module docstring).

    Raises
    ------
    SpecError
        A bad header, a non-number, a non-positive frequency, input or displacement, a
        negative harmonic, or fewer than 4 rows: naming the file, row and column.
    """
    _, header, rows, fail = read_csv_rows(path, REQUIRED, OPTIONAL, what="a chain sweep")
    cols = {c: [] for c in REQUIRED}
    harm = {2: ([], []), 3: ([], [])}
    for line, row in rows:
        values = row_values(header, line, row, fail)
        for c in REQUIRED:
            x = csv_number(values[c], line, c, fail)
            if c != "phase_deg" and x <= 0:
                raise fail(line, c, f"{values[c]} must be positive")
            if c == "input_v" and x > MAX_INPUT_V:
                raise fail(line, c, f"{values[c]} V is beyond any generator (at most "
                                    f"{MAX_INPUT_V:g} V): a typo, or another unit?")
            cols[c].append(x)
        for order in (2, 3):
            c = f"harmonic{order}_um"
            text = values.get(c, "")
            if text:
                x = csv_number(text, line, c, fail)
                if x <= 0:
                    raise fail(line, c, f"{text} must be positive (leave it blank when "
                                        "not measured)")
                harm[order][0].append(len(cols["frequency_hz"]) - 1)
                harm[order][1].append(x * UM)
    if len(cols["frequency_hz"]) < 4:
        from planner.core.errors import SpecError

        raise SpecError(f"a chain sweep needs at least 4 rows, {len(cols['frequency_hz'])} "
                        "given", source=str(path))
    return ChainSweep(np.array(cols["frequency_hz"]), np.array(cols["input_v"]),
                      np.array(cols["displacement_um"]) * UM,
                      np.radians(np.array(cols["phase_deg"])),
                      {k: (np.array(i, dtype=int), np.array(v)) for k, (i, v) in harm.items()
                       if i}, str(path))


def fit_sweep(sweep: ChainSweep) -> ChainCalibration:
    """Fit the chain to a sweep: the transfer (table and model) and the harmonics'
    levels at the sweep's largest displacement (the stroke a spec's ``at_stroke_um``
    then states).

    Raises
    ------
    ValueError
        Fewer than 4 distinct frequencies.
    """
    fit = fit_chain(sweep.frequency_hz, sweep.response)
    stroke = float(np.max(sweep.displacement_m))
    levels = {order: harmonic_levels(sweep.displacement_m[idx], amp, order, stroke)
              for order, (idx, amp) in sorted(sweep.harmonics_m.items())}
    return ChainCalibration(fit, levels, stroke, sweep)


def chain_yaml(cal: ChainCalibration, table_name: str) -> str:
    """The ``drive.chain`` block of a spec (YAML text), its transfer the table
    ``table_name`` (a path relative to the spec), the fitted model in a comment."""
    fit = cal.fit
    lo, hi = float(fit.frequency_hz[0]), float(fit.frequency_hz[-1])
    model = fit.model
    res = ", ".join(f"{{frequency_hz: {f:.6g}, q: {q:.4g}}}" for f, q in model.resonances)
    parts = [f"gain_um_per_v: {model.gain_m_per_v / UM:.6g}", f"resonances: [{res}]"]
    if model.low_pass_hz is not None:
        parts.append(f"low_pass_hz: {model.low_pass_hz:.6g}")
    lines = [f"# drive.chain fitted by `vibroplan calibrate --chain {Path(cal.sweep.source).name}`",
             f"# ({len(fit.frequency_hz)} frequencies, {lo:g}-{hi:g} Hz; the table holds "
             "them and, between them, the fitted model's shape;",
             "# it covers this range only: the spec's drive.band_hz must lie inside)."]
    if fit.resonances:
        for r in fit.resonances:
            lines.append(f"# resonance: {r['frequency_hz']:.1f} +- {r['frequency_std_hz']:.2g} Hz,"
                         f" Q {r['q']:.3g} +- {r['q_std']:.2g} (gain peak at "
                         f"{r['peak_hz']:.1f} Hz)")
    else:
        lines.append("# no resonance found in the sweep")
    lines.append(f"# fitted model (rms {fit.gain_rms:.2%} in gain, "
                 f"{math.degrees(fit.phase_rms):.2g} deg in phase); to use it instead "
                 "of the table:")
    lines.append(f"#   transfer: {{{', '.join(parts)}}}")
    lines += ["drive:", "  chain:", f"    transfer: {table_name}"]
    if cal.harmonics_db:
        inner = ", ".join(f"{k}: {v:.4g}" for k, v in cal.harmonics_db.items())
        lines.append(f"    harmonics_db: {{{inner}}}")
        lines.append(f"    at_stroke_um: {cal.stroke_m / UM:.6g}")
    return "\n".join(lines) + "\n"


def write_table(fit: ChainFit, path) -> None:
    """The transfer as ``frequency_hz,gain_um_per_v,phase_deg``
    (:meth:`~planner.synthesis.chain_fit.ChainFit.table`: the measured points, the
    model's shape between them; phase unwrapped from the lowest frequency)."""
    freqs, response = fit.table()
    with open(path, "w", newline="") as fh:
        fh.write("frequency_hz,gain_um_per_v,phase_deg\n")
        for f, h, p in zip(freqs, response, np.unwrap(np.angle(response))):
            fh.write(f"{f:.10g},{abs(h) / UM:.10g},{math.degrees(p):.10g}\n")


__all__ = ["ChainCalibration", "ChainSweep", "chain_yaml", "fit_sweep", "read_chain_sweep",
           "write_table"]
