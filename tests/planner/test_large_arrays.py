"""Large arrays (issue 18): one separation rule for assigner and designer, refusals in
seconds, ``plan --dry-run`` with a time estimate, and the large-array configs."""

import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from planner.assignment.assign import assign, plan_steps
from planner.cli import main
from planner.core.errors import PlanningError
from planner.manufacturability import channel_grid
from planner.planning.exposure import forbidden_tones
from planner.planning.estimate import estimate
from planner.planning.settings import resolve_settings
from planner.core.separation import check_target, position_grid, separated
from planner.arrayspec import load_spec

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = ROOT / "configs"
_TINY = (CONFIGS / "tiny_1x2.yaml").read_text()


def _old_7x7_text():
    """The 7 x 7 spec that died in the designer after minutes (issue 18): the default
    5 x 5 spec on 7 x 7 devices, band 4-60 kHz, 100 Hz channels, with the 1 % design
    guard the default had then (the default before issue 25 is kept for the design-for-
    yield benchmark)."""
    text = (ROOT / "benchmarks" / "data" / "array_5x5_before_yield.yaml").read_text()
    for old, new in (("rows: 5", "rows: 7"), ("cols: 5", "cols: 7"),
                     ("band_hz: [4000, 42000]", "band_hz: [4000, 60000]"),
                     ("count: 381", "count: 561"), ("  guard: 0.004", "  guard: 0.01")):
        assert old in text
        text = text.replace(old, new)
    return text


@pytest.mark.parametrize("spacing", ["linear", "log"])
@pytest.mark.parametrize("sep,guard", [(1, 0.01), (5, 0.01), (3, 0.05), (8, 0.02)])
def test_positions_separate_by_channels_and_by_the_guard(spacing, sep, guard):
    grid = (np.linspace(4000, 60000, 561) if spacing == "linear"
            else np.geomspace(2000, 20000, 240))
    pos = position_grid(grid, sep, guard)
    assert pos[0] == 0 and np.all(np.diff(pos) >= 1) and pos[-1] < grid.size
    # any two positions sep or more apart: that many channels apart and outside each
    # other's guard band (checked on every pair exactly sep apart and on all further
    # ones of a sample)
    for i in range(len(pos) - sep):
        assert pos[i + sep] - pos[i] >= sep
        assert separated(grid[pos[i]], grid[pos[i + sep]], guard)
    for i in range(0, len(pos), 37):
        for j in range(i + sep, len(pos), 11):
            assert separated(grid[pos[i]], grid[pos[j]], guard)
    # tight: each position is the lowest channel that keeps the rule
    for k in range(sep, len(pos)):
        c = pos[k] - 1
        if c > pos[k - 1]:
            assert not separated(grid[pos[k - sep]], grid[c], guard)


def test_positions_are_the_channels_where_the_guard_is_narrower():
    # the default 5 x 5 spec: 500 Hz > 1 % of every tone below 50 kHz
    loaded = load_spec(CONFIGS / "array_5x5.yaml")
    grid = channel_grid(loaded.spec)
    pos = position_grid(grid, loaded.spec.drive.guard.separation_channels,
                        loaded.spec.design.guard)
    assert np.array_equal(pos, np.arange(grid.size))
    assert np.array_equal(position_grid(grid, 5, 0.0), np.arange(grid.size))


def test_old_7x7_spec_is_refused_with_the_reason_not_left_to_the_designer():
    loaded = load_spec(_old_7x7_text(), source="old_7x7")
    settings = resolve_settings(loaded)
    with pytest.raises(PlanningError) as err:
        assign(settings, settings.steps)
    msg = str(err.value)
    assert "guard band" in msg and "design.guard" in msg and "Fixes" in msg
    # where the guard band starts and what it costs (561 channels of the grid, 5 apart)
    assert ("above 49500 Hz, 5 channels are inside the designer's guard band" in msg
            and "the 561 channels hold only 543 positions 5 apart" in msg), msg


