"""Issue 24, each hostile case at the real CLI: no output replaces an input or a user's
file, no process outlives its run, every connect and wait is bounded, every request the
machine cannot serve is refused with the figure, one reader of plan.json names the key
at fault, and the results are honest.

Real CLI runs (click's runner, or a subprocess where signals, process trees, hangs or
allocations matter), real files read back, a real dask scheduler; nothing is mocked.
Subprocesses that could allocate without bound run under an address-space limit, so
that the old behaviour fails the test instead of the machine.
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from planner.cli import main
from tests.planner.test_pipeline import TINY

CONFIGS = Path(__file__).resolve().parents[2] / "configs"

#: Tolerances that fail some chips of the tiny plan.
HUGE = """\
name: huge tolerance
fabrication:
  natural_frequency_pct: {die: 0, device: 15}
  line_width_um: {die: 0.2, device: 0.1}
"""

#: Address space of a subprocess that could try to allocate without bound [bytes].
ADDRESS_SPACE = 6 * 2**30


def cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def one_line_error(res, code=2):
    """The run ended with ``code``, one ``error:`` line and no traceback."""
    assert res.exit_code == code, res.output
    assert res.exception is None or isinstance(res.exception, SystemExit), res.exception
    assert "Traceback" not in res.output and "error" in res.output.lower()


def run(args, cwd, timeout=180, limit=True):
    """The real CLI in a subprocess, its address space limited (see the module docstring)."""
    def limited():
        import resource

        resource.setrlimit(resource.RLIMIT_AS, (ADDRESS_SPACE, ADDRESS_SPACE))

    return subprocess.run([sys.executable, "-m", "planner.cli", *map(str, args)], cwd=cwd,
                          capture_output=True, text=True, timeout=timeout,
                          preexec_fn=limited if limit else None)


def snapshot(folder):
    return sorted((str(p.relative_to(folder)), p.read_bytes() if p.is_file() else None)
                  for p in Path(folder).rglob("*"))


@pytest.fixture
def plan_copy(tiny_plan_dir, tmp_path):
    """A copy of the tiny plan's folder (marker included), free to be attacked."""
    return Path(shutil.copytree(tiny_plan_dir, tmp_path / "plan"))


@pytest.fixture
def huge_spec(tmp_path):
    path = tmp_path / "huge.yaml"
    path.write_text(HUGE)
    return path


def _sweep_csv(path, nu=4300.0, q=50.0, freqs=None):
    """A lab sweep of one impacter around its resonance (eqs. 1, 5)."""
    from planner.lab.calibrate import transmissibility

    f = np.linspace(0.93 * nu, 1.07 * nu, 40) if freqs is None else np.asarray(freqs)
    a = 0.1 * transmissibility(f, nu, q)
    path.write_text("impacter,frequency_hz,amplitude_um\n"
                    + "".join(f"A1.forward,{float(fi)!r},{float(ai)!r}\n"
                              for fi, ai in zip(f, a)))
    return path


# ----------------------------------------------------------------------------------
# 1. packaging (the wheel itself: tests/test_packaging.py and .ci/run)


