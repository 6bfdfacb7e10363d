"""Issue 38's hostile cases, each at the command line: bad input is exit 2 naming the key,
row or column before any work, an OS error exit 3 in every command, nothing silently
substituted, one answer for one chip, a lock for the whole run, a failed write that
leaves the old files as they were.

Every test runs the real CLI (click's CliRunner, or a subprocess where a second process
or the real stderr matters) on the session's planned tiny array (or the close plan of
conftest) and reads the files it wrote back.
"""

import json
import math
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from click.testing import CliRunner

from planner.cli import main

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def _plan_json(tiny_plan_dir):
    return json.loads((tiny_plan_dir / "plan.json").read_text())


def _write(tmp_path, data, name="plan.json"):
    path = tmp_path / name
    path.write_text(json.dumps(data, allow_nan=True))
    return path


def _measured(tmp_path, rows, header="impacter,natural_frequency_hz", name="measured.csv"):
    path = tmp_path / name
    path.write_text(header + "\n" + "".join(",".join(map(str, r)) + "\n" for r in rows))
    return path


def _as_designed(tmp_path, tiny_plan_dir):
    return _measured(tmp_path, [(r["id"], r["natural_frequency_hz"])
                                for r in _plan_json(tiny_plan_dir)["impacters"]])


def _refused(res, *words):
    assert res.exit_code == 2, res.output
    # two asserts: one ``A and B or C`` let C (a SystemExit, which every refusal is)
    # excuse a traceback in the output
    assert "Traceback" not in res.output, res.output
    assert res.exception is None or isinstance(res.exception, SystemExit), res.exception
    for w in words:
        assert w in res.output, res.output


# --------------------------------------------------------------------------- plan.json


def _separations(value):
    def edit(d):
        first = next(iter(d["manufacturability"]["separation_hz"]))
        if value == "delete key":
            del d["manufacturability"]["separation_hz"][first]["silent_below"]
        elif isinstance(value, float):
            d["manufacturability"]["separation_hz"][first]["silent_below"] = value
        else:
            d["manufacturability"]["separation_hz"] = value
    return edit


@pytest.mark.parametrize("value", ["x", None, [1.0], math.nan, -5.0, 0.0, 1e12,
                                   "delete key"],
                         ids=["string", "null", "list", "nan", "negative", "zero", "1e12",
                              "deleted-key"])
@pytest.mark.parametrize("command", ["replan", "trim", "yield"])
def test_a_broken_separation_is_refused_naming_the_key(tiny_plan_dir, tmp_path, value,
                                                       command):
    """Issue 38: a string, null or list separation_hz, a deleted key (tracebacks), a NaN,
    negative, zero or 1e12 Hz reach (used silently): exit 2 naming the key, nothing
    written, in every command that reads it."""
    data = _plan_json(tiny_plan_dir)
    _separations(value)(data)
    plan = _write(tmp_path, data)
    out = tmp_path / "out"
    if command == "yield":
        res = cli("yield", plan, "--out", out, "--replan", "--allow-zero", "--quiet")
    else:
        res = cli(command, plan, "--measured", _as_designed(tmp_path, tiny_plan_dir),
                  "--out", out, "--quiet", "--no-figures")
    _refused(res, "manufacturability.separation_hz")
    assert not out.exists()


@pytest.mark.parametrize("where", ["step tone", "impacter tone"])
@pytest.mark.parametrize("command", ["replan", "yield", "layout", "drive"])
def test_a_tone_edited_by_300_hz_is_refused(tiny_plan_dir, tmp_path, where, command):
    """Issue 38: a tone edited by +300 Hz in plan.json was accepted by replan, yield and
    layout; the reader now holds each step's tones to its impacters' and each
    impacter's tone to its channel of the spec's grid."""
    data = _plan_json(tiny_plan_dir)
    if where == "step tone":
        data["steps"][0]["tones"][0]["frequency_hz"] += 300.0
        key = "steps[0] (s/push).tones[0].frequency_hz"
    else:
        data["impacters"][0]["frequency_hz"] += 300.0
        key = "impacters[0] (A1.forward).frequency_hz"
    plan = _write(tmp_path, data)
    if command == "replan":
        res = cli("replan", plan, "--measured", _as_designed(tmp_path, tiny_plan_dir),
                  "--out", tmp_path / "o", "--quiet", "--no-figures")
    elif command == "yield":
        res = cli("yield", plan, "--out", tmp_path / "o", "--allow-zero", "--quiet")
    elif command == "layout":
        res = cli("layout", plan, "--out", tmp_path / "o.gds")
    else:
        res = cli("drive", plan, "--step", "push", "--out", tmp_path / "o.wav")
    _refused(res, key, "contradict")
    assert not any(p.name.startswith("o") for p in tmp_path.iterdir())


