"""The CLI never destroys a user's files, stops cleanly on signals, exits honestly.

Real CLI runs (subprocesses where signals or process trees matter, click's runner
elsewhere) on real folders; nothing is mocked.
"""

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from click.testing import CliRunner

from planner.files import MARKER, check_output_folder, output_folder
from planner.cli import main
from planner.core.errors import OutputError
from tests.planner.test_pipeline import TINY  # the 1 x 2 spec every plan test uses

CONFIGS = Path(__file__).resolve().parents[2] / "configs"



def _snapshot(folder):
    return sorted((str(p.relative_to(folder)), p.read_bytes() if p.is_file() else None)
                  for p in folder.rglob("*"))


def _run(args, cwd):
    """The real CLI in a subprocess (an installed `vibroplan` or `python -m planner.cli`)."""
    return subprocess.run([sys.executable, "-m", "planner.cli", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=600)


# ----------------------------------------------------------------------------------
# output folders


def test_out_dot_refused_and_nothing_touched(tmp_path):
    """The data-loss case: `--out .` in a folder holding the spec, a file and a folder."""
    (tmp_path / "spec.yaml").write_text(TINY)
    (tmp_path / "notes.txt").write_text("my notes")
    (tmp_path / "lab").mkdir()
    (tmp_path / "lab" / "data.csv").write_text("1,2\n")
    before = _snapshot(tmp_path)
    proc = _run(["plan", "spec.yaml", "--out", "."], tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert "current directory" in proc.stderr and "Traceback" not in proc.stderr
    assert _snapshot(tmp_path) == before
    # --force does not unlock the current directory either
    proc = _run(["plan", "spec.yaml", "--out", ".", "--force"], tmp_path)
    assert proc.returncode == 2 and _snapshot(tmp_path) == before


@pytest.mark.parametrize("out, why", [("..", "ancestors"), ("specs", "holds the input"),
                                      ("lab", "not written by vibroplan"),
                                      ("notes.txt", "is a file"),
                                      ("missing/plan_out", "does not exist")])
def test_refused_output_folders_exit_2_before_any_work(tmp_path, out, why):
    work = tmp_path / "work"
    (work / "specs").mkdir(parents=True)
    (work / "specs" / "tiny.yaml").write_text(TINY)
    (work / "lab").mkdir()
    (work / "lab" / "data.csv").write_text("1,2\n")
    (work / "notes.txt").write_text("my notes")
    before = _snapshot(tmp_path)
    proc = _run(["plan", "specs/tiny.yaml", "--out", out, "--quiet"], work)
    assert proc.returncode == 2, proc.stderr
    assert why in proc.stderr and "Traceback" not in proc.stderr
    assert "design" not in proc.stderr  # refused before any stage started
    assert _snapshot(tmp_path) == before


def test_output_folder_swaps_in_and_replaces_only_its_own(tmp_path):
    out = tmp_path / "plan_out"
    with output_folder(out) as tmp:
        (tmp / "a.txt").write_text("first")
    assert (out / "a.txt").read_text() == "first"
    marker = json.loads((out / MARKER).read_text())
    assert marker["written_by"] == "vibroplan" and marker["command"] == "plan"
    assert set(marker["files"]) == {"a.txt"}
    assert oct(out.stat().st_mode & 0o777) != oct(0o700)  # not mkdtemp's private mode
    # a folder vibroplan wrote, holding only its own files, is replaced whole, atomically
    with output_folder(out) as tmp:
        (tmp / "b.txt").write_text("second")
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "b.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["plan_out"]  # no temporaries, no lock
    # a user's file added to it is never deleted silently: refused, or replaced on --force
    (out / "user-note.txt").write_text("mine")
    with pytest.raises(OutputError, match="user-note.txt"), output_folder(out):
        pass
    assert (out / "user-note.txt").read_text() == "mine"
    with output_folder(out, force=True) as tmp:
        (tmp / "c.txt").write_text("third")
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "c.txt"]


def test_output_folder_failure_leaves_target_untouched(tmp_path):
    out = tmp_path / "plan_out"
    with output_folder(out) as tmp:
        (tmp / "a.txt").write_text("good")
    with pytest.raises(RuntimeError), output_folder(out) as tmp:
        (tmp / "a.txt").write_text("half")
        raise RuntimeError("the plan failed half-way")
    assert (out / "a.txt").read_text() == "good"
    assert [p.name for p in tmp_path.iterdir()] == ["plan_out"]
    with pytest.raises(KeyboardInterrupt), output_folder(out) as tmp:
        raise KeyboardInterrupt
    assert (out / "a.txt").read_text() == "good"
    assert [p.name for p in tmp_path.iterdir()] == ["plan_out"]


def test_foreign_folder_needs_force(tmp_path):
    lab = tmp_path / "lab"
    lab.mkdir()
    (lab / "data.csv").write_text("1,2\n")
    with pytest.raises(OutputError, match="--force"):
        check_output_folder(lab)
    with output_folder(lab, force=True) as tmp:
        (tmp / "plan.json").write_text("{}")
    assert sorted(p.name for p in lab.iterdir()) == [MARKER, "plan.json"]
    # an empty folder is fine without --force
    empty = tmp_path / "empty"
    empty.mkdir()
    assert check_output_folder(empty) == empty.resolve()


def test_concurrent_writer_fails_cleanly(tmp_path):
    out = tmp_path / "plan_out"
    with output_folder(out) as tmp:
        (tmp / "a.txt").write_text("first")
        with pytest.raises(OutputError, match="another vibroplan run"), output_folder(out):
            pass
    assert (out / "a.txt").read_text() == "first"
    assert [p.name for p in tmp_path.iterdir()] == ["plan_out"]


@pytest.mark.slow
def test_concurrent_cli_writers_one_wins_one_refused(tmp_path):
    """Two real `vibroplan plan` runs into one folder: one writes it, the other is refused
    at once with exit 2, and the folder is whole."""
    spec = tmp_path / "tiny.yaml"
    spec.write_text(TINY)
    cmd = [sys.executable, "-m", "planner.cli", "plan", str(spec), "--out", "shared",
           "--quiet", "--no-figures"]
    first = subprocess.Popen(cmd, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True)
    lock = tmp_path / ".shared.lock"
    deadline = time.monotonic() + 120
    while not lock.exists() and first.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    assert lock.exists(), "the first run never took the folder's lock"
    second = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    out1, err1 = first.communicate(timeout=600)
    assert second.returncode == 2 and "another vibroplan run" in second.stderr
    assert first.returncode in (0, 1), err1
    assert json.loads((tmp_path / "shared" / "plan.json").read_text())["spec"]["name"] == "tiny"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["shared", "tiny.yaml"]


# ----------------------------------------------------------------------------------
# signals


def _children(pid):
    """PIDs of the direct children of ``pid`` (Linux /proc)."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


def _alive(pid):
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.skipif(not Path("/proc").exists(), reason="needs Linux /proc")
def test_sigterm_with_workers_running_stops_everything(tmp_path):
    """SIGTERM to the main process while two design workers run: exit 143 within a few
    seconds, every worker (and the resource tracker) gone, nothing written."""
    proc = subprocess.Popen([sys.executable, "-m", "planner.cli", "plan", "--out", "plan_out",
                             "--quiet", "--jobs", "2"], cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 180
    kids = []
    while time.monotonic() < deadline and proc.poll() is None:
        kids = _children(proc.pid)
        if len(kids) >= 3:  # the resource tracker and two spawned workers
            break
        time.sleep(0.1)
    assert proc.poll() is None and len(kids) >= 3, "no design workers seen"
    time.sleep(1.0)
    kids = _children(proc.pid)
    proc.send_signal(signal.SIGTERM)
    # the timeout is a hang guard (measured ~1.3 s), not a timing target
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err
    assert "interrupted (SIGTERM)" in err and "Traceback" not in err
    time.sleep(0.5)
    assert [k for k in kids if _alive(k)] == []
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc").exists(), reason="needs Linux /proc")
def test_sigint_while_outputs_are_written(tmp_path):
    """Ctrl-C once plan.json is in the temporary folder (figures and waveforms still to
    come): exit 130, no output folder, no temporary, no lock, no traceback.

    Slow because flaky, and not understood (issue 43's note): in 2 of about 9 runs of the
    suite on a loaded 2-core machine the plan ended with exit 0 (the interrupt not
    honoured); 9 runs of the same command by hand, 6 of them beside two CPU-bound
    processes, all ended 130 with nothing written."""
    spec = tmp_path / "tiny.yaml"
    spec.write_text(TINY)
    proc = subprocess.Popen([sys.executable, "-m", "planner.cli", "plan", str(spec), "--out",
                             "plan_out", "--quiet"], cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300
    caught = False
    while time.monotonic() < deadline and proc.poll() is None:
        if any((p / "plan.json").exists() for p in tmp_path.glob(".plan_out.new-*")):
            proc.send_signal(signal.SIGINT)
            caught = True
            break
        time.sleep(0.002)
    out, err = proc.communicate(timeout=60)
    assert caught, f"the run ended before its outputs could be interrupted: {err}"
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tiny.yaml"]


# ----------------------------------------------------------------------------------
# exit codes and input hygiene


def test_os_error_is_exit_3_naming_the_path(tmp_path):
    res = CliRunner().invoke(main, ["sweep", str(CONFIGS / "paper_fig7.yaml"), "--from", "4000",
                                    "--to", "5000", "--step", "500", "--out", "/proc/r.csv"])
    assert res.exit_code == 3, res.output
    assert "/proc" in res.output and "Traceback" not in res.output


def test_missing_output_parent_is_an_error_not_created(tmp_path):
    missing = tmp_path / "nope" / "deeper"
    res = CliRunner().invoke(main, ["sweep", str(CONFIGS / "paper_fig7.yaml"), "--from", "4000",
                                    "--to", "5000", "--step", "500", "--out",
                                    str(missing / "r.csv")])
    assert res.exit_code == 2 and "does not exist" in res.output
    assert not (tmp_path / "nope").exists()


@pytest.mark.parametrize("content, message", [
    ("", "the file is empty"),
    ("# just a comment\n\n   \n", "the file is empty"),
    (b"\x7fELF\x02\x01\x01\x00\x00\x00binary", "not a text file"),
    (b"name: \xff\xfe bad\n", "not a UTF-8 text file"),
    ("name: a\narray: {rows: 2}\nname: b\n", "duplicate key 'name' (lines 1 and 3)"),
])
def test_bad_spec_files_exit_2_naming_the_file(tmp_path, content, message):
    spec = tmp_path / "bad.yaml"
    if isinstance(content, bytes):
        spec.write_bytes(content)
    else:
        spec.write_text(content)
    res = CliRunner().invoke(main, ["plan", str(spec), "--out", str(tmp_path / "out")])
    assert res.exit_code == 2, res.output
    assert message in res.output and "bad.yaml" in res.output
    assert not (tmp_path / "out").exists()


def test_duplicate_nested_key_names_field_and_lines(tmp_path):
    spec = tmp_path / "dup.yaml"
    spec.write_text("name: d\ndrive:\n  band_hz: [3000, 9000]\n  band_hz: [4000, 9000]\n")
    res = CliRunner().invoke(main, ["plan", str(spec), "--out", str(tmp_path / "out")])
    assert res.exit_code == 2
    assert "drive.band_hz" in res.output and "lines 3 and 4" in res.output


@pytest.mark.parametrize("command, config, says", [
    (["simulate", "--freq", "6200"], "array_5x5.yaml", "this is an array spec"),
    (["sweep", "--from", "4000", "--to", "5000", "--step", "500", "--out", "r.csv"],
     "row_assembly.yaml", "this is an array spec"),
    (["plan", "--out", "o"], "paper_fig7.yaml", "this is a device config"),
    (["design", "--forward", "6000", "--backward", "3000"], "array_5x5.yaml",
     "this is an array spec"),
])
def test_a_file_of_the_wrong_kind_says_which_command_reads_it(tmp_path, command, config, says):
    with CliRunner().isolated_filesystem(temp_dir=tmp_path):
        res = CliRunner().invoke(main, [command[0], str(CONFIGS / config), *command[1:]])
    assert res.exit_code == 2, res.output
    assert says in res.output and "use vibroplan" in res.output
    assert res.output.count("\n") <= 2  # one line, not a wall of unknown keys


def test_exit_codes_are_documented_in_help():
    res = CliRunner().invoke(main, ["--help"])
    assert "Exit codes" in res.output and "130" in res.output and "143" in res.output
    assert "129" in res.output
    res = CliRunner().invoke(main, ["plan", "--help"])
    assert "3 OS, I/O, environment or scheduler error" in " ".join(res.output.split())
    assert "--force" in res.output


def test_huge_independent_array_refused_in_seconds(tmp_path):
    """A 26 x 99 independent array cannot fit the default band: refused fast (it ran
    4 min and 12 GB in the feasibility check before)."""
    spec = tmp_path / "huge.yaml"
    spec.write_text("name: huge\narray: {rows: 26, cols: 99}\nindependent: true\n")
    # a subprocess under _run's timeout: a hang guard, not a timing target (the time
    # of a refusal is measured in benchmarks/results/plan_speed.md)
    proc = _run(["plan", str(spec), "--out", str(tmp_path / "out")], tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert "5148 impacters" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "out").exists()


# ----------------------------------------------------------------------------------
# units at the API's edge


@pytest.mark.parametrize("call, unit", [
    (lambda m: m.Impacter.from_geometry(1.5e4, 4, 1242, 3), "m^2"),
    (lambda m: m.Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3.0), "in m"),
    (lambda m: m.Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6, natural_frequency=5.2),
     "Hz"),
    (lambda m: m.Drive.tone(6.2), "Hz"),
    (lambda m: m.Drive([6200.0], [1.27]), "in m"),
    (lambda m: m.Slider.from_geometry(8.0e4), "m^2"),
])
def test_values_in_the_wrong_unit_are_refused(call, unit):
    import model

    with pytest.raises(ValueError, match="implausibly|is in|are in") as info:
        call(model)
    assert unit in str(info.value)


def test_synthesize_amplitudes_in_um_refused():
    from planner.synthesis import synthesize

    with pytest.raises(ValueError, match="in m"):
        synthesize([5000.0, 7000.0], [1.2, 0.8], 200_000.0)


def test_unusual_values_warn():
    import model

    with pytest.warns(model.UnitWarning):
        model.Drive([6200.0], [2e-3])


# ----------------------------------------------------------------------------------
# issue 44 case 6: a signal answered in every long stage


def _stage_cmd(stage, tiny_plan_dir, tmp_path):
    """(command, the file whose appearance says the run is under way, seconds to let
    it get into its stage after that) of each long stage."""
    cli = [sys.executable, "-m", "planner.cli"]
    if stage == "kernel":
        # one RK4 simulation of 10^4 s below resonance: one compiled call of minutes
        return (cli + ["simulate", str(CONFIGS / "paper_fig7.yaml"), "--freq", "500",
                       "--method", "rk4", "--duration", "1e7"], None, 12.0)
    if stage == "yield chips":
        return (cli + ["yield", str(tiny_plan_dir), "--out", "y", "--allow-zero",
                       "--chips", "100000", "--jobs", "1", "--quiet"], ".y.lock", 3.0)
    spec = tmp_path / "tiny.yaml"
    spec.write_text(TINY)
    # the reach probes of a plan that reads nothing from a design cache (its designs
    # end too soon on the tiny spec to be hit reliably: not tested here)
    return (cli + ["plan", str(spec), "--out", "p", "--no-cache", "--jobs", "1",
                   "--no-figures", "--quiet"], ".p.lock", 3.0)


@pytest.mark.slow
@pytest.mark.parametrize("stage", ["kernel", "yield chips", "reach"])
def test_sigterm_is_answered_in_every_long_stage(tiny_plan_dir, tmp_path, stage):
    """Python answers a signal only between bytecodes of its main thread: a numba call
    held SIGTERM off for its whole length (issue 44: > 60 s, SIGKILL needed, leaving
    .OUT.lock and .new-*).  Sent inside each long stage, the run ends with 143, leaving
    no lock, no temporary and no output.  The timeout is a hang guard, not a target."""
    cmd, started, settle = _stage_cmd(stage, tiny_plan_dir, tmp_path)
    proc = subprocess.Popen(cmd, cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        if started is not None:
            for _ in range(30000):
                if (tmp_path / started).exists() or proc.poll() is not None:
                    break
                time.sleep(0.01)
        time.sleep(settle)
        assert proc.poll() is None, proc.communicate()
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 143, err
    assert "Traceback" not in err and "interrupted (SIGTERM)" in err, err
    left = sorted(p.name for p in tmp_path.iterdir() if p.name != "tiny.yaml")
    assert left == [], left
