"""`vibroplan replan`: as-built re-plan of a fabricated chip from measured resonances.

A tiny 1 x 2 plan is made once (real designer, real verification); the chips are its
impacters with their natural frequencies moved, re-planned and verified by simulation.
"""

import dataclasses
import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from planner.afterfab import Measurement
from planner.core.nodes import Node

A1F, A2B = Node("A1", "forward"), Node("A2", "backward")


@pytest.fixture(scope="module")
def plan_data(tiny_plan_dir):
    """The tiny plan's plan.json as a dict (tests edit copies of it)."""
    return json.loads((tiny_plan_dir / "plan.json").read_text())


@pytest.fixture(scope="module")
def plan(tiny_plan_dir):
    """The tiny plan read back (the record the re-plan takes)."""
    from planner.planfile.reader import read_plan

    return read_plan(tiny_plan_dir)


def _write(path, text):
    path.write_text(text)
    return path


def _measured_csv(path, freqs, extra=""):
    rows = ["impacter,natural_frequency_hz" + extra]
    rows += [f"{n},{f!r}" + ("," * extra.count(",")) for n, f in freqs.items()]
    return _write(path, "\n".join(rows) + "\n")


def _models(built):
    """Node -> model of an :class:`~planner.afterfab.AsBuilt`."""
    return {Node.parse(n): m for n, m in built.impacters.items()}


def _run(*args):
    from planner.cli import main

    return CliRunner().invoke(main, ["replan", *map(str, args)], catch_exceptions=False)


def test_chip_models_follow_the_measurement(plan_data, plan):
    """Without fabrication tolerances (the tiny spec) nothing splits a shift into mass,
    damping and gap: the stiffness takes it, a measured Q the damping, a measured gap
    the gap."""
    from planner.afterfab import Measurement
    from planner.afterfab.replan import chip_models

    rec = plan_data["impacters"][0]
    nu = 1.03 * rec["natural_frequency_hz"]
    built = chip_models(plan, {rec["id"]: Measurement.of(nu, quality_factor=12.0,
                                                         gap_m=2.5e-6)})
    p = built.parameters()[rec["id"]]
    m = rec["mass_kg"]
    assert p["mass_kg"] == pytest.approx(m, rel=1e-12)
    assert p["stiffness_n_per_m"] == pytest.approx(m * (2 * math.pi * nu) ** 2, rel=1e-12)
    assert p["damping_ns_per_m"] == pytest.approx(m * 2 * math.pi * nu / 12.0, rel=1e-12)
    assert p["gap_m"] == 2.5e-6
    other = plan_data["impacters"][1]
    q = built.parameters()[other["id"]]
    # not measured: the design's damping and gap, and its own resonance
    assert q["damping_ns_per_m"] == pytest.approx(other["damping_ns_per_m"], rel=1e-12)
    assert q["gap_m"] == pytest.approx(other["gap_m"], rel=1e-12)
    assert q["stiffness_n_per_m"] == pytest.approx(other["stiffness_n_per_m"], rel=1e-6)


def test_replan_of_the_design_verifies(plan_data, tmp_path):
    freqs = {r["id"]: r["natural_frequency_hz"] for r in plan_data["impacters"]}
    res, d, out = _replan_verified(plan_data, tmp_path, freqs)
    assert d["replan"]["original_drive"]["passed"] is True
    # the as-built record of the pinned contract, equal to the design here
    for r in plan_data["impacters"]:
        ab = d["as_built"][r["id"]]
        assert {"natural_frequency_hz", "stiffness_n_per_m", "damping_ns_per_m",
                "gap_m", "mass_kg"} <= set(ab)
        assert ab["natural_frequency_hz"] == pytest.approx(r["natural_frequency_hz"])
    # same output contract as vibroplan plan
    assert {"impacters", "devices", "steps", "verification", "spec", "seed",
            "assignment", "scenes"} <= set(d)
    for st in d["steps"]:
        for rel in st["files"].values():
            assert (out / rel).exists()
    assert "As-built re-plan" in (out / "report.md").read_text()


