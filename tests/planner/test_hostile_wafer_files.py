"""Issue 44, hostile cases 4, 5 and 7: what a wafer's files, an STDF file, a wafer spec
and the flags of ``replan``, ``yield`` and ``calibrate`` may not get away with.

Every test runs the real command on the tiny 1 x 2 plan (real designer, solver and
verification), writes its input files and reads the outputs back.
"""

from __future__ import annotations

import csv
import struct
from pathlib import Path

import pytest
from click.testing import CliRunner

from planner.cli import main

#: The tiny plan's impacters at a resonance the plan's drive does not survive on
#: A2.backward (designed 12863 Hz): a fully measured die is re-planned.
SHIFTED = {"A1.forward": 4444.48, "A2.backward": 12700.0}


def _run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def _summary(folder: Path) -> dict:
    return {(int(r["die_x"]), int(r["die_y"])): r
            for r in csv.DictReader((folder / "summary.csv").open())}


def _refused(res, *needles):
    """Exit 2, every needle in the one-line message, no traceback."""
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output, res.output
    for n in needles:
        assert n in res.output, res.output


# ------------------------------------------------------------------ 4. a die not measured whole

def test_a_die_with_an_impacter_missing_is_said_and_not_counted_as_designed(tiny_plan_dir,
                                                                            tmp_path):
    """Die (1, 0) is die (0, 0) without its A2.backward row: its twin is re-planned, it
    must not pass for 'as designed' on A2.backward's design value unsaid."""
    wafer = tmp_path / "w.csv"
    wafer.write_text("die_x,die_y,impacter,natural_frequency_hz\n"
                     + "".join(f"0,0,{n},{v}\n" for n, v in SHIFTED.items())
                     + f"1,0,A1.forward,{SHIFTED['A1.forward']}\n")
    out = tmp_path / "r"
    res = _run("replan", tiny_plan_dir, "--measured", wafer, "--jobs", 1, "--out", out,
               "--quiet")
    assert res.exit_code == 0, res.output
    assert ("warning: die (1, 0): not measured, taken as designed: A2.backward"
            in res.output)
    rows = _summary(out)
    assert rows[(0, 0)]["outcome"] == "after re-plan"
    assert rows[(1, 0)]["outcome"] == "partly measured"
    assert rows[(1, 0)]["causes"].startswith("not measured, taken as designed: A2.backward")
    report = (out / "report.md").read_text()
    assert "## Dies not measured whole" in report
    assert "| (1, 0) | A2.backward | partly measured |" in report
    assert "| as designed | 0 |" in report and "| partly measured | 1 |" in report
    assert "partly measured 1" in res.output


def test_an_stdf_die_with_a_test_missing_is_said_too(tiny_plan_dir, tmp_path):
    from planner.afterfab.stdf import write_stdf

    path = tmp_path / "w.stdf"
    write_stdf(path, [(0, 0, dict(SHIFTED)),
                      (1, 0, {"A1.forward": SHIFTED["A1.forward"]})])
    out = tmp_path / "r"
    res = _run("replan", tiny_plan_dir, "--measured", path, "--jobs", 1, "--out", out,
               "--quiet")
    assert res.exit_code == 0, res.output
    assert "die (1, 0): not measured, taken as designed: A2.backward" in res.output
    assert {k: r["outcome"] for k, r in _summary(out).items()} == {
        (0, 0): "after re-plan", (1, 0): "partly measured"}


# ------------------------------------------------------------------ 5. STDF flags and records

def _records(raw: bytes):
    """(offset, REC_TYP, REC_SUB, REC_LEN) of each record of a little-endian STDF file."""
    at, out = 0, []
    while at < len(raw):
        (length,) = struct.unpack("<H", raw[at:at + 2])
        out.append((at, raw[at + 2], raw[at + 3], length))
        at += 4 + length
    return out


def _flag_ptr(raw: bytes, index: int, flags: int) -> bytes:
    """``raw`` with the TEST_FLG of its ``index``-th PTR (0-based) set to ``flags``."""
    ptrs = [at for at, typ, sub, _ in _records(raw) if (typ, sub) == (15, 10)]
    at = ptrs[index] + 4 + 6        # header, TEST_NUM (4), HEAD_NUM, SITE_NUM
    return raw[:at] + bytes([flags]) + raw[at + 1:]


@pytest.mark.parametrize("flag, word", [(0x10, "not executed"), (0x04, "unreliable"),
                                        (0x20, "aborted")])
