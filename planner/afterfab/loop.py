"""The after-fabrication loop: one chip measured, rebuilt as built, its drive checked,
re-planned, tuned and trimmed -- on a simulated chip of a yield study and on a measured
die of the test floor alike.

:func:`run_loop` runs the stages a lab runs on a chip, in order:

1. **measure**: the chip's resonances (:class:`~planner.afterfab.measurement.
   Measurement`).  On the test floor they are given (measured.csv, a wafer file); a
   study measures its chip's truth (:meth:`Truth.measure`, seeded per chip);
2. **as-built**: the chip's models from the measurement
   (:func:`planner.afterfab.replan.chip_models`);
3. **the plan's drive** checked on the chip (:func:`planner.afterfab.checks.
   check_drive`): on its truth where known, else on its as-built models;
4. **re-plan**: the drive re-planned from the measurement
   (:func:`planner.afterfab.replan.replan`), verified on the measured models and, with
   the truth, checked on it;
5. **tune** (only with the truth, whose sweep a study simulates; a lab's sweep reaches
   the floor as a measurement's working windows): the tones moved to the middle of the
   working windows a speed sweep finds on the chip, re-planned and checked again;
6. **trim**, for a chip whose re-plan finds impacters no drive tells apart: the cuts
   chosen pass by pass (:func:`planner.afterfab.trim.trim_sequence`), and the drive
   re-planned for the trimmed chip.  With the truth, the cuts are made on it (each off
   its target by the trim's precision), the chip measured again, up to ``trim.passes``
   times, and the re-plan checked on the trimmed truth (and tuned); on the test floor
   the lab cuts after this command, so one pass is chosen and its drive weighed over
   the cuts' errors (:func:`planner.afterfab.trim.trim_chip`, as ``vibroplan trim``).

On the test floor the loop stops at the first stage that works (a lab plays the first
drive that works); with the truth every stage asked for runs on every chip (a study
counts each stage's yield), but a chip is trimmed only where its re-plan needs it.

The outcome and causes (:mod:`planner.afterfab.outcome`) follow from the stages' by one
rule, whichever the chip: ``vibroplan yield`` (:func:`planner.yield_.verify_chip`) and
the wafer batch (:func:`planner.afterfab.batch.replan_die`) both call :func:`run_loop`.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from planner.afterfab.checks import check_drive
from planner.afterfab.measurement import measure_models
from planner.afterfab.outcome import (CANNOT_TRIM, NO_REPLAN, TRIMMED_FAILS, Collision,
                                      DriveCheck, LoopResult, ReplanOutcome, Seconds,
                                      TrimOutcome, TuneOutcome, replan_causes)
from planner.afterfab.replan import chip_models, replan
from planner.afterfab.trim import trimmed_chip

#: A tuned chip's tone is moved to its working window's middle only when it sits further
#: than this fraction of the window's width from it (a lab retunes the tones near an
#: edge; a chip whose every tone is central needs no second re-plan) [-].
TUNE_CENTRE = 0.25
#: The streams of a simulated chip's seed (children of its SeedSequence,
#: :meth:`Truth.stream`) that what a lab reads of it is drawn from: its measurement,
#: the tuning sweep of its re-plan; trim pass k's cuts and the measurement after them
#: are streams ``TRIM_STREAM + 2 k`` and ``TRIM_STREAM + 2 k + 1``, and the tuning sweep
#: of the trimmed chip's re-plan the one after the last pass's.
MEASURE_STREAM, TUNE_STREAM, TRIM_STREAM = 0, 1, 2


@dataclass(frozen=True)
class Truth:
    """A simulated chip as it really is: what a yield study knows and a lab does not.

    Attributes
    ----------
    impacters : dict
        Impacter id -> its true model (:class:`model.Impacter`, or
        :class:`model.PairHalves`).
    sliders : dict
        Device -> its true :class:`model.Slider`.
    seed : numpy.random.SeedSequence
        The chip's (:func:`planner.core.rng.chip_seed`): the noise of everything a lab
        reads of it comes from its children (:data:`MEASURE_STREAM` ...).
    unbuildable : tuple of str
        Impacters and devices the sampled errors left unbuildable (nothing to simulate).
    """

    impacters: dict
    sliders: dict
    seed: np.random.SeedSequence
    unbuildable: tuple = ()

    def stream(self, k: int) -> np.random.SeedSequence:
        """Child ``k`` of the chip's seed, as ``seed.spawn(k + 1)[k]`` gives it (without
        spawning from the chip's own sequence)."""
        s = self.seed
        return np.random.SeedSequence(s.entropy, spawn_key=tuple(s.spawn_key) + (int(k),),
                                      pool_size=s.pool_size)

    def measure(self, ids, noise_pct: float, stream: int = MEASURE_STREAM) -> dict:
        """What a lab measures of the chip: id -> :class:`~planner.afterfab.measurement.
        Measurement` of each impacter of ``ids`` (in that order), each resonance off by
        ``noise_pct`` [%] (:func:`~planner.afterfab.measurement.measure_models`, the
        normals from ``stream``)."""
        return measure_models(self.impacters, list(ids), noise_pct, self.stream(stream))