def test_capacity_counts_the_guard_band():
    """A band whose channels would hold every independent impacter at the channel
    separation, but not once the designer's 1 % guard thins them out above 50 kHz, is
    refused by the capacity bound, before any colouring."""
    text = _old_7x7_text().replace("band_hz: [4000, 60000]", "band_hz: [20000, 68600]")
    text = text.replace("count: 561", "count: 487")
    # no scenes: only the capacity bound can refuse it this early
    text = text[: text.index("scenes:")]
    loaded = load_spec(text, source="tight_7x7")
    grid = channel_grid(loaded.spec)
    steps = plan_steps(loaded, 0.01)
    n = len({nd for st in steps for nd in st.active_nodes()})
    need = (n - 1) * 5 + 1
    positions = position_grid(grid, 5, loaded.spec.design.guard)
    assert len(positions) < need <= grid.size     # the case the old bound let through
    with pytest.raises(PlanningError) as err:
        assign(resolve_settings(loaded), steps, separation=5)
    msg = str(err.value)
    assert f"needs at least {need} positions" in msg
    assert f"{len(positions)} positions" in msg and "design.guard" in msg
    assert f"at most {(len(positions) - 1) // 5 + 1} independent impacters fit" in msg


@pytest.mark.parametrize("name", ["array_7x7.yaml", "array_10x10_rows.yaml"])
def test_no_assigned_target_is_forbidden_to_the_designer(name):
    loaded = load_spec(CONFIGS / name)
    settings = resolve_settings(loaded)
    a = assign(settings, settings.steps)
    forbidden = forbidden_tones(settings.steps, a.frequencies)
    assert len(a.frequencies) == 2 * loaded.spec.array.rows * loaded.spec.array.cols
    for n, f in a.frequencies.items():
        check_target(f, forbidden[n], settings.guard)    # the designer's entry check
    assert max(a.frequencies.values()) <= loaded.spec.drive.band_hz[1]


def test_estimate_counts_the_work_left():
    loaded = load_spec(CONFIGS / "array_10x10_rows.yaml")
    settings = resolve_settings(loaded)
    a = assign(settings, settings.steps)
    one = estimate(settings, settings.steps, a, jobs=1)
    two = estimate(settings, settings.steps, a, jobs=2)
    # a row's ten devices share their tone, forbidden set and settings: one design each
    assert one.designs == len(set(a.frequencies.values())) == a.graph.number_of_nodes()
    assert one.impacters == len(a.frequencies)
    assert 0 < two.total_s < one.total_s
    assert "estimate" in one.lines()[1]


#: The tiny 1 x 2 spec with its two devices always moving together: four impacters, two
#: designs (each direction's pair shares its tone, forbidden tones and settings).
SHARED = (_TINY[:_TINY.index("scenes:")].replace("name: tiny", "name: shared")
          + "scenes:\n  s:\n"
            "    - {name: push, duration_ms: 5, forward: [A1, A2]}\n"
            "    - {name: pull, duration_ms: 5, backward: [A1, A2]}\n")


@pytest.fixture(scope="module")
def shared_plan():
    """The SHARED plan (real designs and verification) and the estimate the pipeline
    made of it once its frequencies were assigned."""
    from planner.planning import run_plan

    made = {}
    plan = run_plan(load_spec(SHARED), on_assignment=lambda s, steps, a: made.setdefault(
        "estimate", estimate(s, steps, a)))
    return plan, made["estimate"]


class _Trajectories:
    """Counts the solver's trajectories while the real solver runs: one per
    ``model.simulate`` call, one per initial position of a ``model.responses`` batch."""

    def __init__(self, monkeypatch):
        import model

        self.count = 0
        simulate, responses = model.simulate, model.responses

        def counted_simulate(*args, **kwargs):
            self.count += 1
            return simulate(*args, **kwargs)

        def counted_responses(impacter, drive, x0s, *args, **kwargs):
            self.count += len(x0s)
            return responses(impacter, drive, x0s, *args, **kwargs)

        monkeypatch.setattr(model, "simulate", counted_simulate)
        monkeypatch.setattr(model, "responses", counted_responses)


