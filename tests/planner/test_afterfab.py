"""Issue 37, after fabrication: the as-built model from the measurement, designs with a
tone window, tuning on the chip, trim until it holds, one after-fabrication package.

The close plan (four impacters one tolerance spacing apart, line-width tolerances;
``conftest.CLOSE``) and the tiny plan are planned once per session with the real
designer and verification; every chip here is sampled, measured, re-planned and checked
by simulation on its true models.
"""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from planner.cli import main


def _cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def close(close_plan_dir):
    """(plan record, settings, chip design) of the close plan."""
    from planner.fabrication.tolerances import design_from_plan
    from planner.planfile.reader import read_plan
    from planner.planning.settings import plan_settings

    rec = read_plan(close_plan_dir)
    return rec, plan_settings(rec), design_from_plan(rec)


# ------------------------------------------------------------- 1. the as-built model

def test_a_line_width_chip_measured_exactly_is_rebuilt_as_it_is(close):
    """Line-width errors only, no measurement noise: each impacter's single error is
    what its resonance says, and the rebuilt mass, stiffness, damping and gap are the
    true chip's (the sliders' own errors are unmeasured: the die's share is taken, off
    by the device's part, well under 0.1 %).  The re-planned drive then does on the true
    chip exactly what it does on the inferred models, and passes there."""
    from planner.afterfab.as_built import symmetric
    from planner.afterfab.checks import check_drive
    from planner.afterfab.measurement import measure_models
    from planner.afterfab.replan import chip_models, replan_chip
    from planner.fabrication.tolerances import sample_chip

    rec, settings, design = close
    fab = rec.spec.fabrication
    assert fab.line_width_um.die > 0 and fab.thickness_um.die == 0 == fab.gap_um.die
    verified = 0
    for k in range(3):
        chip = sample_chip(design, fab, np.random.default_rng(9100 + k))
        measured = measure_models(chip.impacters, design.node_ids, 0.0,
                                  np.random.SeedSequence(k))
        built = chip_models(rec, measured, 0.0)
        for n, true in chip.impacters.items():
            t, b = symmetric(true), symmetric(built.impacters[n])
            for attr in ("mass", "stiffness", "damping", "gap"):
                assert getattr(b, attr) == pytest.approx(getattr(t, attr), rel=1e-9), (n, attr)
            # the inferred error is the drawn one
            assert built.errors[n][0][0] == pytest.approx(chip.errors[n][0], abs=1e-9)
        for dev, slider in chip.sliders.items():
            assert built.sliders[dev].mass == pytest.approx(slider.mass, rel=1e-3)
        ok, plan = replan_chip(rec, measured, settings=settings, record=False, models=built)
        on_model = check_drive(settings, plan.run_steps, plan.waveforms, plan.dwells,
                               built.impacters, built.sliders)
        on_chip = check_drive(settings, plan.run_steps, plan.waveforms, plan.dwells,
                              chip.impacters, chip.sliders)
        assert ok == on_model["passed"] == on_chip["passed"]
        assert on_model["failures"] == on_chip["failures"]
        verified += ok
    assert verified >= 2, "the re-plans must verify for the implication to mean anything"


def test_with_line_width_tolerances_a_shift_moves_the_mass_too(close):
    """With line-width tolerances a measured shift is a line-width error: the plate
    and beam mass move with it (the stiffness-only model of a spec without tolerances
    is test_replan's), and the rebuilt model's resonance is exactly the measured one."""
    from planner.afterfab import Measurement
    from planner.afterfab.replan import chip_models

    rec, _, _ = close
    r = rec.impacters[0]
    p = chip_models(rec, {r.id: Measurement.of(1.01 * r.natural_frequency_hz)}).parameters()
    assert abs(p[r.id]["mass_kg"] / r.mass_kg - 1.0) > 1e-4
    assert p[r.id]["natural_frequency_hz"] == pytest.approx(1.01 * r.natural_frequency_hz,
                                                            rel=1e-10, abs=0)
    assert p[r.id]["errors"]["line_width_um"] > 0.0         # stiffer: wider lines


# ----------------------------------------------------------- 2. designs with a window

