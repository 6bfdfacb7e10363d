"""Yield of a plan under fabrication variation: the Monte Carlo behind ``vibroplan yield``.

Every chip is a sample of the spec's ``fabrication:`` tolerance model
(:mod:`planner.fabrication.tolerances`) built from the plan's designs.  On each chip every step
of the plan is re-verified with the plan's own checks
(:func:`planner.planning.verify.check_step`, from the same initial-state grid, with the
drive rebuilt exactly from ``plan.json``'s tones) and every scene is simulated with the
state carried across steps and the plan's settle dwells
(:func:`planner.planning.scenes.simulate_scenes`,
:func:`planner.planning.scenes.scene_failures`).  A chip passes when every step passes
the plan's own checks AND the carried-state check passes -- the criterion
``vibroplan plan`` calls PASSED since the carried-state check became part of
``verification.passed`` (issue 15).  The yield is the fraction of chips that pass, with
a 95 % Wilson score interval.  ``carried_state`` (chips passing the carried-state check
too) is kept for compatibility: it now equals the yield.

Check kinds counted in ``failures`` (chips on which that check failed at least once):

- ``idle responds``: an impacter that must be idle hits its slider (r > 0, eq. (14));
- ``too slow``: a driven slider is slower than ``verification.min_speed_mm_s`` from
  some initial state;
- ``idle slider moves``: an idle slider moves more than ``verification.idle_tolerance_um``;
- ``travel over limit``, ``still moving``: a step's travel beyond
  ``verification.max_travel_um``, or motion left at the end of the longest dwell;
- ``idle slider moves (carried state)``: the same when each scene runs in order with
  the state the previous step left (``travel over limit (carried state)`` and
  ``still moving (carried state)`` likewise);
- ``unbuildable``: the sampled errors closed a gap or removed a beam (no simulation).

With ``replan=True`` (``vibroplan yield --replan``) every chip is also *measured* --
its true natural frequencies (of the sampled impacters) times ``1 + noise z / 100``,
z standard normal from the chip's own seed -- re-planned from the measurement with
:func:`planner.afterfab.replan.replan_chip` (only the drive changes), and the re-planned
drive is verified with the same checks on the chip's TRUE models (the sampled impacters
and sliders, not the re-plan's as-built models built from the measurement).

Chip ``i`` at sigma scale ``s`` draws from :func:`chip_seed` ``(seed, s, i)``: a
``numpy.random.SeedSequence`` of the seed, the 64 bits of the scale's value and the
chip's index (its measurement noise from that sequence's first spawned child).  The
numbers depend on the seed, the scale's value and the chip only: never on the number of
workers, the order they finish in, or where the scale stands in ``--sigma-scale``
(and scales 1.0000001 and 1.0000002 are two scales).

Layout of this package (each module imports only those listed below it); the outputs
(``yield.json``, report.md, figures) are written by :mod:`planner.yield_.report`.

- :mod:`~planner.yield_.run`: :func:`run_yield`, the driver (in this process or on
  Dask, :func:`planner.runtime.engine.run_tasks`).
- :mod:`~planner.yield_.statistics`: Wilson intervals, the tallies of failing checks
  and causes, and the content of ``yield.json``.
- :mod:`~planner.yield_.chip`: :func:`verify_chip`, the per-chip worker: a chip sampled
  and put through the after-fabrication loop with its truth known
  (:func:`planner.afterfab.loop.run_loop`, the loop the wafer batch runs on a measured
  die: measure, as-built, the plan's drive, re-plan, tune, trim).
- :mod:`~planner.yield_.results`: what a chip's worker returns (:class:`ChipResult`,
  holding the loop's :class:`ReplanOutcome`, :class:`TuneOutcome`,
  :class:`TrimOutcome`, :class:`Collision` and :class:`Seconds` of
  :mod:`planner.afterfab.outcome`), each with the ``to_dict()`` of its plain-dict form.
- :func:`check_drive` (:mod:`planner.afterfab.checks`): every check of a drive on one
  chip's models, by kind, with the impacters implicated.
- :mod:`~planner.yield_.inputs`: :class:`Payload` and :func:`make_payload` (what the
  workers get from the plan), and the checks of the command's numbers.
- :func:`wilson_interval` and ``Z95`` (from :mod:`planner.core.intervals`): the 95 % interval of a yield.
"""


from planner.afterfab.checks import CARRIED, CARRIED_KINDS, KINDS, check_drive
from planner.afterfab.outcome import REPLAN_CAUSES
from planner.yield_.chip import measured_frequencies, verify_chip
from planner.yield_.inputs import (Payload, check_chip_count, check_noise, make_payload,
                                   parse_scales)
from planner.yield_.results import (ChipResult, Collision, ReplanOutcome, Seconds,
                                    TrimOutcome, TuneOutcome)
from planner.yield_.run import run_yield
from planner.core.intervals import Z95, wilson_interval
from planner.yield_.statistics import scale_key

__all__ = ["CARRIED", "CARRIED_KINDS", "KINDS", "REPLAN_CAUSES", "Z95", "ChipResult",
           "Collision", "Payload", "ReplanOutcome", "Seconds", "TrimOutcome", "TuneOutcome",
           "check_chip_count", "check_drive", "check_noise", "make_payload",
           "measured_frequencies", "parse_scales", "run_yield", "scale_key", "verify_chip",
           "wilson_interval"]
