"""The per-chip worker of a yield run: sample a chip, check the plan's drive on it and,
with ``--replan``, measure it, re-plan it and (with ``--trim``) trim it."""

from __future__ import annotations

import dataclasses

import numpy as np

from planner.core.rng import chip_seed
from planner.fabrication.tolerances import sample_chip
from planner.fabrication.wafer import line_width_offsets
from planner.afterfab.checks import check_drive
from planner.yield_.inputs import Payload
from planner.yield_.results import (ChipResult, Collision, ReplanOutcome, Seconds,
                                    TrimOutcome, TuneOutcome)

#: Why a re-plan failed, in the order reports list them (a chip may have several):
#: two impacters the spec must tell apart can no longer be (the re-plan's unresolved
#: conflict: the idle one responds at every candidate tone of the other -- close
#: resonances, or response bands that overlap although the resonances do not); a
#: scaled tone fell beyond ``drive.band_hz``; the re-plan does not verify even on the
#: measured models it was made for; it verifies there but not on the chip's true
#: models (measurement noise, or what the re-plan's model does not know: the as-built
#: mass, damping, gap and sliders); its steps pass on the true models but the
#: carried-state check fails (the re-plan does not simulate the scenes); the chip
#: cannot be built.
REPLAN_CAUSES = ("cannot be told apart", "outside band", "fails on the measured models",
                 "fails only on the true models", "carried state", "unbuildable",
                 "drive not playable")
#: A tuned chip's tone is moved to its working window's middle only when it sits further
#: than this fraction of the window's width from it (a lab retunes the tones near an
#: edge; a chip whose every tone is central needs no second re-plan) [-].
TUNE_CENTRE = 0.25


def verify_chip(payload: Payload, scale_index: int, chip_index: int,
                scale: float) -> ChipResult:
    """Sample chip ``chip_index`` at sigma scale ``scale`` and run every check on it.

    Returns
    -------
    ChipResult
        ``passed``, ``carried_passed`` (equal to ``passed``: the carried-state check is
        part of the pass), ``failures`` (kind -> failed checks), ``nodes`` (the
        impacter pairs implicated in a failure: sorted :class:`~planner.core.nodes.Node`),
        ``scale_index``, ``chip``; with
        ``payload.replan`` also ``replan`` (see :func:`replan_chip_on`) and
        ``seconds`` (wall time of the nominal checks and of the re-plan [s]); with
        ``payload.trim`` also ``trim`` (see :func:`trim_chip_on`).
    """
    from planner.planning.verify import shared_device_checks

    # one chip is checked several times over (the plan's drive, the re-plan on its
    # measured models and its true ones, the same after the tune and after a trim): a
    # device checked again with the same models, step and drive is answered from memory
    with shared_device_checks():
        return _verify_chip(payload, scale_index, chip_index, scale)


def _verify_chip(payload: Payload, scale_index: int, chip_index: int,
                 scale: float) -> ChipResult:
    """:func:`verify_chip`'s work."""
    import time

    if payload.threads:
        import numba

        # per thread: every task sets it in the worker thread that runs it
        numba.set_num_threads(min(payload.threads, numba.config.NUMBA_NUM_THREADS))
    t0 = time.perf_counter()
    rng = np.random.default_rng(chip_seed(payload.seed, scale, chip_index))
    chip = sample_chip(payload.design, payload.fabrication, rng, scale,
                       line_width_offsets(payload.design.spec, payload.fabrication,
                                          payload.seed, scale, chip_index))
    if chip.unbuildable:
        # a node or a device (its slider) that cannot be built
        nodes = {n for n in payload.nodes for x in chip.unbuildable
                 if n.text == x or n.device == x}
        replan = trim = seconds = None
        if payload.replan:
            fields = dict(passed=False, measured_passed=False, causes=("unbuildable",),
                          failures={"unbuildable": 1})
            # nothing to sweep on a chip that cannot be built: tuned, it fails as it is
            replan = ReplanOutcome(**fields, tuned=TuneOutcome(**fields) if payload.tune
                                   else None)
            if payload.trim:
                trim = TrimOutcome(passed=False, trimmed=(), passes=None,
                                   causes=("unbuildable",), failures={"unbuildable": 1})
            seconds = Seconds(nominal=time.perf_counter() - t0, replan=0.0)
        return ChipResult(scale_index=scale_index, chip=chip_index, passed=False,
                          carried_passed=False,
                          failures={"unbuildable": len(chip.unbuildable)},
                          nodes=tuple(sorted(nodes)), replan=replan, trim=trim,
                          seconds=seconds)
    settings = payload.settings
    # re-planning, the plan's own drive is only a reference: its checks stop at the
    # first failing step (a chip the die moved fails the first one it plays)
    got = check_drive(settings, payload.loaded.steps, payload.waveforms, payload.dwells,
                      chip.impacters, chip.sliders, first_failure=payload.replan)
    replan = trim = seconds = None
    if payload.replan:
        t1 = time.perf_counter()
        replan = replan_chip_on(payload, settings, scale, chip_index, chip, got)
        t2 = time.perf_counter()
        trim_s = None
        if payload.trim:
            trim = trim_chip_on(payload, settings, scale, chip_index, chip, got, replan)
            trim_s = time.perf_counter() - t2
        seconds = Seconds(nominal=t1 - t0, replan=t2 - t1, trim=trim_s)
    return ChipResult(scale_index=scale_index, chip=chip_index, passed=got["passed"],
                      carried_passed=got["passed"], failures=got["failures"],
                      nodes=tuple(sorted(got["nodes"])), replan=replan, trim=trim,
                      seconds=seconds)