def test_a_natural_frequency_edited_by_300_hz_is_refused(tiny_plan_dir, tmp_path):
    data = _plan_json(tiny_plan_dir)
    data["impacters"][1]["natural_frequency_hz"] += 300.0
    res = cli("layout", _write(tmp_path, data), "--out", tmp_path / "o.gds")
    _refused(res, "impacters[1] (A2.backward).natural_frequency_hz")


def test_layout_spec_that_is_a_plan_json_is_named_so(tiny_plan_dir, tmp_path):
    res = cli("layout", tiny_plan_dir, "--out", tmp_path / "c.gds", "--spec",
              tiny_plan_dir / "plan.json")
    _refused(res, "this is a plan.json", "not an array spec")
    assert "wrong unit" not in res.output and not (tmp_path / "c.gds").exists()


# --------------------------------------------------------------------------- measured.csv


def test_a_gap_typed_in_metres_names_its_row_and_column(tiny_plan_dir, tmp_path):
    plan = _plan_json(tiny_plan_dir)
    nu = {r["id"]: r["natural_frequency_hz"] for r in plan["impacters"]}
    csv = _measured(tmp_path, [("A1.forward", nu["A1.forward"], "3e-6"),
                               ("A2.backward", nu["A2.backward"], "")],
                    header="impacter,natural_frequency_hz,gap_um")
    res = cli("replan", tiny_plan_dir, "--measured", csv, "--out", tmp_path / "o", "--quiet")
    _refused(res, "row 2, column gap_um", "metres")
    assert not (tmp_path / "o").exists()


def test_a_resonance_of_5e8_hz_names_its_row(tiny_plan_dir, tmp_path):
    plan = _plan_json(tiny_plan_dir)
    nu = {r["id"]: r["natural_frequency_hz"] for r in plan["impacters"]}
    csv = _measured(tmp_path, [("A1.forward", nu["A1.forward"]), ("A2.backward", "5e8")])
    for command in ("replan", "trim"):
        res = cli(command, tiny_plan_dir, "--measured", csv, "--out", tmp_path / command,
                  "--quiet")
        _refused(res, "row 3, column natural_frequency_hz", "design's")
        assert "sample rate" not in res.output and "sample_rate" not in res.output


def test_trim_refuses_an_impacter_missing_from_measured_csv(tiny_plan_dir, tmp_path):
    """Issue 38: trim wrote the design's resonance as measured_hz without a word."""
    plan = _plan_json(tiny_plan_dir)
    a1 = next(r for r in plan["impacters"] if r["id"] == "A1.forward")
    csv = _measured(tmp_path, [("A1.forward", a1["natural_frequency_hz"] * 1.003)])
    res = cli("trim", tiny_plan_dir, "--measured", csv, "--out", tmp_path / "t", "--quiet",
              "--no-figures")
    _refused(res, "A2.backward", "no measured resonance")
    assert not (tmp_path / "t").exists()