@dataclass(frozen=True)
class LoopJob:
    """What every chip's loop needs of the plan and the options; sent to each worker once.

    Attributes
    ----------
    record : PlanRecord or None
        The plan the chip was made by (None only when nothing is re-planned).
    settings : Settings
        Its settings, resolved once (:func:`planner.planning.settings.plan_settings`).
    steps, waveforms, dwells :
        The plan's drive (:func:`planner.afterfab.checks.drive_of`).
    nodes : tuple of planner.core.nodes.Node
        The plan's impacters, in its order.
    replan, tune, trim : bool
        The stages to run after the plan's drive (``tune`` needs the truth).
    measure_noise_pct : float
        One sigma of a measured resonance's noise [%]: a study's measurement's, and the
        as-built models' assumption (:func:`planner.afterfab.replan.chip_models`).
    trim_precision_pct : float or None
        One sigma of a simulated cut's error [%] (None: the spec's
        ``trim.precision_pct``).
    tune_tones, tune_noise_pct :
        The simulated tuning sweep's tones per impacter and a speed reading's noise [%].
    outputs : bool
        Keep what a lab writes (the re-plan's records, the trim's drive): the test
        floor's dies; a study keeps only the outcomes.
    """

    record: object
    settings: object
    steps: tuple
    waveforms: dict
    dwells: dict
    nodes: tuple = ()
    replan: bool = True
    tune: bool = False
    trim: bool = False
    measure_noise_pct: float = 0.0
    trim_precision_pct: float | None = None
    tune_tones: int = 7
    tune_noise_pct: float = 5.0
    outputs: bool = False

    @property
    def ids(self) -> tuple:
        """The plan's impacter ids, in its order."""
        return tuple(n.text for n in self.nodes)