def test_estimate_counts_what_the_plan_does(shared_plan, monkeypatch):
    """The estimate, made before any design, against the plan that followed: the designs
    it counts are the distinct designs the designer made (impacters sharing every
    input share one), and its simulation counts are those the coupling matrix and the
    verification run (counted on the real solver, re-running the plan's own checks)."""
    from planner.planning.verify import check_steps, coupling_matrix

    plan, e = shared_plan
    assert (e.impacters, e.designs) == (4, 2)
    assert e.impacters == len(plan.designs)
    assert e.designs == len({id(d) for d in plan.designs.values()})
    assert e.steps == len(plan.data["steps"])
    settings = plan.settings
    impacters = {n: d.impacter for n, d in plan.designs.items()}
    tones = sorted(set(plan.assignment.frequencies.values()))
    runs = _Trajectories(monkeypatch)
    coupling_matrix(impacters, tones, settings, settings.single_step_s)
    # every impacter under every tone from every x0: exactly the estimate's count
    assert runs.count == e.coupling_runs
    runs.count = 0
    check_steps(settings, settings.steps, plan.waveforms, impacters, dict(settings.sliders))
    # each impacter of each device from each x0 of every step is the estimate's count;
    # the checks also run a moving device's other impacter from each x0 and every
    # device's travel and settle dwell from rest, which its unit cost absorbs (1.9x here)
    assert e.verification_runs <= runs.count <= 2 * e.verification_runs


def test_estimate_range_covers_retries_repair_rounds_and_compilation():
    """The low end is one round at first tries; the typical and high ends add the
    designs' retries, then every repair round: each more than the one before, and the
    high end shrinks when the spec allows no repair round (the low end does not)."""
    loaded = load_spec(CONFIGS / "row_assembly.yaml")
    settings = resolve_settings(loaded)
    a = assign(settings, settings.steps)
    e = estimate(settings, settings.steps, a, jobs=1)
    assert e.rounds == 1 + settings.repair_rounds
    assert e.high_s > e.typical_s > e.total_s > e.compile_s >= 0
    text = "\n".join(e.lines())
    assert "typically about" in text
    assert ("(1 try each when fast enough, a slow one retried until 2 tries in a row gain "
            f"less than 2 % in speed ({e.tries} at most), an infeasible one given up after 2 "
            "ever wider: up to") in text and f"up to {e.rounds} rounds" in text
    assert "1-8 tries" not in text
    fewer = estimate(dataclasses.replace(settings, repair_rounds=0),
                     settings.steps, a, jobs=1)
    assert fewer.rounds == 1 and fewer.high_s < e.high_s
    assert fewer.total_s == pytest.approx(e.total_s)


def test_cold_numba_cache_is_detected_and_adds_compilation(tmp_path):
    """In a fresh NUMBA_CACHE_DIR no plan kernel is cached; once one kernel has run,
    that one is found in numba's cache (and the rest still are not)."""
    code = ("import numpy as np\n"
            "from planner.planning.estimate import COMPILE_S, numba_cache_state\n"
            "print(numba_cache_state())\n"
            "from model.kernels.closed_form import tone_coefficients\n"
            "tone_coefficients(1e5, 10.0, np.array([9e4]), np.array([1.0]), np.array([0.0]))\n"
            "print(numba_cache_state())\n")
    env = dict(os.environ, PYTHONPATH=str(ROOT), NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, timeout=600, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    before, after = out.stdout.split()[:2], out.stdout.split()[2:]
    from planner.planning.estimate import PLAN_KERNELS

    n = len(PLAN_KERNELS)
    assert "".join(before) == f"({n},{n})"
    assert "".join(after) == f"({n - 1},{n})"


@pytest.mark.slow
def test_dry_run_with_a_cold_numba_cache_counts_the_compilation(tmp_path):
    """Slow (~90 s on 2 cores): the reach probes compile every kernel from cold."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    out = subprocess.run([sys.executable, "-m", "planner.cli", "plan",
                          str(_tiny_spec(tmp_path)), "--dry-run", "--jobs", "1"], env=env,
                         capture_output=True, text=True, timeout=900, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    from planner.planning.estimate import COMPILE_S, PLAN_KERNELS

    n = len(PLAN_KERNELS)
    assert f"compilation ~{COMPILE_S:.0f} s (numba cache cold: {n} of {n} kernels)" in out.stdout
    low = next(x for x in out.stdout.splitlines() if x.startswith("estimated time"))
    # the low end includes the compilation
    assert float(low.split("about ")[1].split(" s")[0]) >= COMPILE_S


@pytest.mark.slow
def test_dry_run_on_10x10_prints_an_estimate_and_writes_nothing(tmp_path):
    out = tmp_path / "never"
    res = CliRunner().invoke(main, ["plan", str(CONFIGS / "array_10x10_rows.yaml"),
                                    "--dry-run", "--out", str(out), "--jobs", "1"])
    assert res.exit_code == 0, res.output
    assert "200 impacters on 100 devices" in res.output
    assert "remaining: 20 designs" in res.output
    line = next(x for x in res.output.splitlines() if x.startswith("estimated time"))
    assert " s " in line and "estimate" in line
    assert not out.exists()


def test_dry_run_refuses_the_old_7x7_spec_with_exit_2(tmp_path):
    spec = tmp_path / "old_7x7.yaml"
    spec.write_text(_old_7x7_text())
    res = CliRunner().invoke(main, ["plan", str(spec), "--dry-run"])
    assert res.exit_code == 2, res.output
    assert "guard band" in res.output and "Traceback" not in res.output


def _tiny_spec(tmp_path):
    """A 1 x 2 array, every impacter independent: four designs, a plan in seconds."""
    text = (CONFIGS / "array_5x5.yaml").read_text()
    text = text.replace("rows: 5", "rows: 1").replace("cols: 5", "cols: 2")
    text = text[: text.index("scenes:")]
    spec = tmp_path / "tiny.yaml"
    spec.write_text(text)
    return spec


def _plan_in_subprocess(spec, out, *args):
    """``vibroplan plan`` in a fresh process with the environment as it is (BLAS on its
    default thread count), from this tree."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "planner.cli", "plan", str(spec), "--out",
                           str(out), "--no-figures", "--quiet", *args], env=env,
                          cwd=out.parent, capture_output=True, text=True, timeout=1800)