def test_pair_halves_keep_each_halfs_q_and_gap(tiny_plan_dir, tmp_path):
    """Issue 38: a Q given for one half was dropped, as_built kept only the halves' mean,
    per-half gaps were not used.  Now each half keeps its own resonance, Q and gap (the
    other half its design's), in the models and in plan.json's as_built, and the
    re-planned plan.json reads back."""
    from planner.planfile.reader import read_plan

    plan = read_plan(tiny_plan_dir)
    a1 = plan.impacter("A1.forward")
    a2 = plan.impacter("A2.backward")
    nu = a1.natural_frequency_hz
    csv = _measured(tmp_path, [("A1.forward", 0.99 * nu, 10, 2.5, "a"),
                               ("A1.forward", 1.01 * nu, "", 6, "b"),
                               ("A2.backward", a2.natural_frequency_hz, "", "", "")],
                    header="impacter,natural_frequency_hz,quality_factor,gap_um,half")
    out = tmp_path / "r"
    res = cli("replan", tiny_plan_dir, "--measured", csv, "--out", out, "--quiet",
              "--no-figures")
    assert res.exit_code in (0, 1), res.output
    again = read_plan(out)
    halves = {h.half: h for h in again.as_built["A1.forward"].halves}
    m = a1.mass_kg
    assert halves["a"].natural_frequency_hz == pytest.approx(0.99 * nu)
    assert halves["b"].natural_frequency_hz == pytest.approx(1.01 * nu)
    assert halves["a"].damping_ns_per_m == pytest.approx(m * 2 * math.pi * 0.99 * nu / 10)
    assert halves["b"].damping_ns_per_m == pytest.approx(a1.damping_ns_per_m)
    assert (halves["a"].gap_m, halves["b"].gap_m) == pytest.approx((2.5e-6, 6e-6))
    assert again.as_built["A2.backward"].halves is None
    # the pair's own record is the halves' symmetric stand-in, the same in both places
    rec = again.impacter("A1.forward")
    assert rec.damping_ns_per_m == pytest.approx(0.5 * (halves["a"].damping_ns_per_m
                                                        + halves["b"].damping_ns_per_m))
    assert rec.gap_m == pytest.approx(6e-6)


# --------------------------------------------------------------------------- one chip


def test_trim_reckons_from_the_designs_whatever_the_plan_json(close_plan_dir, tmp_path):
    """Issue 38: the same chip got +0.58 %, 'cannot be trimmed' or '0 to trim' depending
    on whether plan.json carried its manufacturability block or was a re-planned plan.
    The separations, tone ratios and the re-plan's tones are the designs' for all three
    (the re-plan of the chip written by the CLI and read back)."""
    import numpy as np

    from planner.planfile.reader import plan_record, read_plan
    from planner.afterfab.drive import rescaled_tones
    from planner.afterfab.separations import separations_of
    from planner.planning.settings import plan_settings

    plan = read_plan(close_plan_dir)
    meas = {r.id: r.natural_frequency_hz * (1.004 if k % 2 else 0.997)
            for k, r in enumerate(plan.impacters)}
    csv = _measured(tmp_path, list(meas.items()))
    out = tmp_path / "replanned"
    res = cli("replan", close_plan_dir, "--measured", csv, "--out", out, "--quiet",
              "--no-figures")
    assert res.exit_code in (0, 1), res.output
    replanned = read_plan(out)
    assert replanned.replanned and replanned.manufacturability is not None
    data = json.loads((close_plan_dir / "plan.json").read_text())
    data.pop("manufacturability")
    bare = plan_record(data)
    settings = plan_settings(plan)
    seps = [separations_of(p, settings) for p in (plan, bare, replanned)]
    for other in seps[1:]:
        for name in ("rho", "below", "above", "lo", "hi"):
            np.testing.assert_allclose(getattr(other, name), getattr(seps[0], name),
                                       rtol=1e-6, err_msg=name)
    tones = [rescaled_tones(p, meas, s) for p, s in zip((plan, bare, replanned), seps)]
    for other in tones[1:]:
        assert other == pytest.approx(tones[0], rel=1e-9)


