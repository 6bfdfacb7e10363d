"""What a lab measures of a fabricated chip: :class:`Measurement`, measured.csv, and the
measurement a yield study simulates.

A lab sweeps each impacter pair (a vibrometer or a camera, the paper's Section IV) and
fits its resonance (:mod:`planner.lab.calibrate`); where it can tell the two cantilevers of a
pair apart, each half's.  Optionally a quality factor (the damping) and a gap.  Every
after-fabrication step -- the as-built models (:mod:`planner.afterfab.as_built`), the
re-plan, the trim, a yield study's chips -- reads one :class:`Measurement` per impacter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planner.core.nodes import node_key
from planner.core.units import UM

#: Columns of measured.csv: required, optional, and ignored (calibrate's uncertainties).
MEASURED_REQUIRED = ("impacter", "natural_frequency_hz")
MEASURED_OPTIONAL = ("quality_factor", "gap_um", "half")
#: The halves of a pair in measured.csv's ``half`` column.
HALVES = ("a", "b")
#: How far a measured resonance may lie from its design's, as a factor [-]: a fabricated
#: chip's resonances move by a few per cent (1.2 % per line-width sigma on the default);
#: one 4 x off is no measurement of this design (a typo, kHz for Hz, another chip),
#: while a chip as far off as a study asks (a neighbour's resonance, 0.38 x) is read.
MAX_MEASURED_FACTOR = 4.0
#: The smallest gap a measurement may give [um]: the process's gaps are microns; a
#: smaller number is a gap typed in metres (3e-6) or nm.
MIN_GAP_UM = 0.05
#: The quality factors a measurement may give [-].  A resonance is measured as a peak of
#: the amplitude against frequency, and a damped oscillator's amplitude has a peak only
#: for Q > 1/sqrt(2): a smaller Q is no resonance one could have measured (and Q 1e-6
#: makes every simulation crawl in steps of picoseconds: a re-plan ran for minutes).
#: Above, the best MEMS resonators reach ~1e6 in vacuum and these impacters 10-1000 in
#: air: 1e7 and more is a typo.
MIN_QUALITY = 1.0 / math.sqrt(2.0)
MAX_QUALITY = 1e7


@dataclass(frozen=True)
class Measurement:
    """What was measured of one impacter pair (SI).

    Attributes
    ----------
    halves_hz : tuple of float
        The resonance [Hz]: one value for the pair as a whole, or (a, b) for its two
        cantilevers measured apart.
    quality : tuple of (float or None)
        Quality factor [-] per entry of ``halves_hz`` (None: not measured).
    gap_m : tuple of (float or None)
        Gap [m] per entry of ``halves_hz`` (None: not measured).
    damping_ns_per_m : float, optional
        A damping [N s/m] known otherwise (a re-plan of a re-plan); a quality factor
        overrides it.
    window_hz : (float, float), optional
        The working window (lo, hi) [Hz] a tuning sweep measured: the tones that move
        its slider on the chip (:mod:`planner.afterfab.tune`).
    """

    halves_hz: tuple
    quality: tuple = ()
    gap_m: tuple = ()
    damping_ns_per_m: float | None = None
    window_hz: tuple | None = None

    def __post_init__(self):
        hz = tuple(float(f) for f in np.atleast_1d(self.halves_hz))
        if len(hz) not in (1, 2) or not all(math.isfinite(f) and f > 0 for f in hz):
            raise ValueError(f"a measured resonance is one or two finite frequencies > 0 "
                             f"[Hz], {self.halves_hz!r} was given")
        object.__setattr__(self, "halves_hz", hz)
        if self.window_hz is not None:
            lo, hi = (float(x) for x in self.window_hz)
            if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi):
                raise ValueError(f"a working window is (lo, hi) with 0 < lo < hi [Hz], "
                                 f"{self.window_hz!r} was given")
            object.__setattr__(self, "window_hz", (lo, hi))
        for name in ("quality", "gap_m"):
            v = tuple(getattr(self, name)) or (None,) * len(hz)
            if len(v) != len(hz):
                raise ValueError(f"{name} needs one entry per measured half ({len(hz)}), "
                                 f"{v!r} was given")
            object.__setattr__(self, name, tuple(None if x is None else float(x) for x in v))

    @classmethod
    def of(cls, natural_frequency_hz, *, quality_factor=None, gap_m=None):
        """A pair measured as a whole (``natural_frequency_hz`` a number) or half by half
        (a pair (a, b)); ``quality_factor`` and ``gap_m`` likewise (None: not measured)."""
        hz = tuple(np.atleast_1d(natural_frequency_hz))

        def per_half(v):
            if v is None:
                return ()
            return tuple(v) if isinstance(v, (tuple, list)) else (v,) * len(hz)

        return cls(hz, per_half(quality_factor), per_half(gap_m))

    @property
    def natural_frequency_hz(self) -> float:
        """The pair's resonance [Hz]: the mean of its halves."""
        return float(np.mean(self.halves_hz))

    @property
    def by_halves(self) -> bool:
        return len(self.halves_hz) == 2

    @property
    def resonance(self):
        """The resonance [Hz] as the tone rules read it: a number, or (a, b)."""
        return self.halves_hz if self.by_halves else self.halves_hz[0]

    def scaled(self, factor: float) -> Measurement:
        """The same pair with every resonance times ``factor`` (a trim moves both halves
        by the same fraction)."""
        return Measurement(tuple(f * factor for f in self.halves_hz), self.quality,
                           self.gap_m, self.damping_ns_per_m,
                           None if self.window_hz is None else
                           tuple(f * factor for f in self.window_hz))

    def with_window(self, window_hz) -> Measurement:
        """The same measurement with a tuning sweep's working window (lo, hi) [Hz]."""
        import dataclasses

        return dataclasses.replace(self, window_hz=window_hz)

    def to_dict(self) -> dict:
        out = {"natural_frequency_hz": self.natural_frequency_hz}
        if self.by_halves:
            out["halves_hz"] = list(self.halves_hz)
        if any(q is not None for q in self.quality):
            out["quality_factor"] = list(self.quality) if self.by_halves else self.quality[0]
        if any(g is not None for g in self.gap_m):
            out["gap_m"] = list(self.gap_m) if self.by_halves else self.gap_m[0]
        if self.window_hz is not None:
            out["window_hz"] = list(self.window_hz)
        return out