def test_a_ptr_flagged_not_to_be_used_is_skipped_naming_die_and_test(tiny_plan_dir,
                                                                     tmp_path, flag, word):
    """Die (1, 0)'s A2.backward PTR carries a flag saying its RESULT is no measurement
    (a value far from the die's 12700 Hz): skipped with a note naming the die, the
    test and the record, and the die counted 'partly measured'."""
    from planner.afterfab.stdf import write_stdf

    path = tmp_path / "w.stdf"
    write_stdf(path, [(0, 0, dict(SHIFTED)),
                      (1, 0, {"A1.forward": SHIFTED["A1.forward"], "A2.backward": 9000.0})])
    path.write_bytes(_flag_ptr(path.read_bytes(), 3, flag))
    out = tmp_path / "r"
    res = _run("replan", tiny_plan_dir, "--measured", path, "--jobs", 1, "--out", out,
               "--quiet")
    assert res.exit_code == 0, res.output
    assert (f"warning: die (1, 0): record 10 (PTR): test 'A2.backward' {word} "
            f"(TEST_FLG 0x{flag:02x}): skipped") in res.output
    assert _summary(out)[(1, 0)]["outcome"] == "partly measured"


def test_a_die_whose_every_test_is_flagged_is_refused_naming_the_record(tiny_plan_dir,
                                                                        tmp_path):
    from planner.afterfab.stdf import write_stdf

    path = tmp_path / "w.stdf"
    write_stdf(path, [(0, 0, {"A1.forward": 4444.0})])
    path.write_bytes(_flag_ptr(path.read_bytes(), 0, 0x10))
    out = tmp_path / "r"
    res = _run("replan", tiny_plan_dir, "--measured", path, "--out", out)
    _refused(res, "record 6 (PRR)", "die (0, 0): every test naming an impacter is flagged",
             "not executed")
    assert not out.exists()


def test_a_part_without_its_prr_is_refused_naming_the_records(tiny_plan_dir, tmp_path):
    """PIR, PTRs, PIR: the first part's die is unknown (STDF gives it in the PRR only);
    it is refused, not dropped."""
    from planner.afterfab.stdf import write_stdf

    path = tmp_path / "w.stdf"
    write_stdf(path, [(0, 0, dict(SHIFTED)), (1, 0, dict(SHIFTED))])
    raw = path.read_bytes()
    first_prr = [(at, n) for at, typ, sub, n in _records(raw) if (typ, sub) == (5, 20)][0]
    at, n = first_prr
    path.write_bytes(raw[:at] + raw[at + 4 + n:])
    out = tmp_path / "r"
    res = _run("replan", tiny_plan_dir, "--measured", path, "--out", out)
    _refused(res, "record 7 (PIR)", "part begun at record 4 (PIR) has no PRR")
    assert not out.exists() and not (tmp_path / ".r.dies").exists()


@pytest.mark.parametrize("cut", [3, 12, 20])
def test_a_file_cut_inside_its_first_prr_says_cut_short(tiny_plan_dir, tmp_path, cut):
    from planner.afterfab.stdf import write_stdf

    path = tmp_path / "w.stdf"
    write_stdf(path, [(0, 0, dict(SHIFTED)), (1, 0, dict(SHIFTED))])
    raw = path.read_bytes()
    at = [at for at, typ, sub, _ in _records(raw) if (typ, sub) == (5, 20)][0]
    path.write_bytes(raw[:at + cut])
    res = _run("replan", tiny_plan_dir, "--measured", path, "--out", tmp_path / "r")
    _refused(res, "cut short", "record 7")
    assert "X_COORD" not in res.output


# ------------------------------------------------------------------ 7. the smaller list

def _wafer_spec(tmp_path, wafer: str) -> Path:
    """A --spec whose fabrication: has the tiny plan's tolerances and ``wafer``."""
    spec = tmp_path / "fab.yaml"
    spec.write_text("fabrication:\n"
                    "  natural_frequency_pct: {die: 4, device: 2}\n"
                    "  line_width_um: {die: 0.02, device: 0.01}\n"
                    "  wafer:\n" + "".join(f"    {line}\n" for line in wafer.splitlines()))
    return spec


@pytest.mark.parametrize("order", [(0, 1, 2, 3), (3, 2, 1, 0)])
def test_calibrate_motion_refuses_one_tone_given_twice_in_any_order(tmp_path, order):
    rows = ["A1.forward,5000,0.2", "A1.forward,5050,0.5", "A1.forward,5050,0.4",
            "A1.forward,5100,0.1"]
    sweep = tmp_path / "motion.csv"
    sweep.write_text("impacter,frequency_hz,speed_mm_s\n"
                     + "".join(rows[k] + "\n" for k in order))
    out = tmp_path / "windows.csv"
    res = _run("calibrate", "--motion", sweep, "--out", out)
    lines = sorted(2 + order.index(k) for k in (1, 2))
    _refused(res, f"row {lines[1]}, column frequency_hz", "A1.forward at 5050 Hz given twice",
             f"rows {lines[0]} and {lines[1]}")
    assert not out.exists()


