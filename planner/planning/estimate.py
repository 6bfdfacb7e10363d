"""What a plan will cost, known once the frequencies are assigned (before any design).

A cost model, not a measurement.  It prints a range, because three things that the
assignment cannot know yet multiply the time:

* **numba compilation**: the simulation kernels compile on their first call unless
  numba's on-disk cache holds them (:func:`numba_cache_state` reads the cache index of
  each kernel a plan calls, where numba itself looks: next to the sources or in
  ``NUMBA_CACHE_DIR``); a cold cache adds ``COMPILE_S`` once, scaled by the share of
  kernels missing;
* **designer retries**: a design that is infeasible or predicted slower than
  ``SPEED_MARGIN`` x the minimum speed is retried with the next seed, up to
  :data:`planner.planning.designs.DESIGN_RETRIES` times: 1 to 1 + DESIGN_RETRIES tries
  (fewer once RETRY_STALL tries in a row gain less than RETRY_GAIN in speed);
  while every try has been infeasible the next searches wider
  (:func:`planner.designer.budget.widened`), so the slowest design is either
  1 + DESIGN_RETRIES tries or INFEASIBLE_TRIES ever wider ones, counted in first-try
  units by their candidate evaluations (:func:`planner.designer.budget.search_cost`);
* **the loop's rounds**: when a design is infeasible or a step fails verification, the
  plan draws a step's phases anew, moves channels or re-designs from further seeds, and
  designs and verifies again, up to ``verification.repair_rounds`` more rounds
  (:func:`planner.planning.pipeline._repair_rounds`).  A later round designs again only
  the impacters whose tone moved or that were re-seeded; every other one is kept by a
  re-check of what changed (a few per cent of a design) or comes from the cache.  The
  upper end assumes every design is redone at its last try in every round.

Low end: compilation (if cold) + one round with every design kept at its first try +
scenes and coupling.  High end: compilation + (1 + repair_rounds) rounds with every
design at its last try + scenes and coupling.

The terms:

* one design try costs ``DESIGN_TRY_S + DESIGN_S_PER_FORBIDDEN x forbidden tones +
  DESIGN_S_PER_DRIVE x forbidden summed drives`` of one core: the designer checks every
  forbidden tone across its guard band and every summed drive it must sit out, from
  every x0 of its grid.  Fitted (least squares) to the first tries of real design tasks
  of five specs (204 design tasks of the default, row_assembly, tiny_1x2, pattern_5x5
  and array_7x7 plans: 1-97 forbidden tones, 0-2 drives, 4-53 kHz) timed in-process
  with BLAS and numba on one thread (the tasks captured as ``benchmarks/plan_speed.py
  --profile-tasks`` does); single tries scatter 0.3-7x around the fit (the search is
  stochastic; a try that finds no feasible design on its grid searches again with more
  samples), sums over many designs much less (within 3 % on the 50- and 98-design
  plans);
* a verification step simulates every device's impacters from every initial position of
  the x0 grid over the step: cost ~ impacters x x0 points x duration x frequency;
* the coupling matrix simulates every impacter under every tone alone over the
  single-impacter step (cheap: most of them are silent), and the scenes replay each
  scene's steps once, every device's slider and impacters together, carrying the state.

The verification and scene constants were fitted on the default 5 x 5 plan and the
10 x 10 row plan (``configs/array_10x10_rows.yaml``); docs/large_arrays.md compares the
estimate with measured runs.  The constants are for an idle machine; when the load
average exceeds the cores, the CLI says so (every stage then runs about load / cores
times slower).  Reported as an estimate, never as a promise.
"""

from __future__ import annotations

from dataclasses import dataclass

from model.warmup import PLAN_KERNELS, numba_cache_state  # noqa: F401 (re-exported)
from planner.manufacturability import CHIPS
from planner.core.nodes import Node
from planner.planning.designs import (DESIGN_RETRIES, INFEASIBLE_TRIES, RETRY_GAIN,
                                      RETRY_STALL)
from planner.planning.exposure import driven_ensembles, forbidden_tones, idle_ensembles