def trim_chip_on(payload: Payload, settings, scale: float, chip_index: int, chip,
                 nominal: dict, replanned: ReplanOutcome) -> TrimOutcome:
    """Trim a chip the re-plan could not rescue because two of its impacters cannot be
    told apart: the trim sequence a lab runs (:func:`planner.afterfab.trim.trim_sequence`:
    measure, trim, measure again, up to ``trim.passes`` times, each cut off its target
    by the trim precision, drawn anew every pass), then the re-plan from the last
    measurement on the chip's as-built models with the trims applied, verified on its
    trimmed true models.

    A chip the re-plan rescued needs no trim (its result is the re-plan's); a chip the
    re-plan lost for another reason is not helped by one.

    Returns
    -------
    TrimOutcome
        ``passed``, ``trimmed`` (impacters trimmed), ``passes`` (trim passes made),
        ``causes`` (``cannot be trimmed``, with ``beyond_range`` naming the moves beyond
        the range, or the re-plan's causes after the trims), ``failures`` (kind ->
        failed checks on the trimmed true models).
    """
    from planner.afterfab.drive import must_differ
    from planner.afterfab.separations import separations_of
    from planner.afterfab.trim import trim_models, trim_sequence, trimmed_resonances
    from planner.arrayspec import TrimSpec

    last = replanned.final
    if last.passed or not replanned.collisions:
        return TrimOutcome(passed=last.passed, trimmed=(), passes=0, causes=last.causes,
                           failures=last.failures)
    spec = payload.record.spec.trim or TrimSpec()
    precision = (spec.precision_pct if payload.trim_precision_pct is None
                 else payload.trim_precision_pct)
    seq = chip_seed(payload.seed, scale, chip_index).spawn(3 + 2 * spec.passes)
    measured = _measure(payload, chip.impacters, seq[0])
    state = {"true": chip.impacters}

    def cut(tp, k):
        # where the cuts really put the resonances: the targets, off by the precision
        actual = trimmed_resonances(tp, precision, np.random.default_rng(seq[2 + 2 * k]))
        ratios = {n: actual[n] / tp.measured[n] for n in tp.moved}
        state["true"] = trim_models(state["true"], ratios, spec.direction)

    def measure_again(k):
        return _measure(payload, state["true"], seq[3 + 2 * k])

    out = trim_sequence(separations_of(payload.record, settings), measured,
                        must_differ(settings.steps), spec, cut=cut,
                        measure_again=measure_again, precision_pct=precision)
    if out.scrapped:
        return TrimOutcome(passed=False, trimmed=tuple(out.moved), passes=len(out.passes),
                           causes=("cannot be trimmed",), failures={},
                           beyond_range=tuple(f["impacter"] for f in out.scrapped))
    # the re-plan's models: the chip as first measured, with the trims the measurements
    # saw applied
    from planner.afterfab.replan import chip_models

    first = chip_models(payload.record, measured, payload.measure_noise_pct)
    models = dataclasses.replace(first, impacters=trim_models(first.impacters, out.ratios,
                                                              spec.direction))
    got = _replan_and_check(payload, settings, out.measured, state["true"], chip.sliders,
                            (nominal["steps_passed"], nominal["rows"]), remeasure=out.moved,
                            models=models, tune_seq=seq[2 + 2 * spec.passes])
    got = got.final
    return TrimOutcome(passed=got.passed, trimmed=tuple(out.moved), passes=len(out.passes),
                       causes=got.causes, failures=got.failures)