def test_bench_without_mpmath_is_one_line_not_a_traceback(tmp_path):
    code = ("import sys; sys.modules['mpmath'] = None\n"
            "from planner.cli import main; main()")
    proc = subprocess.run([sys.executable, "-c", code, "bench", "--quick", "--out",
                           str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 3, proc.stderr
    assert "mpmath" in proc.stderr and "pip install mpmath" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------------
# 2. no output replaces an input or a file that is not the command's


@pytest.mark.parametrize("case", ["calibrate", "sweep", "assign", "drive --out",
                                  "drive sidecar", "drive --plot"])
def test_no_output_replaces_an_input_not_even_with_force(plan_copy, tmp_path, case):
    if case == "calibrate":
        src = _sweep_csv(tmp_path / "sweep.csv")
        args = ["calibrate", src, "--out", src]
    elif case == "sweep":
        src = Path(shutil.copy(CONFIGS / "paper_fig7.yaml", tmp_path / "fig7.yaml"))
        args = ["sweep", src, "--from", 4000, "--to", 5000, "--step", 500, "--out", src]
    elif case == "assign":
        src = tmp_path / "spec.yaml"
        src.write_text(TINY)
        args = ["assign", src, "--out", src]
    else:
        src = plan_copy / "plan.json"
        target = {"drive --out": ["--out", src],
                  # the JSON sidecar of PLAN/plan is PLAN/plan.json
                  "drive sidecar": ["--out", plan_copy / "plan"],
                  "drive --plot": ["--out", tmp_path / "x.wav", "--plot", src]}[case]
        args = ["drive", plan_copy, "--step", "push", *target]
    before = src.read_bytes()
    for extra in ([], ["--force"]):
        res = cli(*args, *extra)
        one_line_error(res)
        assert "input" in res.output and "never replaces its inputs" in res.output
        assert src.read_bytes() == before
    assert not (plan_copy / "plan").exists() and not (tmp_path / "x.wav").exists()


def test_an_existing_file_is_replaced_only_when_this_command_wrote_it(tmp_path):
    cfg = Path(shutil.copy(CONFIGS / "paper_fig7.yaml", tmp_path / "fig7.yaml"))
    sweep = ["sweep", cfg, "--from", 4000, "--to", 5000, "--step", 500, "--quiet", "--out"]
    lab = tmp_path / "lab.csv"
    lab.write_text("my measurements\n")
    res = cli(*sweep, lab)
    one_line_error(res)
    assert "not written by vibroplan" in res.output and "--force" in res.output
    assert lab.read_text() == "my measurements\n"
    out = tmp_path / "r.csv"
    assert cli(*sweep, out).exit_code == 0
    assert cli(*sweep, out).exit_code == 0          # its own file: replaced
    with out.open("a") as fh:                        # ... until someone edits it
        fh.write("0,0\n")
    res = cli(*sweep, out)
    one_line_error(res)
    assert "changed since" in res.output
    assert cli(*sweep, out, "--force").exit_code == 0
    # a file another command wrote is not this one's either
    png = tmp_path / "fig.png"
    assert cli("simulate", cfg, "--freq", 6200, "--plot", png).exit_code == 0
    res = cli(*sweep, tmp_path / "r2.csv", "--plot", png)
    one_line_error(res)
    assert "written by `vibroplan simulate`" in res.output
    assert not (tmp_path / "r2.csv").exists()


def test_a_file_output_inside_a_plan_folder_needs_force(plan_copy):
    before = snapshot(plan_copy)
    res = cli("drive", plan_copy, "--step", "push", "--out", plan_copy / "extra.wav")
    one_line_error(res)
    assert "inside" in res.output and "`vibroplan plan`" in res.output
    assert snapshot(plan_copy) == before
    res = cli("drive", plan_copy, "--step", "push", "--out", plan_copy / "extra.wav", "--force")
    assert res.exit_code == 0, res.output
    assert (plan_copy / "extra.wav").is_file()
    assert (plan_copy / "plan.json").read_bytes() == dict(before)["plan.json"]


def test_a_command_replaces_only_its_own_kind_of_folder(tiny_plan_dir, tmp_path, huge_spec):
    """The data-loss case: a `yield --out` at a plan folder replaced the plan."""
    other = Path(shutil.copytree(tiny_plan_dir, tmp_path / "another_plan"))
    before = snapshot(other)
    res = cli("yield", tiny_plan_dir, "--spec", huge_spec, "--chips", 1, "--out", other,
              "--quiet")
    one_line_error(res)
    assert "written by `vibroplan plan`" in res.output
    assert snapshot(other) == before


def test_a_users_files_in_an_output_folder_are_refused_not_deleted(tiny_plan_dir, tmp_path):
    """The data-loss case: a re-plan run again deleted the notes a user had put beside
    the previous re-plan."""
    measured = tmp_path / "measured.csv"
    measured.write_text("impacter,natural_frequency_hz\nA1.forward,4400\n")
    out = tmp_path / "replan_out"
    args = ["replan", tiny_plan_dir, "--measured", measured, "--out", out, "--no-figures",
            "--quiet"]
    assert cli(*args).exit_code == 0
    (out / "notes.txt").write_text("what I saw in the lab")
    res = cli(*args)
    one_line_error(res)
    assert "notes.txt" in res.output and "--force" in res.output
    assert (out / "notes.txt").read_text() == "what I saw in the lab"
    assert cli(*args, "--force").exit_code == 0     # said so in --help: they are deleted
    assert not (out / "notes.txt").exists()
    for command in ("plan", "replan", "yield"):
        text = " ".join(cli(command, "--help").output.split())
        assert "is refused, not emptied" in text and "they are deleted" in text


# ----------------------------------------------------------------------------------
# 3. no process outlives its run; a dead run's leftovers are cleaned


def _descendants(pid):
    """PIDs of every live descendant of ``pid`` (Linux /proc)."""
    parents = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if fields[0] != "Z":
            parents.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    out, todo = [], [pid]
    while todo:
        kids = parents.get(todo.pop(), [])
        out += kids
        todo += kids
    return out


def _alive(pid):
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def _start_and_wait_for_workers(args, cwd, workers):
    proc = subprocess.Popen([sys.executable, "-m", "planner.cli", *map(str, args)], cwd=cwd,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 180
    kids = []
    while time.monotonic() < deadline and proc.poll() is None:
        kids = _descendants(proc.pid)
        if len(kids) >= workers:
            break
        time.sleep(0.1)
    assert proc.poll() is None and len(kids) >= workers, "no workers seen"
    time.sleep(1.0)
    return proc, _descendants(proc.pid)


def _gone(pids, within_s=30.0):
    deadline = time.monotonic() + within_s      # a hang guard, not a timing target
    while time.monotonic() < deadline and any(_alive(p) for p in pids):
        time.sleep(0.1)
    return [p for p in pids if _alive(p)]


@pytest.mark.skipif(not Path("/proc").exists(), reason="needs Linux /proc")
def test_sigkill_mid_design_leaves_no_process_and_its_leftovers_are_cleaned(tiny_plan_dir,
                                                                             tmp_path):
    # the default 5 x 5 plan: two design workers and the resource tracker
    proc, kids = _start_and_wait_for_workers(["plan", "--out", "plan_out", "--quiet",
                                              "--jobs", 2], tmp_path, 3)
    proc.kill()
    proc.wait(timeout=60)
    assert _gone(kids) == [], "workers outlived the run they belonged to"
    left = sorted(p.name for p in tmp_path.iterdir())
    assert ".plan_out.lock" in left and any(n.startswith(".plan_out.new-") for n in left)
    # the next run writing that folder recognises them as a dead run's and cleans them
    res = cli("yield", tiny_plan_dir, "--allow-zero", "--chips", 1, "--quiet", "--out",
              tmp_path / "plan_out")
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plan_out"]


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc").exists(), reason="needs Linux /proc")
def test_sighup_stops_the_plan_and_its_workers(tmp_path):
    proc, kids = _start_and_wait_for_workers(["plan", "--out", "plan_out", "--quiet",
                                              "--jobs", 2], tmp_path, 3)
    proc.send_signal(signal.SIGHUP)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 129, err
    assert "interrupted (SIGHUP)" in err and "Traceback" not in err
    assert _gone(kids) == []
    assert list(tmp_path.iterdir()) == []


@pytest.mark.skipif(not Path("/proc").exists(), reason="needs Linux /proc")
def test_sigkill_of_yield_leaves_no_dask_worker(tiny_plan_dir, tmp_path, huge_spec):
    proc, kids = _start_and_wait_for_workers(
        ["yield", tiny_plan_dir, "--spec", huge_spec, "--chips", 5000, "--jobs", 2, "--out",
         "y", "--quiet"], tmp_path, 2)
    proc.kill()
    proc.wait(timeout=60)
    assert _gone(kids) == [], "Dask workers outlived the run"


# ----------------------------------------------------------------------------------
# 4. bounds: schedulers, cores, input files, memory


def _silent_peer():
    """A TCP server that accepts every connection and never says a word."""
    server = socket.create_server(("127.0.0.1", 0))
    held = []

    def serve():
        while True:
            try:
                conn, _ = server.accept()
            except OSError:
                return
            held.append(conn)

    threading.Thread(target=serve, daemon=True).start()
    return server, f"tcp://127.0.0.1:{server.getsockname()[1]}"


# slow (~6 s): it waits out the scheduler's timeout; test_unusable_scheduler_addresses
# keeps the scheduler's refusals in the default run
@pytest.mark.slow
def test_a_scheduler_that_never_answers_is_given_up_on(tiny_plan_dir, tmp_path, monkeypatch):
    # the connect timeout (20 s) shortened through its environment variable
    monkeypatch.setenv("VIBROPLAN_CONNECT_TIMEOUT_S", "3")
    server, address = _silent_peer()
    try:
        proc = run(["yield", tiny_plan_dir, "--allow-zero", "--chips", 1, "--out", "y",
                    "--scheduler", address, "--quiet"], tmp_path, timeout=150)
    finally:
        server.close()
    assert proc.returncode == 3, proc.stderr
    assert address in proc.stderr and "answered within 3 s" in proc.stderr
    assert "Traceback" not in proc.stderr and proc.stderr.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("address, code, says", [
    ("inproc://foo", 2, "tcp://"),
    ("tcp://127.0.0.1", 2, "HOST:PORT"),
    ("ucx://127.0.0.1:8786", 3, "ucx://127.0.0.1:8786"),
])
def test_unusable_scheduler_addresses(tmp_path, address, code, says):
    spec = tmp_path / "tiny.yaml"
    spec.write_text(TINY)
    res = cli("plan", spec, "--out", tmp_path / "out", "--scheduler", address)
    one_line_error(res, code)
    assert says in res.output
    assert not (tmp_path / "out").exists()


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_a_scheduler_that_dies_mid_run_is_exit_3(tiny_plan_dir, tmp_path, huge_spec):
    address = f"tcp://127.0.0.1:{_free_port()}"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
    quiet = dict(stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env, cwd=tmp_path)
    scheduler = subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_scheduler",
                                  "--host", "127.0.0.1", "--port", address.rsplit(":", 1)[1],
                                  "--no-dashboard"], **quiet)
    worker = subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", address,
                               "--nworkers", "1", "--nthreads", "1", "--no-dashboard"], **quiet)
    try:
        yielding = subprocess.Popen(
            [sys.executable, "-m", "planner.cli", "yield", tiny_plan_dir, "--spec", huge_spec,
             "--chips", "5000", "--out", "y", "--scheduler", address],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env, cwd=tmp_path)
        # the chips run once the progress bar moves past the first one
        deadline = time.monotonic() + 120
        seen = ""
        while time.monotonic() < deadline and yielding.poll() is None and "2/5001" not in seen:
            seen += yielding.stderr.read(64)
        assert yielding.poll() is None, seen
        scheduler.kill()
        _, err = yielding.communicate(timeout=180)
    finally:
        for p in (scheduler, worker):
            p.kill()
            p.wait(timeout=60)
    lines = [x for x in err.replace("\r", "\n").splitlines() if x.startswith("error")]
    assert yielding.returncode == 3, err[-2000:]
    assert len(lines) == 1 and address in lines[0], err[-2000:]
    assert "Traceback" not in err
    assert not (tmp_path / "y").exists()


