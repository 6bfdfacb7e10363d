"""The after-fabrication loop (issue 44, item 3): one loop -- measure, as-built, the
plan's drive, re-plan, tune, trim -- run by ``vibroplan yield`` on a simulated chip (its
truth passed in) and by the wafer batch on a measured die (no truth); one typed result,
one list of outcomes and causes, one trim path."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

#: The close plan's device scatter doubled (test_yield_replan's SCATTER): of the first
#: four chips of seed 3, some have neighbours no drive tells apart and some a re-plan
#: rescues.
SCATTER = """\
name: scatter
fabrication:
  line_width_um: {die: 0.05, device: 0.04}
trim: {range_pct: 1.0, direction: up, precision_pct: 0.1}
"""
SEED = 3


@pytest.fixture(scope="module")
def study(close_plan_dir, tmp_path_factory):
    """(plan record, yield payload with --replan, the batch's job) of the close plan."""
    from planner.afterfab.batch import make_job
    from planner.arrayspec import load_spec
    from planner.planfile.reader import read_plan
    from planner.yield_ import make_payload

    spec = tmp_path_factory.mktemp("scatter") / "scatter.yaml"
    spec.write_text(SCATTER)
    rec = read_plan(close_plan_dir)
    payload = make_payload(rec, SEED, load_spec(spec).spec.fabrication, replan=True,
                           measure_noise_pct=0.05)
    return rec, payload, make_job(rec)


def _chip(payload, i):
    from planner.core.rng import chip_seed
    from planner.fabrication.tolerances import sample_chip
    from planner.fabrication.wafer import line_width_offsets

    rng = np.random.default_rng(chip_seed(payload.seed, 1.0, i))
    return sample_chip(payload.design, payload.fabrication, rng, 1.0,
                       line_width_offsets(payload.design.spec, payload.fabrication,
                                          payload.seed, 1.0, i))


def test_the_yield_and_the_batch_call_one_loop(study, monkeypatch):
    """The yield's per-chip worker and the batch's per-die worker are one function:
    both hand the chip to :func:`planner.afterfab.loop.run_loop` (the study with its
    truth, the batch with the measurement), and the same die through both -- the
    study's measurement of its chip written for the batch, as ``yield`` writes
    wafer_<k>.csv -- gets the same re-plan (made from the same measurement by the same
    code: whether it verifies on the measured models, the pairs no drive tells apart,
    the tones outside the band, the steps split, the tones moved) and here, where the
    truth judges the drive as the measured models do, the same outcome and causes."""
    import planner.afterfab.batch as batch
    import planner.afterfab.loop as loop
    import planner.yield_.chip as chip_mod
    from planner.afterfab.outcome import OUTCOMES, SCRAPPED
    from planner.yield_ import verify_chip
    from planner.yield_.dies import chip_outcome

    assert chip_mod.run_loop is loop.run_loop and batch.run_loop is loop.run_loop
    _, payload, job = study
    calls = []

    def spy(job, **kw):
        got = loop.run_loop(job, **kw)
        calls.append(("truth" if kw.get("truth") is not None else "measured", got))
        return got

    monkeypatch.setattr(chip_mod, "run_loop", spy)
    monkeypatch.setattr(batch, "run_loop", spy)
    seen = set()
    for i in range(4):
        calls.clear()
        result = verify_chip(payload, 0, i, 1.0)
        measured = chip_mod.truth_of(payload, 1.0, i, _chip(payload, i)).measure(
            payload.design.node_ids, payload.measure_noise_pct)
        die = batch.replan_die(job, 0, i, measured)
        assert [c[0] for c in calls] == ["truth", "measured"], "each worker runs the loop"
        (_, in_study), (_, on_floor) = calls
        s, f = in_study.replan, on_floor.replan
        assert (s.measured_passed, s.collisions, s.outside_band, s.split_steps,
                s.tones_moved) == (f.measured_passed, f.collisions, f.outside_band,
                                   f.split_steps, f.tones_moved)
        # the study's outcome is the loop's, and the batch's die record the same words
        outcome, causes = chip_outcome(result)
        assert (outcome, tuple(causes)) == (in_study.outcome, in_study.causes)
        assert (die["outcome"], die["causes"]) == (on_floor.outcome, list(on_floor.causes))
        assert die["outcome"] == (SCRAPPED if outcome == OUTCOMES[-1] else outcome)
        assert die["causes"] == causes
        seen.add(outcome)
    assert seen == {"after re-plan", "fails"}, "both kinds of die must be among these"


def test_a_trim_runs_one_pass_of_the_trim_sequence_on_the_loops_models(study,
                                                                      monkeypatch):
    """One trim path: on the test floor the loop's trim is :func:`trim_chip` (as
    ``vibroplan trim``), which chooses its cuts as one pass of :func:`trim_sequence`
    (the sequence a study's chip is cut by) on the settings and as-built models the
    loop already built (the chip's models are built once per die), and gives what it
    gives when it builds them itself."""
    import planner.afterfab.loop as loop
    import planner.afterfab.trim as trim
    from planner.afterfab.loop import Truth, run_loop
    from planner.afterfab.outcome import TRIMMED_FAILS
    from planner.afterfab.replan import chip_models

    rec, payload, job = study
    # chip 0 has neighbours no drive tells apart (the test above)
    measured = Truth(_chip(payload, 0).impacters, {}, _seed(payload, 0)).measure(
        payload.design.node_ids, payload.measure_noise_pct)
    passes, built = [], []
    real_sequence, real_models = trim.trim_sequence, loop.chip_models

    def sequence(*a, **kw):
        out = real_sequence(*a, **kw)
        passes.append((kw.get("passes"), out))
        return out

    def models(*a, **kw):
        built.append(a)
        return real_models(*a, **kw)

    monkeypatch.setattr(trim, "trim_sequence", sequence)
    monkeypatch.setattr(loop, "chip_models", models)
    got = run_loop(dataclasses.replace(job, trim=True), measured=measured)
    assert got.replan.collisions and got.trim is not None and got.trimmed is not None
    assert len(passes) == 1 and passes[0][0] == 1, "trim_chip is one pass of the sequence"
    assert passes[0][1].last is got.trimmed.trims
    assert len(built) == 1, "the as-built models are built once, by the loop"
    alone = trim.trim_chip(rec, measured, models=chip_models(rec, measured))
    assert alone.rows == got.trimmed.rows and alone.passed == got.trimmed.passed
    assert alone.plan.data == got.trimmed.plan.data
    assert got.trim.passed == got.trimmed.passed
    assert got.trim.trimmed == tuple(got.trimmed.trims.moved)
    # this die's drive verifies on the targets, but its odds over the cuts' errors fall
    # short of the target yield (92 of 100 draws against 0.95)
    assert got.trimmed.plan.passed and not got.trimmed.odds.meets_target
    assert (got.trim.passes, got.outcome, got.causes) == (1, "scrapped", (TRIMMED_FAILS,))


def _seed(payload, i):
    from planner.core.rng import chip_seed

    return chip_seed(payload.seed, 1.0, i)


def test_a_truths_streams_are_its_seeds_children():
    """A simulated chip's measurement, sweep and cuts draw from the children of its
    seed exactly as ``seed.spawn(n)`` gives them (the numbers a yield study has always
    drawn), and reading one does not spawn from the chip's sequence."""
    from planner.afterfab.loop import Truth
    from planner.core.rng import chip_seed

    seed = chip_seed(7, 1.0, 3)
    truth = Truth({}, {}, seed)
    children = chip_seed(7, 1.0, 3).spawn(6)
    for k in (5, 0, 3):
        assert np.array_equal(np.random.default_rng(truth.stream(k)).standard_normal(4),
                              np.random.default_rng(children[k]).standard_normal(4))
    assert seed.n_children_spawned == 0


def test_the_loop_takes_a_measurement_or_a_truth(study):
    from planner.afterfab.loop import Truth, run_loop

    _, payload, job = study
    truth = Truth({}, {}, _seed(payload, 0))
    with pytest.raises(ValueError, match="one of the two"):
        run_loop(job)
    with pytest.raises(ValueError, match="one of the two"):
        run_loop(job, measured={}, truth=truth)
    with pytest.raises(ValueError, match="tune needs the chip's truth"):
        run_loop(dataclasses.replace(job, tune=True), measured={})


def test_one_list_of_outcomes_and_causes():
    """Every outcome and cause comes from one rule (:func:`outcome_of`): the first stage
    that works, else the last stage's causes; the test floor says ``scrapped`` for the
    study's ``fails``, and a die not measured whole is ``partly measured`` when it would
    work, its unmeasured impacters named either way."""
    import planner.afterfab.batch as batch
    import planner.yield_.dies as dies
    from planner.afterfab.outcome import (CAUSES, NOT_MEASURED, OUTCOMES, PARTLY_MEASURED,
                                          REPLAN_CAUSES, DriveCheck, LoopResult,
                                          ReplanOutcome, TrimOutcome, outcome_of)
    from planner.yield_ import REPLAN_CAUSES as YIELD_CAUSES

    assert dies.OUTCOMES is OUTCOMES
    assert batch.OUTCOMES == OUTCOMES[:-1] + ("scrapped",)
    assert YIELD_CAUSES is REPLAN_CAUSES and CAUSES[:len(REPLAN_CAUSES)] == REPLAN_CAUSES
    failed = DriveCheck(False, {"too slow": 2, "idle responds": 1})
    replan = ReplanOutcome(passed=False, measured_passed=False,
                           causes=("cannot be told apart",), failures={})
    cut = TrimOutcome(passed=False, trimmed=(), passes=0, causes=("cannot be trimmed",),
                      failures={})
    assert outcome_of(True, {}, None, None) == ("as designed", ())
    assert outcome_of(False, failed.failures, None, None) == (
        "fails", ("idle responds", "too slow"))
    assert outcome_of(False, {}, replan, None) == ("fails", ("cannot be told apart",))
    assert outcome_of(False, {}, replan, cut) == ("fails", ("cannot be trimmed",))
    assert outcome_of(False, {}, replan, TrimOutcome(True, ("A1.forward",), 1, (), {})) \
        == ("after trim", ())
    assert LoopResult(failed, replan, cut).outcome == "fails"
    floor = LoopResult(failed, replan, cut, on_floor=True)
    assert (floor.outcome, floor.causes) == ("scrapped", ("cannot be trimmed",))
    partly = LoopResult(DriveCheck(True, {}), on_floor=True, not_measured=("A2.backward",))
    assert partly.outcome == PARTLY_MEASURED
    assert partly.causes == (NOT_MEASURED + "A2.backward",
                             "works as designed if A2.backward is at its design")
    gone = LoopResult(failed, replan, cut, on_floor=True, not_measured=("A1.a", "A1.b"))
    assert (gone.outcome, gone.causes) == (
        "scrapped", ("cannot be trimmed", NOT_MEASURED + "A1.a A1.b"))
