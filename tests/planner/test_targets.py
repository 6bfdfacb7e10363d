"""Scenes that put every slider where it is asked (issue 29): ``targets_um`` steps, the
gated bursts they play, and their verification by the carried-state scene simulation."""

import dataclasses
import json
import subprocess
import sys

import numpy as np
import pytest

from planner.core.errors import PlanningError, SpecError
from planner.arrayspec import load_spec
from planner.core.units import UM
from tests.planner.test_pipeline import TINY

#: Two devices, two different targets, then back: the tiny spec of test_pipeline with a
#: scene that asks for positions (1 um = 1e-6 m, tolerance 2 um by default).
TWO = (TINY.split("scenes:")[0].replace("name: tiny", "name: two")
       + "scenes:\n  s:\n    - {name: write, targets_um: {A1: 12, A2: 5}}\n"
       "    - {name: back, targets_um: {all: 0}}\n")


@pytest.fixture(scope="module")
def two_plan(tmp_path_factory):
    from planner.planning import plan

    out = tmp_path_factory.mktemp("two") / "plan"
    return plan(TWO, out_dir=out, figures=True, jobs=1)


# --------------------------------------------------------------------------- the plan


def test_two_devices_reach_different_targets_within_tolerance(two_plan):
    """The issue's first 'done means': A1 to +12 um and A2 to +5 um from where the scene
    started, then both back to 0, each within 2 um in the carried-state simulation, and
    the plan verifies."""
    assert two_plan.passed, two_plan.verification[~two_plan.verification.passed].cause.tolist()
    rows = {r["step"]: r for r in two_plan.data["scenes"]}
    write = rows["write"]
    assert write["targets_m"] == {"A1": pytest.approx(12 * UM), "A2": pytest.approx(5 * UM)}
    for dev, want in (("A1", 12 * UM), ("A2", 5 * UM)):
        assert abs(write["positions_m"][dev] - want) <= 2 * UM
        assert write["position_errors_m"][dev] == pytest.approx(write["positions_m"][dev] - want)
    # the two moves differ by more than twice the tolerance: one burst length for both
    # could not have done it
    assert abs(write["positions_m"]["A1"] - write["positions_m"]["A2"]) > 4 * UM
    tail = rows["(drive off)"]
    assert tail["expected_positions_m"] == {"A1": 0.0, "A2": 0.0}
    assert max(abs(z) for z in tail["final_positions_m"].values()) <= 2 * UM


def test_plan_json_records_targets_and_final_positions(two_plan):
    data = json.loads((two_plan.out_dir / "plan.json").read_text())
    steps = {s["name"]: s for s in data["steps"]}
    assert steps["write"]["targets_m"] == {"A1": 1.2e-05, "A2": 5e-06}
    assert steps["write"]["relative_to"] == "scene_start"
    assert steps["back"]["targets_m"] == {"A1": 0.0, "A2": 0.0}
    assert steps["write"]["playback"] == "once" and steps["A1.forward"]["playback"] == "loop"
    gating = steps["write"]["gating"]
    # each tone has its own gate; a gated step lasts until its last tone has faded out
    assert set(gating["gates_s"]) == {"A1.forward", "A2.forward"}
    assert steps["write"]["duration_s"] == pytest.approx(
        max(gating["gates_s"].values()) + gating["ramp_s"])
    tails = [s for s in data["scenes"] if not s["driven"]]
    assert len(tails) == 1 and set(tails[0]["final_positions_m"]) == {"A1", "A2"}
    assert data["verification"]["position_tolerance_m"] == 2e-06
    # the per-step check: from every x0 of the mover's impacter, within tolerance too
    checks = data["verification"]["steps"]["s/write"]
    for dev in ("A1", "A2"):
        assert abs(checks[dev]["worst_position_error_m"]) <= 2e-06
        assert checks[dev]["move_m"] == pytest.approx(steps["write"]["moves_m"][dev])


def test_exported_burst_is_the_drive_the_verification_simulated(two_plan):
    """The lab plays what was verified: the exported file (read back through its
    sidecar) is the gated burst's samples, which its program of constant-tone stretches
    reproduces, and verify_export accepts it."""
    from planner.lab.exporters import read_sidecar, read_waveform, verify_export

    burst = two_plan.waveforms["s/write"]
    rec = next(s for s in two_plan.data["steps"] if s["name"] == "write")
    path = two_plan.out_dir / rec["files"]["csv"]
    samples, rate = read_waveform(path)
    t = np.arange(len(samples)) / rate
    np.testing.assert_allclose(samples, burst.evaluate(t), rtol=0, atol=1e-17)
    assert samples[0] == 0.0 and abs(samples[-1]) < 1e-15
    start, t_prog = 0.0, []
    for duration, drive in burst.program():
        inside = (t >= start) & (t < start + duration)
        t_prog.append(np.abs(drive.displacement(t[inside] - start) - samples[inside]).max())
        start += duration
    assert max(t_prog) < 1e-16 and start == pytest.approx(burst.length_s)
    side = read_sidecar(path)
    assert side["playback"] == "once" and len(side["gates_s"]) == len(side["tones"])
    for fmt in ("wav", "wav16", "csv", "arb"):
        assert verify_export(two_plan.out_dir / rec["files"][fmt]).ok, fmt