def run_loop(job: LoopJob, *, measured: dict | None = None, truth: Truth | None = None
             ) -> LoopResult:
    """One chip through measure -> as-built -> plan's drive -> re-plan -> tune -> trim
    (the module docstring).

    Parameters
    ----------
    job : LoopJob
        The plan and the stages asked for.
    measured : dict, optional
        The test floor's measurement: impacter id -> :class:`~planner.afterfab.
        measurement.Measurement` (an impacter left out is taken at its design, and
        named in the result's ``not_measured``).
    truth : Truth, optional
        A simulated chip (a yield study): it is measured, and every drive is judged on
        it.  Exactly one of ``measured`` and ``truth``.

    Returns
    -------
    LoopResult
        Each stage's outcome, the chip's outcome and causes; with ``job.outputs`` on the
        test floor, the re-plan and the trim to write.

    Raises
    ------
    ValueError
        Both or neither of ``measured`` and ``truth``; ``job.tune`` without the truth.
    """
    if (measured is None) == (truth is None):
        raise ValueError("run_loop: give the chip's measurement (the test floor) or its "
                         "truth (a study), one of the two")
    if job.tune and truth is None:
        raise ValueError("run_loop: tune needs the chip's truth (a sweep simulated on it); "
                         "a lab's sweep reaches the loop as the measurement's windows")
    if truth is not None and truth.unbuildable:
        return _unbuildable(job, truth)
    if job.settings is not None and (job.settings.measurement_noise
                                     != job.measure_noise_pct / 100.0):
        # the re-plans' margins on the measurement are the noise this lab measures with
        # (the as-built models' assumption), whatever the spec's
        job = dataclasses.replace(job, settings=dataclasses.replace(
            job.settings, measurement_noise=job.measure_noise_pct / 100.0))
    t0 = time.perf_counter()
    floor = truth is None
    missing = () if not floor else tuple(r.id for r in job.record.impacters
                                         if r.id not in measured)
    # 1.-2. measure, and the chip as built from the measurement
    models = None
    if job.replan or floor:
        if not floor:
            measured = truth.measure(job.ids, job.measure_noise_pct)
        models = chip_models(job.record, measured, job.measure_noise_pct)
    t_measure = time.perf_counter() - t0
    # 3. the plan's drive, on the truth where known; a chip to be re-planned stops at
    # the first failing step (a chip the die moved fails the first one it plays)
    ts = time.perf_counter()
    on = truth if not floor else models
    got = check_drive(job.settings, job.steps, job.waveforms, job.dwells, on.impacters,
                      on.sliders, first_failure=job.replan)
    nominal = DriveCheck.of(got)
    t_nominal = time.perf_counter() - ts
    if not job.replan or (floor and nominal.passed):
        return LoopResult(nominal, seconds=Seconds(t_nominal, 0.0), on_floor=floor,
                          not_measured=missing)
    # 4.-5. re-plan (tuned with the truth): the plan's drive on this chip is the
    # re-plan's ``original``, not verified a second time
    ts = time.perf_counter()
    original = (got["steps_passed"], got["rows"])
    replanned, plan = _replan(job, measured, models, original, truth, TUNE_STREAM)
    if not job.outputs:
        plan = None     # a study keeps the outcomes only
    t_replan = t_measure + time.perf_counter() - ts
    if not job.trim or (floor and replanned.passed):
        return LoopResult(nominal, replanned, seconds=Seconds(t_nominal, t_replan),
                          on_floor=floor, not_measured=missing, replanned=plan)
    # 6. trim, where the re-plan needs it
    ts = time.perf_counter()
    trimmed, trim_result = _trim(job, measured, models, original, truth, replanned,
                                 missing)
    return LoopResult(nominal, replanned, trimmed,
                      seconds=Seconds(t_nominal, t_replan, time.perf_counter() - ts),
                      on_floor=floor, not_measured=missing, replanned=plan,
                      trimmed=trim_result)


def _unbuildable(job: LoopJob, truth: Truth) -> LoopResult:
    """A simulated chip that cannot be built (a node or a device, its slider): nothing to
    simulate, measure, re-plan or trim; every stage fails as it is."""
    nodes = {n for n in job.nodes for x in truth.unbuildable if n.text == x or n.device == x}
    nominal = DriveCheck(False, {"unbuildable": len(truth.unbuildable)},
                         tuple(sorted(nodes)))
    replanned = trimmed = None
    if job.replan:
        fields = dict(passed=False, measured_passed=False, causes=("unbuildable",),
                      failures={"unbuildable": 1})
        # nothing to sweep on a chip that cannot be built: tuned, it fails as it is
        replanned = ReplanOutcome(**fields, tuned=TuneOutcome(**fields) if job.tune
                                  else None)
        if job.trim:
            trimmed = TrimOutcome(passed=False, trimmed=(), passes=None,
                                  causes=("unbuildable",), failures={"unbuildable": 1})
    return LoopResult(nominal, replanned, trimmed, seconds=Seconds(0.0, 0.0))