def plan_data_path(plan_data, tmp_path):
    path = tmp_path / "orig_plan.json"
    path.write_text(json.dumps(plan_data))
    return path


def _replan_verified(plan_data, tmp_path, freqs):
    """`vibroplan replan` of the plan for a chip measured at ``freqs``: exit 0 and a
    verifying plan.json; returns (result, plan.json data, out folder)."""
    csv = _measured_csv(tmp_path / "measured.csv", freqs)
    out = tmp_path / "out"
    res = _run(plan_data_path(plan_data, tmp_path), "--measured", csv, "--out", out)
    assert res.exit_code == 0, res.output
    d = json.loads((out / "plan.json").read_text())
    assert d["verification"]["passed"] is True
    return res, d, out


def test_shifted_chip_is_rescued(plan_data, plan, tmp_path):
    # every impacter a few percent off its design, in opposite directions
    shifts = [1.04, 0.96]
    freqs = {r["id"]: s * r["natural_frequency_hz"]
             for r, s in zip(plan_data["impacters"], shifts)}
    res, d, _ = _replan_verified(plan_data, tmp_path, freqs)
    assert d["replan"]["original_drive"]["passed"] is False
    assert "original drive on this chip: FAILS" in res.output
    # the tones moved with the resonances
    for m in d["replan"]["moved"]:
        assert (m["tone_shift"] > 0) == (m["natural_frequency_shift"] > 0)
    # and the re-planned drive, checked independently on the same models, passes
    from planner.afterfab import Measurement
    from planner.afterfab.replan import chip_models, verify_drive
    from planner.planfile.reader import plan_record

    chip = chip_models(plan, {n: Measurement.of(f) for n, f in freqs.items()})
    passed, rows = verify_drive(plan_record(d), chip)
    assert passed and len(rows) == 4
    # while the original drive does not
    passed, _ = verify_drive(plan, chip)
    assert not passed


def test_replan_chip_api(plan):
    from planner.afterfab.replan import replan_chip

    from planner.afterfab import Measurement

    chip = {r.id: Measurement.of(1.02 * r.natural_frequency_hz) for r in plan.impacters}
    passed, result = replan_chip(plan, chip, seed=1)
    assert passed is result.passed
    assert result.data["seed"] == 1
    assert set(result.data["as_built"]) == set(chip)


def test_colliding_resonances_fail_naming_both(plan_data, tmp_path):
    # A2.backward's resonance moves by the ratio that puts its re-planned tone on
    # A1.forward's (designs need not sit their resonance inside the band: a design's tone
    # is above its natural frequency); the spec's own steps drive each alone
    nu = {r["id"]: r["natural_frequency_hz"] for r in plan_data["impacters"]}
    tone = {r["id"]: r["frequency_hz"] for r in plan_data["impacters"]}
    csv = _measured_csv(tmp_path / "measured.csv",
                        {"A1.forward": nu["A1.forward"],
                         "A2.backward": nu["A2.backward"] * tone["A1.forward"]
                         / tone["A2.backward"]})
    out = tmp_path / "out"
    res = _run(plan_data_path(plan_data, tmp_path), "--measured", csv, "--out", out)
    assert res.exit_code == 1
    assert "cannot be told apart" in res.output
    assert "A1.forward" in res.output and "A2.backward" in res.output
    d = json.loads((out / "plan.json").read_text())
    assert d["verification"]["passed"] is False
    (c,) = d["replan"]["inseparable"]
    assert set(c["pair"]) == {"A1.forward", "A2.backward"}
    # named with their as-built resonances and the separation they would need
    assert c["apart_hz"] < c["needs_hz"]
    assert c["as_built_hz"][1] - c["as_built_hz"][0] == pytest.approx(c["apart_hz"])
    assert f"they need {c['needs_hz']:.0f} Hz" in res.output