@pytest.mark.slow
def test_trim_gives_one_answer_for_one_chip(close_plan_dir, tmp_path):
    """The same measured chip trimmed from the plan, the plan without its
    manufacturability block and the chip's re-planned plan: one trim.csv."""
    import csv as csvmod

    from planner.planfile.reader import read_plan
    from planner.afterfab.separations import separations_of
    from planner.planning.settings import plan_settings

    plan = read_plan(close_plan_dir)
    seps = separations_of(plan, plan_settings(plan))
    recs = sorted(plan.impacters, key=lambda r: r.natural_frequency_hz)
    lo, hi = min(zip(recs, recs[1:]), key=lambda p: p[1].natural_frequency_hz
                 - p[0].natural_frequency_hz)
    need = seps.needed(seps.ids.index(lo.id), seps.ids.index(hi.id),
                       1.004 * lo.natural_frequency_hz)
    meas = {r.id: 1.004 * r.natural_frequency_hz for r in plan.impacters}
    meas[hi.id] = need - 30.0
    csv = _measured(tmp_path, list(meas.items()))
    res = cli("replan", close_plan_dir, "--measured", csv, "--out", tmp_path / "rp",
              "--quiet", "--no-figures")
    assert res.exit_code == 1 and "cannot be told apart" in res.output, res.output
    data = json.loads((close_plan_dir / "plan.json").read_text())
    data.pop("manufacturability")
    (tmp_path / "bare").mkdir()
    _write(tmp_path / "bare", data)
    got = []
    for src in (close_plan_dir, tmp_path / "bare", tmp_path / "rp"):
        out = tmp_path / f"trim_{len(got)}"
        res = cli("trim", src, "--measured", csv, "--out", out, "--quiet", "--no-figures")
        assert res.exit_code == 0, res.output
        got.append(list(csvmod.DictReader((out / "trim.csv").open())))
    moved = [r for r in got[0] if float(r["change_pct"]) != 0.0]
    assert [r["impacter"] for r in moved] == [hi.id]
    for rows in got[1:]:
        assert [r["impacter"] for r in rows] == [r["impacter"] for r in got[0]]
        assert [float(r["target_hz"]) for r in rows] == pytest.approx(
            [float(r["target_hz"]) for r in got[0]], rel=1e-9)


# --------------------------------------------------------------------------- options


@pytest.mark.parametrize("command", ["plan", "replan", "trim", "yield", "drive"])
def test_a_negative_seed_is_refused_while_parsing(tiny_plan_dir, tmp_path, command):
    args = {"plan": ["plan", CONFIGS / "tiny_1x2.yaml", "--out", tmp_path / "o"],
            "replan": ["replan", tiny_plan_dir, "--measured",
                       _as_designed(tmp_path, tiny_plan_dir), "--out", tmp_path / "o"],
            "trim": ["trim", tiny_plan_dir, "--measured",
                     _as_designed(tmp_path, tiny_plan_dir), "--out", tmp_path / "o"],
            "yield": ["yield", tiny_plan_dir, "--out", tmp_path / "o", "--allow-zero"],
            "drive": ["drive", tiny_plan_dir, "--step", "push", "--out", tmp_path / "o.wav"]}
    res = cli(*args[command], "--seed", "-5")
    _refused(res, "--seed")
    assert not any(p.name.startswith("o") for p in tmp_path.iterdir())


def test_sigma_scale_zero_needs_allow_zero(tiny_plan_dir, tmp_path):
    spec = tmp_path / "fab.yaml"
    spec.write_text("fabrication:\n  line_width_um: {die: 0.05, device: 0.02}\n")
    res = cli("yield", tiny_plan_dir, "--out", tmp_path / "y", "--spec", spec,
              "--sigma-scale", "0", "--quiet")
    _refused(res, "--sigma-scale", "--allow-zero")
    assert not (tmp_path / "y").exists()
    res = cli("yield", tiny_plan_dir, "--out", tmp_path / "y", "--spec", spec,
              "--sigma-scale", "0", "--allow-zero", "--quiet", "--chips", "1")
    assert res.exit_code == 0, res.output
    assert json.loads((tmp_path / "y" / "yield.json").read_text())["yield"] == 1.0


def test_tolerance_spacing_without_fabrication_is_refused(tmp_path):
    spec = tmp_path / "tol.yaml"
    spec.write_text((CONFIGS / "tiny_1x2.yaml").read_text().replace(
        "channels: {count: 60}", "channels: {spacing: tolerance}"))
    for args in (["plan", spec, "--dry-run"], ["assign", spec]):
        res = cli(*args)
        _refused(res, "drive.channels.spacing", "fabrication", "(line 10)")


