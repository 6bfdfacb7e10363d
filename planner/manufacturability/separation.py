"""Per design, once: sensitivities of the natural frequency to each fabrication error, and
the separation (silent band, tone window) measured by simulation (see the package notes)."""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from planner.fabrication.tolerances import ERRORS, NodeDesign, frequency_sensitivities

#: A tone drives an impacter while the least response over x0 stays above this fraction
#: of the least response at its planned tone [-].  A heuristic of "still drives": the
#: designs are retried until they are predicted 1.75 x faster than the speed floor
#: (planner.planning.designs.SPEED_MARGIN), so at a window's edge the response is about
#: 0.9 x the floor's; a re-plan puts each tone at its window's middle and verifies the
#: speeds by simulation.
RESPONDS_FRACTION = 0.5
#: Scan step of :func:`measure_separation`, relative to the frequency, and its floor [Hz].
SCAN_STEP_REL = 2e-3
SCAN_STEP_MIN_HZ = 5.0
#: Consecutive silent (or not driving) scan points that end a band [-].
SCAN_QUIET = 3
#: The largest scan, either side, relative to the frequency [-].
SCAN_SPAN_REL = 0.15
#: Edge tolerance of the bisection [Hz].
EDGE_TOL_HZ = 0.5
#: Every use of a silent band (the Monte Carlo's collision rule, the re-plan's tones, the
#: trim's targets) widens it by this fraction of its reach: measured on the nominal
#: design, its edge moves by a few per cent of its reach when the resonance moves by
#: ~2 % (the tone amplitude follows the power convention, ~f^-1.5): a tone 6 Hz below
#: a measured edge made a close pair answer on a chip 2 % off its design [-].
BAND_MARGIN = 0.1


def sensitivities(spec, node: NodeDesign) -> dict:
    """Parameter name -> d ln nu_n / d parameter [1/unit] of one design (every
    :data:`planner.fabrication.tolerances.ERRORS` entry)."""
    s = frequency_sensitivities(spec, node)
    return {name: float(v) for name, v in zip(ERRORS, s)}


@dataclass(frozen=True)
class Separation:
    """How far a design's silent band and tone window reach (by simulation).

    Attributes
    ----------
    natural_frequency_hz, tone_hz : float
        nu_n and the planned tone [Hz].
    silent_below_hz, silent_above_hz : float
        The design answers a tone (from some x0, at full power) only within
        (nu_n - silent_below, nu_n + silent_above) [Hz].
    responds_below_hz, responds_above_hz : float
        Its tone may move down or up this far and still drive it (least response over
        x0 at least :data:`RESPONDS_FRACTION` of the planned tone's) [Hz], at the
        amplitude its tone plays at alone.
    """

    natural_frequency_hz: float
    tone_hz: float
    silent_below_hz: float
    silent_above_hz: float
    responds_below_hz: float
    responds_above_hz: float

    @property
    def silent_beyond_hz(self) -> float:
        """The larger reach of the silent band from nu_n [Hz]."""
        return max(self.silent_below_hz, self.silent_above_hz)

    @property
    def responds_within_hz(self) -> float:
        """The smaller reach of the tone window [Hz]."""
        return min(self.responds_below_hz, self.responds_above_hz)

    def to_dict(self) -> dict:
        return {"silent_beyond": self.silent_beyond_hz,
                "responds_within": self.responds_within_hz,
                "silent_below": self.silent_below_hz, "silent_above": self.silent_above_hz,
                "responds_below": self.responds_below_hz,
                "responds_above": self.responds_above_hz}


def _edge(pred, inside, outside, tol):
    """Bisect between ``inside`` (pred true) and ``outside`` (false) to ``tol`` [Hz]."""
    while abs(outside - inside) > tol:
        mid = 0.5 * (inside + outside)
        if pred(mid):
            inside = mid
        else:
            outside = mid
    return inside


def _reach(pred, start, direction, step, limit, tol):
    """How far from ``start`` (pred true there) pred stays true walking in
    ``direction`` (+1, -1), a run of SCAN_QUIET false points ending it [Hz]."""
    last_true, quiet, k = start, 0, 0
    while True:
        k += 1
        f = start + direction * k * step
        if abs(f - start) > limit or f <= 0:
            return abs(last_true - start)
        if pred(f):
            last_true, quiet = f, 0
        else:
            quiet += 1
            if quiet >= SCAN_QUIET:
                break
    edge = _edge(pred, last_true, last_true + direction * step, tol)
    return abs(edge - start)