@pytest.mark.slow
def test_serial_process_pool_and_local_cluster_give_the_same_plan_json(tmp_path):
    """Issue 18 item 3: the designs and the verification steps on Dask (a two-worker
    LocalCluster reached through --scheduler, as a remote cluster would be), the designs
    in a two-process pool (--jobs 2) and a serial run give a byte-identical plan.json.

    No BLAS environment variables: every design runs with BLAS pinned to one thread
    (planner.runtime.workers.single_thread_blas), whatever the process's default.  No design
    cache (--no-cache): every run computes its designs, so the cluster runs them too."""
    distributed = pytest.importorskip("distributed")
    spec = _tiny_spec(tmp_path)
    serial = _plan_in_subprocess(spec, tmp_path / "serial", "--jobs", "1", "--no-cache")
    assert serial.returncode in (0, 1), serial.stderr
    pool = _plan_in_subprocess(spec, tmp_path / "pool", "--jobs", "2", "--no-cache")
    assert pool.returncode == serial.returncode, pool.stderr
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        remote = CliRunner().invoke(main, ["plan", str(spec), "--out", str(tmp_path / "dask"),
                                           "--jobs", "1", "--no-figures", "--quiet",
                                           "--no-cache",
                                           "--scheduler", cluster.scheduler_address])
        # the cluster ran the designs and the verification steps
        prefixes = set(cluster.scheduler.task_prefixes)
    assert remote.exit_code == serial.returncode, remote.output
    # (dask drops the leading underscore)
    assert {"design_on_engine", "check_on_engine"} <= prefixes, prefixes
    a = (tmp_path / "serial" / "plan.json").read_bytes()
    assert (tmp_path / "pool" / "plan.json").read_bytes() == a
    assert (tmp_path / "dask" / "plan.json").read_bytes() == a


def test_single_thread_blas_pins_blas_and_restores_it_after_the_last_block():
    threadpoolctl = pytest.importorskip("threadpoolctl")
    from planner.runtime.workers import single_thread_blas

    def blas_threads():
        return sorted({i["num_threads"] for i in threadpoolctl.threadpool_info()
                       if i["user_api"] == "blas"})

    with threadpoolctl.threadpool_limits(limits=2, user_api="blas"):
        before = blas_threads()
        with single_thread_blas():
            assert blas_threads() == [1]
            with single_thread_blas():          # nested (reentrant): still one thread
                assert blas_threads() == [1]
            assert blas_threads() == [1]        # the outer block still holds the limit
        assert blas_threads() == before