def test_trim_precision_zero_is_refused_by_the_spec(tiny_plan_dir, tmp_path):
    """trim.precision_pct: 0 passed plan and was refused by layout only: a cut has an
    error, and trim tabs of 0 % would be infinitely many; refused up front everywhere
    (the spec for plan, the plan's spec for every plan command)."""
    spec = tmp_path / "p0.yaml"
    spec.write_text((CONFIGS / "tiny_1x2.yaml").read_text()
                    + "trim: {range_pct: 1, direction: up, precision_pct: 0}\n")
    _refused(cli("plan", spec, "--dry-run"), "trim.precision_pct", "(line 16)")
    data = _plan_json(tiny_plan_dir)
    data["spec"]["trim"] = {"range_pct": 1.0, "direction": "up", "precision_pct": 0.0}
    plan = _write(tmp_path, data)
    _refused(cli("layout", plan, "--out", tmp_path / "c.gds"), "spec.trim.precision_pct")
    _refused(cli("trim", plan, "--measured", _as_designed(tmp_path, tiny_plan_dir), "--out",
                 tmp_path / "t"), "spec.trim.precision_pct")


def test_plan_dry_run_refuses_what_the_real_run_refuses(tmp_path):
    spec = CONFIGS / "tiny_1x2.yaml"
    foreign = tmp_path / "notes"
    foreign.mkdir()
    (foreign / "mine.txt").write_text("a user's file")
    _refused(cli("plan", spec, "--dry-run", "--out", foreign), "not empty")
    res = cli("plan", spec, "--dry-run", "--out", "/proc/x")
    assert res.exit_code == 3 and "/proc" in res.output, res.output
    res = cli("plan", spec, "--dry-run", "--out", tmp_path / "p", "--scheduler",
              "tcp://127.0.0.1:1")
    assert res.exit_code == 3 and "127.0.0.1:1" in res.output, res.output
    assert cli("plan", spec, "--dry-run", "--out", tmp_path / "p").exit_code == 0


def test_an_unwritable_out_is_exit_3_in_every_command(tiny_plan_dir, tmp_path):
    """Issue 38: --out /proc/x gave 2 in replan and trim, 3 in layout, calibrate, yield."""
    from tests.planner.test_cli_fuzz import _sweep_text

    csv = _as_designed(tmp_path, tiny_plan_dir)
    sweep = tmp_path / "sweep.csv"
    sweep.write_text(_sweep_text())
    for args in (["replan", tiny_plan_dir, "--measured", csv, "--out", "/proc/x"],
                 ["trim", tiny_plan_dir, "--measured", csv, "--out", "/proc/x"],
                 ["yield", tiny_plan_dir, "--out", "/proc/x", "--allow-zero"],
                 ["layout", tiny_plan_dir, "--out", "/proc/x.gds"],
                 ["calibrate", sweep, "--out", "/proc/x.csv"],
                 ["plan", CONFIGS / "tiny_1x2.yaml", "--out", "/proc/x"]):
        res = cli(*args)
        assert res.exit_code == 3, (args[0], res.output)
        assert "error: /proc: cannot write here" in res.output, res.output


def test_calibrate_refuses_a_sweep_in_khz(tmp_path):
    """Issue 38: a sweep written in kHz fitted 4.44 Hz and marked it ok."""
    import numpy as np

    from planner.lab.calibrate import transmissibility

    f = np.linspace(4.0, 4.8, 40)
    a = 0.1 * transmissibility(f, 4.44, 40.0)
    sweep = tmp_path / "khz.csv"
    sweep.write_text("impacter,frequency_hz,amplitude_um\n"
                     + "".join(f"A1.forward,{float(x)!r},{float(y)!r}\n" for x, y in zip(f, a)))
    res = cli("calibrate", sweep, "--out", tmp_path / "measured.csv")
    _refused(res, "row 2, column frequency_hz", "kHz")
    assert not (tmp_path / "measured.csv").exists()