def test_designs_drive_their_sliders_over_the_whole_tone_window(close_plan_dir, close):
    """Every design answers its tone over the window plan.json gives (the designer's
    max-min over x0, extended over the tone): at both edges the slider moves its way
    from every initial state, a full single step at the spec's amplitude, at least half
    the speed floor (the designer asks 1.25 x the floor at the edges of its short
    window); the report names the designed window."""
    from model import Drive
    from planner.afterfab.replan import chip_models
    from planner.planning.motion import by_node
    from planner.planning.settings import tone_amplitudes
    from planner.planning.verify import device_motion, pair_starts

    rec, settings, _ = close
    d = json.loads((close_plan_dir / "plan.json").read_text())
    assert settings.tone_window == pytest.approx(0.0015)        # 3 x 0.05 % noise
    built = chip_models(rec, {}, 0.0)
    models = by_node(built.impacters)
    for r in d["impacters"]:
        node = next(n for n in models if n.text == r["id"])
        lo, hi = r["tone_window_hz"]
        assert lo == pytest.approx(r["frequency_hz"] * (1 - settings.tone_window))
        assert hi == pytest.approx(r["frequency_hz"] * (1 + settings.tone_window))
        own = {n: m for n, m in models.items() if n.device == node.device}
        for f in (lo, hi):
            drive = Drive(np.array([f]), tone_amplitudes(settings, np.array([f])),
                          np.zeros(1))
            speeds = [node.sign * device_motion(own, built.sliders[node.device], drive,
                                                settings.single_step_s, {node: x0},
                                                settings.contacts[node.device])[0]
                      / settings.single_step_s for x0 in pair_starts(models[node], 5)]
            assert min(speeds) > 0.5 * settings.min_speed_m_s, (r["id"], f, speeds)
    report = (close_plan_dir / "report.md").read_text()
    assert "designed to answer over +-0.15 % of the tone" in report


# ------------------------------------------------------------------- 3. tuning

def test_fit_window_interpolates_its_edges():
    """A triangle of speeds peaking at 1000 Hz: the half-peak edges are where the
    straight lines cross half the peak, exactly."""
    from planner.afterfab.tune import fit_window

    f = np.linspace(990.0, 1010.0, 11)                      # 2 Hz apart
    v = np.maximum(0.0, 1.0 - np.abs(f - 1000.0) / 8.0) * 1e-3
    w = fit_window(f, v, fraction=0.5)
    assert w.ok and w.peak_hz == 1000.0 and w.peak_speed_m_s == pytest.approx(1e-3)
    assert (w.lo_hz, w.hi_hz) == (pytest.approx(996.0), pytest.approx(1004.0))
    # a floor above half the peak narrows it; a peak at the sweep's end is flagged
    assert fit_window(f, v, fraction=0.5, min_speed=0.75e-3).hi_hz == pytest.approx(1002.0)
    assert fit_window(f, np.linspace(0, 1e-3, 11)).status == "the window reaches the sweep's end"
    # a cliff (the response collapses: the slider stops dead) ends the window at the last
    # tone that moved it, not at an interpolated point in the unknown between
    cliff = np.where(f <= 1004.0, np.linspace(0.2, 1.0, 11), 0.0) * 1e-3
    wc = fit_window(f, cliff, fraction=0.5)
    assert wc.ok and wc.hi_hz == 1004.0 and wc.peak_hz == 1004.0
    assert fit_window(f, -v).status == "no tone moves its slider"


def _motion_csv(path, rows):
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["impacter", "frequency_hz", "speed_mm_s"])
        for r in rows:
            w.writerow([r["impacter"], repr(r["frequency_hz"]), repr(r["speed_m_s"] * 1e3)])
    return path