def _replan(job: LoopJob, measured: dict, models, original, truth: Truth | None,
            tune_stream: int, remeasure=()):
    """Re-plan from ``measured`` on ``models`` and judge the drive: on the truth where
    known (and tuned there with ``job.tune``, its sweep's noise from ``tune_stream``),
    else on the measured models.  ``remeasure``: the trimmed impacters, whose
    separations the re-plan measures again.

    Returns
    -------
    (ReplanOutcome, Plan or None)
        The outcome, and the re-plan (None when none could be made).
    """
    from planner.core.errors import PlanningError
    from planner.synthesis import LoopLengthError

    try:
        plan = replan(job.record, measured, settings=job.settings, original=original,
                      record=job.outputs, remeasure=remeasure, models=models)
    except LoopLengthError:
        # this chip's tones fit no loop the synthesis may play: the chip fails (with
        # that cause), the study or the batch goes on
        return _no_drive(job, "drive not playable"), None
    except PlanningError as exc:
        # this chip's re-plan cannot be made (the others go on)
        return _no_drive(job, f"{NO_REPLAN}{exc}"), None
    ok = plan.passed
    rp = plan.replan
    collisions = tuple(Collision.from_inseparable(c) for c in rp.inseparable)
    if collisions:      # no drive can pass: not simulated on the true models
        fields = dict(passed=False, measured_passed=False,
                      causes=replan_causes(ok, rp, collisions=True,
                                           truth_known=truth is not None),
                      failures={}, collisions=collisions,
                      outside_band=tuple(rp.outside_band),
                      split_steps=tuple(sorted(rp.split_steps)),
                      tones_moved=len(rp.moved), repairs=dict(rp.repairs))
        # no sweep tells a colliding pair apart
        tuned = TuneOutcome(**fields, windows=0) if job.tune else None
        return ReplanOutcome(**fields, tuned=tuned), plan
    # the re-planned drive as it plays, checked on the chip's true models in memory
    got = (None if truth is None else
           check_drive(job.settings, plan.run_steps, plan.waveforms, plan.dwells,
                       truth.impacters, truth.sliders))
    out = _judged(ok, rp, got)
    if not job.tune:
        return ReplanOutcome(**out), plan
    return ReplanOutcome(**out, tuned=_tune(job, measured, models, original, remeasure,
                                            truth, plan, out, tune_stream, got)), plan


def _no_drive(job: LoopJob, cause: str) -> ReplanOutcome:
    """The outcome of a re-plan that made no drive (``cause``): nothing to tune, tuned
    the chip fails as it is."""
    fields = dict(passed=False, measured_passed=False, causes=(cause,), failures={},
                  split_steps=(), tones_moved=0)
    return ReplanOutcome(**fields, tuned=TuneOutcome(**fields) if job.tune else None)


def _judged(ok: bool, rp, got: dict | None) -> dict:
    """A simulated re-plan's outcome (the fields of a :class:`ReplanOutcome` or
    :class:`TuneOutcome`): whether it works -- on the truth ``got`` where known, else on
    the measured models (``ok``) -- and why not (:func:`replan_causes`)."""
    return {"passed": bool(ok) if got is None else got["passed"],
            "measured_passed": bool(ok), "causes": replan_causes(ok, rp, got),
            "failures": {} if got is None else got["failures"], "collisions": (),
            "outside_band": tuple(rp.outside_band),
            "split_steps": tuple(sorted(rp.split_steps)),
            "tones_moved": sum(1 for m in rp.moved
                               if m.frequency_hz != m.original_frequency_hz),
            "repairs": dict(rp.repairs)}