def test_tampered_burst_fails_verify_export(two_plan, tmp_path):
    from planner.lab.exporters import export, verify_export

    burst = two_plan.waveforms["s/write"]
    path = tmp_path / "b.csv"
    export(burst, path, "csv")
    assert verify_export(path).ok
    lines = path.read_text().splitlines()
    k = len(lines) // 2
    t, x = lines[k].split(",")
    lines[k] = f"{t},{float(x) + 1e-8:.12e}"
    path.write_text("\n".join(lines) + "\n")
    assert not verify_export(path).ok


def test_report_shows_asked_against_got_and_the_pattern_figure(two_plan):
    report = (two_plan.out_dir / "report.md").read_text()
    assert "## Positions asked and got" in report
    section = report.split("## Positions asked and got", 1)[1]
    assert "| A1 | 12.00 |" in section and "| A2 | 5.00 |" in section
    assert "![pattern s](figures/pattern_s.png)" in section
    assert (two_plan.out_dir / "figures" / "pattern_s.png").stat().st_size > 10_000
    assert "a gated burst of" in report


# --------------------------------------------------------------------------- refused


def test_unreachable_against_the_acceleration_limit_names_the_device(two_plan):
    """With a limit below one tone's own peak acceleration, every tone is lowered and the
    slider can no longer travel its move in the longest a tone may play: refused, with
    the device, what it must move and what it travels."""
    from planner.planning.motion import rest_state
    from planner.planning.targets import search_gates

    settings = two_plan.settings
    low = dataclasses.replace(settings, max_acceleration_m_s2=20.0 * 9.80665)
    step = next(st for st in settings.steps if st.name == "write")
    step = dataclasses.replace(step, max_duration_s=0.02)
    impacters = {n: d.impacter for n, d in two_plan.designs.items()}
    from planner.planning.drives import synthesize_steps

    loop = synthesize_steps(settings, [step], two_plan.assignment)[step.key]
    # every tone lowered by one factor: the limit over the loudest tone's own w^2 Z
    loudest = float(np.max((2 * np.pi * loop.frequencies) ** 2 * loop.amplitudes))
    with pytest.raises(PlanningError, match=r"s/write: A1 cannot reach its target: it must "
                                            r"move \+12 um but travels .* lowered x") as exc:
        search_gates(low, step, loop, two_plan.assignment.frequencies, impacters,
                     settings.sliders, {n: rest_state(i) for n, i in impacters.items()},
                     {d: (0.0, 0.0) for d in settings.sliders})
    assert f"lowered x{low.max_acceleration_m_s2 / loudest:.3g} " in str(exc.value)