def test_solver_warnings_are_one_readable_line():
    """Issue 38: raw SolverWarnings with the source path reached stderr."""
    run = subprocess.run([sys.executable, "-m", "planner.cli", "simulate",
                          str(CONFIGS / "paper_fig7.yaml"), "--freq", "5200", "--duration",
                          "20000"], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    lines = [x for x in run.stderr.splitlines() if x.strip()]
    assert len(lines) == 1 and lines[0].startswith("warning: the solver stopped early"), \
        run.stderr
    assert "event cap" in lines[0]
    assert "SolverWarning" not in run.stderr and ".py:" not in run.stderr


# --------------------------------------------------------------------------- outputs


def test_a_second_yield_to_one_folder_is_refused_at_once(tiny_plan_dir, tmp_path):
    """Issue 38: two yield runs to one folder both ran to the end (the lock was taken
    only to write).  The first holds the lock for its whole run: the second is refused
    at once (exit 2, naming the lock); the first, stopped, leaves nothing."""
    out = tmp_path / "y"
    lock = tmp_path / ".y.lock"
    first = subprocess.Popen([sys.executable, "-m", "planner.cli", "yield",
                              str(tiny_plan_dir), "--out", str(out), "--allow-zero",
                              "--chips", "100000", "--quiet"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not lock.exists():
            assert first.poll() is None, first.communicate()
            assert time.monotonic() < deadline, "the first run never took its lock"
            time.sleep(0.1)
        res = cli("yield", tiny_plan_dir, "--out", out, "--allow-zero", "--chips", "1",
                  "--quiet")
        _refused(res, "another vibroplan run is writing this folder")
    finally:
        first.send_signal(signal.SIGTERM)
        # a hang guard (a run stopped inside a numba compilation on a cold cache answers
        # the signal when that ends), not a timing target
        first.wait(timeout=300)
    assert first.returncode == 143
    assert not out.exists() and not lock.exists()


def _layout(src, out, *extra):
    return cli("layout", src, "--out", out, *extra)


def test_layout_over_a_checked_layout_drops_its_old_check(tiny_plan_dir, tmp_path):
    """Issue 38: a layout written over another plan's layout left the old _drc.json."""
    out = tmp_path / "chip.gds"
    res = _layout(tiny_plan_dir, out, "--check")
    assert res.exit_code in (0, 1), res.output
    assert (tmp_path / "chip_drc.json").is_file()
    res = _layout(tiny_plan_dir, out)
    assert res.exit_code == 0, res.output
    assert not (tmp_path / "chip_drc.json").exists()
    assert sorted(p.name for p in tmp_path.iterdir() if not p.name.startswith(".")) == [
        "chip.gds", "chip.md", "chip.png", "chip_A1.png"]
    # another writer's file of that name is left alone
    (tmp_path / "chip_drc.json").write_text('{"clean": true}')
    assert _layout(tiny_plan_dir, out).exit_code == 0
    assert (tmp_path / "chip_drc.json").read_text() == '{"clean": true}'


def test_a_layout_failing_while_writing_leaves_the_old_files(tiny_plan_dir, tmp_path):
    """Issue 38: a layout that failed while writing (exit 3) left a mix of two chips'
    files.  The registry beside the files made a folder: the swap fails after the
    files are moved in, and every old file comes back."""
    from planner.files import REGISTRY

    out = tmp_path / "chip.gds"
    assert _layout(tiny_plan_dir, out, "--check").exit_code in (0, 1)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    (tmp_path / REGISTRY).unlink()
    (tmp_path / REGISTRY).mkdir()
    data = _plan_json(tiny_plan_dir)
    data["spec"]["array"]["pitch_um"] = 1500.0          # another chip
    other = tmp_path / "other"
    other.mkdir()
    _write(other, data)
    res = _layout(other, out, "--force")
    assert res.exit_code == 3, res.output
    after = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    before.pop(REGISTRY)
    assert after == before
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".chip")] == []


def test_layout_of_a_replanned_plan_draws_the_design(tiny_plan_dir, tmp_path):
    """Issue 38: layout of a re-planned plan exited 1 (its as-built resonances against
    the drawn design's).  The layout draws the design: the round trip passes."""
    plan = _plan_json(tiny_plan_dir)
    csv = _measured(tmp_path, [(r["id"], r["natural_frequency_hz"] * f) for r, f in
                               zip(plan["impacters"], (1.035, 0.975))])
    res = cli("replan", tiny_plan_dir, "--measured", csv, "--out", tmp_path / "r",
              "--quiet", "--no-figures")
    assert res.exit_code in (0, 1), res.output
    res = _layout(tmp_path / "r", tmp_path / "chip.gds")
    assert res.exit_code == 0, res.output
    assert "(passed)" in res.output
    report = (tmp_path / "chip.md").read_text()
    assert "A1.forward" in report

