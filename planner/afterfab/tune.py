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
  between the last tone in and the first out.  ``vibroplan calibrate --motion`` fits a
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
        # linear interpolation of the threshold between the last tone in and the first out
        a, b = v[i_in], v[i_out]
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
                 count=TUNE_TONES, noise_pct=SPEED_NOISE_PCT, window=None) -> list:
    """A simulated tuning sweep on a chip's models: for every impacter, ``count`` tones
    around its re-planned tone (:func:`sweep_tones`), each played alone for the
    single-impacter step's length at the spec's amplitude, its slider's speed the
    slowest of :data:`SWEEP_STARTS` initial states times (1 + pct z / 100), z normal
    from ``rng`` (the lab's reading).

    Parameters
    ----------
    settings : planner.planning.settings.Settings
    tones : dict
        Node -> its re-planned tone [Hz].
    impacters, sliders : dict
        The chip's models (node -> model; device -> Slider): the truth a lab sweeps.
    rng : numpy.random.Generator
        The reading noise's normals, one per tone in node order.
    count, noise_pct : optional
        Tones per impacter, and the reading's relative noise [%].
    window : float, optional
        The designs' tone window [-]; default ``settings.tone_window``.

    Returns
    -------
    list of dict
        ``impacter`` (id), ``frequency_hz`` [Hz], ``speed_m_s`` [m/s]: what
        :func:`fit_windows` reads.
    """
    models = by_node(impacters)
    window = settings.tone_window if window is None else window
    rows = []
    for node in sorted(tones):
        freqs = sweep_tones(tones[node], window, count)
        amps = tone_amplitudes(settings, freqs)
        own = {n: m for n, m in models.items() if n.device == node.device}
        starts = pair_starts(models[node], SWEEP_STARTS)
        z = rng.standard_normal(freqs.size)
        contact = settings.contacts[node.device]
        for f, a, zk in zip(freqs, amps, z):
            drive = Drive(np.array([f]), np.array([a]), np.zeros(1))
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", SolverWarning)
                speed = min(node.sign * device_motion(own, sliders[node.device], drive,
                                                      settings.single_step_s,
                                                      {node: start}, contact)[0]
                            / settings.single_step_s for start in starts)
            rows.append({"impacter": node.text, "frequency_hz": float(f),
                         "speed_m_s": float(speed) * (1.0 + noise_pct / 100.0 * float(zk))})
    return rows


def windows_of(fitted: dict, keep_flagged=False) -> dict:
    """Impacter id -> (lo, hi) [Hz] of the fitted windows a re-plan uses: those with
    status ok (and the flagged ones with ``keep_flagged``)."""
    return {n: (w.lo_hz, w.hi_hz) for n, w in fitted.items()
            if (w.ok or keep_flagged) and math.isfinite(w.lo_hz) and w.hi_hz > w.lo_hz}
