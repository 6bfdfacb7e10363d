"""Closed-form bounds that answer a question without a simulation.

:func:`silence_bound` proves that an impacter never reaches its wall under a drive,
from any start in D = {x0 in [-c, c], v0 = 0} (eq. 18), with any phasing of the
drive's tones and over any duration: its response r (eq. 12) is then zero and a
check of constraint (14) needs no simulation.  The proof is the linear motion's
exact worst case over starts and phases (:func:`linear_envelope`) kept below the
gap after the first quarter period, with a margin; see
:mod:`model.kernels.silence`.  It never says silent where the exact simulator finds
an impact (``tests/model/test_bounds.py`` holds it against the simulator on random,
grazing, resonant and extreme cases); where it cannot prove silence it says so and
the caller simulates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from model.impacter import impacter_forcing
from model.kernels import silence as _s

#: After the first quarter period the linear motion must stay below c (1 - margin) [-].
SILENCE_MARGIN = 0.005
#: Safe steps allowed before the proof gives up (a motion hovering near the wall).
MAX_BOUND_STEPS = 20_000


@dataclass(frozen=True)
class SilenceBound:
    """What :func:`silence_bound` found.

    Attributes
    ----------
    silent : bool
        Proven: no start in D and no phasing of the tones gives a response (eq. 12),
        over any duration: the motion never reaches the wall, or reaches it at most
        once (the impact eq. 12 excludes) and never again.
    impacts : int
        0 when not even one impact is possible, 1 when one may be, -1 not proven.
    peak : float
        Largest W / c seen after the first quarter period (NaN when the proof stopped
        before looking: undamped, over-damped, or a drive pressing through the gap).
    steps : int
        Safe steps the proof took.
    """

    silent: bool
    impacts: int
    peak: float
    steps: int

    def __bool__(self):
        return self.silent


def silence_bound(impacter, drive, margin=SILENCE_MARGIN, max_steps=MAX_BOUND_STEPS):
    """Prove that ``impacter`` stays off its wall under ``drive`` from every x0 in D.

    Parameters
    ----------
    impacter : model.Impacter
    drive : model.Drive
        Its tones' phases do not matter: the proof holds for every phasing.
    margin : float
        In (0, 0.25): how far below the gap, as a fraction of it, the motion must stay
        after the first quarter period.
    max_steps : int
        Safe steps allowed before giving up.

    Returns
    -------
    SilenceBound
        True-valued when silence is proven; ``peak`` says how close it came.

    Examples
    --------
    A tone an octave above a 10 kHz impacter's resonance, at the paper's power
    convention, cannot bring it to a 4 um gap; its own resonance can:

    >>> from model import Drive, Impacter
    >>> imp = Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 4e-6, viscosity=1.79e-5).with_natural_frequency(1e4)
    >>> bool(silence_bound(imp, Drive.tone(2e4)))
    True
    >>> bool(silence_bound(imp, Drive.tone(1e4)))
    False
    """
    if not (0.0 < margin < 0.25):
        raise ValueError(f"margin must be in (0, 0.25), {margin!r} was given")
    w, a, _ = impacter_forcing(impacter, drive)
    verdict, peak, steps = _s.linear_silence(
        float(impacter.omega_n), float(impacter.sigma), float(impacter.gap),
        float(impacter.restitution), w, np.abs(a), float(margin), int(max_steps))
    impacts = {_s.SILENT: 0, _s.ONE_IMPACT: 1}.get(int(verdict), -1)
    return SilenceBound(impacts >= 0, impacts, float(peak), int(steps))


def linear_envelope(impacter, drive, t, x0_max=None):
    """W(t): the largest |x(t)| of the wall-free motion over x0 in [-x0_max, x0_max]
    (v0 = 0) and every phasing of the drive's tones [m].

    Exact for eq. (1) without the wall; NaN unless the impacter is under-damped with
    some damping (0 < sigma < wn).  ``x0_max`` defaults to the gap.
    """
    w, a, _ = impacter_forcing(impacter, drive)
    c = float(impacter.gap if x0_max is None else x0_max)
    t = np.ascontiguousarray(np.atleast_1d(np.asarray(t, dtype=float)))
    return _s.linear_envelope(float(impacter.omega_n), float(impacter.sigma), c, w,
                              np.abs(a), t)