#: Seconds of one core per design try, fixed part (Sobol seeding, annealing, SLSQP and
#: the re-checks at the target).
DESIGN_TRY_S = 0.34
#: Seconds of one core per design try and forbidden frequency (checked across its
#: guard band).
DESIGN_S_PER_FORBIDDEN = 0.0043
#: Seconds of one core per design try and summed drive (idle or target ensemble): small
#: since the designer checks a summed drive in its search only once a re-check found it
#: binding.
DESIGN_S_PER_DRIVE = 0.0035
#: Seconds per (impacter x x0 point x second of step x kHz of tone) of the verification:
#: 6.2e-4 on the default 5 x 5 plan, 1.0e-3 on the 10 x 10 row plan.
VERIFY_S_PER_UNIT = 8e-4
#: Seconds per (impacter x second of scene step x kHz) of the scene simulation: from the
#: 10 x 10 row plan (~8 s idle-equivalent for 2400 units).
SCENE_S_PER_UNIT = 6e-3
#: Seconds per (impacter x tone x x0 point x second x kHz) of the coupling matrix: the
#: default plan's 0.3 s of scenes and coupling less its scenes.
COUPLING_S_PER_UNIT = 4e-5
#: Seconds of one core per distinct design of the manufacturability stage's separations
#: (silent band and tone window scanned by simulation): the default plan's 50 designs,
#: 2.4 s on two numba threads (~4.1 s of one core).
SEPARATION_S_PER_DESIGN = 0.082
#: Seconds per (pair told apart x chip) of the collision-free yield's Monte Carlo (one
#: core, numpy): the default plan's 1225 pairs x 10^4 chips, 0.45 s.
YIELD_S_PER_PAIR_CHIP = 3.7e-8
#: Seconds to compile every cached kernel of model.kernels that a plan calls, on one
#: core, with an empty numba cache (measured: :func:`model.warmup.compile_kernels`
#: cold, 17.3 s on an idle 2-core machine; a plan with workers overlaps it with the
#: assignment, see planner.planning.pipeline._workers).
COMPILE_S = 18.0
#: Design time of a typical first round relative to every design kept at its first try:
#: slow designs are retried (up to 8 tries) and single tries scatter.  Measured (one
#: process, numba and BLAS on one thread, every design task of the plan timed): 1.60 on
#: the default 5 x 5 plan (68 tries for 50 designs), 1.49 on pattern_5x5, 1.90 on the
#: 7 x 7, 1.02-1.03 on row_assembly and the tests' 1 x 2 spec.
TYPICAL_DESIGN_FACTOR = 1.6
#: Parallel efficiency of a second worker (processes for designs, threads for simulation).
PARALLEL_EFFICIENCY = 0.8