def test_jobs_beyond_the_cores_are_refused(tiny_plan_dir, tmp_path, huge_spec):
    from planner.runtime.limits import cores

    res = cli("yield", tiny_plan_dir, "--spec", huge_spec, "--chips", 1, "--out",
              tmp_path / "y", "--jobs", cores() + 1, "--quiet")
    one_line_error(res)
    assert f"between 1 and {cores()}" in res.output and not (tmp_path / "y").exists()


@pytest.fixture
def fifo(tmp_path):
    path = tmp_path / "input.fifo"
    os.mkfifo(path)
    return path


@pytest.mark.skipif(not Path("/dev/zero").exists(), reason="needs /dev/zero")
@pytest.mark.parametrize("special", ["/dev/zero", "fifo"])
@pytest.mark.parametrize("command", ["plan", "sweep", "calibrate", "drive", "color", "replan",
                                     "yield"])
def test_inputs_must_be_regular_files(tiny_plan_dir, tmp_path, fifo, special, command):
    bad = fifo if special == "fifo" else Path(special)
    args = {"plan": ["plan", bad, "--out", "o"],
            "sweep": ["sweep", bad, "--from", 1, "--to", 2, "--step", 1, "--out", "o.csv"],
            "calibrate": ["calibrate", bad, "--out", "o.csv"],
            "drive": ["drive", bad, "--step", "push", "--out", "o.wav"],
            "color": ["color", bad],
            "replan": ["replan", tiny_plan_dir, "--measured", bad, "--out", "o"],
            "yield": ["yield", bad, "--chips", 1, "--out", "o", "--allow-zero"]}[command]
    proc = run(args, tmp_path, timeout=120)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert ("FIFO" if special == "fifo" else "device") in proc.stderr
    assert "Traceback" not in proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["input.fifo"]