def _tune(job: LoopJob, measured, models, original, remeasure, truth: Truth, plan,
          first: dict, stream: int, first_got: dict | None = None) -> TuneOutcome:
    """Tune a re-planned chip, as a lab with the piezo on would: a speed sweep around
    each re-planned tone on the chip itself (:func:`planner.afterfab.tune.sweep_speeds`,
    the true models, a speed reading's noise from ``stream``), the working windows fitted
    (:func:`planner.afterfab.tune.fit_windows`, at least the speed floor), the drive
    re-planned with each tone in its window's middle and checked on the true models.

    Only the tones further than :data:`TUNE_CENTRE` of their window's width from its
    middle move; with none to move the re-plan stands as it was (``first``), and so does
    it when the tuned re-plan fails the checks on the chip's measured models that the
    re-plan passed (a lab keeps the drive that verifies), or fails on the chip where the
    re-plan worked (the lab played both).  The drive kept, where a slider is still too
    slow or off its target on the chip, is repaired there (:func:`_played_on_chip`).
    """
    from planner.afterfab.tune import fit_windows, sweep_speeds, windows_of

    settings = job.settings
    rng = np.random.default_rng(truth.stream(stream))
    rows = sweep_speeds(settings, plan.assignment.frequencies, truth.impacters,
                        truth.sliders, rng, count=job.tune_tones,
                        noise_pct=job.tune_noise_pct)
    fitted = fit_windows(rows, min_speed=settings.min_speed_m_s)
    swept = windows_of(fitted, keep_flagged=True)
    tones = {n.text: f for n, f in plan.assignment.frequencies.items()}
    # a tone already in the middle half of its window stays (a lab retunes the others)
    windows = {n: w for n, w in swept.items()
               if abs(tones[n] - 0.5 * (w[0] + w[1])) > TUNE_CENTRE * (w[1] - w[0])}
    if not windows:
        return TuneOutcome(**_played_on_chip(job, models, truth, plan, first_got, first),
                           windows=0)
    tuned = {n: (m.with_window(windows[n]) if n in windows else m)
             for n, m in measured.items()}
    again = replan(job.record, tuned, settings=settings, original=original,
                   record=job.outputs, remeasure=remeasure, models=models)
    ok = again.passed
    if not ok and first["measured_passed"] and not _swept_speeds_hold(again, swept):
        # the re-plan at the windows' middles fails the checks on the chip's own models,
        # where the re-plan before the sweep passed them: a lab keeps the drive that
        # verifies (at 0.01 % noise, 200 chips of the default: 7 chips lost to the tune
        # without this, 185 rather than 178 tuned chips working)
        return TuneOutcome(**_played_on_chip(job, models, truth, plan, first_got, first),
                           windows=0)
    rp = again.replan
    got = check_drive(settings, again.run_steps, again.waveforms, again.dwells,
                      truth.impacters, truth.sliders)
    if not got["passed"] and first["passed"]:
        # the lab plays the tuned drive on the chip and sees a slider fail that the
        # re-plan before the sweep moved (it played that one too: the sweep is around
        # its tones): it keeps the drive that works on the chip.  The sweep reads each
        # impacter alone; a step plays them together, and the tuned step can fail where
        # every sweep said the tone works (200 chips of the default: 2 chips at 0.01 %,
        # 1 at 0.05 % lost to the tune without this)
        return TuneOutcome(**first, windows=0, kept_replan=True)
    return TuneOutcome(**_played_on_chip(job, models, truth, again, got,
                                        _judged(ok, rp, got)), windows=len(windows))