def test_a_weakened_multi_tone_step_splits_into_runs_that_keep_the_scale(plan_data):
    """The synthesis and acceleration limit of the re-plan: a two-device step whose summed
    drive the limit lowers below the plan's scale splits into sub-steps of neighbouring
    tones, each synthesised and limited again and keeping at least the scale asked."""
    from planner.planning.drives import limit_acceleration, synthesize_steps
    from planner.planfile.reader import plan_record
    from planner.afterfab.drive import split_step, weakened
    from planner.planning.settings import resolve_settings
    from planner.arrayspec import Step

    record = plan_record(plan_data)
    settings = resolve_settings(record.loaded)
    tones = {r.node: r.frequency_hz for r in record.impacters}
    both = Step("s", "both", 0, 0.005, ("A1",), ("A2",))
    single = Step("s", "one", 1, 0.005, ("A1",), ())

    def synth(steps, freqs, limit):
        s = dataclasses.replace(settings, max_acceleration_m_s2=limit)
        return limit_acceleration(s, synthesize_steps(s, steps, freqs))

    _, free = synth([both], tones, None)
    peak = free["s/both"]["peak_acceleration_m_s2"]
    _, notes = synth([both, single], tones, 0.6 * peak)
    assert notes["s/both"]["acceleration_scale"] == pytest.approx(0.6, rel=1e-3)
    need = weakened([both, single], notes, {"s/both": 1.0, "s/one": 1.0})
    assert list(need) == ["s/both"]            # a single tone is never split
    subs, w, nt = split_step(both, tones, need["s/both"],
                             lambda st, f: synth(st, f, 0.6 * peak))
    assert [s.key for s in subs] == ["s/both.1", "s/both.2"]
    assert sorted(d for s in subs for d in s.forward + s.backward) == ["A1", "A2"]
    assert all(nt[s.key]["acceleration_scale"] >= need["s/both"] for s in subs)
    assert all(len(w[s.key].frequencies) == 1 for s in subs)


@pytest.mark.parametrize("text, row, column", [
    ("impacter,quality_factor\nA1.forward,10\n", 1, "natural_frequency_hz"),
    ("impacter,natural_frequency_hz\nA1.forward,2600\nB7.forward,3000\n", 3, "impacter"),
    ("impacter,natural_frequency_hz\nA1.forward,-2600\n", 2, "natural_frequency_hz"),
    ("impacter,natural_frequency_hz,gap_um\nA1.forward,2600,0\n", 2, "gap_um"),
    ("impacter,natural_frequency_hz\nA1.forward,nan\n", 2, "natural_frequency_hz"),
])
def test_malformed_csv_exit_2_nothing_written(plan_data, tmp_path, text, row, column):
    csv = _write(tmp_path / "measured.csv", text)
    out = tmp_path / "out"
    res = _run(plan_data_path(plan_data, tmp_path), "--measured", csv, "--out", out)
    assert res.exit_code == 2
    assert f"row {row}, column {column}" in res.output
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["measured.csv", "orig_plan.json"]


def test_pair_halves_are_read_from_the_half_column(plan_data, tmp_path):
    """measured.csv may give each half of a pair (``half`` a/b): both halves are kept,
    the pair's resonance is their mean; half a pair, or a pair measured both ways, is
    refused naming the row."""
    from planner.core.errors import SpecError
    from planner.afterfab.measurement import read_measured

    ids = [r["id"] for r in plan_data["impacters"]]
    csv = _write(tmp_path / "m.csv", "impacter,half,natural_frequency_hz\n"
                 "A1.forward,a,6100\nA1.forward,b,6140\nA2.backward,,9000\n")
    got = read_measured(csv, ids)
    assert got["A1.forward"].halves_hz == (6100.0, 6140.0)
    assert got["A1.forward"].natural_frequency_hz == 6120.0
    assert not got["A2.backward"].by_halves
    for text, row in (("A1.forward,a,6100\n", 2),
                      ("A1.forward,a,6100\nA1.forward,,6100\n", 3),
                      ("A1.forward,c,6100\n", 2)):
        with pytest.raises(SpecError) as err:
            read_measured(_write(tmp_path / "bad.csv",
                                 "impacter,half,natural_frequency_hz\n" + text), ids)
        assert f"row {row}" in str(err.value)