def test_target_beyond_max_travel_is_refused_at_the_cli(tmp_path):
    """The issue's second 'done means', at the CLI: exit 2, one line naming the device,
    the field and its YAML line, no traceback, nothing written."""
    spec = tmp_path / "far.yaml"
    spec.write_text(TWO.replace("A1: 12", "A1: 120").replace(
        "x0_points: 5}", "x0_points: 5, max_travel_um: 100}"))
    out = tmp_path / "plan_out"
    proc = subprocess.run([sys.executable, "-m", "planner.cli", "plan", str(spec), "--out",
                           str(out), "--quiet"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    line = proc.stderr.strip()
    assert "scenes.s[0].targets_um.A1" in line and "A1:" in line and "+120 um" in line
    want = next(k for k, text in enumerate(spec.read_text().splitlines(), 1)
                if "A1: 120" in text)
    assert "max_travel_um (100 um)" in line and f"(line {want})" in line
    assert not out.exists()


@pytest.mark.parametrize("step, why", [
    ("{name: w, targets_um: {A1: 5}, forward: [A2]}", "forward and backward cannot be given"),
    ("{name: w, targets_um: {A1: 5}, travel_um: 3}", "cannot be given together"),
    ("{name: w, duration_ms: 5, forward: [A1], relative_to: scene_start}",
     "relative_to applies to targets_um only"),
    ("{name: w, targets_um: {}}", "targets_um needs at least one device"),
    ("{name: w, targets_um: {A: 5, A1: 3}}", "device A1 is given twice"),
    ("{name: w, targets_um: {Z9: 5}}", "unknown device 'Z9'"),
    ("{name: w, targets_um: {A1: 0}}", "every target is where its device already is"),
])
def test_bad_targets_are_refused_by_field(step, why):
    text = f"name: t\narray: {{rows: 1, cols: 2}}\nscenes:\n  s:\n    - {step}\n"
    with pytest.raises(SpecError, match=why) as exc:
        load_spec(text)
    assert exc.value.line == 5


def test_scene_start_target_after_a_sized_step_is_refused():
    text = ("name: t\narray: {rows: 1, cols: 2}\nscenes:\n  s:\n"
            "    - {name: go, travel_um: 10, forward: [A1]}\n"
            "    - {name: put, targets_um: {A1: 5}}\n")
    with pytest.raises(SpecError, match="A1 was moved by step 'go' by an amount the planner "
                                        "sizes.*relative_to: previous_step") as exc:
        load_spec(text)
    assert exc.value.path == "scenes.s[1].targets_um.A1" and exc.value.line == 6
    ok = load_spec(text.replace("{name: put,", "{name: put, relative_to: previous_step,"))
    assert ok.steps[1].moves == {"A1": pytest.approx(5 * UM)}


def test_targets_resolve_to_moves_and_directions():
    """Selectors as in forward lists (a bare column number too); each device moves by its
    target minus its previous one, forward or backward by the sign; a device already at
    its target stays."""
    text = ("name: t\narray: {rows: 2, cols: 2}\nscenes:\n  s:\n"
            "    - {name: a, targets_um: {A: 10, 2: -5}}\n"  # A1, A2 (A) then B2 (2)...
            "    - {name: b, targets_um: {A1: 10, A2: 4, B2: 0}}\n"
            "    - {name: c, relative_to: previous_step, targets_um: {B1: 3}}\n")
    with pytest.raises(SpecError, match="device A2 is given twice"):
        load_spec(text)
    text = text.replace("{A: 10, 2: -5}", "{A1: 10, 2: -5}")
    steps = load_spec(text).steps
    a, b, c = steps
    assert a.forward == ("A1",) and a.backward == ("A2", "B2")
    assert a.moves == pytest.approx({"A1": 10 * UM, "A2": -5 * UM, "B2": -5 * UM})
    # A1 is already at 10: it stays; A2 from -5 to 4; B2 from -5 back to 0
    assert b.forward == ("A2", "B2") and b.backward == ()
    assert b.moves == pytest.approx({"A1": 0.0, "A2": 9 * UM, "B2": 5 * UM})
    assert c.relative_to == "previous_step" and c.targets == {"B1": pytest.approx(3 * UM)}


def test_position_tolerance_reaches_the_settings():
    from planner.planning.settings import resolve_settings

    text = TWO.replace("x0_points: 5}", "x0_points: 5, position_tolerance_um: 0.5}")
    assert resolve_settings(load_spec(text)).position_tolerance_m == pytest.approx(0.5 * UM)
    with pytest.raises(SpecError, match="position_tolerance_um"):
        load_spec(TWO.replace("x0_points: 5}", "x0_points: 5, position_tolerance_um: 0}"))


def test_gated_impacters_get_single_impacter_steps():
    """Tones of one targets step stop one by one, so each must be told apart from the
    others and move its slider alone: an implicit single-impacter step for each (not for
    a targets step that moves one device)."""
    from planner.planning.settings import resolve_settings

    keys = [st.key for st in resolve_settings(load_spec(TWO)).steps]
    assert keys == ["s/write", "s/back", "independent/A1.forward",
                    "independent/A1.backward", "independent/A2.forward",
                    "independent/A2.backward"]
    one = TWO.replace("{A1: 12, A2: 5}", "{A1: 12}").replace("{all: 0}", "{A1: 0}")
    assert [st.key for st in resolve_settings(load_spec(one)).steps] == ["s/write", "s/back"]


def test_vibroplan_drive_writes_the_plans_burst(two_plan, tmp_path):
    """`vibroplan drive PLAN --step write` rebuilds the gated burst from plan.json's tone
    table (each tone's start_s and gate_s), not a loop of the summed tones."""
    from click.testing import CliRunner

    from planner.cli import main
    from planner.lab.exporters import read_sidecar, read_waveform

    out = tmp_path / "write.csv"
    res = CliRunner().invoke(main, ["drive", str(two_plan.out_dir), "--step", "write",
                                    "--format", "csv", "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "read back: ok: burst samples within" in res.output
    assert "a gated burst, played once" in res.output
    rec = next(s for s in two_plan.data["steps"] if s["name"] == "write")
    mine, _ = read_waveform(out)
    theirs, _ = read_waveform(two_plan.out_dir / rec["files"]["csv"])
    assert len(mine) == len(theirs)
    # plan.json keeps 12 significant digits of each tone
    np.testing.assert_allclose(mine, theirs, rtol=0, atol=1e-17)
    assert read_sidecar(out)["playback"] == "once"


# --------------------------------------------------------------------------- after fabrication


def _cli(*args):
    from click.testing import CliRunner

    from planner.cli import main

    return CliRunner().invoke(main, [str(a) for a in args])


def test_yield_checks_the_positions_of_a_targets_plan(two_plan, tmp_path):
    """Issue 38: yield on a targets_um plan reported 1.000 without checking positions
    (its steps were read back without their targets and played without their gates).
    The nominal chip passes as the plan did; the same plan whose write step asks A1 for
    30 um instead of the 12 um its burst was gated for fails off target (exit 1)."""
    res = _cli("yield", two_plan.out_dir, "--out", tmp_path / "y", "--allow-zero",
               "--chips", "1", "--quiet")
    assert res.exit_code == 0, res.output
    d = json.loads((tmp_path / "y" / "yield.json").read_text())
    assert d["nominal"]["passed"] and d["yield"] == 1.0
    data = json.loads((two_plan.out_dir / "plan.json").read_text())
    write = next(s for s in data["steps"] if s["name"] == "write")
    write["moves_m"]["A1"] = write["targets_m"]["A1"] = 30e-6
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps(data))
    res = _cli("yield", plan, "--out", tmp_path / "y2", "--allow-zero", "--chips", "1",
               "--quiet")
    assert res.exit_code == 1, res.output
    d = json.loads((tmp_path / "y2" / "yield.json").read_text())
    assert "off target" in d["nominal"]["failures"]


def test_replan_of_a_perfectly_measured_chip_of_a_targets_plan_verifies(two_plan, tmp_path):
    """Issue 38: the re-plan of a chip measured exactly as designed failed off target
    (its targets steps played as loops for their whole length); it gates them again
    for the chip, and every position check passes; the re-planned plan.json is a plan
    (read back) whose gated steps keep their targets.  Issue 37: the re-plan's move of
    each tone toward its measured window's middle stays inside the designed tone window
    (it had moved a tone 0.7 % down, where the slider was below the speed floor)."""
    from planner.planfile.reader import read_plan

    data = json.loads((two_plan.out_dir / "plan.json").read_text())
    csv = tmp_path / "measured.csv"
    csv.write_text("impacter,natural_frequency_hz\n" + "".join(
        f"{r['id']},{r['natural_frequency_hz']!r}\n" for r in data["impacters"]))
    out = tmp_path / "r"
    res = _cli("replan", two_plan.out_dir, "--measured", csv, "--out", out, "--quiet",
               "--no-figures")
    assert res.exit_code == 0, res.output
    again = read_plan(out)
    assert again.verified
    write = again.step("s/write")
    assert write.gated and write.targets_m == {"A1": 12e-6, "A2": 5e-6}
    rows = json.loads((out / "plan.json").read_text())["verification"]["steps"]["s/write"]
    for dev in ("A1", "A2"):
        assert abs(rows[dev]["worst_position_error_m"]) <= 2e-6


def test_a_slider_off_its_target_on_the_chip_has_its_gates_timed_there(two_plan):
    """Issue 45's loop on a scene of positions: a chip whose A1 slider slides on 1.5 x
    (and 0.6 x) its design's dynamic friction (a slider's friction is not measured): the
    re-plan's gates, found on the measured models, leave it off its target on the chip;
    the loop's tune stage plays the step on the chip and times the gates there
    (``gates_timed_on_chip``), and the drive then passes every check on the chip."""
    from planner.afterfab.checks import KINDS
    from planner.afterfab.loop import run_loop
    from planner.afterfab.replan import GATES_ON_CHIP
    from planner.fabrication.tolerances import sample_chip
    from planner.planfile.reader import read_plan
    from planner.yield_.chip import loop_job, truth_of
    from planner.yield_.inputs import make_payload

    rec = read_plan(two_plan.out_dir)
    payload = make_payload(rec, 0, replan=True, tune=True, measure_noise_pct=0.0,
                           allow_zero=True)
    truth = truth_of(payload, 0.0, 0, sample_chip(payload.design, payload.fabrication,
                                                  np.random.default_rng(0), 0.0))
    for factor in (1.5, 0.6):
        sliders = dict(truth.sliders)
        sliders["A1"] = dataclasses.replace(
            sliders["A1"], dynamic_friction=sliders["A1"].dynamic_friction * factor)
        out = run_loop(loop_job(payload), truth=dataclasses.replace(truth, sliders=sliders))
        assert out.replan.measured_passed and not out.replan.passed
        assert "off target" in out.replan.failures and set(out.replan.failures) <= set(KINDS)
        tuned = out.replan.tuned
        assert tuned.passed, tuned.failures
        assert tuned.repairs.get(GATES_ON_CHIP, 0) >= 1