def _played_on_chip(job: LoopJob, models, truth: Truth, plan, got: dict | None,
                    fields: dict) -> dict:
    """The drive a lab keeps, played on the chip and repaired where the lab sees it fail:

    - a slider too slow: its moving impacters' tones raised in that step
      (:func:`planner.afterfab.drive.raise_slow`), as a lab that sees the slider crawl
      raises its tone before it scraps the chip, each raised step checked on the measured
      models and on the chip;
    - a slider off its target (a ``targets_um`` step): the step's tone gates found again
      on the chip (:func:`planner.afterfab.replan.regate` with the chip as the models),
      as a lab times each tone by playing the step and reading where its sliders end: the
      gates the re-plan found on the measured models put a slider wherever the measured
      speed would have, and a 0.05 % error in a resonance changes a slider's speed by
      tens of per cent near its window's edge, against a position tolerance of a few um.
      The positions are read exactly (a microscope reads ~0.1 um; a few plays of the
      step, as the plan's own search makes them).  Not with a drive chain (whose input
      limit the re-gated tones would have to be held to again).

    The drive is then checked on the chip again as a whole (the scenes' carried state
    included).  Returns the outcome's fields (``fields``, the drive's as it was, when
    nothing was repaired), the repairs counted by kind in ``repairs``
    (``amplitude_raised``, ``gates_timed_on_chip``).
    """
    from planner.afterfab.drive import plan_phases, raise_slow
    from planner.afterfab.replan import AMPLITUDE_RAISED, GATES_ON_CHIP, regate
    from planner.planning.motion import by_node
    from planner.planning.verify import OFF_TARGET, TOO_SLOW

    if got is None or got["passed"] or plan is None:
        return fields
    kinds = {f.kind for f in got["records"]}
    if not kinds & {TOO_SLOW, OFF_TARGET}:
        return fields
    settings = job.settings
    steps, waveforms, repairs = tuple(plan.run_steps), dict(plan.waveforms), {}

    def check_on(on):
        def run(steps, waveforms):
            g = check_drive(settings, steps, waveforms, plan.dwells, on.impacters,
                            on.sliders, scenes=False)
            return g["rows"], g["records"]
        return run

    if TOO_SLOW in kinds:
        steps, waveforms, raised = raise_slow(
            settings, steps, waveforms, plan.assignment.frequencies, got["records"],
            models.impacters, models.sliders, check_on(models), check_on(truth))
        if raised:
            repairs[AMPLITUDE_RAISED] = len(raised)
    if OFF_TARGET in kinds and settings.chain is None:
        # (through a drive chain the re-plan holds the gated tones to the amplifier
        # input's limit after gating them: not done here, so not gated here either)
        timed, waves, gating = regate(settings, steps, waveforms, plan.assignment.frequencies,
                                      by_node(truth.impacters), truth.sliders,
                                      plan_phases(job.record))
        if gating:
            steps, waveforms = tuple(timed), dict(waves)
            repairs[GATES_ON_CHIP] = len(gating)
    if not repairs:
        return fields
    again = check_drive(settings, steps, waveforms, plan.dwells, truth.impacters,
                        truth.sliders)
    judged = _judged(fields["measured_passed"], plan.replan, again)
    return {**judged, "repairs": {**judged["repairs"], **{
        k: judged["repairs"].get(k, 0) + v for k, v in repairs.items()}}}


def _swept_speeds_hold(plan, swept: dict) -> bool:
    """Whether a tuned re-plan fails on the measured models only where the sweep says
    otherwise: every failed check is a slider too slow whose moving impacter's tone lies
    inside the working window the sweep measured on the chip itself (the slider moved
    at the floor or faster there), and no pair is inseparable or tone outside the band.

    The measured models are inferred from resonances read with the measurement's noise;
    the sweep reads the slider's speed on the chip.  Where they disagree on a speed the
    sweep is the measurement: at 0.1 % noise on 100 chips of the default, keeping the
    re-plan before the sweep whenever the tuned one failed on the measured models lost
    every chip the sweep could have rescued that way."""
    from planner.core.nodes import Node
    from planner.planning.verify import TOO_SLOW

    rp = plan.replan
    if not plan.failures or rp.inseparable or rp.outside_band:
        return False
    by_index = {st.index: st for st in plan.run_steps}
    for f in plan.failures:
        st = by_index.get(f.step)
        if f.kind != TOO_SLOW or st is None:
            return False
        movers = [Node(d, r) for d, r in st.active_nodes() if d == f.device]
        for n in movers:
            window = swept.get(n.text)
            tone = plan.assignment.frequencies.get(n)
            if window is None or tone is None or not window[0] <= tone <= window[1]:
                return False
    return True