def test_a_correlation_length_below_the_bound_is_refused_naming_key_and_line(tiny_plan_dir,
                                                                            tmp_path):
    spec = _wafer_spec(tmp_path, "diameter_mm: 12\nedge_exclusion_mm: 0.5\n"
                                 "line_width_field: {sigma_um: 0.05, "
                                 "correlation_length_mm: 1e-300}")
    out = tmp_path / "y"
    res = _run("yield", tiny_plan_dir, "--chips", 2, "--spec", spec, "--out", out, "--quiet")
    _refused(res, "fabrication.wafer.line_width_field.correlation_length_mm", "line 7",
             "at least 0.01 mm")
    assert not out.exists()


def test_a_wafer_of_a_million_mm_is_refused_by_its_die_count(tiny_plan_dir, tmp_path):
    spec = _wafer_spec(tmp_path, "diameter_mm: 1e6")
    out = tmp_path / "y"
    res = _run("yield", tiny_plan_dir, "--chips", 2, "--spec", spec, "--out", out, "--quiet")
    _refused(res, "fabrication.wafer.diameter_mm: 1e+06 mm holds more than",
             "at most 4000 are supported")
    assert not out.exists()


def test_a_die_smaller_than_its_array_is_refused_naming_the_key(tiny_plan_dir, tmp_path):
    """The tiny plan's 1 x 2 array at a pitch of 1000 um takes 2 x 1 mm."""
    spec = _wafer_spec(tmp_path, "diameter_mm: 12\nedge_exclusion_mm: 0.5\n"
                                 "die_size_mm: [1.5, 1.0]")
    out = tmp_path / "y"
    res = _run("yield", tiny_plan_dir, "--chips", 2, "--spec", spec, "--out", out, "--quiet")
    _refused(res, "fabrication.wafer.die_size_mm: [1.5, 1.0] mm cannot hold the 1 x 2 array",
             "(2 x 1 mm)")
    assert not out.exists()


def test_a_measurement_noise_beyond_a_lab_is_refused_before_any_work(tiny_plan_dir, tmp_path):
    out = tmp_path / "y"
    res = _run("yield", tiny_plan_dir, "--chips", 2, "--replan", "--measure-noise", "1e6",
               "--out", out, "--quiet")
    _refused(res, "--measure-noise: 1e+06 % is beyond what a lab measures: at most 60 %")
    assert not out.exists()


def test_a_noise_bound_by_nyquist_names_the_sample_rate():
    """A band whose top lies near the Nyquist frequency bounds the noise by it."""
    from planner.arrayspec import ArraySpec
    from planner.yield_.inputs import check_measure_noise

    drive = ArraySpec.model_validate({"drive": {"band_hz": [5000, 40000],
                                                "sample_rate_hz": 100000}}).drive
    assert check_measure_noise(4.9, drive) == 4.9
    with pytest.raises(ValueError, match=r"at most 5 % .*Nyquist frequency 50000 Hz"):
        check_measure_noise(5.1, drive)