def read_measured(path, impacter_ids, design_hz=None) -> dict:
    """Read and check a lab's measured.csv.

    Parameters
    ----------
    path : str or os.PathLike
        CSV with header ``impacter,natural_frequency_hz`` and optionally
        ``quality_factor``, ``gap_um`` and ``half`` (a or b: one cantilever of the pair;
        any order); columns ending in ``_std`` or ``_std_hz``
        (:func:`planner.lab.calibrate.write_measured`'s uncertainties) are ignored.  Blank
        lines and lines starting with ``#`` are skipped.
    impacter_ids : iterable of str
        The plan's impacters; any other name is an error.
    design_hz : dict, optional
        Impacter id -> its designed natural frequency [Hz]: a measured one further than
        a factor :data:`MAX_MEASURED_FACTOR` from it is refused (another unit, a typo).

    Returns
    -------
    dict
        Impacter id -> :class:`Measurement`.  A value given for one half only is that
        half's (the other keeps its design's).

    Raises
    ------
    planner.core.errors.SpecError
        ``FILE: row N, column C: ...`` (N the 1-based line) for a missing or unknown
        column, an unknown or repeated impacter, a value that is not a finite number, a
        frequency, quality factor or gap <= 0, a gap in metres, a resonance beyond a
        factor 4 of its design's, or a pair half measured alone or both whole and by
        halves.
    """
    from planner.lab.csv_files import read_csv_rows

    # calibrate writes uncertainties beside the values: accepted and left alone
    header_line, header, rows, fail = read_csv_rows(
        path, MEASURED_REQUIRED, MEASURED_OPTIONAL, what="measured.csv",
        ignore=lambda c: c.endswith("_std") or c.endswith("_std_hz"))
    return measurements_from_rows(header_line, header, rows, fail, impacter_ids, design_hz)


