"""After fabrication: a measured chip's models, its re-planned drive and its trims.

One package for everything that happens to a chip once it is made (``vibroplan replan``,
``vibroplan trim`` and every chip of ``vibroplan yield --replan``):

- :mod:`~planner.afterfab.measurement` -- :class:`Measurement`, what a lab measures of an
  impacter (resonance, per half where measured apart, quality factor, gap); measured.csv;
  the measurement a yield study simulates;
- :mod:`~planner.afterfab.tune` -- tuning on the chip: a speed-against-tone sweep, the
  working windows fitted to it (``calibrate --motion``, windows.csv, ``yield --tune``);
- :mod:`~planner.afterfab.as_built` -- the one builder of a measured chip's models: the
  fabrication errors inferred from the measured resonances, the chip rebuilt through eqs.
  (2)-(4) (mass, stiffness, damping and gap, not the stiffness alone);
- :mod:`~planner.afterfab.separations` -- the designs' silent bands and tone windows, and
  when two as-built resonances can be told apart;
- :mod:`~planner.afterfab.drive` -- the re-planned drive: tones moved with their
  resonances, pairs that cannot be told apart named, steps split or played weaker;
- :mod:`~planner.afterfab.replan` -- the re-plan verified on the as-built models, its
  plan.json and report;
- :mod:`~planner.afterfab.trim` -- what to trim, and the trim sequence (measure, trim,
  measure again, re-plan) used by ``trim`` and ``yield --trim``;
- :mod:`~planner.afterfab.outcome` -- what the loop finds of a chip (one typed result)
  and the one list of its outcomes and causes;
- :mod:`~planner.afterfab.loop` -- the after-fabrication loop, measure -> as-built ->
  the plan's drive -> re-plan -> tune -> trim, on a yield study's simulated chip (its
  truth passed in) and on a measured die of the test floor alike;
- :mod:`~planner.afterfab.batch` -- a wafer of measured dies, each through the loop;
  its files in :mod:`~planner.afterfab.wafer_file` and :mod:`~planner.afterfab.stdf`.

Each module imports only those listed before it (``[tool.importlinter]``).
"""

from planner.afterfab.as_built import AsBuilt, as_built
from planner.afterfab.measurement import Measurement, measure_models, read_measured
from planner.afterfab.tune import Window, fit_window, fit_windows

__all__ = ["AsBuilt", "Measurement", "Window", "as_built", "fit_window", "fit_windows",
           "measure_models", "read_measured"]