def test_a_wafer_csv_over_the_input_limit_is_said_so_not_taken_for_one_chip(tiny_plan_dir,
                                                                           tmp_path):
    from planner.runtime.limits import MAX_INPUT_BYTES

    big = tmp_path / "w.csv"
    row = "0,0,A1.forward,4444.48\n"
    with big.open("w") as fh:
        fh.write("die_x,die_y,impacter,natural_frequency_hz\n")
        fh.write(row * (MAX_INPUT_BYTES // len(row) + 2))
    assert big.stat().st_size > MAX_INPUT_BYTES
    out = tmp_path / "r"
    res = _run("replan", tiny_plan_dir, "--measured", big, "--jobs", 1, "--out", out)
    assert res.exit_code == 2, res.output
    assert "applies to a wafer" not in res.output and "w.csv" in res.output
    assert "MiB an input may have" in res.output
    assert not out.exists()


def test_options_of_another_option_are_refused_naming_both(tiny_plan_dir, tmp_path):
    wafer = tmp_path / "w.csv"
    wafer.write_text("die_x,die_y,impacter,natural_frequency_hz\n0,0,A1.forward,4444\n")
    chip = tmp_path / "m.csv"
    chip.write_text("impacter,natural_frequency_hz\nA1.forward,4444\n")
    folder = tmp_path / "dies"
    folder.mkdir()
    (folder / "die_0_0.csv").write_text(chip.read_text())
    tmap = tmp_path / "map.csv"
    tmap.write_text("test_name,impacter\nF0,A1.forward\n")
    for given in (["--measured", wafer], ["--measured", chip], ["--measured-dir", folder]):
        res = _run("replan", tiny_plan_dir, *given, "--test-map", tmap, "--out",
                   tmp_path / "o")
        _refused(res, "--test-map needs --measured with a tester's STDF file")
    for flag, value in (("--tune-tones", "9"), ("--tune-noise", "2")):
        res = _run("yield", tiny_plan_dir, "--chips", 2, "--replan", flag, value, "--out",
                   tmp_path / "y")
        _refused(res, f"{flag} needs --tune")
    assert not (tmp_path / "o").exists() and not (tmp_path / "y").exists()


@pytest.mark.parametrize("index", ["1_0", "\u0661", "+ 1", "1.0"])
def test_a_die_index_is_ascii_digits_only(tiny_plan_dir, tmp_path, index):
    wafer = tmp_path / "w.csv"
    wafer.write_text("die_x,die_y,impacter,natural_frequency_hz\n"
                     f"{index},0,A1.forward,4444.48\n", encoding="utf-8")
    out = tmp_path / "r"
    res = _run("replan", tiny_plan_dir, "--measured", wafer, "--out", out)
    _refused(res, "row 2, column die_x", "is not a die index")
    assert not out.exists()


@pytest.mark.parametrize("twin", ["die_-0_3.csv", "die_00_3.csv"])
def test_two_files_naming_one_die_are_refused_up_front(tiny_plan_dir, tmp_path, twin):
    folder = tmp_path / "dies"
    folder.mkdir()
    for name in ("die_0_3.csv", twin, "die_1_3.csv"):
        (folder / name).write_text("impacter,natural_frequency_hz\nA1.forward,4444.48\n")
    (folder / "die_\u0661_3.csv").write_text("x\n")
    out = tmp_path / "r"
    res = _run("replan", tiny_plan_dir, "--measured-dir", folder, "--out", out)
    _refused(res, "die_\u0661_3.csv: a die's measured.csv is named die_<x>_<y>.csv")
    (folder / "die_\u0661_3.csv").unlink()
    res = _run("replan", tiny_plan_dir, "--measured-dir", folder, "--out", out)
    _refused(res, "both name die (0, 3)", twin, "die_0_3.csv")
    assert "die 1/" not in res.output
    assert not out.exists() and not (tmp_path / ".r.dies").exists()


def test_a_window_nearer_another_impacters_tone_is_blamed_on_its_row(tiny_plan_dir,
                                                                     tmp_path):
    """The tiny plan's tones: A1.forward 5088 Hz, A2.backward 13520 Hz; a window at
    9000-9500 Hz is within a factor 2 of A1.forward's tone but nearer A2.backward's."""
    measured = tmp_path / "m.csv"
    measured.write_text("impacter,natural_frequency_hz\n"
                        + "".join(f"{n},{v}\n" for n, v in SHIFTED.items()))
    windows = tmp_path / "windows.csv"
    windows.write_text("impacter,window_lo_hz,window_hi_hz\n"
                       "A2.backward,13300,13500\nA1.forward,9000,9500\n")
    out = tmp_path / "r"
    res = _run("replan", tiny_plan_dir, "--measured", measured, "--windows", windows,
               "--out", out)
    _refused(res, "windows.csv: row 3, column impacter",
             "the window 9000-9500 Hz given for A1.forward lies nearer A2.backward's tone")
    assert "trim one of them" not in res.output and not out.exists()


def test_several_sigma_scales_say_which_the_wafer_holds(tiny_plan_dir, tmp_path):
    import json

    spec = _wafer_spec(tmp_path, "diameter_mm: 12\nedge_exclusion_mm: 0.5")
    out = tmp_path / "y"
    res = _run("yield", tiny_plan_dir, "--chips", 3, "--spec", spec, "--sigma-scale", "0.5,2",
               "--out", out, "--quiet")
    assert res.exit_code in (0, 1), res.output
    data = json.loads((out / "yield.json").read_text())
    assert data["wafer"]["sigma_scale"] == data["sigma_scale"] == 0.5
    for key in ("0.5", "2"):
        got = data["by_sigma_scale"][key]["wafer_outcomes"]
        assert sum(got.values()) == 3
    assert "are the dies of sigma scale 0.5" in res.output
    report = (out / "report.md").read_text()
    assert "dies of sigma scale 0.5 (the headline's); every scale's outcomes" in report
