"""Drive synthesis: the summed-tone substrate displacement of one step, as a seamless loop.

A step drives every impacter that must move with its own tone, all at once, through one
piezo shaker.  The substrate displacement is

    zeta(t) = sum_i Z_i cos(2 pi f_i t + phi_i)                                   (5)

(the paper's eq. (5) summed over tones).  The piezo has a peak-displacement limit, so the
*phases* decide how much amplitude every tone can get: the peak of the sum is what hits
the limit, and the rms (which fixes the tones' amplitudes) is phase-independent.  This
module chooses

- the **loop**: a whole number of samples in which every tone makes a whole number of
  cycles, so that a generator can repeat it with no discontinuity.  Each frequency is
  snapped to the loop's grid ``1 / L`` within a stated tolerance and the shift is reported;
- the **phases**: minimum crest factor (peak / rms), starting from Schroeder's phases and
  improving by L_p-norm minimisation with p raised toward infinity, finished by a minimax
  (L_inf) polish; deterministic for a seed;
- the **scale**: if the optimised peak still exceeds the piezo's limit, every amplitude is
  scaled down by one reported factor (never clipped); :func:`split_tones` offers the
  alternative of splitting a step into sub-steps that each fit.

Everything is in SI units: m, s, Hz, rad.  The phase optimisation evaluates the loop on an
oversampled FFT grid; the samples themselves are an exact sum of cosines, with the
argument reduced in integers so the loop repeats bit for bit.

Layout of this package (each module imports only those listed below it):

- :mod:`~planner.synthesis.api`: the public functions, :func:`synthesize`,
  :func:`split_tones` and :func:`tones_from_power`.
- :mod:`~planner.synthesis.phases`: :func:`optimise_phases` (L_p continuation and the
  minimax polish), :func:`optimise_peaks` (the same over several signals of the same
  tones: the die's displacement and acceleration and a drive chain's input, each
  relative to its limit) and :func:`schroeder_phases`, with their references.
- :mod:`~planner.synthesis.peak`: :func:`peak_of` and :func:`crest_factor`, the peak over
  continuous time.
- :mod:`~planner.synthesis.waveform`: :class:`Waveform`, the drive-signal type.
- :mod:`~planner.synthesis.loop`: the choice of the loop and the snapping tolerance
  (:class:`LoopLengthError`, :func:`check_loop_memory`).
- :mod:`~planner.synthesis.kernels`: sums of cosines over one loop, exact and on an FFT
  grid, in loop units.
- :mod:`~planner.synthesis.validation`: the argument checks.
"""

from __future__ import annotations

from planner.core.rng import as_generator
from planner.synthesis.api import DEFAULT_POWER, split_tones, synthesize, tones_from_power
from planner.synthesis.loop import (FREQUENCY_TOLERANCE_REL, MAX_LOOP_LENGTH, LoopLengthError,
                                    check_loop_memory)
from planner.synthesis.peak import crest_factor, peak_of
from planner.synthesis.phases import optimise_peaks, optimise_phases, schroeder_phases
from planner.synthesis.waveform import Waveform

__all__ = ["Waveform", "LoopLengthError", "synthesize", "tones_from_power", "split_tones",
           "as_generator", "optimise_phases", "optimise_peaks", "schroeder_phases", "peak_of",
           "crest_factor", "check_loop_memory", "DEFAULT_POWER", "FREQUENCY_TOLERANCE_REL",
           "MAX_LOOP_LENGTH"]
