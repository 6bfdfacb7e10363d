"""Issue 39: a wafer at a time.

- where a die sat (``fabrication.wafer``): the die grid, the across-wafer field and the
  within-die gradient, the yield on wafers (its wafer block, map, yield by radius and
  the prober's files), and nothing changed without a wafer;
- a wafer re-planned in batch (``vibroplan replan --measured WAFER.csv``): outcomes per
  die against the yield's, ``--jobs 1`` and ``--jobs 2`` byte for byte, an interrupted
  run resumed, a folder of measured.csv files, bad input;
- tester files (STDF V4 read back through pystdf);
- frequency neighbours placed near each other (``drive.channels.placement``).

The tiny 1 x 2 plan of the plan tests (real designer, real verification); every CLI
test runs the real command and reads its files back.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from planner.cli import main

ROOT = Path(__file__).resolve().parents[2]

#: The tiny plan's tolerances with a wafer: 33 dies of 2 x 1 mm (the 1 x 2 array at
#: 1 mm pitch) on a 12 mm wafer, a line-width field of 0.05 um over 4 mm and a
#: gradient of 0.01 um/mm.  The natural-frequency scatter makes the plan's own drive
#: fail on most dies (a re-plan rescues them).
WAFER = """\
fabrication:
  natural_frequency_pct: {die: 4, device: 2}
  line_width_um: {die: 0.02, device: 0.01}
  wafer:
    diameter_mm: 12
    edge_exclusion_mm: 0.5
    line_width_field: {sigma_um: 0.05, correlation_length_mm: 4}
    line_width_gradient_um_per_mm: 0.01
"""
#: The same tolerances without a wafer, and with a wafer of zero sigmas.
NO_WAFER = WAFER.split("  wafer:")[0]
ZERO_WAFER = NO_WAFER + "  wafer: {diameter_mm: 12, edge_exclusion_mm: 0.5}\n"
#: Dies of the yield runs below (the first 14 of the 33, reading order).
DIES = 14


def _run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def specs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("wafer-specs")
    out = {}
    for name, text in (("wafer", WAFER), ("none", NO_WAFER), ("zero", ZERO_WAFER)):
        out[name] = folder / f"{name}.yaml"
        out[name].write_text(text)
    return out


@pytest.fixture(scope="module")
def wafer_yield(tiny_plan_dir, specs, tmp_path_factory):
    """``vibroplan yield --replan --trim`` of 14 dies of one wafer."""
    out = tmp_path_factory.mktemp("wafer-yield") / "y"
    res = _run("yield", tiny_plan_dir, "--chips", DIES, "--seed", 3, "--spec", specs["wafer"],
               "--replan", "--trim", "--out", out, "--quiet")
    assert res.exit_code == 0, res.output
    return out


@pytest.fixture(scope="module")
def wafer_batch(tiny_plan_dir, wafer_yield, tmp_path_factory):
    """The yield's wafer_1.csv re-planned in batch, in this process (--jobs 1)."""
    out = tmp_path_factory.mktemp("wafer-batch") / "r1"
    res = _run("replan", tiny_plan_dir, "--measured", wafer_yield / "wafer_1.csv", "--trim",
               "--jobs", 1, "--out", out, "--quiet")
    assert res.exit_code in (0, 1), res.output
    return out