def measurements_from_rows(header_line, header, rows, fail, impacter_ids, design_hz=None):
    """:func:`read_measured`'s checks and result for rows already read
    (:func:`planner.lab.csv_files.read_csv_rows`'s ``header_line``, ``header``, ``rows`` and
    ``fail``): one chip's rows of a wafer file too (:mod:`planner.afterfab.wafer_file`),
    whose other columns (the die's) are left alone."""
    from planner.lab.csv_files import csv_number, row_values

    known = set(impacter_ids)
    whole, first_line, halves = {}, {}, {}
    for line, row in rows:
        values = row_values(header, line, row, fail)
        name = values["impacter"]
        if not name:
            raise fail(line, "impacter", "empty impacter name")
        if name not in known:
            raise fail(line, "impacter", f"unknown impacter {name!r} (the plan has: "
                                         f"{', '.join(sorted(known, key=node_key))})")
        half = values.get("half", "").lower()
        if half and half not in HALVES:
            raise fail(line, "half", f"must be a or b (one cantilever of the pair), "
                                     f"{values['half']!r} was given")
        key = (name, half)
        if key in first_line:
            what = f"half {half} of {name}" if half else name
            raise fail(line, "impacter", f"{what} measured twice (rows {first_line[key]} "
                                         f"and {line})")
        if (half and (name, "") in first_line) or (not half and name in halves):
            other = (first_line[(name, "")] if half else
                     min(row_line for row_line, _ in halves[name].values()))
            raise fail(line, "half", f"{name} measured both as a whole and by halves "
                                     f"(rows {other} and {line})")
        rec = {"natural_frequency_hz": None, "quality_factor": None, "gap_m": None}
        for column in MEASURED_REQUIRED[1:] + MEASURED_OPTIONAL[:-1]:
            if column not in header:
                continue
            text = values[column]
            if text == "" and column in MEASURED_OPTIONAL:
                continue        # an optional value left blank: the design's
            x = csv_number(text, line, column, fail)
            if x <= 0:
                raise fail(line, column, f"must be > 0, {text} was given")
            if column == "quality_factor" and not MIN_QUALITY < x <= MAX_QUALITY:
                raise fail(line, column, f"{text} is no quality factor of a measured "
                                         f"resonance: a resonance peak needs Q > 1/sqrt(2) "
                                         f"({MIN_QUALITY:.3f}), and no MEMS resonator "
                                         f"reaches {MAX_QUALITY:g}")
            if column == "gap_um" and x < MIN_GAP_UM:
                raise fail(line, column, f"{text} um is no gap of this process (at least "
                                         f"{MIN_GAP_UM:g} um): a gap in metres? gap_um is "
                                         "in um (3e-6 m is 3)")
            nu0 = (design_hz or {}).get(name)
            if column == "natural_frequency_hz" and nu0 and not (
                    1 / MAX_MEASURED_FACTOR <= x / nu0 <= MAX_MEASURED_FACTOR):
                raise fail(line, column, f"{text} Hz is {x / nu0:.3g} x the design's "
                                         f"{nu0:.6g} Hz: a fabricated chip's resonance "
                                         f"lies within a factor {MAX_MEASURED_FACTOR:g} of "
                                         "its design's (a typo, another unit such as kHz, "
                                         "or another chip?)")
            rec[{"gap_um": "gap_m"}.get(column, column)] = x * UM if column == "gap_um" else x
        first_line[key] = line
        if half:
            halves.setdefault(name, {})[half] = (line, rec)
        else:
            whole[name] = Measurement((rec["natural_frequency_hz"],), (rec["quality_factor"],),
                                      (rec["gap_m"],))
    for name, got in halves.items():
        if len(got) < 2:
            (only, (line, _)), = got.items()
            raise fail(line, "half", f"only half {only} of {name} measured: give both "
                                     "halves, or the pair as a whole")
        (_, a), (_, b) = got["a"], got["b"]
        whole[name] = Measurement((a["natural_frequency_hz"], b["natural_frequency_hz"]),
                                  (a["quality_factor"], b["quality_factor"]),
                                  (a["gap_m"], b["gap_m"]))
    if not whole:
        raise fail(header_line + 1, "impacter", "no impacters after the header")
    return whole


def measure_models(impacters: dict, ids, noise_pct: float, seq) -> dict:
    """What a lab measures of models ``impacters`` (id -> :class:`model.Impacter` or
    :class:`model.PairHalves`): each resonance times (1 + pct z / 100), z standard normal.

    Two normals are drawn per impacter, in the order of ``ids``, whatever ``noise_pct``
    (the second for a pair's second half), from the SeedSequence ``seq``: the same chip
    gets the same normals at every noise level.  A measurement never finds a resonance
    at or below 0 Hz: the factor is floored at 0.1 (only a noise of tens of per cent
    reaches it).

    Returns
    -------
    dict
        Id -> :class:`Measurement` (each half's resonance for a pair of unequal halves).
    """
    from model import halves

    z = np.random.default_rng(seq).standard_normal((len(ids), 2))
    out = {}
    for n, zi in zip(ids, z):
        true = [float(h.natural_frequency) for h, _ in halves(impacters[n])]
        out[n] = Measurement(tuple(nu * max(1.0 + noise_pct / 100.0 * float(zk), 0.1)
                                   for nu, zk in zip(true, zi)))
    return out


def true_resonances(impacters: dict) -> dict:
    """Id -> the resonance [Hz] of each model (each half's, (a, b), for a pair of unequal
    halves): what a perfect measurement gives."""
    from model import halves

    out = {}
    for n, imp in impacters.items():
        parts = [float(h.natural_frequency) for h, _ in halves(imp)]
        out[n] = parts[0] if len(parts) == 1 else tuple(parts)
    return out