def test_calibrate_output_is_accepted(plan_data, tmp_path):
    # calibrate's *_std columns are ignored
    from planner.afterfab.measurement import read_measured

    csv = _write(tmp_path / "m.csv",
                 "impacter,natural_frequency_hz,quality_factor,natural_frequency_std_hz,"
                 "quality_factor_std\nA1.forward,2600.5,11.2,3.1,0.4\n")
    from planner.afterfab import Measurement

    got = read_measured(csv, [r["id"] for r in plan_data["impacters"]])
    assert got == {"A1.forward": Measurement((2600.5,), (11.2,), (None,))}


def test_replanned_drive_meets_the_acceleration_limit(plan_data):
    """drive.max_acceleration_g holds for the re-planned drive as for the plan's: with a
    limit at half the plan's largest peak, every re-planned step's true peak base
    acceleration is at most the limit (before the fix the re-plan played full power)."""
    import copy

    from planner.planfile.reader import plan_record
    from planner.afterfab.replan import replan_chip

    peak = max(st["peak_acceleration_m_s2"] for st in plan_data["steps"])
    limit_g = 0.5 * peak / 9.80665
    data = copy.deepcopy(plan_data)
    data["spec"]["drive"]["max_acceleration_g"] = limit_g
    chip = {r["id"]: Measurement.of(r["natural_frequency_hz"])
            for r in data["impacters"]}
    _, result = replan_chip(plan_record(data), chip)
    peaks = [st["peak_acceleration_m_s2"] for st in result.data["steps"]]
    assert peaks and max(peaks) <= limit_g * 9.80665 * (1 + 1e-6)
    assert max(peaks) > 0.9 * limit_g * 9.80665     # lowered to the limit, not below


def test_the_replan_keeps_a_margin_on_the_travel(plan_data):
    """On the measured models every re-planned travel stays within REPLAN_TRAVEL_MARGIN of
    verification.max_travel_um (a chip's true speeds near the edge of a tone window may be
    higher than its measured models say), while the record keeps the spec's own limit.
    With a limit set 7 % above what the re-plan's mover travels, the re-plan shortens the
    burst until the travel is within 85 % of it."""
    import copy

    from planner.planfile.reader import plan_record
    from planner.afterfab.replan import replan_chip
    from planner.afterfab.drive import REPLAN_TRAVEL_MARGIN

    def travels(data):
        return [r["travel_m"] for st in data["verification"]["steps"].values()
                for r in st.values() if r["expected"] != "idle"]

    chip = {r["id"]: Measurement.of(r["natural_frequency_hz"])
            for r in plan_data["impacters"]}
    # the re-plan's own travel with the default limit (its tones sit mid-window, not
    # where the plan put them), then a limit 7 % above it
    _, free = replan_chip(plan_record(plan_data), chip)
    limit = max(travels(free.data)) / 0.93
    data = copy.deepcopy(plan_data)
    data["spec"]["verification"]["max_travel_um"] = limit * 1e6
    data["spec"]["verification"]["repair_rounds"] = 1      # the tiny spec repairs nothing
    passed, result = replan_chip(plan_record(data), chip)
    assert passed
    got = travels(result.data)
    assert got and max(got) <= REPLAN_TRAVEL_MARGIN * limit * (1 + 1e-9)
    assert max(got) > 0.5 * REPLAN_TRAVEL_MARGIN * limit          # shortened, not stopped
    assert result.data["verification"]["max_travel_m"] == pytest.approx(limit)


