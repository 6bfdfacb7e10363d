"""The drive convention, the x0 grid of D (eq. 18) and batched calls of the model's kernels.

Everything the designer simulates goes through here: :class:`Ensemble` (a forbidden
multi-tone drive), ``_Tones`` (one tone per frequency at Z0^2 w^3 = power, or a fixed
amplitude), the thread policy for small batches, and :func:`x0_grid`.
"""

from __future__ import annotations

import contextlib
import math
import warnings
from dataclasses import dataclass, field

import numba
import numpy as np

from model import Drive, SolverWarning, responses, sweep
from model.drive import POWER

#: x0 = +c is simulated at c (1 - WALL_OFFSET): the limit from inside the gap, the
#: stricter case for (14) (see the module notes) [-].
WALL_OFFSET = 1e-9
#: Extra points just inside the wall, as fractions of c: a drive that presses on the
#: wall at t0 makes starts there chatter, in a zone that can be far thinner than the
#: grid step [-].
EDGE_FRACTIONS = (1.0 - 1e-2, 1.0 - 1e-4, 1.0 - 1e-6)
#: Batches of fewer simulations than this run on one thread: each run takes tens of
#: microseconds, a parallel launch on a busy 2-core machine tens of milliseconds.
PARALLEL_MIN_RUNS = 512


@dataclass(frozen=True, eq=False)
class Ensemble:
    """A forbidden drive of several tones: a step's summed drive in which the design is idle.

    Off-resonant responses to the tones of a step add up, so a design silent under
    each tone alone can still hit its slider under their sum; the array planner
    passes every multi-tone step in which an impacter must be idle as one of these.

    Attributes
    ----------
    drive : model.Drive
        The summed drive, amplitudes and phases as synthesised.
    label : str
        Name for reports (the step).
    """

    drive: Drive
    label: str = "ensemble"

    def __float__(self):          # for sorting and reports: the lowest tone
        return float(np.min(self.drive.frequencies))

    def __repr__(self):
        return f"Ensemble({self.label!r}, {self.drive.frequencies.size} tones)"


def _freq_key(frequency):
    return frequency if isinstance(frequency, Ensemble) else float(frequency)


@dataclass(frozen=True)
class _Tones:
    """One tone per frequency: Z0^2 w^3 = power, or a fixed amplitude [m]."""

    power: float = POWER
    amplitude: float | None = None

    def __post_init__(self):
        p = float(self.power)
        if not (math.isfinite(p) and p > 0):
            raise ValueError(f"power must be finite and > 0, {self.power!r} was given")
        object.__setattr__(self, "power", p)
        if self.amplitude is not None:
            a = float(self.amplitude)
            if not (math.isfinite(a) and a > 0):
                raise ValueError(f"amplitude must be finite and > 0, {self.amplitude!r} was given")
            object.__setattr__(self, "amplitude", a)

    # Drive objects already built, by frequency (validation costs more than a short run)
    built: dict = field(default_factory=dict, compare=False, repr=False)

    def drive(self, frequency):
        if isinstance(frequency, Ensemble):
            return frequency.drive
        d = self.built.get(frequency)
        if d is None:
            d = (Drive.tone(frequency, self.power) if self.amplitude is None
                 else Drive([frequency], [self.amplitude]))
            self.built[frequency] = d
        return d


@contextlib.contextmanager
def _kernel_threads(n_runs):
    """Run small batches on one thread (see PARALLEL_MIN_RUNS); restore afterwards."""
    if n_runs >= PARALLEL_MIN_RUNS:
        yield
        return
    prev = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(prev)


def _runs(impacter, tones, frequency, x0s, window, stop_at_first):
    """r [N] and status codes of one tone from each x0 (one batch kernel call)."""
    with _kernel_threads(len(x0s)), warnings.catch_warnings():
        warnings.simplefilter("ignore", SolverWarning)
        return responses(impacter, tones.drive(frequency), x0s, duration=window,
                         stop_at_first=stop_at_first, return_status=True)


def _responds(impacter, tones, frequencies, x0s, window):
    """Whether some x0 responds at each frequency, shape (n_freq,) of bool.

    One parallel sweep for the power convention; one batch per tone otherwise.
    A run that ends on a cap counts as responding if it recorded a counted impact.
    """
    frequencies = np.asarray(frequencies, dtype=float)
    if frequencies.size == 0:
        return np.zeros(0, dtype=bool)
    if tones.amplitude is None:
        with _kernel_threads(frequencies.size * len(x0s)), warnings.catch_warnings():
            warnings.simplefilter("ignore", SolverWarning)
            r = sweep(impacter, frequencies, x0s, tones.power, window, stop_at_first=True)
        return np.any(r > 0, axis=1)
    return np.array([np.any(_runs(impacter, tones, f, x0s, window, True)[0] > 0)
                     for f in frequencies])


def _u_grid(n):
    """x0 / c on [-1, 1]: n uniform nodes with +1 just inside the wall, and edge points."""
    u = np.linspace(-1.0, 1.0, n)
    u[-1] = 1.0 - WALL_OFFSET
    return np.unique(np.concatenate([u, EDGE_FRACTIONS]))


def _guard_offsets(guard, points):
    """Relative offsets of the checked frequencies in a guard band, centre first."""
    if guard == 0.0 or points <= 1:
        return [0.0]
    k = np.linspace(-1.0, 1.0, points if points % 2 else points + 1)
    ks = sorted(k, key=lambda v: (abs(v) != 1.0, abs(v) != 0.0, abs(v), v))
    ks.remove(0.0)
    return [0.0] + [guard * float(v) for v in ks]


def x0_grid(gap, points=33):
    """The designer's sampling of D = {x0 in [-c, c], v0 = 0}: x0 values [m].

    ``points`` uniform nodes over [-c, c] (odd, so -c, 0 and +c are nodes), +c taken
    at c (1 - WALL_OFFSET), and the points c EDGE_FRACTIONS just inside the wall.

    Parameters
    ----------
    gap : float
        c [m].
    points : int
        Uniform nodes.

    Returns
    -------
    ndarray, shape (n,)
        Sorted initial positions [m].

    Examples
    --------
    >>> x = x0_grid(2e-6, 5)
    >>> float(x[0]), float(x[2]), x.size
    (-2e-06, 0.0, 8)
    """
    return _u_grid(int(points)) * float(gap)


def _default_x0s(impacter, n=33):
    return x0_grid(impacter.gap, n)
