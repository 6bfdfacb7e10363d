"""What a plan will cost, known once the frequencies are assigned (before any design).

A simple cost model, not a measurement: every constant below was calibrated on the
default 5 x 5 plan (``configs/array_5x5.yaml``: the README's warm stage split on the idle
2-core machine, ``--jobs 2``: design 47.4 s, verification 1.7 s, scenes and coupling
0.3 s), and the shape of each term follows from what the stage simulates:

* a design evaluates candidate geometries over a window of fixed length at its
  target, at every forbidden frequency (across its guard band) and under every summed
  drive it must sit out: its cost grows with the number of drive cycles in the window
  (its frequency) times the number of those checks;
* a verification step simulates every device's impacters from every initial position of
  the x0 grid over the step: cost ~ impacters x x0 points x duration x frequency;
* the coupling matrix simulates every impacter under every tone alone over the
  single-impacter step (cheap: most of them are silent), and the scenes replay each
  scene's steps once, every device's slider and impacters together, carrying the state.

The design constant comes from the 5 x 5 plan alone; the verification and scene
constants also use the 10 x 10 row plan (``configs/array_10x10_rows.yaml``, 20 steps of
100 devices: 170 s design, 212 s verification, 218 s scenes and coupling on the busy
machine, scaled to the idle machine by its design stage's ratio), because the 5 x 5 plan
spends too little in them (2 s) to fix their shape.

The estimate is for the first round; repair rounds (after verification failures) come on
top.  The constants are for an idle machine; when the load average exceeds the cores,
the CLI says so (every stage then runs about load / cores times slower).  Reported as an
estimate, never as a promise; benchmarks/results/scaling.md compares it with measured
plans.
"""

from __future__ import annotations

from dataclasses import dataclass

from planner.nodes import Node
from planner.planning.designs import forbidden_tones, idle_ensembles

#: Seconds of one design per (target / 10 kHz) x (1 + checks), serial, retries included
#: on average: 47.4 s x 1.8 effective workers / 5778 units of the default 5 x 5 plan.
DESIGN_S_PER_UNIT = 0.0148
#: Weight of a forbidden summed drive relative to one forbidden frequency [-] (a summed
#: drive is simulated over the design's long window as well; not separately calibrated).
DRIVE_WEIGHT = 3.0
#: Seconds per (impacter x x0 point x second of step x kHz of tone) of the verification:
#: 6.2e-4 on the default 5 x 5 plan, 1.0e-3 on the 10 x 10 row plan.
VERIFY_S_PER_UNIT = 8e-4
#: Seconds per (impacter x second of scene step x kHz) of the scene simulation: from the
#: 10 x 10 row plan (~8 s idle-equivalent for 2400 units).
SCENE_S_PER_UNIT = 6e-3
#: Seconds per (impacter x tone x x0 point x second x kHz) of the coupling matrix: the
#: default plan's 0.3 s of scenes and coupling less its scenes.
COUPLING_S_PER_UNIT = 4e-5
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
        Estimated wall time of each stage on ``jobs`` workers [s].
    jobs : int
        Workers the estimate is for.
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
    #: 1-minute load average and cores when the estimate was made (None: not known).
    load: tuple | None = None

    @property
    def total_s(self) -> float:
        """Estimated wall time of the first round [s]."""
        return self.design_s + self.verify_s + self.coupling_s

    def lines(self) -> list[str]:
        """The estimate as the CLI prints it."""
        return [
            f"remaining: {self.designs} designs for {self.impacters} impacters, "
            f"{self.steps} steps to verify ({self.verification_runs} simulations), "
            f"coupling matrix ({self.coupling_runs} simulations)",
            f"estimated time on {self.jobs} worker{'s' if self.jobs > 1 else ''}: "
            f"{_fmt(self.total_s)} (designs {_fmt(self.design_s)}, verification "
            f"{_fmt(self.verify_s)}, scenes and coupling {_fmt(self.coupling_s)}); an "
            f"estimate from a cost model calibrated on the 5 x 5 and 10 x 10 plans on an "
            f"idle machine, before any repair round",
        ] + self._load_lines()

    def _load_lines(self):
        if self.load is None or self.load[0] <= self.load[1]:
            return []
        avg, cores = self.load
        return [f"the machine is busy (load average {avg:.1f} on {cores} cores): expect "
                f"at least ~{avg / cores:.0f}x that"]


def _fmt(seconds):
    if seconds < 120:
        return f"{seconds:.0f} s"
    return f"{seconds:.0f} s (~{seconds / 60:.0f} min)"


def _speedup(jobs, tasks):
    """Effective workers for ``tasks`` independent tasks on ``jobs`` workers."""
    used = max(1, min(jobs, tasks))
    return 1.0 + (used - 1) * PARALLEL_EFFICIENCY


def design_units(frequency_hz, n_forbidden, n_drives):
    """Cost units of one design: (f / 10 kHz) x (1 + forbidden + weight x drives)."""
    return frequency_hz / 1e4 * (1.0 + n_forbidden + DRIVE_WEIGHT * n_drives)


def estimate(settings, steps, assignment, jobs=1) -> Estimate:
    """Estimate the work and time left once ``assignment`` is known.

    Parameters
    ----------
    settings : Settings
    steps : sequence of Step
    assignment : planner.assign.Assignment
    jobs : int
        Worker processes for the designs and threads for the simulations.

    Returns
    -------
    Estimate
    """
    jobs = max(1, int(jobs))
    freqs = assignment.frequencies
    forbidden = forbidden_tones(steps, freqs)
    ensembles = idle_ensembles(steps, freqs)
    # the design cache's key without the drives' phases (they follow from the steps)
    keys = {}
    for n in sorted(freqs):
        key = (round(freqs[n], 6), forbidden[n], ensembles[n], settings.impacters[n])
        keys.setdefault(key, (freqs[n], len(forbidden[n]), len(ensembles[n])))
    design_cpu = DESIGN_S_PER_UNIT * sum(design_units(*v) for v in keys.values())
    # every device of the array is checked in every step (idle or moving)
    devices = len(settings.sliders)
    x0 = settings.x0_points
    ver_units, ver_runs, scene_units = 0.0, 0, 0.0
    for st in steps:
        tones = [freqs[Node(d, dr).text] for d, dr in st.active_nodes()
                 if Node(d, dr).text in freqs]
        f_khz = (sum(tones) / len(tones) if tones else 0.0) / 1e3
        ver_units += 2 * devices * x0 * st.duration_s * f_khz
        ver_runs += 2 * devices * x0
        if st.scene in settings.scenes:
            # the scenes replay their steps once, every device from the state carried in
            scene_units += 2 * devices * (st.duration_s + settings.settle_s) * f_khz
    tones = sorted(set(freqs.values()))
    coup_units = len(freqs) * x0 * settings.single_step_s * sum(tones) / 1e3
    coup_runs = len(freqs) * len(tones) * x0
    return Estimate(
        impacters=len(freqs), designs=len(keys), steps=len(steps),
        verification_runs=ver_runs, coupling_runs=coup_runs,
        design_s=design_cpu / _speedup(jobs, len(keys)),
        verify_s=VERIFY_S_PER_UNIT * ver_units / _speedup(jobs, devices),
        coupling_s=(COUPLING_S_PER_UNIT * coup_units + SCENE_S_PER_UNIT * scene_units)
        / _speedup(jobs, len(freqs)),
        jobs=jobs, load=_load())


def _load():
    import os

    try:
        return (os.getloadavg()[0], os.cpu_count() or 1)
    except (OSError, AttributeError):
        return None