def test_a_step_an_idle_impacter_answers_is_played_weaker(plan_data):
    """`quieten`: an idle impacter whose resonance sits where the step's tone reaches it
    at full drive but not at 85 % answers the step (the real check), and the step played
    weaker no longer does; its notes say by how much, and the mover still moves."""
    from planner.planning.drives import limit_acceleration, scaled, synthesize_steps
    from planner.planfile.reader import plan_record
    from planner.afterfab import Measurement
    from planner.afterfab.drive import RescuedDrive, quieten
    from planner.afterfab.replan import chip_models
    from planner.planning.settings import resolve_settings
    from planner.planning.verify import IDLE_RESPONSE, check_steps

    record = plan_record(plan_data)
    settings = resolve_settings(record.loaded)
    step = next(st for st in settings.steps if st.forward == ("A1",) and not st.backward)
    step = dataclasses.replace(step, index=0)
    tones = {r.node: r.frequency_hz for r in record.impacters}
    waveforms, notes = limit_acceleration(settings, synthesize_steps(settings, [step], tones))
    sliders = dict(settings.sliders)

    def check(steps, w, models):
        rows, fails = [], []
        for r, f in check_steps(settings, steps, w, models, sliders):
            rows += r
            fails += f
        return rows, fails

    def answers(nu, factor):
        models = _models(chip_models(record, {"A2.backward": Measurement.of(nu)}))
        w = {step.key: scaled(waveforms[step.key], factor, "test")}
        return any(f.kind == IDLE_RESPONSE for f in check([step], w, models)[1])

    def edge(factor):
        # A2.backward's highest resonance at which A1.forward's tone (below it) reaches it
        silent, answer = tones[A1F] / 0.6, tones[A1F] / 0.7
        assert answers(answer, factor) and not answers(silent, factor)
        for _ in range(16):
            mid = 0.5 * (silent + answer)
            silent, answer = (silent, mid) if answers(mid, factor) else (mid, answer)
        return answer

    full, weak = edge(1.0), edge(0.85)
    assert full > weak                       # a stronger drive reaches further
    nu = 0.5 * (full + weak)
    models = _models(chip_models(record, {"A2.backward": Measurement.of(nu)}))
    rows, fails = check([step], waveforms, models)
    assert [f.impacter for f in fails if f.kind == IDLE_RESPONSE] == [A2B]
    drive = RescuedDrive((step,), waveforms, notes, {step.key: 0.0}, tones, [], {}, {})
    got, rows, fails = quieten(settings, drive, rows, fails, models, sliders,
                               lambda s, w: check(s, w, models))
    assert not fails and all(r["passed"] for r in rows)
    factor = got.notes[step.key]["quietened_by"]
    assert 0.8 <= factor < 1.0
    assert got.waveforms[step.key].amplitudes[0] == pytest.approx(
        factor * waveforms[step.key].amplitudes[0])


def test_the_replan_plays_the_plans_phases(plan_data):
    """The designs were verified under the plan's drive, phases included: a chip's
    re-plan moves the tones and keeps each impacter's phase (the plan's phases set to
    values an optimiser would not give a single tone)."""
    import copy

    from planner.planfile.reader import plan_record
    from planner.afterfab.replan import replan_chip
    from planner.afterfab.drive import plan_phases

    data = copy.deepcopy(plan_data)
    for k, st in enumerate(data["steps"]):
        st["tones"][0]["phase_rad"] = 0.7 - 1.1 * k
    plan = plan_record(data)
    phases = plan_phases(plan)
    assert set(phases) == {st["scene"] + "/" + st["name"] for st in data["steps"]}
    measured = {r.id: Measurement.of(1.01 * r.natural_frequency_hz) for r in plan.impacters}
    _, result = replan_chip(plan, measured, record=False)
    for st in result.data["steps"]:
        old = next(s for s in data["steps"] if s["name"] == st["name"])
        assert st["tones"][0]["frequency_hz"] != pytest.approx(
            old["tones"][0]["frequency_hz"], rel=1e-3)            # the tone moved
        assert st["tones"][0]["phase_rad"] == pytest.approx(old["tones"][0]["phase_rad"])