def test_calibrate_motion_then_replan_windows_puts_each_tone_in_its_window(
        close_plan_dir, close, tmp_path):
    """A tuning sweep simulated on a sampled chip of the close plan (seven tones per
    impacter around its re-planned tone, 5 % speed noise) is written as a lab's CSV;
    ``calibrate --motion`` fits windows.csv, which reads back as fit_windows' own
    result; ``replan --windows`` puts each tone at its window's middle (or as near as
    the silent bands allow), records the windows, and its drive verifies on the chip's
    true models."""
    from planner.afterfab.checks import check_drive
    from planner.afterfab.measurement import measure_models
    from planner.afterfab.replan import chip_models, replan_chip
    from planner.afterfab.tune import fit_windows, sweep_speeds
    from planner.fabrication.tolerances import sample_chip

    rec, settings, design = close
    chip = sample_chip(design, rec.spec.fabrication, np.random.default_rng(9200))
    measured = measure_models(chip.impacters, design.node_ids, 0.05,
                              np.random.SeedSequence(1))
    ok, first = replan_chip(rec, measured, settings=settings, record=False,
                            models=chip_models(rec, measured))
    assert ok
    rows = sweep_speeds(settings, first.assignment.frequencies, chip.impacters, chip.sliders,
                        np.random.default_rng(3))
    sweep = _motion_csv(tmp_path / "motion.csv", rows)
    windows = tmp_path / "windows.csv"
    res = _cli("calibrate", "--motion", sweep, "--out", windows)
    assert res.exit_code == 0, res.output
    assert "4 of 4 windows fitted ok" in res.output
    got = list(csv.DictReader(windows.open()))
    assert list(got[0]) == ["impacter", "window_lo_hz", "window_hi_hz", "peak_hz",
                            "peak_speed_mm_s", "points", "status"]
    want = fit_windows([{**r, "speed_m_s": float(repr(r["speed_m_s"] * 1e3)) * 1e-3}
                        for r in rows])
    for g in got:
        w = want[g["impacter"]]
        assert float(g["window_lo_hz"]) == pytest.approx(w.lo_hz, rel=1e-9)
        assert float(g["window_hi_hz"]) == pytest.approx(w.hi_hz, rel=1e-9)
        assert g["status"] == "ok"
        # the seven of the sweep, and those that followed the window past its top
        assert int(g["points"]) == w.points == sum(r["impacter"] == g["impacter"] for r in rows)
        assert 7 <= w.points <= 14
    # the lab's measured.csv with the same resonances, then the tuned re-plan
    mcsv = tmp_path / "measured.csv"
    mcsv.write_text("impacter,natural_frequency_hz\n" + "".join(
        f"{n},{m.natural_frequency_hz!r}\n" for n, m in measured.items()))
    out = tmp_path / "tuned"
    res = _cli("replan", close_plan_dir, "--measured", mcsv, "--windows", windows, "--out",
               out, "--no-figures", "--quiet")
    assert res.exit_code == 0, res.output
    d = json.loads((out / "plan.json").read_text())
    for m in d["replan"]["moved"]:
        lo, hi = m["working_window_hz"]
        assert lo < m["frequency_hz"] < hi
        assert abs(m["frequency_hz"] - 0.5 * (lo + hi)) < 0.25 * (hi - lo), m
    assert "working window [Hz]" in (out / "report.md").read_text()
    # the tuned drive on the true chip
    from planner.afterfab import Measurement

    tuned = {n: Measurement.of(m.natural_frequency_hz).with_window(
        tuple(next(x["working_window_hz"] for x in d["replan"]["moved"] if x["id"] == n)))
        for n, m in measured.items()}
    ok, again = replan_chip(rec, tuned, settings=settings, record=False,
                            models=chip_models(rec, measured))
    assert ok
    on_chip = check_drive(settings, again.run_steps, again.waveforms, again.dwells,
                          chip.impacters, chip.sliders)
    assert on_chip["passed"], on_chip["failures"]


@pytest.mark.parametrize("text, row, column", [
    ("impacter,frequency_hz\nA1.forward,1000\n", 1, "speed_mm_s"),
    ("impacter,frequency_hz,speed_mm_s\nA1.forward,20.5,x\n", 2, "speed_mm_s"),
    ("impacter,frequency_hz,speed_mm_s\nA1.forward,4.5,0.1\n", 2, "frequency_hz"),
    ("impacter,frequency_hz,speed_mm_s\nA1.forward,20500,0.1\nA1.forward,20600,0.2\n", 2,
     "impacter"),
])
def test_a_malformed_motion_sweep_exits_2_naming_row_and_column(tmp_path, text, row, column):
    sweep = tmp_path / "motion.csv"
    sweep.write_text(text)
    out = tmp_path / "windows.csv"
    res = _cli("calibrate", "--motion", sweep, "--out", out)
    assert res.exit_code == 2, res.output
    assert f"row {row}, column {column}" in res.output
    assert "Traceback" not in res.output and not out.exists()


def test_replan_refuses_a_window_it_cannot_use(close_plan_dir, close, tmp_path):
    """A window of an impacter measured.csv does not measure, or one that is not an
    interval, is refused naming it (exit 2, nothing written)."""
    rec, _, _ = close
    a, b = rec.impacters[0], rec.impacters[1]
    mcsv = tmp_path / "measured.csv"
    mcsv.write_text(f"impacter,natural_frequency_hz\n{a.id},{a.natural_frequency_hz!r}\n")
    for body, needle in [
        (f"{b.id},{b.frequency_hz - 10},{b.frequency_hz + 10}\n", "does not measure"),
        (f"{a.id},{a.frequency_hz + 10},{a.frequency_hz - 10}\n", "column window_hi_hz"),
        (f"{a.id},{a.frequency_hz / 1000},{a.frequency_hz / 1000 + 0.02}\n", "factor 2"),
    ]:
        windows = tmp_path / "windows.csv"
        windows.write_text("impacter,window_lo_hz,window_hi_hz\n" + body)
        out = tmp_path / "r"
        res = _cli("replan", close_plan_dir, "--measured", mcsv, "--windows", windows,
                   "--out", out, "--quiet")
        assert res.exit_code == 2, res.output
        assert needle in res.output and not out.exists()