def _tree(folder: Path) -> dict:
    return {p.relative_to(folder).as_posix(): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def _summary(folder: Path) -> dict:
    return {(int(r["die_x"]), int(r["die_y"])): r
            for r in csv.DictReader((folder / "summary.csv").open())}


# ------------------------------------------------------------------ 1. where a die sat

def test_the_die_grid_fills_the_wafer_inside_its_edge_exclusion():
    from planner.arrayspec import ArraySpec, WaferSpec
    from planner.fabrication.wafer import wafer_layout

    spec = ArraySpec.model_validate({"array": {"rows": 5, "cols": 5, "pitch_um": 2000.0}})
    lay = wafer_layout(spec.array, WaferSpec(diameter_mm=135.0, edge_exclusion_mm=3.0))
    w, h = lay.die_size
    assert (w, h) == pytest.approx((0.01, 0.01))     # 5 x 2 mm
    # every die's farthest corner inside the usable radius, and no die left out that
    # would fit: the ring of the grid's next dies all reach beyond it
    far = np.hypot(np.abs(lay.x) + w / 2, np.abs(lay.y) + h / 2)
    assert np.all(far <= lay.usable_radius + 1e-12)
    assert lay.count == 101 and (0, 0) in set(zip(lay.die_x.tolist(), lay.die_y.tolist()))
    places = set(zip(lay.die_x.tolist(), lay.die_y.tolist()))
    assert len(places) == lay.count
    for ix, iy in places:
        for nx, ny in ((ix + 1, iy), (ix, iy + 1), (ix - 1, iy), (ix, iy - 1)):
            if (nx, ny) not in places:
                assert np.hypot(abs(nx) * w + w / 2, abs(ny) * h + h / 2) > lay.usable_radius
    # reading order: top row first, left to right
    order = list(zip((-lay.die_y).tolist(), lay.die_x.tolist()))
    assert order == sorted(order)


def test_the_field_is_correlated_over_its_length_and_the_gradient_is_linear():
    from planner.arrayspec import ArraySpec
    from planner.fabrication.wafer import device_positions, line_width_offsets, wafer_draws, wafer_layout

    spec = ArraySpec.model_validate({
        "array": {"rows": 3, "cols": 3, "pitch_um": 2000.0},
        "fabrication": {"wafer": {"diameter_mm": 100.0, "line_width_field": {
            "sigma_um": 0.05, "correlation_length_mm": 20.0},
            "line_width_gradient_um_per_mm": 0.004}}})
    wafer = spec.fabrication.wafer
    lay = wafer_layout(spec.array, wafer)
    fields = np.array([wafer_draws(spec.array, wafer, 0, 1.0, k)[0] for k in range(300)])
    # the field's variance is sigma^2 everywhere, and two dies r apart differ by
    # 2 sigma^2 (1 - exp(-r^2 / 2 L^2)) in variance (the squared exponential)
    assert np.mean(fields.var(axis=0)) == pytest.approx(0.05 ** 2, rel=0.1)
    i = int(np.argmin(np.hypot(lay.x, lay.y)))
    for j in (int(np.argmin(np.hypot(lay.x - 0.006, lay.y))),
              int(np.argmin(np.hypot(lay.x - 0.036, lay.y)))):
        r = float(np.hypot(lay.x[i] - lay.x[j], lay.y[i] - lay.y[j]))
        want = 2 * 0.05 ** 2 * (1 - np.exp(-r * r / (2 * 0.02 ** 2)))
        assert np.var(fields[:, i] - fields[:, j]) == pytest.approx(want, rel=0.2)
    # a die's offsets: its field value plus a plane over the devices' places
    off = line_width_offsets(spec, spec.fabrication, 0, 1.0, 5)
    pos = device_positions(spec.array)
    assert off["A1"] + off["A3"] == pytest.approx(2 * off["A2"], abs=1e-15)
    assert off["A1"] - off["C1"] != pytest.approx(0.0, abs=1e-9)
    assert pos["B2"] == (0.0, 0.0) and off["B2"] == pytest.approx(
        wafer_draws(spec.array, wafer, 0, 1.0, 0)[0][5])
    # scale 0 (the nominal chip) and no wafer: nothing added
    assert line_width_offsets(spec, spec.fabrication, 0, 0.0, 5) is None
    assert line_width_offsets(ArraySpec(), ArraySpec().fabrication, 0, 1.0, 5) is None


def test_a_zero_wafer_draws_the_chips_of_no_wafer(tiny_plan_dir, specs, tmp_path):
    """Dies on a wafer of zero field and gradient are the chips without a wafer: the
    same die, device and pair draws (the wafer's own come from a stream of their own);
    and without a wafer yield.json has no trace of one."""
    got = {}
    for name in ("none", "zero"):
        out = tmp_path / name
        res = _run("yield", tiny_plan_dir, "--chips", 5, "--seed", 4, "--spec", specs[name],
                   "--out", out, "--quiet")
        assert res.exit_code == 0, res.output
        got[name] = json.loads((out / "yield.json").read_text())
    assert "wafer" not in got["none"] and "wafer" not in got["none"]["tolerance"]
    zero = got["zero"]
    assert zero.pop("wafer")["dies_per_wafer"] == 33
    assert zero["tolerance"].pop("wafer")["diameter_mm"] == 12
    assert zero == got["none"]
    assert not (tmp_path / "none" / "wafer_1.csv").exists()


def test_a_yield_on_wafers_maps_every_die(wafer_yield):
    d = json.loads((wafer_yield / "yield.json").read_text())
    w = d["wafer"]
    assert w["dies_per_wafer"] == 33 and w["wafers"] == 1
    assert w["die_size_mm"] == [2.0, 1.0] and w["diameter_mm"] == 12
    dies = w["dies"]
    assert [x["chip"] for x in dies] == list(range(DIES))
    assert len({(x["die_x"], x["die_y"]) for x in dies}) == DIES
    per = {c["chip"]: c for c in d["replan"]["per_chip"]}
    for x in dies:
        assert x["radius_mm"] == pytest.approx(np.hypot(x["x_mm"], x["y_mm"]))
        c = per[x["chip"]]
        # the outcome is the first stage of the lab's loop that works on the true models
        want = ("as designed" if c["nominal_passed"] else "after re-plan" if c["replan_passed"]
                else "after trim" if c["trim_passed"] else "fails")
        assert x["outcome"] == want
        assert (x["causes"] == []) == (want != "fails")
    assert sum(w["outcomes"].values()) == DIES
    assert w["outcomes"]["as designed"] == d["passed"]
    assert 0 < w["outcomes"]["after re-plan"] < DIES, "the wafer must need re-plans"
    rings = w["by_radius"]
    assert sum(r["dies"] for r in rings) == DIES
    for r in rings:
        if r["dies"]:
            assert sum(r["outcomes"].values()) == r["dies"]
            assert r["yield"] == r["works"] / r["dies"]
            assert r["ci95"][0] <= r["yield"] <= r["ci95"][1]
    for png in ("wafer_map.png", "yield_radius.png"):
        assert (wafer_yield / "figures" / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    report = (wafer_yield / "report.md").read_text()
    assert "## The wafer" in report and "figures/wafer_map.png" in report


def test_the_wafer_file_holds_what_the_yield_measured(tiny_plan_dir, wafer_yield, specs):
    """wafer_1.csv is each die's measurement as the yield's re-plan made it (the same
    normals of the chip's own seed), read back through the wafer reader."""
    from planner.afterfab.wafer_file import read_wafer
    from planner.planfile.reader import read_plan
    from planner.arrayspec import load_spec
    from planner.yield_ import make_payload, measured_frequencies
    from planner.yield_.dies import die_measurements

    plan = read_plan(tiny_plan_dir)
    dies = read_wafer(wafer_yield / "wafer_1.csv", plan.impacter_ids,
                      plan.design_natural_frequency_hz)
    payload = make_payload(plan, 3, load_spec(specs["wafer"]).spec.fabrication, replan=True,
                           measure_noise_pct=0.05)
    want = die_measurements(payload, 1.0, range(DIES))
    assert [(x, y) for x, y, _ in dies] == [(w["die_x"], w["die_y"]) for w in want]
    for (_, _, got), w in zip(dies, want):
        assert {n: m.resonance for n, m in got.items()} == w["measured"]
    # and that is what the study's re-plan measured of the chip
    from planner.core.rng import chip_seed
    from planner.fabrication.tolerances import sample_chip
    from planner.fabrication.wafer import line_width_offsets

    rng = np.random.default_rng(chip_seed(3, 1.0, 2))
    chip = sample_chip(payload.design, payload.fabrication, rng, 1.0,
                       line_width_offsets(plan.spec, payload.fabrication, 3, 1.0, 2))
    assert {n: m for n, (_, m) in measured_frequencies(payload, 1.0, 2, chip).items()} == \
        want[2]["measured"]


def test_a_wafer_that_holds_no_die_is_refused_naming_the_field(tiny_plan_dir, tmp_path):
    spec = tmp_path / "small.yaml"
    spec.write_text(NO_WAFER + "  wafer: {diameter_mm: 2.0, edge_exclusion_mm: 0.2}\n")
    res = _run("yield", tiny_plan_dir, "--chips", 2, "--spec", spec, "--out", tmp_path / "y")
    assert res.exit_code == 2, res.output
    assert "fabrication.wafer.diameter_mm" in res.output and "Traceback" not in res.output
    assert not (tmp_path / "y").exists()
    spec.write_text(NO_WAFER + "  wafer: {diameter_mm: 10, edge_exclusion_mm: 5}\n")
    res = _run("yield", tiny_plan_dir, "--chips", 2, "--spec", spec, "--out", tmp_path / "y")
    assert res.exit_code == 2 and "edge_exclusion_mm" in res.output, res.output


# ------------------------------------------------------------------ 2. a wafer in batch

def test_a_batch_replan_gives_each_die_the_yields_replan(wafer_yield, wafer_batch):
    """Each die's outcome in the batch (from its measurement) against the yield's (on
    its true models): the re-plan is the study's own, so a die the batch re-planned
    passes exactly when the study's re-plan verified on the measured models; the plan's
    own drive is judged on the measured models here and on the truth there, the one
    place the two may differ."""
    y = json.loads((wafer_yield / "yield.json").read_text())
    per = {c["chip"]: c for c in y["replan"]["per_chip"]}
    batch = _summary(wafer_batch)
    assert set(batch) == {(x["die_x"], x["die_y"]) for x in y["wafer"]["dies"]}
    agree = 0
    for x in y["wafer"]["dies"]:
        b = batch[(x["die_x"], x["die_y"])]
        c = per[x["chip"]]
        if b["outcome"] == "after re-plan":
            assert c["measured_passed"], (x, b)
        elif b["outcome"] != "as designed":
            assert not c["measured_passed"], (x, b)
        agree += b["outcome"] == x["outcome"].replace("fails", "scrapped")
    assert agree >= DIES - 2, f"only {agree} of {DIES} dies agree"
    # each re-planned die's drive files, read back as a plan
    from planner.planfile.reader import read_plan

    for (dx, dy), b in batch.items():
        folder = wafer_batch / b["folder"]
        result = json.loads((folder / "result.json").read_text())
        assert (result["die_x"], result["die_y"], result["outcome"]) == (dx, dy, b["outcome"])
        if b["outcome"] == "after re-plan":
            rec = read_plan(folder / "plan.json")
            assert rec.replanned
            assert any((folder / "waveforms").glob("*.wav"))
            text = (folder / "report.md").read_text()
            heads = [x[3:] for x in text.splitlines() if x.startswith("## ")]
            assert "Timings" not in heads and heads[:2] == ["As-built re-plan",
                                                            "Frequency assignment"]
            assert text.startswith("# vibroplan replan: ") and not text.endswith("\n\n")
    report = (wafer_batch / "report.md").read_text()
    assert "| as designed |" in report and "wafer_map.png" in report
    assert (wafer_batch / "wafer_map.png").read_bytes()[:4] == b"\x89PNG"
    assert not any(wafer_batch.parent.glob(".r1.dies*")), "the work folder is removed"


@pytest.mark.slow
def test_jobs_1_and_2_write_the_same_bytes(tiny_plan_dir, wafer_yield, wafer_batch, tmp_path):
    """~15 s, most of it the two-worker LocalCluster starting."""
    out = tmp_path / "r2"
    res = _run("replan", tiny_plan_dir, "--measured", wafer_yield / "wafer_1.csv", "--trim",
               "--jobs", 2, "--out", out, "--quiet")
    assert res.exit_code in (0, 1), res.output
    assert _tree(out) == _tree(wafer_batch)


def _interrupted(cmd, cwd, ready, polls=60000):
    """Run ``cmd`` in ``cwd``, SIGINT it once ``ready()`` holds (polled every 5 ms; no time
    limit is asserted, a hang guard of ``polls`` polls and 120 s to unwind); returns
    (the finished process, its stderr)."""
    proc = subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        for _ in range(polls):
            if ready() or proc.poll() is not None:
                break
            time.sleep(0.005)
        assert proc.poll() is None, "the batch ended before it could be interrupted"
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    return proc, err


def test_an_interrupted_batch_resumes_without_redoing_finished_dies(tiny_plan_dir, wafer_yield,
                                                                   wafer_batch, tmp_path):
    """SIGINT once three dies are kept: exit 130, no output folder, the dies kept; the
    same command again reads them back and writes what an uninterrupted run writes."""
    out = tmp_path / "r3"
    work = tmp_path / ".r3.dies"
    cmd = [sys.executable, "-m", "planner.cli", "replan", str(tiny_plan_dir), "--measured",
           str(wafer_yield / "wafer_1.csv"), "--trim", "--jobs", "1", "--out", str(out)]
    proc, err = _interrupted(cmd, tmp_path,
                             lambda: len(list(work.glob("die_*/result.json"))) >= 3)
    assert proc.returncode == 130, err
    kept = sorted(p.parent.name for p in work.glob("die_*/result.json"))
    assert len(kept) >= 3 and "run the same command again to resume" in err
    assert not out.exists()
    # a mark in one kept die's result: read back, it reaches the output; redone, it would not
    probe = work / kept[0] / "result.json"
    probe.write_text(json.dumps({**json.loads(probe.read_text()), "kept": True}))
    again = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True)
    assert again.returncode in (0, 1), again.stderr
    assert f"resuming: {len(kept)} of {DIES} dies already re-planned" in again.stderr
    assert not work.exists()
    got, want = _tree(out), _tree(wafer_batch)
    marked = f"dies/{kept[0]}/result.json"
    assert json.loads(got.pop(marked))["kept"] is True
    want.pop(marked)
    for tree in (got, want):
        tree.pop(".vibroplan-output")       # it lists the files' digests
    assert got == want


def test_a_folder_of_measured_csv_files_is_the_same_wafer(tiny_plan_dir, wafer_yield,
                                                          wafer_batch, tmp_path):
    rows = list(csv.reader((wafer_yield / "wafer_1.csv").open()))
    header, rows = rows[0], rows[1:]
    folder = tmp_path / "dies"
    folder.mkdir()
    by_die = {}
    for r in rows:
        by_die.setdefault((r[0], r[1]), []).append(r[2:])
    for (x, y), rs in by_die.items():
        with (folder / f"die_{x}_{y}.csv").open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(header[2:])
            w.writerows(rs)
    out = tmp_path / "rd"
    res = _run("replan", tiny_plan_dir, "--measured-dir", folder, "--trim", "--jobs", 1, "--out",
               out, "--quiet")
    assert res.exit_code in (0, 1), res.output
    # the same dies, outcomes and drive files (the summary lists them in file order)
    assert _summary(out) == _summary(wafer_batch)
    tree = {k: v for k, v in _tree(out).items() if k.startswith("dies/")}
    assert tree == {k: v for k, v in _tree(wafer_batch).items() if k.startswith("dies/")}
    (folder / "notes.csv").write_text("x\n")
    res = _run("replan", tiny_plan_dir, "--measured-dir", folder, "--out", tmp_path / "rx")
    assert res.exit_code == 2 and "notes.csv" in res.output and "die_<x>_<y>.csv" in res.output


@pytest.mark.parametrize("edit, needle", [
    (lambda t: t.replace("\n0,", "\nzero,", 1), "column die_x: 'zero' is not a die index"),
    (lambda t: t.replace("A2.backward", "A9.backward", 1), "unknown impacter 'A9.backward'"),
    (lambda t: t + t.splitlines()[1] + "\n", "measured twice"),
    (lambda t: t.replace("die_y,", "die_z,", 1), "column die_z: unknown column"),
])
def test_a_bad_wafer_file_is_one_line_exit_2_and_nothing_written(tiny_plan_dir, wafer_yield,
                                                                 tmp_path, edit, needle):
    bad = tmp_path / "bad.csv"
    bad.write_text(edit((wafer_yield / "wafer_1.csv").read_text()))
    out = tmp_path / "r"
    res = _run("replan", tiny_plan_dir, "--measured", bad, "--out", out)
    assert res.exit_code == 2, res.output
    assert needle in res.output and "Traceback" not in res.output
    assert len(res.output.strip().splitlines()) == 1, res.output
    assert not out.exists() and not (tmp_path / ".r.dies").exists()


def test_wafer_options_need_a_wafer(tiny_plan_dir, tmp_path):
    measured = tmp_path / "m.csv"
    measured.write_text("impacter,natural_frequency_hz\nA1.forward,6000\n")
    for flag in (["--jobs", "2"], ["--trim"]):
        res = _run("replan", tiny_plan_dir, "--measured", measured, "--out", tmp_path / "o", *flag)
        assert res.exit_code == 2 and flag[0] in res.output and "wafer" in res.output
    res = _run("replan", tiny_plan_dir, "--out", tmp_path / "o")
    assert res.exit_code == 2 and "--measured" in res.output


# ------------------------------------------------------------------ 3. tester files

def test_stdf_round_trips_through_pystdf(tmp_path):
    """A wafer written as STDF V4 by vibroplan's writer, read back by pystdf: every die's
    coordinates and every parametric result (4-byte floats), halves by their test names."""
    from pystdf import V4
    from pystdf.IO import Parser

    from planner.afterfab.stdf import read_stdf, write_stdf

    dies = [(0, 0, {"A1.forward": 6012.345678, "A2.backward": 11234.5}),
            (-3, 2, {"A1.forward": 5999.0, "A2.backward:a": 11000.25,
                     "A2.backward:b": 11010.75, "continuity": 1.0})]
    path = tmp_path / "w.stdf"
    write_stdf(path, dies, wafer_id="W7")
    seen = []

    class Sink:
        def after_send(self, _source, data):
            seen.append(data)

    with path.open("rb") as fh:
        p = Parser(inp=fh)
        p.addSink(Sink())
        p.parse()
    kinds = [type(t).__name__ for t, _ in seen]
    assert kinds == ["Far", "Mir", "Wir", "Pir", "Ptr", "Ptr", "Prr", "Pir", "Ptr", "Ptr", "Ptr",
                     "Ptr", "Prr", "Wrr", "Mrr"]
    ptrs = [dict(zip(t.fieldNames, f)) for t, f in seen if isinstance(t, V4.Ptr)]
    want = [v for _, _, tests in dies for v in tests.values()]
    assert [r["RESULT"] for r in ptrs] == [float(np.float32(v)) for v in want]
    prrs = [dict(zip(t.fieldNames, f)) for t, f in seen if isinstance(t, V4.Prr)]
    assert [(r["X_COORD"], r["Y_COORD"]) for r in prrs] == [(0, 0), (-3, 2)]
    got = read_stdf(path, ["A1.forward", "A2.backward"])
    assert [(x, y) for x, y, _ in got] == [(0, 0), (-3, 2)]
    assert [(imp, half) for _, imp, _, half in got[1][2]] == [
        ("A1.forward", ""), ("A2.backward", "a"), ("A2.backward", "b")]
    assert float(got[1][2][1][2]) == 11000.25


def test_the_yields_stdf_wafer_replans_as_its_csv(tiny_plan_dir, wafer_yield, wafer_batch,
                                                  tmp_path):
    from planner.afterfab.wafer_file import read_wafer
    from planner.planfile.reader import read_plan

    plan = read_plan(tiny_plan_dir)
    a = read_wafer(wafer_yield / "wafer_1.csv", plan.impacter_ids)
    b = read_wafer(wafer_yield / "wafer_1.stdf", plan.impacter_ids)
    assert [(x, y) for x, y, _ in a] == [(x, y) for x, y, _ in b]
    for (_, _, ma), (_, _, mb) in zip(a, b):
        for n in ma:
            assert mb[n].natural_frequency_hz == pytest.approx(ma[n].natural_frequency_hz,
                                                               rel=1e-7)
    out = tmp_path / "rs"
    res = _run("replan", tiny_plan_dir, "--measured", wafer_yield / "wafer_1.stdf", "--trim",
               "--jobs", 1, "--out", out, "--quiet")
    assert res.exit_code in (0, 1), res.output
    assert {k: v["outcome"] for k, v in _summary(out).items()} == \
        {k: v["outcome"] for k, v in _summary(wafer_batch).items()}


def test_a_test_map_names_the_testers_tests(tiny_plan_dir, tmp_path):
    from planner.afterfab.stdf import write_stdf

    path = tmp_path / "t.stdf"
    write_stdf(path, [(0, 0, {"F0 res": 6000.0, "B1 res": 11000.0, "idd": 0.1})])
    res = _run("replan", tiny_plan_dir, "--measured", path, "--out", tmp_path / "a")
    assert res.exit_code == 2 and "none of its tests names an impacter" in res.output
    assert "record 8 (PRR)" in res.output
    tmap = tmp_path / "map.csv"
    tmap.write_text("test_name,impacter\nF0 res,A1.forward\nB1 res,A2.backward\n")
    res = _run("replan", tiny_plan_dir, "--measured", path, "--test-map", tmap, "--jobs", 1,
               "--out", tmp_path / "b", "--quiet")
    assert res.exit_code in (0, 1), res.output
    assert set(_summary(tmp_path / "b")) == {(0, 0)}
    tmap.write_text("test_name,impacter\nF0 res,A7.forward\n")
    res = _run("replan", tiny_plan_dir, "--measured", path, "--test-map", tmap, "--out",
               tmp_path / "c")
    assert res.exit_code == 2 and "row 2, column impacter" in res.output


@pytest.mark.parametrize("damage, needle", [
    (lambda b: b[:-9], "the file is cut short: record 9"),
    (lambda b: b[:-11], "without its MRR: truncated?"),
    (lambda b: b[:70], "cut short inside record 5 (PTR)"),
    (lambda b: b[:57], "ends inside a part"),
    (lambda b: b.replace(b"\x02Hz", b"\x02kV"), "UNITS 'kV'"),
    (lambda b: b"\x02\x00\x00\x0a\x02\x03" + b[6:], "not an STDF V4 file"),
])
def test_a_damaged_stdf_file_is_exit_2_naming_the_record(tiny_plan_dir, tmp_path, damage,
                                                         needle):
    from planner.afterfab.stdf import write_stdf

    path = tmp_path / "t.stdf"
    write_stdf(path, [(0, 0, {"A1.forward": 6000.0, "A2.backward": 11000.0})])
    path.write_bytes(damage(path.read_bytes()))
    res = _run("replan", tiny_plan_dir, "--measured", path, "--out", tmp_path / "o")
    assert res.exit_code == 2, res.output
    assert needle in res.output and "Traceback" not in res.output


# ------------------------------------------------------------------ 4. placement

INDEPENDENT = """\
name: nine
array: {rows: 3, cols: 3, pitch_um: 2000}
drive:
  band_hz: [4000, 40000]
  channels: {count: 400, placement: %s}
  guard: {separation_channels: 6}
"""


def _assignment(placement):
    from planner.assignment.assign import assign, plan_steps
    from planner.planning.settings import resolve_settings
    from planner.arrayspec import load_spec

    loaded = load_spec(INDEPENDENT % placement)
    settings = resolve_settings(loaded, 0)
    return assign(settings, plan_steps(loaded, settings.single_step_s))


def test_neighbours_put_tone_neighbours_on_neighbouring_devices():
    from planner.assignment.assign import verify_assignment
    from planner.core.nodes import device_key

    def steps_between_neighbours(a):
        order = sorted(a.frequencies, key=lambda n: a.frequencies[n])
        out = []
        for u, v in zip(order, order[1:]):
            (ru, cu), (rv, cv) = device_key(u.device), device_key(v.device)
            out.append(abs(ord(ru) - ord(rv)) + abs(cu - cv))
        return out

    today, near = _assignment("coloring"), _assignment("neighbours")
    assert verify_assignment(near) == [] and near.span == today.span
    assert sorted(near.channels.values()) == sorted(today.channels.values())
    # within each direction's run of tones, every tone neighbour is a grid neighbour
    for a, worst in ((near, 1), (today, None)):
        for direction in ("forward", "backward"):
            mine = {n: f for n, f in a.frequencies.items() if n.direction == direction}
            order = sorted(mine, key=mine.get)
            gaps = [abs(ord(device_key(u.device)[0]) - ord(device_key(v.device)[0]))
                    + abs(device_key(u.device)[1] - device_key(v.device)[1])
                    for u, v in zip(order, order[1:])]
            if worst is not None:
                assert max(gaps) == worst, (direction, order)
    assert max(steps_between_neighbours(today)) > max(steps_between_neighbours(near))


def test_the_gradient_costs_far_tone_neighbours_yield():
    """The prediction with a within-die gradient: two colliding-prone impacters far
    apart on the die collide more often than the same two side by side; without a
    gradient nothing changes (the same number, bit for bit)."""
    from planner.manufacturability import collision_free_yield

    kw = dict(ids=["a", "b"], nu=[10000.0, 10400.0], tone=[10000.0, 10400.0],
              sens=[[0.24, 0, 0, 0, 0]] * 2, sigma_die=[0.05, 0, 0, 0, 0],
              sigma_device=[0.02, 0, 0, 0, 0], pairs=[[0, 1]], silent_below=[300, 300],
              silent_above=[300, 300], chips=20000, seed=1)
    base = collision_free_yield(**kw)
    same = collision_free_yield(**kw, sigma_gradient=0.0, positions=[[0, 0], [0.008, 0]])
    assert same == base
    near = collision_free_yield(**kw, sigma_gradient=5.0, positions=[[0, 0], [0.002, 0]])
    far = collision_free_yield(**kw, sigma_gradient=5.0, positions=[[0, 0], [0.008, 0]])
    assert far.value < near.value - 0.01
    assert near.value <= base.value + 0.005


# ------------------------------------------------------------------ issue 44: the work folder

def _die_file(folder: Path, x: int, y: int, a1_hz: float, a2_hz: float) -> Path:
    p = folder / f"die_{x}_{y}.csv"
    p.write_text(f"impacter,natural_frequency_hz\nA1.forward,{a1_hz}\nA2.backward,{a2_hz}\n")
    return p


def _a1_of(die_folder: Path) -> float:
    plan = json.loads((die_folder / "plan.json").read_text())
    return {i["id"]: i["natural_frequency_hz"] for i in plan["impacters"]}["A1.forward"]


# slow (~6 s): a second interrupted batch; test_an_interrupted_batch_resumes_... keeps the
# resume in the default run
@pytest.mark.slow
def test_a_resume_reuses_a_die_only_for_its_own_measurement(tiny_plan_dir, tmp_path):
    """Issue 44 case 1: interrupted once die_0_5 is kept, the files then renamed
    (die_0_5.csv -> die_0_6.csv, die_0_4.csv -> die_0_5.csv: the files' bytes in name
    order are unchanged, so a batch-wide key matched and the kept die_0_5 was read back
    for a file that now measures another chip).  Every die's re-plan must be of its own
    file's resonances."""
    folder = tmp_path / "m"
    folder.mkdir()
    # three dies that all need a re-plan, each with its own A1 (read back from plan.json)
    _die_file(folder, 0, 5, 4700.0, 12650.0)
    _die_file(folder, 0, 4, 4620.5, 12500.0)
    _die_file(folder, 0, 3, 4650.0, 12550.0)
    work = tmp_path / ".r.dies"
    cmd = [sys.executable, "-m", "planner.cli", "replan", str(tiny_plan_dir), "--measured-dir",
           str(folder), "--jobs", "1", "--out", "r"]
    proc, err = _interrupted(cmd, tmp_path,
                             lambda: (work / "die_0_5" / "result.json").is_file())
    assert proc.returncode == 130, err
    assert (work / "die_0_5" / "result.json").is_file()
    os.rename(folder / "die_0_5.csv", folder / "die_0_6.csv")
    os.rename(folder / "die_0_4.csv", folder / "die_0_5.csv")
    again = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr
    out = tmp_path / "r"
    assert _summary(out).keys() == {(0, 6), (0, 5), (0, 3)}
    for name, a1 in (("die_0_6", 4700.0), ("die_0_5", 4620.5), ("die_0_3", 4650.0)):
        assert _a1_of(out / "dies" / name) == a1, name
    assert not work.exists()


@pytest.mark.parametrize("case", ["measured-dir", "user folder", "user file"])
def test_a_work_folder_vibroplan_did_not_write_is_refused_not_removed(tiny_plan_dir, tmp_path,
                                                                      case):
    """Issue 44 case 2: `--measured-dir .r5b.dies --out r5b` removed the measurements;
    a user's `.OUT.dies/` was emptied.  Both are refused (exit 2, naming it), untouched."""
    name = "r5b"
    work = tmp_path / f".{name}.dies"
    if case == "measured-dir":
        work.mkdir()
        _die_file(work, 0, 5, 4700.0, 12650.0)
        src = ["--measured-dir", work]
    else:
        folder = tmp_path / "m"
        folder.mkdir()
        _die_file(folder, 0, 5, 4700.0, 12650.0)
        src = ["--measured-dir", folder]
        if case == "user folder":
            work.mkdir()
            (work / "notes.txt").write_text("mine\n")
        else:
            work.write_text("mine\n")
    before = _tree(work) if work.is_dir() else work.read_bytes()
    res = _run("replan", tiny_plan_dir, *src, "--jobs", 1, "--out", tmp_path / name)
    assert res.exit_code == 2, res.output
    assert str(work) in res.output and "Traceback" not in res.output
    assert (_tree(work) if work.is_dir() else work.read_bytes()) == before
    assert not (tmp_path / name).exists()
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(f".{name}")) == [
        work.name]