def test_synthesis_takes_given_phases_per_impacter(plan):
    """`synthesize_steps(..., phases=)`: a step whose every impacter has a phase plays
    them (a shared tone its first impacter's); a step missing one optimises its own."""
    from planner.planning.drives import synthesize_steps
    from planner.planning.settings import resolve_settings
    from planner.arrayspec import Step

    settings = resolve_settings(plan.loaded)
    both = Step("s", "both", 0, 0.005, ("A1",), ("A2",))
    tones = {A1F: 5000.0, A2B: 7000.0}
    given = {"s/both": {A1F: 0.5, A2B: -1.25}}
    w = synthesize_steps(settings, [both], tones, phases=given)["s/both"]
    assert w.phases == pytest.approx([0.5, -1.25])
    free = synthesize_steps(settings, [both], tones)["s/both"]
    partial = synthesize_steps(settings, [both], tones,
                               phases={"s/both": {A1F: 0.5}})["s/both"]
    assert partial.phases == pytest.approx(free.phases)
    shared = synthesize_steps(settings, [both], {A1F: 5000.0, A2B: 5000.0},
                              phases=given)["s/both"]
    assert shared.phases == pytest.approx([0.5])


def test_tones_closer_than_the_loop_resolution_play_as_one(plan):
    """A re-plan of a row sharing one design gives each impacter its own measured tone,
    some a fraction of a hertz apart: no loop of <= 1 s keeps them distinct (the
    synthesis stopped the whole yield study with a LoopLengthError).  Tones of one step
    within MERGE_HZ play as one, at their mean, with the first impacter's phase; the
    rest keep theirs."""
    from planner.planning.drives import MERGE_HZ, merged_tones, synthesize_steps
    from planner.planning.settings import resolve_settings
    from planner.arrayspec import Step
    from planner.synthesis import synthesize

    # one step of row_assembly's re-plan under the 5 x 5 tolerances (its chip 4)
    freqs = [4782.00732551, 4813.82536784, 4820.6025336, 4841.23256583, 4842.03717645,
             4852.75925104, 4853.0403854, 4853.46945067, 4853.56419374, 4858.21514823,
             4861.82125873, 4863.43888197, 4877.99702244, 4887.11645048, 4888.17280014,
             8091.25036241, 8093.7602566, 8095.63160679, 8120.74712274, 8132.11983369,
             8136.84199902, 8141.6029637, 8145.30870233, 8147.92733125, 8183.91600388]
    settings = resolve_settings(plan.loaded)
    with pytest.raises(ValueError, match="no loop"):
        synthesize(freqs, [1e-8] * len(freqs), settings.sample_rate_hz, seed=0)
    played, tone_of = merged_tones(freqs)
    assert len(played) == len(freqs) - 4    # 4841.2 + 4842.0 and 4852.8-4853.6 (four) merged
    assert all(abs(tone_of[f] - f) < MERGE_HZ for f in freqs)
    assert all(b - a >= 0.5 * MERGE_HZ for a, b in zip(played, played[1:]))
    devices = tuple(f"R{k}" for k in range(len(freqs)))
    step = Step("s", "row", 0, 0.005, devices, ())
    tones = {Node(d, "forward"): f for d, f in zip(devices, freqs)}
    phases = {"s/row": {Node(d, "forward"): 0.01 * k for k, d in enumerate(devices)}}
    w = synthesize_steps(settings, [step], tones, phases=phases)["s/row"]
    assert len(w.frequencies) == len(played)
    assert w.requested_frequencies == pytest.approx(played)
    # every played tone within the synthesis' tolerance of what it stands for
    assert np.all(np.abs(np.asarray(w.frequencies) - played) <= 1e-3 * np.asarray(played))
    # the merged 4852.8-4853.6 Hz tone plays at the phase of its first impacter (R5)
    k = int(np.argmin(np.abs(np.asarray(played) - 4853.2)))
    assert w.phases[k] == pytest.approx(0.05)