@dataclass(frozen=True)
class Estimate:
    """Work left after the assignment and its estimated time.

    Attributes
    ----------
    impacters : int
        Driven impacters.
    designs : int
        Distinct designs to run (impacters sharing every design input share one).
    steps : int
        Steps to verify.
    verification_runs : int
        Simulations of the verification: step x impacter x x0 point.
    coupling_runs : int
        Simulations of the coupling matrix: impacter x tone x x0 point.
    design_s, verify_s, coupling_s : float
        Estimated wall time on ``jobs`` workers [s] of one round of designs (every
        design kept at its first try), of one round of verification, and of the scenes
        and the coupling matrix (once).
    manufacturability_s : float
        Estimated wall time [s] of the manufacturability stage (once): every distinct
        design's separation and, with tolerances, the yield's Monte Carlo.
    jobs : int
        Workers the estimate is for.
    load : tuple or None
        1-minute load average and cores when the estimate was made (None: not known).
    tries : int
        Most tries of one design: 1 + ``DESIGN_RETRIES``.
    worst_tries : float
        The slowest design in first-try units (:func:`worst_design_tries`); the high
        end's multiplier.
    rounds : int
        Most design and verification rounds: 1 + ``verification.repair_rounds``.
    compile_s : float
        Estimated numba compilation [s] (0 when the cache holds every kernel).
    cold_kernels, kernels : int
        Kernels of :data:`PLAN_KERNELS` missing from numba's cache, and all of them.
    """

    impacters: int
    designs: int
    steps: int
    verification_runs: int
    coupling_runs: int
    design_s: float
    verify_s: float
    coupling_s: float
    jobs: int
    load: tuple | None = None
    tries: int = 1
    worst_tries: float = 1.0
    rounds: int = 1
    compile_s: float = 0.0
    cold_kernels: int = 0
    kernels: int = 0
    manufacturability_s: float = 0.0

    @property
    def total_s(self) -> float:
        """The low end [s]: compilation, one round at first tries, scenes and coupling."""
        return (self.compile_s + self.design_s + self.verify_s + self.coupling_s
                + self.manufacturability_s)

    @property
    def typical_s(self) -> float:
        """The typical time [s]: one round with the designs' retries as measured on the
        default plan (:data:`TYPICAL_DESIGN_FACTOR` x the first-try designs)."""
        return (self.compile_s + TYPICAL_DESIGN_FACTOR * self.design_s + self.verify_s
                + self.coupling_s + self.manufacturability_s)

    @property
    def high_s(self) -> float:
        """The high end [s]: compilation, every round, every design at its last try."""
        return (self.compile_s + self.rounds * (self.worst_tries * self.design_s
                                                + self.verify_s)
                + self.coupling_s + self.manufacturability_s)

    def lines(self) -> list[str]:
        """The estimate as the CLI prints it."""
        if self.kernels == 0:
            comp = "compilation not known (numba's cache could not be read)"
        elif self.cold_kernels:
            comp = (f"compilation ~{_fmt(self.compile_s)} (numba cache cold: "
                    f"{self.cold_kernels} of {self.kernels} kernels)")
        else:
            comp = "no compilation (numba cache warm)"
        return [
            f"remaining: {self.designs} designs for {self.impacters} impacters, "
            f"{self.steps} steps to verify ({self.verification_runs} simulations), "
            f"coupling matrix ({self.coupling_runs} simulations)",
            f"estimated time on {self.jobs} worker{'s' if self.jobs > 1 else ''}: "
            f"{_fmt(self.total_s)} if every design is kept at its first try and every step "
            f"verifies at once, typically about {_fmt(self.typical_s)} (with retries, as "
            f"measured on the default plan), at most {_fmt(self.high_s)}; an estimate from a "
            f"cost model calibrated on an idle machine (docs/large_arrays.md)",
            f"  per round: designs {_range(self.design_s, self.worst_tries * self.design_s)} "
            f"({self.tries_text()}: up to {self.worst_tries:.0f} x a first try), "
            f"verification {_fmt(self.verify_s)}; up to "
            f"{self.rounds} round{'s' if self.rounds != 1 else ''} (1 if every design is "
            f"feasible and every step verifies; a later round designs again only what it "
            f"moved or re-seeded, the high end redoes every design in every round at its "
            f"last try); then scenes and coupling "
            f"{_fmt(self.coupling_s)}, manufacturability {_fmt(self.manufacturability_s)}; "
            f"{comp}",
        ] + self._load_lines()

    def tries_text(self) -> str:
        """How many tries a design takes, as :func:`planner.planning.designs.
        _design_task` stops them: most designs one; a slow one retried while a try
        gains, stopping after :data:`RETRY_STALL` in a row that do not (the "1-8 tries"
        this said before the stall rule was the cap only); an infeasible one given up
        after :data:`INFEASIBLE_TRIES`, each searching wider."""
        return (f"1 try each when fast enough, a slow one retried until "
                f"{RETRY_STALL} tries in a row gain less than {100 * RETRY_GAIN:g} % in "
                f"speed ({self.tries} at most), an infeasible one given up after "
                f"{INFEASIBLE_TRIES} ever wider")

    def _load_lines(self):
        if self.load is None or self.load[0] <= self.load[1]:
            return []
        avg, cores = self.load
        return [f"the machine is busy (load average {avg:.1f} on {cores} cores): expect "
                f"about {avg / cores:.1f}x that"]


def _fmt(seconds):
    if seconds < 10:
        return f"{seconds:.1f} s"
    if seconds < 120:
        return f"{seconds:.0f} s"
    return f"{seconds / 60:.1f} min"


def _range(low, high):
    """``low``-``high`` in the unit of ``high``."""
    if high < 120:
        return f"{low:.1f}-{high:.1f} s" if high < 10 else f"{low:.0f}-{high:.0f} s"
    return f"{low / 60:.1f}-{high / 60:.1f} min"


def _speedup(jobs, tasks):
    """Effective workers for ``tasks`` independent tasks on ``jobs`` workers."""
    used = max(1, min(jobs, tasks))
    return 1.0 + (used - 1) * PARALLEL_EFFICIENCY


def design_try_s(n_forbidden, n_drives):
    """Seconds of one core for one design try with ``n_forbidden`` forbidden tones and
    ``n_drives`` forbidden summed drives."""
    return DESIGN_TRY_S + DESIGN_S_PER_FORBIDDEN * n_forbidden + DESIGN_S_PER_DRIVE * n_drives