# ------------------------------------------------- 4. trim until it holds (API)

def test_trim_passes_measure_again_until_the_chip_separates(close):
    """A cut that lands far short of its target (30 % of the move asked, then 60 %)
    leaves the pair colliding after the first pass; the sequence measures again and
    trims again, within what the range has left, and ends separable; with one pass it
    ends still colliding (not scrapped: the range was not the limit)."""
    from planner.afterfab import Measurement
    from planner.afterfab.drive import inseparable, must_differ
    from planner.afterfab.separations import separations_of
    from planner.afterfab.trim import trim_sequence
    from planner.arrayspec import TrimSpec

    rec, settings, _ = close
    seps = separations_of(rec, settings)
    pairs = must_differ(settings.steps)
    recs = sorted(rec.impacters, key=lambda r: r.natural_frequency_hz)
    lo, hi = min(zip(recs, recs[1:]), key=lambda p: p[1].natural_frequency_hz
                 - p[0].natural_frequency_hz)
    need = seps.needed(seps.ids.index(lo.id), seps.ids.index(hi.id), lo.natural_frequency_hz)
    truth = {r.id: r.natural_frequency_hz for r in rec.impacters}
    truth[hi.id] = need - 40.0
    spec = TrimSpec(passes=3)
    factors = iter([0.3, 0.6, 1.0, 1.0])           # each cut lands at this share of its move

    def cut(tp, k):
        f = next(factors)
        for n in tp.moved:
            truth[n] = tp.measured[n] + f * (tp.target[n] - tp.measured[n])

    def measure_again(k):
        return {n: Measurement.of(v) for n, v in truth.items()}

    first = measure_again(-1)
    out = trim_sequence(seps, first, pairs, spec, cut=cut, measure_again=measure_again)
    assert not out.scrapped and len(out.passes) >= 2
    assert not inseparable(seps, {n: m.natural_frequency_hz for n, m in out.measured.items()},
                           pairs)
    truth[hi.id] = need - 40.0
    factors = iter([0.3])
    once = trim_sequence(seps, measure_again(-1), pairs, spec, cut=cut,
                         measure_again=measure_again, passes=1)
    assert not once.scrapped and len(once.passes) == 1
    assert inseparable(seps, {n: m.natural_frequency_hz for n, m in once.measured.items()},
                       pairs)


# --------------------------------------- 5. the yield: in memory, structured records

def test_yield_tune_reports_its_block_and_counts_failures_by_kind(tiny_plan_dir, tmp_path,
                                                                   monkeypatch):
    """``yield --replan --tune``: every chip's re-plan is tuned (a simulated sweep on its
    true models), yield.json has the tune block and each chip's tuned verdict; the
    failures are counted by the kinds of the structured check records; no plan.json is
    written or read per chip (the writer is disabled for the run)."""
    import planner.planning.outputs as outputs
    from planner.afterfab.checks import KINDS

    def refuse(*a, **k):
        raise AssertionError("a yield chip wrote plan outputs")

    monkeypatch.setattr(outputs, "write_outputs", refuse, raising=False)
    spec = tmp_path / "shift.yaml"
    spec.write_text("fabrication:\n  natural_frequency_pct: {die: 3, device: 1.5}\n")
    out = tmp_path / "y"
    res = _cli("yield", tiny_plan_dir, "--chips", 4, "--seed", 2, "--spec", spec, "--replan",
               "--tune", "--tune-tones", 5, "--out", out, "--quiet")
    assert res.exit_code == 0, res.output
    d = json.loads((out / "yield.json").read_text())
    t = d["tune"]
    assert t["tones_per_impacter"] == 5 and t["speed_noise_pct"] == 5.0
    assert 0 <= t["passed"] <= d["chips"] and math.isclose(t["yield"], t["passed"] / d["chips"])
    assert set(d["failures"]) <= set(KINDS)
    assert set(d["replan"]["failures"]) <= set(KINDS)
    per = d["replan"]["per_chip"]
    assert len(per) == 4 and all("tuned_passed" in c for c in per)
    assert sum(c["tuned_passed"] for c in per) == t["passed"]
    assert "tuned" in (out / "report.md").read_text().lower()
    # played on the chip: the re-plans kept, counted (a tuned chip never lost now)
    assert t["kept_replan"] == sum(1 for c in per if c.get("tuned_kept_replan"))
    assert t["lost"] == 0