def measure_separation(impacter, tone_hz, *, power=50.0, amplitude=None, tone_amplitude=None,
                       x0s=None, window=3e-3, silent_window=None) -> Separation:
    """Silent band and tone window of one design (see :class:`Separation`).

    Parameters
    ----------
    impacter : model.Impacter
        The design.
    tone_hz : float
        Its planned tone [Hz].
    power : float
        Z0^2 w^3 of a tone [m^2/s^3]: the amplitude a neighbour's tone plays at.
    amplitude : float, optional
        A fixed tone amplitude [m] instead of the power convention.
    tone_amplitude : float, optional
        The amplitude its own tone plays at where it must be told apart from its
        neighbours [m]; default the power convention's at ``tone_hz``.
    x0s : array_like, optional
        Initial positions [m]; default the designer's grid over [-c, c].
    window : float
        Simulated time of the tone window's responses [s] (the designer's window).
    silent_window : float, optional
        Simulated time of the silent band's checks [s]: the longest an impacter sits
        idle under one tone (a single-impacter step, 10 ms in an array plan; a slow beat
        can bring an idle impacter to its wall late).  Default ``window``.

    Returns
    -------
    Separation
    """
    from model import Drive, SolverWarning, responses
    from model.drive import amplitude_from_power
    from planner.designer.runs import x0_grid

    x0s = x0_grid(impacter.gap) if x0s is None else np.asarray(x0s, dtype=float)
    nu = float(impacter.natural_frequency)
    tone_hz = float(tone_hz)

    silent_window = window if silent_window is None else float(silent_window)

    def r_of(f, z0, duration=window, stop=False, starts=x0s):
        drive = Drive(np.array([f]), np.array([z0]), np.zeros(1))
        return responses(impacter, drive, starts, duration=duration, stop_at_first=stop,
                         check_input=False)

    def some_start(run, decisive, lead):
        """Whether some initial state's run is ``decisive``; ``run(starts)`` gives the
        runs' r.  The state that was decisive last time (``lead``, a one-item list) is
        run alone first: inside a band it answers again, beyond a tone window's edge it
        is the first to drive too weakly, and the other runs are not needed.  Each run
        is independent of the others, so the verdict is the whole grid's (measured: the
        same separations, 22 % less time)."""
        k = lead[0]
        if k is not None and decisive(run(x0s[k:k + 1])[0]):
            return True
        hit = np.flatnonzero([decisive(v) for v in run(x0s)])
        if hit.size:
            lead[0] = int(hit[0])
        return bool(hit.size)

    def z_at(f):
        return amplitude if amplitude is not None else float(amplitude_from_power(f, power))

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SolverWarning)

        answered = [None]

        def answers(f):
            return some_start(lambda starts: r_of(f, z_at(f), silent_window, True, starts),
                              lambda r: r > 0, answered)

        step = max(SCAN_STEP_REL * nu, SCAN_STEP_MIN_HZ)
        limit = SCAN_SPAN_REL * nu
        start = nu if answers(nu) else tone_hz
        below = nu - start + _reach(answers, start, -1, step, limit, EDGE_TOL_HZ)
        above = start - nu + _reach(answers, start, +1, step, limit, EDGE_TOL_HZ)

        z_tone = tone_amplitude if tone_amplitude is not None else z_at(tone_hz)
        r0 = float(np.min(r_of(tone_hz, z_tone)))
        if r0 > 0:
            floor, weak = RESPONDS_FRACTION * r0, [None]

            def drives(f):
                return not some_start(lambda starts: r_of(f, z_tone, window, False, starts),
                                      lambda r: not r >= floor, weak)

            step_t = max(SCAN_STEP_REL * 0.25 * tone_hz, SCAN_STEP_MIN_HZ)
            r_below = _reach(drives, tone_hz, -1, step_t, limit, EDGE_TOL_HZ)
            r_above = _reach(drives, tone_hz, +1, step_t, limit, EDGE_TOL_HZ)
        else:
            r_below = r_above = 0.0
    return Separation(nu, tone_hz, float(below), float(above), float(r_below), float(r_above))
