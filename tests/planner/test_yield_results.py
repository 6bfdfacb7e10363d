"""A yield chip's result as declared types (:mod:`planner.yield_.results`): each
``to_dict()`` is the plain dict a chip's result was before them (the keys and values
yield.json is made of), and every type pickles (a Dask worker sends its chips back)."""

from __future__ import annotations

import dataclasses
import json
import pickle

import pytest

from planner.core.nodes import Node
from planner.planfile.schema import Inseparable
from planner.yield_ import (ChipResult, Collision, ReplanOutcome, Seconds, TrimOutcome,
                            TuneOutcome)

#: A pair too close on a chip, as a re-plan's ``inseparable`` lists it.
CLOSE_PAIR = {"pair": ["A1.forward", "A2.backward"], "as_built_hz": [21000.0, 21100.0],
              "apart_hz": 100.0, "needs_hz": 400.0,
              "message": "A1.forward and A2.backward cannot be told apart"}

#: A broken chip's gap: the tiny plan's 3 um gaps scattered by 1.2 um per device close
#: on some chips (they cannot be built).
BROKEN = """\
name: broken
fabrication:
  natural_frequency_pct: {die: 2, device: 2}
  gap_um: {die: 0.0, device: 1.2}
"""


def _full() -> ChipResult:
    """A chip the plan's drive fails, re-planned (its neighbours collide), tuned and
    trimmed."""
    collision = Collision.from_inseparable(Inseparable.model_validate(CLOSE_PAIR))
    common = dict(passed=False, measured_passed=False, causes=("cannot be told apart",),
                  failures={}, collisions=(collision,), outside_band=("A2.backward",),
                  split_steps=("s/push",), tones_moved=2)
    return ChipResult(
        scale_index=0, chip=7, passed=False, carried_passed=False,
        failures={"too slow": 2, "idle responds": 1},
        nodes=(Node("A1", "forward"), Node("A2", "backward")),
        replan=ReplanOutcome(**common, tuned=TuneOutcome(**common, windows=0)),
        trim=TrimOutcome(passed=True, trimmed=("A2.backward",), passes=2, causes=(),
                         failures={}),
        seconds=Seconds(nominal=0.5, replan=1.25, trim=2.0))


def test_a_chip_result_gives_the_dict_it_was_before():
    replan = {"passed": False, "measured_passed": False, "causes": ["cannot be told apart"],
              "failures": {},
              "collisions": [{k: CLOSE_PAIR[k]
                              for k in ("pair", "as_built_hz", "apart_hz", "needs_hz")}],
              "outside_band": ["A2.backward"], "split_steps": ["s/push"], "tones_moved": 2}
    assert _full().to_dict() == {
        "scale_index": 0, "chip": 7, "passed": False, "carried_passed": False,
        "failures": {"too slow": 2, "idle responds": 1},
        "nodes": [Node("A1", "forward"), Node("A2", "backward")],
        "replan": {**replan, "tuned": {**replan, "windows": 0}},
        "trim": {"passed": True, "trimmed": ["A2.backward"], "passes": 2, "causes": [],
                 "failures": {}},
        "seconds": {"nominal": 0.5, "replan": 1.25, "trim": 2.0}}


def test_an_unbuildable_chip_leaves_out_the_keys_it_never_had():
    """No re-plan was made of a chip that cannot be built: its re-plan has no
    ``split_steps``, ``tones_moved`` or ``tuned``, its trim no ``passes``, its wall
    times no ``trim``; a chip the trim scrapped names the moves beyond the range."""
    chip = ChipResult(
        scale_index=1, chip=3, passed=False, carried_passed=False,
        failures={"unbuildable": 1}, nodes=(Node("A1", "forward"),),
        replan=ReplanOutcome(passed=False, measured_passed=False, causes=("unbuildable",),
                             failures={"unbuildable": 1}),
        trim=TrimOutcome(passed=False, trimmed=(), passes=None, causes=("unbuildable",),
                         failures={"unbuildable": 1}),
        seconds=Seconds(nominal=0.1, replan=0.0))
    assert chip.to_dict() == {
        "scale_index": 1, "chip": 3, "passed": False, "carried_passed": False,
        "failures": {"unbuildable": 1}, "nodes": [Node("A1", "forward")],
        "replan": {"passed": False, "measured_passed": False, "causes": ["unbuildable"],
                   "failures": {"unbuildable": 1}, "collisions": [], "outside_band": []},
        "trim": {"passed": False, "trimmed": [], "causes": ["unbuildable"],
                 "failures": {"unbuildable": 1}},
        "seconds": {"nominal": 0.1, "replan": 0.0}}
    assert chip.replan.final is chip.replan
    scrapped = TrimOutcome(passed=False, trimmed=("A1.forward",), passes=1,
                           causes=("cannot be trimmed",), failures={},
                           beyond_range=("A2.backward",))
    assert scrapped.to_dict() == {"passed": False, "trimmed": ["A1.forward"], "passes": 1,
                                  "causes": ["cannot be trimmed"], "failures": {},
                                  "beyond_range": ["A2.backward"]}
    # without --replan a chip is its checks alone
    bare = dataclasses.replace(chip, replan=None, trim=None, seconds=None)
    assert set(bare.to_dict()) == {"scale_index", "chip", "passed", "carried_passed",
                                   "failures", "nodes"}