@pytest.mark.parametrize("args", [
    ["plan", "/dev/zero", "--out", "o"],
    ["plan", "--out", "."],
    ["plan", "--out", "users"],
    ["sweep", "/dev/zero", "--from", 1, "--to", 2, "--step", 1, "--out", "o.csv"],
    ["yield", "input.fifo", "--chips", 1, "--out", "o"],
], ids=["plan /dev/zero", "plan --out .", "plan --out a user's folder", "sweep /dev/zero",
        "yield FIFO"])
def test_a_refusal_before_any_work_imports_neither_solver_nor_planner(tmp_path, args):
    # a bad input or output folder is refused before the command imports numba, the
    # solver or the planner's stages (over a second): the refusal is then immediate.
    # -X importtime lists every module the process imported, on stderr
    os.mkfifo(tmp_path / "input.fifo")
    (tmp_path / "users").mkdir()
    (tmp_path / "users" / "notes.txt").write_text("mine")
    proc = subprocess.run([sys.executable, "-X", "importtime", "-m", "planner.cli",
                           *map(str, args)], cwd=tmp_path, capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert "error: " in proc.stderr and "Traceback" not in proc.stderr
    imported = {line.rsplit("|", 1)[-1].strip() for line in proc.stderr.splitlines()
                if line.startswith("import time:")}
    assert "planner.cli" in imported                      # the listing is there
    heavy = sorted(m for m in imported if m.split(".")[0] in ("numba", "model", "scipy")
                   or m.startswith(("planner.planning", "planner.arrayspec")))
    assert heavy == [], heavy[:10]
    assert (tmp_path / "users" / "notes.txt").read_text() == "mine"


def test_an_input_over_the_size_limit_is_refused_unread(tmp_path):
    from planner.runtime.limits import MAX_INPUT_BYTES

    big = tmp_path / "big.yaml"
    with big.open("wb") as fh:
        fh.truncate(MAX_INPUT_BYTES + 1)          # sparse: nothing is really written
    res = cli("plan", big, "--out", tmp_path / "o")
    one_line_error(res)
    assert "MiB" in res.output and "big.yaml" in res.output


@pytest.mark.parametrize("args", [
    ["yield", "PLAN", "--chips", 10**12, "--out", "o", "--allow-zero"],
    ["drive", "PLAN", "--step", "push", "--sample-rate", "1e12", "--out", "o.wav"],
    ["sweep", CONFIGS / "paper_fig7.yaml", "--from", 4000, "--to", 5000, "--step", "1e-9",
     "--out", "o.csv"],
    ["color", "GRAPH"],
], ids=["yield --chips", "drive --sample-rate", "sweep --step", "color 'p band'"])
def test_requests_beyond_the_memory_are_refused_with_the_figure(tiny_plan_dir, tmp_path, args):
    graph = tmp_path / "g.col"
    graph.write_text("p band 1000000000000 0\n")
    args = [tiny_plan_dir if a == "PLAN" else graph if a == "GRAPH" else a for a in args]
    proc = run(args, tmp_path, timeout=120)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert re.search(r"needs about [0-9.]+ [TP]B of memory", proc.stderr), proc.stderr[-2000:]
    assert "available" in proc.stderr and proc.stderr.count("\n") == 1
    assert "Traceback" not in proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["g.col"]


# ----------------------------------------------------------------------------------
# 5. one reader of plan.json


def _edit(data, what):
    imp, step = data["impacters"][0], data["steps"][0]
    if what == "missing mass":
        del imp["mass_kg"]
    elif what == "mass as text":
        imp["mass_kg"] = str(imp["mass_kg"])
    elif what == "channel as bool":
        imp["channel"] = True
    elif what == "tones as text":
        step["tones"] = "x"
    elif what == "another format":
        data["format_version"] = 2
    elif what == "edited natural frequency":
        imp["natural_frequency_hz"] *= 1.3
    elif what == "edited geometry":
        imp["geometry"]["width_m"] *= 1.1
    elif what == "stiffness not from the geometry":
        # k and nu edited together (they agree with each other, not with the geometry)
        imp["stiffness_n_per_m"] *= 1.21
        imp["natural_frequency_hz"] *= 1.1
    elif what == "no steps":
        data["steps"] = []
    elif what == "bad spec":
        data["spec"]["array"]["rows"] = "x"
    elif what == "missing seed":
        del data["seed"]
    elif what == "unknown device":
        step["forward"] = ["B7"]


@pytest.mark.parametrize("what, key", [
    ("missing mass", "impacters[0] (A1.forward).mass_kg"),
    ("mass as text", "impacters[0] (A1.forward).mass_kg"),
    ("channel as bool", "impacters[0] (A1.forward).channel"),
    ("tones as text", "steps[0] (s/push).tones"),
    ("another format", "format_version"),
    ("edited natural frequency", "impacters[0] (A1.forward).natural_frequency_hz"),
    ("edited geometry", "impacters[0] (A1.forward).mass_kg"),
    ("stiffness not from the geometry", "impacters[0] (A1.forward).stiffness_n_per_m"),
    ("no steps", "steps"),
    ("bad spec", "spec.array.rows"),
    ("missing seed", "seed"),
    ("unknown device", "steps[0] (s/push).forward"),
])
def test_a_faulty_plan_json_is_refused_naming_the_key(plan_copy, tmp_path, what, key):
    """Every command that reads a plan reads it through one reader: the same fault gets
    the same one-line answer from drive, replan and yield."""
    data = json.loads((plan_copy / "plan.json").read_text())
    _edit(data, what)
    bad = tmp_path / "edited.json"
    bad.write_text(json.dumps(data))
    measured = tmp_path / "measured.csv"
    measured.write_text("impacter,natural_frequency_hz\nA1.forward,4400\n")
    for args in (["drive", bad, "--step", "pull", "--out", tmp_path / "d.wav"],
                 ["replan", bad, "--measured", measured, "--out", tmp_path / "r"],
                 ["yield", bad, "--chips", 1, "--out", tmp_path / "y", "--allow-zero"]):
        res = cli(*args)
        one_line_error(res)
        assert f"{bad}: {key}:" in res.output, (args[0], res.output)
        assert res.output.count("\n") == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["edited.json", "measured.csv", "plan"]


def test_a_replanned_plan_is_a_plan(tiny_plan_dir, tmp_path, huge_spec):
    from planner.planfile.reader import FORMAT_VERSION, read_plan

    assert json.loads((tiny_plan_dir / "plan.json").read_text())["format_version"] \
        == FORMAT_VERSION
    measured = tmp_path / "measured.csv"
    nu = read_plan(tiny_plan_dir).impacter("A1.forward").natural_frequency_hz
    measured.write_text(f"impacter,natural_frequency_hz\nA1.forward,{1.02 * nu!r}\n")
    res = cli("replan", tiny_plan_dir, "--measured", measured, "--out", tmp_path / "rp",
              "--no-figures", "--quiet")
    assert res.exit_code == 0, res.output
    rp = tmp_path / "rp"
    record = read_plan(rp)
    assert record.replanned
    assert math.isclose(record.impacter("A1.forward").natural_frequency_hz, 1.02 * nu,
                        rel_tol=1e-9)
    # yield reads it: its chips are the as-built chip with errors on top, so the nominal
    # chip is the one the re-plan verified
    res = cli("yield", rp, "--spec", huge_spec, "--chips", 2, "--out", tmp_path / "y",
              "--quiet")
    assert res.exit_code == 0, res.output
    assert json.loads((tmp_path / "y" / "yield.json").read_text())["nominal"]["passed"] is True
    assert cli("drive", rp, "--step", "push", "--out", tmp_path / "p.wav").exit_code == 0
    res = cli("replan", rp, "--measured", measured, "--out", tmp_path / "rp2", "--no-figures",
              "--quiet")
    assert res.exit_code == 0, res.output


# ----------------------------------------------------------------------------------
# 6. honest results


def test_chips_are_seeded_by_the_scales_value(tiny_plan_dir, tmp_path, huge_spec):
    """Scale 1 alone and scale 1 listed second give the same chips; 1.0000001 is a scale
    of its own (it collapsed into "1")."""
    def yield_json(scales):
        out = tmp_path / scales.replace(",", "_")
        res = cli("yield", tiny_plan_dir, "--spec", huge_spec, "--chips", 6, "--seed", 2,
                  "--sigma-scale", scales, "--out", out, "--quiet")
        assert res.exit_code == 0, res.output
        return json.loads((out / "yield.json").read_text())

    alone = yield_json("1")
    among = yield_json("0.75,1,1.0000001")
    assert set(among["by_sigma_scale"]) == {"0.75", "1", "1.0000001"}
    assert among["sigma_scale"] == 1.0
    assert among["failed_chips"] == alone["failed_chips"]
    assert among["by_sigma_scale"]["1"]["failures"] == alone["failures"]
    assert 0 < alone["passed"] < alone["chips"], "the comparison needs chips of both kinds"


@pytest.mark.parametrize("text, field", [
    ("fabrication:\n  line_width_um: {die: true}\n", "fabrication.line_width_um.die"),
    ('fabrication:\n  line_width_um: {die: "0.05"}\n', "fabrication.line_width_um.die"),
    ("verification: {repair_rounds: 0, x0_points: 5.0}\n", "verification.x0_points"),
    ("design: {seed: yes}\n", "design.seed"),
])
def test_spec_values_keep_their_types(tmp_path, text, field):
    spec = tmp_path / "spec.yaml"
    spec.write_text(TINY.replace("verification: {repair_rounds: 0, x0_points: 5}\n", "")
                    + text)
    res = cli("assign", spec)
    one_line_error(res)
    assert field in res.output and "spec.yaml" in res.output


def test_ints_and_exponents_are_still_numbers(tmp_path):
    spec = tmp_path / "spec.yaml"
    spec.write_text(TINY + "fabrication:\n  line_width_um: {die: 1, device: 2e-2}\n")
    res = cli("assign", spec)
    assert res.exit_code == 0, res.output


def test_lab_numbers_beyond_any_mems_device_are_refused_by_row_and_column(tiny_plan_dir,
                                                                          tmp_path):
    sweep = _sweep_csv(tmp_path / "sweep.csv", nu=1e300)   # a resonance "fitted ok" at 1e300 Hz
    res = cli("calibrate", sweep, "--out", tmp_path / "m.csv")
    one_line_error(res)
    assert "row 2, column frequency_hz" in res.output
    measured = tmp_path / "measured.csv"
    measured.write_text("impacter,natural_frequency_hz\nA1.forward,1e300\n")
    res = cli("replan", tiny_plan_dir, "--measured", measured, "--out", tmp_path / "r")
    one_line_error(res)
    assert "measured.csv: row 2, column natural_frequency_hz" in res.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["measured.csv", "sweep.csv"]


def test_a_fit_outside_the_sweep_is_flagged_not_ok(tmp_path):
    # the resonance at 4300 Hz, the sweep 3000-4000 Hz: the fit cannot place it inside
    sweep = _sweep_csv(tmp_path / "sweep.csv", freqs=np.linspace(3000, 4000, 30))
    res = CliRunner().invoke(main, ["calibrate", str(sweep), "--out", str(tmp_path / "m.csv")])
    assert res.exit_code == 1, res.output
    assert "[ok]" not in res.output and "peak_outside_sweep" in res.output
    assert not (tmp_path / "m.csv").exists()


# ----------------------------------------------------------------------------------
# 7. exit codes


def test_a_nan_option_is_bad_input_not_a_conversion_error(tmp_path):
    res = cli("sweep", CONFIGS / "paper_fig7.yaml", "--from", 4000, "--to", 5000, "--step",
              "nan", "--out", tmp_path / "r.csv")
    assert res.exit_code == 2 and "not a finite number" in res.output
    assert not (tmp_path / "r.csv").exists()


def test_the_warm_pool_runs_its_warm_up_first_and_then_the_tasks():
    """planner.runtime.workers.warm_pool: the warm-up (numba's compilation, model.warmup) starts
    in a worker at once; the first task submitted waits for it, so no second worker
    compiles the same kernels at the same time; the tasks then run as in any pool."""
    from model.warmup import compile_kernels
    from planner.runtime.workers import warm_pool

    with warm_pool(2, compile_kernels) as pool:
        futures = [pool.submit(math.sqrt, x) for x in (4.0, 9.0)]
        assert pool.wait_warm() is None           # read by the first submit already
        assert [f.result() for f in futures] == [2.0, 3.0]
    with warm_pool(2, compile_kernels) as pool:
        seconds = pool.wait_warm()
        assert isinstance(seconds, float) and seconds > 0
    # not eager (a plan the cache saw through): no worker until a task needs one
    with warm_pool(2, compile_kernels, eager=False) as pool:
        assert pool.pool is None
    with warm_pool(2, compile_kernels, eager=False) as pool:
        assert pool.submit(math.sqrt, 16.0).result() == 4.0 and pool.pool is not None


def _square_where(shared, x):
    """A dispatch task: (the process it ran in, shared + x^2)."""
    return os.getpid(), shared + x * x


def test_this_process_does_tasks_while_the_workers_start():
    """planning.designs.dispatch on a pool whose workers still import the solver
    (warm_pool's ``preload``, started at the first dispatch): this process does the
    last tasks itself meanwhile, and the results are the same, in order (a dry run of a
    spec of two probes is done before the workers are: 6.2 -> 4.5 s)."""
    from planner.planning.designs import dispatch
    from planner.planning.pipeline import WORKER_MODULES
    from planner.runtime.workers import warm_pool

    args = [(x,) for x in range(6)]
    with warm_pool(2, eager=False, preload=WORKER_MODULES) as pool:
        assert pool.pool is None                   # nothing started before the dispatch
        got = dispatch(_square_where, 10, args, jobs=2, pool=pool)
        assert pool.pool is not None
    assert [v for _, v in got] == [10 + x * x for x in range(6)]
    here = [pid == os.getpid() for pid, _ in got]
    # the workers take seconds to import the planner; this process runs a task in
    # microseconds: it does every task, the last first, before they are up
    assert here[-1] and sum(here) >= 1
    # a pool without preload (or already started) gets every task
    with warm_pool(2) as pool:
        got = dispatch(_square_where, 0, args, jobs=2, pool=pool)
    assert [v for _, v in got] == [x * x for x in range(6)]
    assert all(pid != os.getpid() for pid, _ in got)


def test_a_refused_scheduler_address_is_refused_at_once(tmp_path):
    """Nothing listens at the port: exit 3 naming the address, without waiting out the
    connect timeout (distributed retries a refused connection until then)."""
    port = _free_port()
    spec = tmp_path / "tiny.yaml"
    spec.write_text(TINY)
    res = cli("plan", spec, "--out", tmp_path / "out", "--scheduler", f"tcp://127.0.0.1:{port}")
    one_line_error(res, 3)
    assert f"127.0.0.1:{port}" in res.output and "connection refused" in res.output
    assert not (tmp_path / "out").exists()