def _trim(job: LoopJob, measured, models, original, truth: Truth | None,
          replanned: ReplanOutcome, missing=()):
    """The trim stage: a chip whose last re-plan works, or fails for a reason other than
    impacters no drive tells apart, is not trimmed (its outcome is the re-plan's); the
    others are trimmed as the module docstring says.

    Returns
    -------
    (TrimOutcome, TrimResult or None)
        The outcome, and on the test floor the trim (trim.csv's rows, its drive).
    """
    last = replanned.final
    if last.passed or not replanned.collisions:
        return TrimOutcome(passed=last.passed, trimmed=(), passes=0, causes=last.causes,
                           failures=last.failures), None
    if truth is not None:
        return _trim_simulated(job, measured, models, original, truth), None
    if missing:
        # a trim is chosen from every impacter's measured resonance
        return TrimOutcome(passed=False, trimmed=(), passes=0, failures={}, causes=(
            *last.causes, f"{CANNOT_TRIM}: not measured: " + " ".join(missing))), None
    from planner.afterfab.trim import trim_chip

    res = trim_chip(job.record, measured, settings=job.settings, models=models)
    tp = res.trims
    if not tp.ok:
        return TrimOutcome(passed=False, trimmed=(), passes=0, causes=(CANNOT_TRIM,),
                           failures={},
                           beyond_range=tuple(f["impacter"] for f in tp.failures)), res
    causes = () if res.passed else (
        replan_causes(res.plan.passed, res.plan.replan,
                      collisions=bool(res.plan.replan.inseparable))
        or (TRIMMED_FAILS,))
    return TrimOutcome(passed=res.passed, trimmed=tuple(tp.moved), passes=1, causes=causes,
                       failures={}), res


def _trim_simulated(job: LoopJob, measured, models, original, truth: Truth) -> TrimOutcome:
    """A simulated chip trimmed as a lab trims one (:func:`planner.afterfab.trim.
    trim_sequence`: trim, measure again, up to ``trim.passes`` times, each cut off its
    target by the trim precision, drawn anew every pass), then re-planned from the last
    measurement on the chip's as-built models with the trims the measurements saw
    applied, and judged on its trimmed truth (tuned there with ``job.tune``)."""
    from planner.afterfab.drive import must_differ
    from planner.afterfab.separations import separations_of
    from planner.afterfab.trim import trim_models, trim_sequence, trimmed_resonances

    settings = job.settings
    spec = settings.trim
    precision = (spec.precision_pct if job.trim_precision_pct is None
                 else job.trim_precision_pct)
    state = {"true": truth}

    def cut(tp, k):
        # where the cuts really put the resonances: the targets, off by the precision
        actual = trimmed_resonances(tp, precision,
                                    np.random.default_rng(truth.stream(TRIM_STREAM + 2 * k)))
        ratios = {n: actual[n] / tp.measured[n] for n in tp.moved}
        now = state["true"]
        state["true"] = dataclasses.replace(
            now, impacters=trim_models(now.impacters, ratios, spec.direction))

    def measure_again(k):
        return state["true"].measure(job.ids, job.measure_noise_pct,
                                     TRIM_STREAM + 2 * k + 1)

    out = trim_sequence(separations_of(job.record, settings), measured,
                        must_differ(settings.steps), spec, cut=cut,
                        measure_again=measure_again, precision_pct=precision)
    if out.scrapped:
        return TrimOutcome(passed=False, trimmed=tuple(out.moved), passes=len(out.passes),
                           causes=(CANNOT_TRIM,), failures={},
                           beyond_range=tuple(f["impacter"] for f in out.scrapped))
    # the re-plan's models: the chip as first measured, with the trims the measurements
    # saw applied
    got, _ = _replan(job, out.measured, trimmed_chip(models, out.ratios, spec.direction),
                     original, state["true"], TRIM_STREAM + 2 * spec.passes,
                     remeasure=out.moved)
    got = got.final
    return TrimOutcome(passed=got.passed, trimmed=tuple(out.moved), passes=len(out.passes),
                       causes=got.causes, failures=got.failures)
