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