def test_impacters_sharing_a_tone_keep_one_tone_within_their_windows():
    """A row of four that shared one tone in the plan (one channel, one design) is
    re-planned on one tone again, the mean of their measured tones, when it lies within
    each one's tone window: each on its own measured tone, the step played four tones
    7-20 Hz apart that beat to four times the plan's amplitude, and on a 2 x 4 of our own
    the nominal chip's re-plan failed (B1.forward at 41.5 kHz answered the four tones
    at 25.43 kHz).  Spread beyond the window, each keeps its own tone."""
    from types import SimpleNamespace

    from planner.afterfab.drive import shared_tones

    row = [Node(f"B{k}", "backward") for k in range(1, 5)]
    lone = Node("B1", "forward")
    plan = SimpleNamespace(impacters=[SimpleNamespace(node=n, frequency_hz=25465.8385093)
                                      for n in row]
                           + [SimpleNamespace(node=lone, frequency_hz=41573.0337079)])
    measured = {row[0]: 25437.30, row[1]: 25418.96, row[2]: 25433.17, row[3]: 25430.42,
                lone: 41542.63}
    window = 1.5e-3                      # the default's: 3 x 0.05 % of measurement noise
    got = shared_tones(plan, measured, window)
    mean = sum(measured[n] for n in row) / 4
    assert all(got[n] == mean for n in row) and got[lone] == measured[lone]
    assert all(abs(measured[n] - mean) <= window * measured[n] for n in row)
    # spread by fabrication beyond the window: each keeps its own
    spread = {**measured, row[0]: 25620.0}
    assert shared_tones(plan, spread, window) == spread
    # no window (no measurement noise): nothing is moved
    assert shared_tones(plan, measured, 0.0) == measured


# ------------------------------------------------------------------ issue 44: the drive band

def _cli(*args):
    """``vibroplan replan ARGS`` with exceptions caught (exit codes and output checked)."""
    from planner.cli import main

    return CliRunner().invoke(main, ["replan", *map(str, args)])


def _all_tones(out) -> list:
    d = json.loads((out / "plan.json").read_text())
    return [t["frequency_hz"] for st in d["steps"] for t in st["tones"]]


@pytest.mark.parametrize("ratio, beyond", [(1.0586, False), (1.0885, True)])
def test_a_resonance_above_the_band_is_never_played_outside_it(plan_data, tiny_plan_dir,
                                                                tmp_path, ratio, beyond):
    """Issue 44 case 3: A2.backward measured 13617 Hz (x1.0586 of its design) in the
    5-14 kHz tiny plan was reported "driven at the band edge" while its waveform played
    14292.5 Hz.  No tone of a re-plan lies outside the band: where the impacter's window
    reaches into the band its tone is there (and the re-plan may pass); where the whole
    window lies beyond (x1.0885), the drive plays the band edge, says so with the tone it
    plays, and the re-plan fails (exit 1), as plan.json and report.md say."""
    lo, hi = plan_data["spec"]["drive"]["band_hz"]
    nat = {i["id"]: i["natural_frequency_hz"] for i in plan_data["impacters"]}
    measured = _measured_csv(tmp_path / "m.csv", {"A1.forward": nat["A1.forward"],
                                                  "A2.backward": nat["A2.backward"] * ratio})
    out = tmp_path / "r"
    res = _cli(tiny_plan_dir, "--measured", measured, "--out", out, "--no-figures")
    assert "Traceback" not in res.output and "driven at the band edge" not in res.output
    tones = _all_tones(out)
    assert tones and all(lo <= f <= hi for f in tones), tones
    d = json.loads((out / "plan.json").read_text())
    rp = d["replan"]
    played = {m["id"]: m["frequency_hz"] for m in rp["moved"]}
    report = (out / "report.md").read_text()
    if beyond:
        assert res.exit_code == 1, res.output
        assert rp["outside_band"] == ["A2.backward"] and played["A2.backward"] == hi
        assert rp["outside_band_hz"]["A2.backward"] > hi
        line = f"the drive plays the band edge (A2.backward at {hi:.1f} Hz)"
        assert line in res.output and "the re-plan fails" in res.output
        assert line in report
        assert d["verification"]["passed"] is False
    else:
        assert rp["outside_band"] == [] and played["A2.backward"] <= hi
        assert res.exit_code == 0, res.output