def test_the_results_pickle_and_are_frozen():
    full = _full()
    for obj in (full, full.replan, full.replan.tuned, full.trim, full.seconds,
                full.replan.collisions[0]):
        back = pickle.loads(pickle.dumps(obj))
        assert back == obj and type(back) is type(obj)
        assert back.to_dict() == obj.to_dict()
    assert full.replan.final is full.replan.tuned
    with pytest.raises(dataclasses.FrozenInstanceError):
        full.passed = True


def test_verified_chips_round_trip(tiny_plan_dir, tmp_path):
    """The chips of a real run, re-planned, tuned and trimmed, one of them unbuildable:
    each pickles to an equal result with the same dict, and its dict holds the keys
    the chip's work made."""
    from planner.arrayspec import load_spec
    from planner.planfile.reader import read_plan
    from planner.yield_ import make_payload, verify_chip

    spec = tmp_path / "broken.yaml"
    spec.write_text(BROKEN)
    payload = make_payload(read_plan(tiny_plan_dir), 3, load_spec(spec).spec.fabrication,
                           replan=True, measure_noise_pct=0.05, trim=True, tune=True)
    chips = [verify_chip(payload, 0, i, 1.0) for i in range(6)]
    assert any("unbuildable" in c.failures for c in chips), "a broken chip is needed"
    assert any("unbuildable" not in c.failures for c in chips)
    for c in chips:
        assert isinstance(c, ChipResult)
        back = pickle.loads(pickle.dumps(c))
        assert back == c and back.to_dict() == c.to_dict()
        d = c.to_dict()
        assert set(d) == {"scale_index", "chip", "passed", "carried_passed", "failures",
                          "nodes", "replan", "trim", "seconds"}
        assert d["chip"] == c.chip and d["nodes"] == list(c.nodes)
        assert d["replan"]["passed"] == c.replan.passed
        assert d["trim"]["causes"] == list(c.trim.causes)
        if "unbuildable" in c.failures:
            assert "tones_moved" not in d["replan"] and "passes" not in d["trim"]
            assert set(d["seconds"]) == {"nominal", "replan"}
            # nothing to tune: tuned, it fails as it is (yield --tune counts it)
            assert d["replan"]["tuned"] == {
                "passed": False, "measured_passed": False, "causes": ["unbuildable"],
                "failures": {"unbuildable": 1}, "collisions": [], "outside_band": [],
                "windows": 0}
        else:
            assert d["replan"]["tuned"]["windows"] == c.replan.tuned.windows
            assert {"split_steps", "tones_moved", "tuned"} <= set(d["replan"])
            assert set(d["seconds"]) == {"nominal", "replan", "trim"}


def test_tune_counts_the_chips_it_has_nothing_to_tune(tiny_plan_dir, tmp_path):
    """yield --replan --tune with a chip that cannot be built: the run completes (it
    stopped on a KeyError when a chip had no tuned re-plan) and the tune block counts
    that chip as failing, for the reason it cannot be re-planned."""
    from click.testing import CliRunner

    from planner.cli import main

    spec = tmp_path / "broken.yaml"
    spec.write_text(BROKEN)
    out = tmp_path / "y"
    res = CliRunner().invoke(main, ["yield", str(tiny_plan_dir), "--chips", "6", "--seed",
                                    "3", "--spec", str(spec), "--replan", "--tune", "--trim",
                                    "--out", str(out), "--quiet"])
    assert res.exit_code == 0, res.output
    d = json.loads((out / "yield.json").read_text())
    assert d["failures"].get("unbuildable", 0) >= 1
    broken = [c for c in d["replan"]["per_chip"] if "unbuildable" in c["causes"]]
    assert broken and all(c["tuned_passed"] is False and c["tuned_causes"] == ["unbuildable"]
                          and c["tuned_windows"] == 0 for c in broken)
    assert d["tune"]["causes"]["unbuildable"] == len(broken)
    assert {c["chip"] for c in broken} <= set(d["tune"]["failed_chips"])