def measured_frequencies(payload: Payload, scale: float, chip_index: int, chip) -> dict:
    """Node id -> (true, measured) natural frequency [Hz] of a sampled chip; for a pair
    of unequal halves each is a tuple (half a, half b): what
    :func:`replan_chip_on` measures of it (:func:`planner.afterfab.measurement.
    measure_models`, the normals from the first child of the chip's SeedSequence)."""
    from planner.afterfab.measurement import true_resonances

    measured = _measure(payload, chip.impacters, chip_seed(payload.seed, scale,
                                                           chip_index).spawn(1)[0])
    true = true_resonances(chip.impacters)
    return {n: (true[n], measured[n].resonance) for n in measured}


def _measure(payload: Payload, impacters: dict, seq) -> dict:
    """The lab's measurement of the models ``impacters`` (node id -> model): id ->
    :class:`~planner.afterfab.measurement.Measurement` at the payload's noise."""
    from planner.afterfab.measurement import measure_models

    return measure_models(impacters, payload.design.node_ids, payload.measure_noise_pct, seq)


def replan_chip_on(payload: Payload, settings, scale: float, chip_index: int, chip,
                   nominal: dict) -> ReplanOutcome:
    """Measure a sampled chip, re-plan its drive, verify it on the chip's true models.

    Parameters
    ----------
    payload : Payload
        With ``record`` and ``measure_noise_pct``.
    settings : Settings
        The plan's settings (the checks).
    scale : float
        The chip's sigma scale.
    chip_index : int
        The chip's index (its measurement noise is seeded from both, :func:`chip_seed`).
    chip : planner.fabrication.tolerances.Chip
        The sampled chip (its impacters and sliders are the truth).
    nominal : dict
        :func:`check_drive` of the original drive on this chip: passed on as the
        re-plan's ``original`` so that it is not verified a second time.

    Returns
    -------
    ReplanOutcome
        ``passed`` (the re-planned drive passes every check on the true models),
        ``measured_passed`` (the re-plan verified on the models it was made from),
        ``causes`` (:data:`REPLAN_CAUSES` that apply when it fails), ``failures``
        (kind -> failed checks on the true models), ``collisions`` (pairs no drive tells
        apart: :class:`~planner.yield_.results.Collision`), ``outside_band`` (impacters
        whose tone fell beyond the band), ``split_steps`` (steps played as sub-steps),
        ``tones_moved``; with ``payload.tune`` also ``tuned``.
    """
    seq = chip_seed(payload.seed, scale, chip_index).spawn(2)
    measured = _measure(payload, chip.impacters, seq[0])
    return _replan_and_check(payload, settings, measured, chip.impacters, chip.sliders,
                             (nominal["steps_passed"], nominal["rows"]), tune_seq=seq[1])


def _replan_and_check(payload, settings, measured, impacters, sliders, original,
                      remeasure=(), models=None, tune_seq=None):
    """Re-plan from ``measured`` (or on ``models``) and verify the drive, in memory, on
    the true models (a yield's re-plan and its trim's; ``remeasure``: the trimmed
    impacters, whose separations the re-plan measures again).  With ``payload.tune``,
    the re-planned chip is also tuned (:func:`_tune_and_check`, its sweep's noise from
    the SeedSequence ``tune_seq``): the result's ``tuned``."""
    from planner.afterfab.replan import chip_models, replan_chip
    from planner.synthesis import LoopLengthError

    if models is None:
        models = chip_models(payload.record, measured, payload.measure_noise_pct)
    try:
        ok, plan = replan_chip(payload.record, measured, settings=settings,
                               original=original, record=False, remeasure=remeasure,
                               models=models)
    except LoopLengthError:
        # this chip's tones fit no loop the synthesis may play: the chip fails (with
        # that cause), the study goes on
        fields = dict(passed=False, measured_passed=False, causes=("drive not playable",),
                      failures={}, split_steps=(), tones_moved=0)
        # no drive to tune: tuned, the chip fails as it is
        return ReplanOutcome(**fields, tuned=TuneOutcome(**fields) if payload.tune else None)
    rp = plan.replan
    collisions = tuple(Collision.from_inseparable(c) for c in rp.inseparable)
    if collisions:      # no drive can pass: not simulated on the true models
        fields = dict(passed=False, measured_passed=False, causes=("cannot be told apart",),
                      failures={}, collisions=collisions,
                      outside_band=tuple(rp.outside_band),
                      split_steps=tuple(sorted(rp.split_steps)),
                      tones_moved=len(rp.moved))
        # no sweep tells a colliding pair apart
        tuned = TuneOutcome(**fields, windows=0) if payload.tune else None
        return ReplanOutcome(**fields, tuned=tuned)
    # the re-planned drive as it plays, checked on the chip's true models in memory
    got = check_drive(settings, plan.run_steps, plan.waveforms, plan.dwells, impacters,
                      sliders)
    out = _checked(ok, rp, got, collisions)
    if not payload.tune:
        return ReplanOutcome(**out)
    return ReplanOutcome(**out, tuned=_tune_and_check(
        payload, settings, measured, impacters, sliders, original, remeasure, models, plan,
        out, tune_seq))