def estimate(settings, steps, assignment, jobs=1, kernels=None) -> Estimate:
    """Estimate the work and time left once ``assignment`` is known.

    Parameters
    ----------
    settings : Settings
    steps : sequence of Step
    assignment : planner.assignment.assign.Assignment
    jobs : int
        Worker processes for the designs and threads for the simulations.
    kernels : (int, int), optional
        numba's cache state the plan started with (:func:`numba_cache_state`); default:
        the assignment's reach's (its probes compiled what was cold, as part of the
        plan), else read now.

    Returns
    -------
    Estimate
    """
    jobs = max(1, int(jobs))
    freqs = assignment.frequencies
    forbidden = forbidden_tones(steps, freqs)
    ensembles = idle_ensembles(steps, freqs)
    targets = driven_ensembles(steps, freqs)
    # the design cache's key without the drives' phases (they follow from the steps);
    # a summed drive the design must respond under costs about what one it must be
    # silent under does
    keys = {}
    for n in sorted(freqs):
        key = (round(freqs[n], 6), forbidden[n], ensembles[n], targets[n],
               settings.impacters[n])
        keys.setdefault(key, (len(forbidden[n]), len(ensembles[n]) + len(targets[n])))
    design_cpu = sum(design_try_s(*v) for v in keys.values())
    # every device of the array is checked in every step (idle or moving)
    devices = len(settings.sliders)
    x0 = settings.x0_points
    ver_units, ver_runs, scene_units = 0.0, 0, 0.0
    for st in steps:
        tones = [freqs[Node(d, dr)] for d, dr in st.active_nodes() if (d, dr) in freqs]
        f_khz = (sum(tones) / len(tones) if tones else 0.0) / 1e3
        ver_units += 2 * devices * x0 * st.duration_s * f_khz
        ver_runs += 2 * devices * x0
        if st.scene in settings.scenes:
            # the scenes replay their steps once, every device from the state carried in
            scene_units += 2 * devices * (st.duration_s + settings.settle_s) * f_khz
    tones = sorted(set(freqs.values()))
    coup_units = len(freqs) * x0 * settings.single_step_s * sum(tones) / 1e3
    coup_runs = len(freqs) * len(tones) * x0
    reach = getattr(assignment, "reach", None)
    if kernels is None and reach is not None and reach.kernels_cold[1]:
        kernels = reach.kernels_cold
    cold, total = numba_cache_state() if kernels is None else kernels
    # manufacturability: one separation per distinct design (in this process, on the
    # numba threads), and the Monte Carlo over the pairs the steps must tell apart
    from planner.assignment.assign import told_apart_pairs

    chips = 0 if settings.tolerances.zero else CHIPS
    pairs = len(told_apart_pairs(assignment, sorted(freqs))) if chips else 0
    manufacture_s = (SEPARATION_S_PER_DESIGN * len(keys) / _speedup(jobs, len(keys))
                     + YIELD_S_PER_PAIR_CHIP * pairs * chips)
    return Estimate(
        impacters=len(freqs), designs=len(keys), steps=len(steps),
        verification_runs=ver_runs, coupling_runs=coup_runs,
        design_s=design_cpu / _speedup(jobs, len(keys)),
        verify_s=VERIFY_S_PER_UNIT * ver_units / _speedup(jobs, devices),
        coupling_s=(COUPLING_S_PER_UNIT * coup_units + SCENE_S_PER_UNIT * scene_units)
        / _speedup(jobs, len(freqs)),
        jobs=jobs, load=_load(), tries=1 + DESIGN_RETRIES,
        worst_tries=worst_design_tries(settings.budget),
        rounds=1 + settings.repair_rounds,
        compile_s=COMPILE_S * cold / total if total else 0.0,
        cold_kernels=cold, kernels=total, manufacturability_s=manufacture_s)


def worst_design_tries(budget="fast") -> float:
    """The slowest design in units of a first try: 1 + ``DESIGN_RETRIES`` tries, or
    ``INFEASIBLE_TRIES`` infeasible ones, each searching wider than the last, every one
    with the escalations it may make when it finds nothing feasible on its grid (their
    candidate evaluations relative to a first try's,
    :func:`planner.designer.budget.escalated_cost`)."""
    from planner.designer.budget import escalated_cost, search_cost, widened

    base = search_cost(budget)
    wider = sum(escalated_cost(widened(budget, k)) / base for k in range(INFEASIBLE_TRIES))
    return max(1.0 + DESIGN_RETRIES, wider)


def _load():
    import os

    try:
        return (os.getloadavg()[0], os.cpu_count() or 1)
    except (OSError, AttributeError):
        return None