def test_a_die_beyond_the_band_is_scrapped_in_a_wafer_batch(plan_data, tiny_plan_dir, tmp_path):
    """The wafer batch counted such a die "after re-plan"; it is scrapped, cause
    "outside band"."""
    nat = {i["id"]: i["natural_frequency_hz"] for i in plan_data["impacters"]}
    folder = tmp_path / "m"
    folder.mkdir()
    _measured_csv(folder / "die_0_0.csv", {"A1.forward": nat["A1.forward"],
                                           "A2.backward": nat["A2.backward"] * 1.0885})
    out = tmp_path / "r"
    res = _cli(tiny_plan_dir, "--measured-dir", folder, "--jobs", 1, "--out", out, "--quiet")
    assert res.exit_code == 1, res.output
    summary = (out / "summary.csv").read_text().splitlines()
    assert summary[1].startswith("0,0,scrapped,outside band"), summary
    assert all(5000.0 <= f <= 14000.0 for f in _all_tones(out / "dies" / "die_0_0" / "replan"))


@pytest.mark.parametrize("name, window", [("A2.backward", "14500,14600"),
                                          ("A1.forward", "100,10000")])
def test_a_window_outside_the_band_is_refused_naming_the_row(plan_data, tiny_plan_dir,
                                                             tmp_path, name, window):
    """Issue 44 case 3: windows.csv rows beyond the 5-14 kHz band were taken."""
    nat = {i["id"]: i["natural_frequency_hz"] for i in plan_data["impacters"]}
    measured = _measured_csv(tmp_path / "m.csv", {name: nat[name]})
    windows = _write(tmp_path / "w.csv",
                     f"impacter,window_lo_hz,window_hi_hz\n{name},{window}\n")
    out = tmp_path / "r"
    res = _cli(tiny_plan_dir, "--measured", measured, "--windows", windows, "--out", out)
    assert res.exit_code == 2, res.output
    assert str(windows) in res.output and "row 2" in res.output
    assert "outside the drive band 5000-14000 Hz" in res.output
    assert "Traceback" not in res.output and not out.exists()


@pytest.mark.parametrize("q", ["1e-6", "0.5", "1e9"])
def test_a_meaningless_quality_factor_is_refused_naming_row_and_column(plan_data,
                                                                       tiny_plan_dir,
                                                                       tmp_path, q):
    """Issue 44 case 6: Q 1e-6 was accepted, and the re-plan crawled for minutes (the
    default's showed no progress for 3.5 min).  No resonance peak has Q <= 1/sqrt(2);
    none reaches 1e7: exit 2 naming the file, row and column, at once.  The wafer's
    readers share the check (a die file of a --measured-dir)."""
    nat = {i["id"]: i["natural_frequency_hz"] for i in plan_data["impacters"]}
    text = ("impacter,natural_frequency_hz,quality_factor\n"
            f"A1.forward,{nat['A1.forward']},20\nA2.backward,{nat['A2.backward']},{q}\n")
    measured = _write(tmp_path / "m.csv", text)
    out = tmp_path / "r"
    res = _cli(tiny_plan_dir, "--measured", measured, "--out", out)
    assert res.exit_code == 2, res.output
    assert f"{measured}: row 3, column quality_factor" in res.output, res.output
    assert "Traceback" not in res.output and not out.exists()
    folder = tmp_path / "dies"
    folder.mkdir()
    die = _write(folder / "die_0_0.csv", text)
    res = _cli(tiny_plan_dir, "--measured-dir", folder, "--jobs", 1, "--out", out)
    assert res.exit_code == 2 and f"{die}: row 3, column quality_factor" in res.output, \
        res.output