def _tune_and_check(payload, settings, measured, impacters, sliders, original, remeasure,
                    models, plan, first, seq):
    """Tune a re-planned chip, as a lab with the piezo on would: a speed sweep around
    each re-planned tone on the chip itself (:func:`planner.afterfab.tune.sweep_speeds`,
    the true models, a speed reading's noise), the working windows fitted
    (:func:`planner.afterfab.tune.fit_windows`, at least the speed floor), the drive
    re-planned with each tone in its window's middle and checked on the true models.

    Only the tones further than :data:`TUNE_CENTRE` of their window's width from its
    middle move; with none to move the re-plan stands as it was, and so does it when the
    tuned re-plan fails the checks on the chip's measured models that the re-plan passed
    (a lab keeps the drive that verifies).

    Returns
    -------
    TuneOutcome
        As the re-plan's (``passed``, ``measured_passed``, ``causes``, ``failures``) plus
        ``windows`` (impacters whose tone moved to its window's middle).
    """
    from planner.afterfab.replan import replan_chip
    from planner.afterfab.tune import fit_windows, sweep_speeds, windows_of

    rng = np.random.default_rng(seq)
    rows = sweep_speeds(settings, plan.assignment.frequencies, impacters, sliders, rng,
                        count=payload.tune_tones, noise_pct=payload.tune_noise_pct)
    fitted = fit_windows(rows, min_speed=settings.min_speed_m_s)
    tones = {n.text: f for n, f in plan.assignment.frequencies.items()}
    # a tone already in the middle half of its window stays (a lab retunes the others)
    windows = {n: w for n, w in windows_of(fitted, keep_flagged=True).items()
               if abs(tones[n] - 0.5 * (w[0] + w[1])) > TUNE_CENTRE * (w[1] - w[0])}
    if not windows:
        return TuneOutcome(**first, windows=0)
    tuned = {n: (m.with_window(windows[n]) if n in windows else m)
             for n, m in measured.items()}
    ok, again = replan_chip(payload.record, tuned, settings=settings, original=original,
                            record=False, remeasure=remeasure, models=models)
    if not ok and first["measured_passed"]:
        # the re-plan at the windows' middles fails the checks on the chip's own models,
        # where the re-plan before the sweep passed them: a lab keeps the drive that
        # verifies (at 0.01 % noise, 200 chips of the default: 7 chips lost to the tune
        # without this, 185 rather than 178 tuned chips working)
        return TuneOutcome(**first, windows=0)
    rp = again.replan
    got = check_drive(settings, again.run_steps, again.waveforms, again.dwells, impacters,
                      sliders)
    return TuneOutcome(**_checked(ok, rp, got, ()), windows=len(windows))


def _checked(ok, rp, got, collisions) -> dict:
    """A re-plan's result as yield.json counts it: passed on the true models or not, and
    why (:data:`REPLAN_CAUSES`); the fields of a :class:`ReplanOutcome` or
    :class:`TuneOutcome` (the checks of a drive that was simulated)."""
    causes = []
    if not got["passed"]:
        if rp.outside_band:
            causes.append("outside band")
        if not ok:
            causes.append("fails on the measured models")
        elif got["steps_passed"]:
            causes.append("carried state")
        else:
            causes.append("fails only on the true models")
    return {"passed": got["passed"], "measured_passed": bool(ok), "causes": tuple(causes),
            "failures": got["failures"], "collisions": tuple(collisions),
            "outside_band": tuple(rp.outside_band),
            "split_steps": tuple(sorted(rp.split_steps)),
            "tones_moved": sum(1 for m in rp.moved
                               if m.frequency_hz != m.original_frequency_hz)}
