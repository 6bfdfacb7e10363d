"""Tuning on the chip: a speed-against-tone sweep around each re-planned tone, and the
working window fitted to it.

A re-plan places each tone from a measured resonance and a model; a lab with the piezo
already on can do better: drive a few tones around each re-planned tone, one impacter at
a time, and watch its slider (a camera, the paper's Section IV).  Where the slider moves
is the *working window* of that impacter on this chip, whatever the model and the
resonance measurement got wrong; the re-plan then puts the tone in the window's middle
(:func:`planner.afterfab.drive.choose_tones`, still clear of every silent band it must
stay out of).

- :func:`fit_windows` reads a sweep (impacter, tone, speed) and returns each impacter's
  window: the run of tones around the fastest one at which the slider moves at least
  ``fraction`` of that fastest speed (and at least ``min_speed``), its edges interpolated
  between the last tone in and the first out (the last tone in where the first out does
  not move its slider at all: the designs' response collapses at a cliff, with the
  fastest tones just before it).  ``vibroplan calibrate --motion`` fits a
  lab's sweep with it.
- :func:`sweep_speeds` simulates such a sweep on a chip's models (a yield study's true
  chip: ``vibroplan yield --replan --tune``), with the lab's speed noise and a budget of
  tones per impacter.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from model import Drive, SolverWarning
from planner.planning.motion import by_node
from planner.planning.settings import tone_amplitudes
from planner.planning.verify import device_motion, pair_starts

#: Tones a tuning sweep drives around each re-planned tone (``--tune-tones``) [-].
TUNE_TONES = 7
#: The sweep's span either side of the re-planned tone, in tone windows
#: (``design.tone_window_pct``): the working window of a design is about one tone
#: window wide, and the sweep must see both its edges [-].
SPAN_WINDOWS = 2.5
#: A tone is in the working window while its slider moves at least this fraction of the
#: fastest speed of the sweep [-] (``calibrate --motion --fraction``).
FRACTION = 0.5
#: Initial states a simulated sweep runs each tone from (over [-c, c]): a lab's slider
#: starts from wherever the last run left it, and the slowest of these is what it sees
#: at worst [-].
SWEEP_STARTS = 3
#: A sweep whose window reaches its end is followed on that side by at most this
#: fraction of its tones more [-].
EXTEND_FRACTION = 1.0
#: The relative noise of a lab's speed reading [%] (``--tune-noise``).
SPEED_NOISE_PCT = 5.0


@dataclass(frozen=True)
class Window:
    """One impacter's working window fitted to a speed sweep (SI).

    Attributes
    ----------
    lo_hz, hi_hz : float
        Its edges [Hz] (interpolated; a sweep's end where the run reaches it).
    peak_hz : float
        The fastest tone [Hz].
    peak_speed_m_s : float
        The fastest speed [m/s].
    points : int
        Tones of the sweep.
    status : str
        "ok", or why the window is doubtful ("no tone moves its slider", "the window
        reaches the sweep's end", "too few tones").
    """

    lo_hz: float
    hi_hz: float
    peak_hz: float
    peak_speed_m_s: float
    points: int
    status: str = "ok"

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @property
    def middle_hz(self) -> float:
        return 0.5 * (self.lo_hz + self.hi_hz)


def fit_window(frequency_hz, speed_m_s, *, fraction=FRACTION, min_speed=0.0) -> Window:
    """The working window of one impacter's speed sweep (see the module docstring).

    Parameters
    ----------
    frequency_hz, speed_m_s : array_like, shape (n,)
        The sweep: tones [Hz] and the slider's speed in the impacter's direction [m/s].
    fraction : float
        A tone is in the window while the speed is at least this fraction of the
        fastest [-].
    min_speed : float
        ... and at least this [m/s] (a plan's floor).

    Returns
    -------
    Window
    """
    f = np.asarray(frequency_hz, dtype=float)
    v = np.asarray(speed_m_s, dtype=float)
    if f.shape != v.shape or f.ndim != 1:
        raise ValueError("frequency_hz and speed_m_s must be 1-D arrays of one length")
    order = np.argsort(f, kind="stable")
    f, v = f[order], v[order]
    if f.size < 3:
        k = int(np.argmax(v)) if f.size else 0
        return Window(float(f[0]) if f.size else math.nan, float(f[-1]) if f.size else math.nan,
                      float(f[k]) if f.size else math.nan,
                      float(v[k]) if f.size else 0.0, int(f.size), "too few tones")
    k = int(np.argmax(v))
    peak = float(v[k])
    threshold = max(fraction * peak, float(min_speed))
    if not peak > 0.0 or peak < threshold:
        return Window(float(f[0]), float(f[-1]), float(f[k]), peak, int(f.size),
                      "no tone moves its slider")
    lo_i = k
    while lo_i > 0 and v[lo_i - 1] >= threshold:
        lo_i -= 1
    hi_i = k
    while hi_i < f.size - 1 and v[hi_i + 1] >= threshold:
        hi_i += 1

    def cross(i_in, i_out):
        # linear interpolation of the threshold between the last tone in and the first
        # out; where the slider stops dead (the response collapsed: a cliff, not a
        # slope) the edge is the last tone in, nothing being known of the cliff between
        a, b = v[i_in], v[i_out]
        if b <= 0.0:
            return float(f[i_in])
        t = (a - threshold) / (a - b) if a != b else 0.5
        return float(f[i_in] + t * (f[i_out] - f[i_in]))

    status = "ok"
    lo = cross(lo_i, lo_i - 1) if lo_i > 0 else float(f[0])
    hi = cross(hi_i, hi_i + 1) if hi_i < f.size - 1 else float(f[-1])
    if lo_i == 0 or hi_i == f.size - 1:
        status = "the window reaches the sweep's end"
    return Window(lo, hi, float(f[k]), peak, int(f.size), status)


def fit_windows(rows, *, fraction=FRACTION, min_speed=0.0) -> dict:
    """Impacter id -> :class:`Window` of a sweep's rows (dicts with ``impacter``,
    ``frequency_hz`` [Hz] and ``speed_m_s`` [m/s])."""
    by = {}
    for r in rows:
        f, v = by.setdefault(r["impacter"], ([], []))
        f.append(float(r["frequency_hz"]))
        v.append(float(r["speed_m_s"]))
    return {n: fit_window(f, v, fraction=fraction, min_speed=min_speed)
            for n, (f, v) in sorted(by.items())}


def sweep_tones(tone_hz: float, window: float, count: int = TUNE_TONES) -> np.ndarray:
    """``count`` tones [Hz] evenly over the re-planned tone +- :data:`SPAN_WINDOWS` tone
    windows (``window``: the designs' relative half-width [-])."""
    span = SPAN_WINDOWS * max(float(window), 1e-4)
    return float(tone_hz) * (1.0 + np.linspace(-span, span, int(count)))


def sweep_speeds(settings, tones: dict, impacters: dict, sliders: dict, rng, *,
                 count=TUNE_TONES, noise_pct=SPEED_NOISE_PCT, window=None,
                 fraction=FRACTION) -> list:
    """A simulated tuning sweep on a chip's models: for every impacter, ``count`` tones
    around its re-planned tone (:func:`sweep_tones`), each played alone for the
    single-impacter step's length at the spec's amplitude, its slider's speed the
    slowest of :data:`SWEEP_STARTS` initial states times (1 + pct z / 100), z normal
    from ``rng`` (the lab's reading).

    As a lab would, a sweep whose window reaches one of its ends (the fastest tones at
    the end: the designs' speed rises toward the edge where the response collapses,
    often beyond the re-planned tone by more than the sweep's span) is followed on that
    side, a tone at a time at the same spacing, until the speed falls below
    ``fraction`` of the fastest or :data:`EXTEND_FRACTION` x ``count`` more tones are
    played.

    Parameters
    ----------
    settings : planner.planning.settings.Settings
    tones : dict
        Node -> its re-planned tone [Hz].
    impacters, sliders : dict
        The chip's models (node -> model; device -> Slider): the truth a lab sweeps.
    rng : numpy.random.Generator
        The reading noise's normals, one per tone played, in node order.
    count, noise_pct : optional
        Tones per impacter of the first sweep, and the reading's relative noise [%].
    window : float, optional
        The designs' tone window [-]; default ``settings.tone_window``.
    fraction : float
        The window's threshold (:func:`fit_window`) the extension follows.

    Returns
    -------
    list of dict
        ``impacter`` (id), ``frequency_hz`` [Hz], ``speed_m_s`` [m/s]: what
        :func:`fit_windows` reads, in the order played.
    """
    models = by_node(impacters)
    window = settings.tone_window if window is None else window
    extra = int(math.ceil(EXTEND_FRACTION * count))
    rows = []
    for node in sorted(tones):
        own = {n: m for n, m in models.items() if n.device == node.device}
        starts = pair_starts(models[node], SWEEP_STARTS)
        contact = settings.contacts[node.device]

        def read(f):
            a = tone_amplitudes(settings, np.array([f]))
            drive = Drive(np.array([f]), a, np.zeros(1))
            memo = {}   # the device's other impacter runs from rest from every start
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", SolverWarning)
                speed = min(node.sign * device_motion(own, sliders[node.device], drive,
                                                      settings.single_step_s,
                                                      {node: start}, contact, memo)[0]
                            / settings.single_step_s for start in starts)
            v = float(speed) * (1.0 + noise_pct / 100.0 * float(rng.standard_normal()))
            rows.append({"impacter": node.text, "frequency_hz": float(f), "speed_m_s": v})
            return v

        freqs = sweep_tones(tones[node], window, count)
        speeds = [read(f) for f in freqs]
        step = float(freqs[1] - freqs[0]) if freqs.size > 1 else 0.0
        fastest = max(speeds)
        # follow the window past either end while it is still in it (the top first: the
        # speed rises toward the collapse)
        for side in (+1, -1):
            f_end = float(freqs[-1] if side > 0 else freqs[0])
            v_end = speeds[-1] if side > 0 else speeds[0]
            added = 0
            while (fastest > 0.0 and step > 0.0 and v_end >= fraction * fastest
                   and added < extra):
                f_end += side * step
                v_end = read(f_end)
                fastest = max(fastest, v_end)
                added += 1
    return rows


def windows_of(fitted: dict, keep_flagged=False) -> dict:
    """Impacter id -> (lo, hi) [Hz] of the fitted windows a re-plan uses: those with
    status ok (and the flagged ones with ``keep_flagged``)."""
    return {n: (w.lo_hz, w.hi_hz) for n, w in fitted.items()
            if (w.ok or keep_flagged) and math.isfinite(w.lo_hz) and w.hi_hz > w.lo_hz}


#: A motion sweep's columns (``vibroplan calibrate --motion``): the impacter, the tone
#: [Hz] and the slider's mean speed in the impacter's own direction [mm/s].
MOTION_COLUMNS = ("impacter", "frequency_hz", "speed_mm_s")
#: windows.csv's columns (``calibrate --motion`` writes it, ``replan --windows`` reads it).
WINDOW_COLUMNS = ("impacter", "window_lo_hz", "window_hi_hz", "peak_hz", "peak_speed_mm_s",
                  "points", "status")
#: The columns ``replan --windows`` needs of windows.csv (the rest are read if present).
WINDOW_REQUIRED = ("impacter", "window_lo_hz", "window_hi_hz")
#: A tone of a motion sweep below this is no resonance of these devices (written in kHz?).
MIN_SWEEP_HZ = 10.0
#: Fewest distinct tones of one impacter's motion sweep: a window needs a peak and a
#: tone either side of it.
MIN_TONES = 3
MM = 1e-3


def read_motion(path) -> list:
    """Read and check a lab's motion sweep CSV (``calibrate --motion``).

    Parameters
    ----------
    path : str or os.PathLike
        CSV with the header ``impacter,frequency_hz,speed_mm_s`` (any order; blank lines
        and ``#`` comments skipped): one row per tone played, the slider's mean speed
        in the direction the impacter drives it [mm/s] (a backward impacter's slider
        moving backward reads positive; moving the wrong way, negative).

    Returns
    -------
    list of dict
        ``impacter``, ``frequency_hz`` [Hz], ``speed_m_s`` [m/s], ``line`` (1-based):
        what :func:`fit_windows` reads.

    Raises
    ------
    planner.core.errors.SpecError
        ``FILE: row N, column C: ...`` for a missing or unknown column, an empty name,
        a number that is not finite, a tone <= 10 Hz, one impacter's tone given twice,
        or an impacter with fewer than :data:`MIN_TONES` distinct tones.
    """
    from planner.lab.csv_files import csv_number, read_csv_rows, row_values

    header_line, header, rows, fail = read_csv_rows(path, MOTION_COLUMNS,
                                                    what="a motion sweep")
    out, lines = [], {}
    for line, row in rows:
        values = row_values(header, line, row, fail)
        name = values["impacter"]
        if not name:
            raise fail(line, "impacter", "empty impacter name")
        f = csv_number(values["frequency_hz"], line, "frequency_hz", fail)
        if f < MIN_SWEEP_HZ:
            raise fail(line, "frequency_hz", f"{values['frequency_hz']} Hz is no tone of "
                                             "these devices: frequency_hz is in Hz (was "
                                             "the sweep written in kHz?)")
        v = csv_number(values["speed_mm_s"], line, "speed_mm_s", fail)
        # one speed per tone: a tone read twice would make the window depend on the
        # rows' order (the fit sorts the tones) and count it twice
        twice = next((n for n, g in lines.get(name, ()) if g == f), None)
        if twice is not None:
            raise fail(line, "frequency_hz", f"{name} at {values['frequency_hz']} Hz given "
                                             f"twice (rows {twice} and {line}): one speed "
                                             "per tone (average the readings, or drop one)")
        out.append({"impacter": name, "frequency_hz": f, "speed_m_s": v * MM, "line": line})
        lines.setdefault(name, []).append((line, f))
    if not out:
        raise fail(header_line + 1, "impacter", "no measurements after the header")
    for name, seen in lines.items():
        tones = {f for _, f in seen}
        if len(tones) < MIN_TONES:
            raise fail(seen[0][0], "impacter",
                       f"impacter {name!r} has {len(tones)} distinct tones (rows "
                       f"{', '.join(str(n) for n, _ in seen)}); a working window needs at "
                       f"least {MIN_TONES}")
    return out


def write_windows(fitted: dict, path) -> None:
    """Write windows.csv (:data:`WINDOW_COLUMNS`) of :func:`fit_windows`' result
    (frequencies to 10 significant digits, speeds in mm/s)."""
    import csv

    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(WINDOW_COLUMNS)
        for name, win in fitted.items():
            w.writerow([name, f"{win.lo_hz:.10g}", f"{win.hi_hz:.10g}", f"{win.peak_hz:.10g}",
                        f"{win.peak_speed_m_s / MM:.6g}", win.points, win.status])


def read_windows(path, impacter_ids, tones_hz=None, band_hz=None) -> dict:
    """Read and check windows.csv (``replan --windows``).

    Parameters
    ----------
    path : str or os.PathLike
        CSV with ``impacter,window_lo_hz,window_hi_hz`` and optionally the other
        :data:`WINDOW_COLUMNS` (``calibrate --motion`` writes them; a flagged row,
        written with ``--keep-flagged``, is used and named in ``flagged``).
    impacter_ids : iterable of str
        The plan's impacters; any other name is an error.
    tones_hz : dict, optional
        Impacter id -> its planned tone [Hz]: a window further than a factor 2 from it
        is refused (another unit, another chip).
    band_hz : (float, float), optional
        The plan's drive band (lo, hi) [Hz] (``drive.band_hz``): a window reaching
        outside it is refused (its middle, the tone, may be one the drive never plays).

    Returns
    -------
    windows : dict
        Impacter id -> (lo, hi) [Hz].
    flagged : dict
        Impacter id -> the status of a window calibrate flagged.
    """
    from planner.lab.csv_files import csv_number, read_csv_rows, row_values

    known = set(impacter_ids)
    optional = tuple(c for c in WINDOW_COLUMNS if c not in WINDOW_REQUIRED)
    _, header, rows, fail = read_csv_rows(path, WINDOW_REQUIRED, optional, what="windows.csv")
    out, first, flagged = {}, {}, {}
    for line, row in rows:
        values = row_values(header, line, row, fail)
        name = values["impacter"]
        if name not in known:
            raise fail(line, "impacter", f"unknown impacter {name!r} (the plan has: "
                                         f"{', '.join(sorted(known))})")
        if name in first:
            raise fail(line, "impacter", f"{name} given twice (rows {first[name]} and {line})")
        first[name] = line
        status = values.get("status", "ok") or "ok"
        if status != "ok":
            flagged[name] = status
        lo = csv_number(values["window_lo_hz"], line, "window_lo_hz", fail)
        hi = csv_number(values["window_hi_hz"], line, "window_hi_hz", fail)
        if not 0.0 < lo < hi:
            raise fail(line, "window_hi_hz", f"a window is 0 < window_lo_hz < window_hi_hz, "
                                             f"{values['window_lo_hz']}-"
                                             f"{values['window_hi_hz']} was given")
        tone = None if tones_hz is None else tones_hz.get(name)
        if tone is not None and not (0.5 * tone < 0.5 * (lo + hi) < 2.0 * tone):
            raise fail(line, "window_lo_hz", f"the window {lo:g}-{hi:g} Hz of {name} is more "
                                             f"than a factor 2 from its tone {tone:.6g} Hz "
                                             "(another unit, or another chip's file?)")
        if band_hz is not None and not (band_hz[0] <= lo and hi <= band_hz[1]):
            column = "window_lo_hz" if lo < band_hz[0] else "window_hi_hz"
            raise fail(line, column, f"the window {lo:g}-{hi:g} Hz of {name} reaches outside "
                                     f"the drive band {band_hz[0]:g}-{band_hz[1]:g} Hz "
                                     "(drive.band_hz): a tone there is never played (a "
                                     "sweep beyond the band: give the part inside it)")
        if tone is not None:
            # a window is where its own impacter's tone moves its slider: one whose
            # middle lies nearer another impacter's tone is that one's row (a name
            # mistyped or rows swapped), not a chip whose impacters cannot be told apart
            mid = 0.5 * (lo + hi)
            other = min((n for n in tones_hz if n != name),
                        key=lambda n: abs(math.log(mid / tones_hz[n])), default=None)
            if other is not None and (abs(math.log(mid / tones_hz[other]))
                                      < abs(math.log(mid / tone))):
                raise fail(line, "impacter",
                           f"the window {lo:g}-{hi:g} Hz given for {name} lies nearer "
                           f"{other}'s tone ({tones_hz[other]:.6g} Hz) than {name}'s "
                           f"({tone:.6g} Hz): a row of {other}, or a name mistyped?")
        out[name] = (lo, hi)
    return out, flagged
