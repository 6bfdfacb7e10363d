"""vibroplan yield: fabrication sampling, the Monte Carlo, the Dask engine, the CLI.

One tiny 1 x 2 plan (two impacters, two steps of one scene) is planned once for the
module and written to a folder; every test reads it back through the real CLI.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from planner.cli import main


HUGE = """\
name: huge tolerance
fabrication:
  natural_frequency_pct: {die: 0, device: 15}
  line_width_um: {die: 0.2, device: 0.1}
"""


def _yield(args, tmp_path=None):
    res = CliRunner().invoke(main, ["yield", *[str(a) for a in args], "--quiet"])
    return res


def _read(out):
    return json.loads((out / "yield.json").read_text())


def test_zero_tolerance_is_refused_unless_allowed(tiny_plan_dir, tmp_path):
    """A plan without fabrication tolerances used to print "yield 1.000" as if measured;
    it is refused (exit 2, nothing written), and with --allow-zero every chip is the
    nominal one."""
    out = tmp_path / "y"
    res = _yield([tiny_plan_dir, "--chips", 4, "--seed", 3, "--out", out])
    assert res.exit_code == 2, res.output
    assert "--allow-zero" in res.output and "tolerance" in res.output
    assert not out.exists()
    res = _yield([tiny_plan_dir, "--chips", 4, "--seed", 3, "--out", out, "--allow-zero"])
    assert res.exit_code == 0, res.output
    d = _read(out)
    assert {"chips", "passed", "yield", "ci95", "seed", "tolerance", "failures",
            "impacters"} <= set(d)
    assert d["chips"] == 4 and d["passed"] == 4 and d["yield"] == 1.0
    assert d["failures"] == {} and d["nominal"]["passed"] is True
    assert set(d["impacters"]) == {"A1.forward", "A2.backward"}
    assert all(r == 0.0 for r in d["impacters"].values())
    assert all(v == {"die": 0.0, "device": 0.0, "pair": 0.0} for v in d["tolerance"].values()
               if isinstance(v, dict))
    lo, hi = d["ci95"]
    assert 0 < lo < 1 and hi == 1.0
    assert "by_sigma_scale" not in d
    assert (out / "report.md").is_file() and (out / "figures" / "impacters.png").is_file()


def test_huge_tolerance_fails_chips_and_names_checks(tiny_plan_dir, tmp_path):
    spec = tmp_path / "huge.yaml"
    spec.write_text(HUGE)
    out = tmp_path / "y"
    res = _yield([tiny_plan_dir / "plan.json", "--chips", 8, "--seed", 1, "--out", out,
                  "--spec", spec, "--sigma-scale", "0,1", "--allow-zero"])
    assert res.exit_code == 0, res.output
    d = _read(out)
    assert d["tolerance"]["natural_frequency_pct"]["device"] == 15.0
    assert d["yield"] < 1.0 and d["passed"] < d["chips"]
    assert d["failures"], "a failing chip must name the check that failed"
    from planner.yield_ import KINDS
    assert set(d["failures"]) <= set(KINDS)
    assert max(d["impacters"].values()) > 0
    assert set(d["by_sigma_scale"]) == {"0", "1"}
    assert d["by_sigma_scale"]["0"]["yield"] == 1.0
    assert d["by_sigma_scale"]["1"]["yield"] == d["yield"]
    report = (out / "report.md").read_text()
    assert next(iter(d["failures"])) in report and (out / "figures" / "failures.png").is_file()


def test_chip_results_depend_on_seed_and_index_only(tiny_plan_dir):
    """A chip's outcome is a function of (seed, scale, chip index): verifying chips in
    another order, or fewer of them, gives each the same result."""
    from planner.planfile.reader import read_plan
    from planner.arrayspec import load_spec
    from planner.yield_ import make_payload, verify_chip

    import dataclasses

    from planner.fabrication.tolerances import sample_chip
    from planner.core.rng import chip_seed

    fab = load_spec(HUGE).spec.fabrication
    record = read_plan(tiny_plan_dir)
    payload = make_payload(record, 5, fab)
    forward = [verify_chip(payload, 0, i, 1.0) for i in range(4)]
    backward = [verify_chip(payload, 0, i, 1.0) for i in reversed(range(4))][::-1]
    assert forward == backward
    # ... and of them all: another seed, another index or another scale draws another
    # chip (a chip that ignored any of them would pass the order check above)
    def drawn(seed, index, scale=1.0):
        chip = sample_chip(payload.design, fab,
                           np.random.default_rng(chip_seed(seed, scale, index)), scale)
        return [(imp.natural_frequency, imp.gap) for imp in chip.impacters.values()]

    assert drawn(5, 0) == drawn(5, 0)
    assert drawn(6, 0) != drawn(5, 0) and drawn(5, 1) != drawn(5, 0)
    assert drawn(5, 0, 0.5) != drawn(5, 0)
    # the verified outcome follows the chip: another seed's four chips differ from these
    other = [verify_chip(dataclasses.replace(payload, seed=6), 0, i, 1.0) for i in range(4)]
    assert other != forward


def test_failure_rates_count_the_impacters_each_chip_implicates(tiny_plan_dir):
    """yield.json's per-impacter failure rate is the fraction of chips whose checks
    implicated that impacter (a Node inside, its text in the file)."""
    from planner.core.nodes import Node
    from planner.planfile.reader import read_plan
    from planner.arrayspec import load_spec
    from planner.yield_ import make_payload, run_yield, verify_chip

    payload = make_payload(read_plan(tiny_plan_dir), 5, load_spec(HUGE).spec.fabrication)
    chips = [verify_chip(payload, 0, i, 1.0) for i in range(4)]
    data = run_yield(payload, 4)
    assert any(c.nodes for c in chips), "the huge tolerance must fail some impacter"
    assert all(isinstance(n, Node) for c in chips for n in c.nodes)
    assert data["impacters"] == {
        n.text: sum(n in c.nodes for c in chips) / 4 for n in payload.nodes}
    assert data["failed_chips"] == [c.chip for c in chips if not c.passed]


def test_failure_rates_land_on_their_devices_cells():
    """The report's array figure puts each impacter's rate on its own device's cell,
    two-digit columns included."""
    from planner.arrayspec import load_spec
    from planner.yield_.report import _grid

    spec = load_spec("name: wide\narray: {rows: 2, cols: 11}\n").spec
    rates = {"A2.forward": 0.5, "A10.forward": 1.0, "B11.backward": 0.25, "A1.backward": 0.0}
    forward, backward = _grid(spec, rates, "forward"), _grid(spec, rates, "backward")
    assert forward.shape == backward.shape == (2, 11)
    assert forward[0, 1] == 0.5 and forward[0, 9] == 1.0
    assert backward[1, 10] == 0.25 and backward[0, 0] == 0.0
    assert np.isnan(forward).sum() == 20 and np.isnan(backward).sum() == 20


def test_as_built_geometry_follows_the_documented_mapping(tiny_plan_dir):
    from planner.fabrication.tolerances import ERRORS, as_built_impacter, sample_chip
    from planner.planfile.reader import read_plan
    from planner.arrayspec import FabricationSpec
    from planner.yield_ import make_payload

    data = json.loads((tiny_plan_dir / "plan.json").read_text())
    payload = make_payload(read_plan(tiny_plan_dir), 0, allow_zero=True)
    # the nominal chip is the plan's impacters exactly
    chip = sample_chip(payload.design, FabricationSpec(), np.random.default_rng(0))
    for rec in data["impacters"]:
        imp = chip.impacters[rec["id"]]
        assert math.isclose(imp.mass, rec["mass_kg"], rel_tol=1e-9)
        assert math.isclose(imp.stiffness, rec["stiffness_n_per_m"], rel_tol=1e-9)
        assert math.isclose(imp.natural_frequency, rec["natural_frequency_hz"], rel_tol=1e-6)
    node = payload.design.nodes[0]
    spec = payload.loaded.spec
    err = dict.fromkeys(ERRORS, 0.0)
    err["line_width_um"] = 0.1
    wide = as_built_impacter(spec, node, [err[k] for k in ERRORS])
    assert math.isclose(wide.geometry.width, node.width + 0.1e-6)
    assert math.isclose(wide.gap, node.gap - 0.1e-6)
    assert math.isclose(wide.geometry.area, (math.sqrt(node.area) + 0.1e-6) ** 2)
    nominal = as_built_impacter(spec, node, [0.0] * len(ERRORS))
    assert wide.stiffness > nominal.stiffness  # k ~ w^3
    err = dict.fromkeys(ERRORS, 0.0)
    err["natural_frequency_pct"] = 3.0
    f3 = as_built_impacter(spec, node, [err[k] for k in ERRORS])
    assert math.isclose(f3.natural_frequency, 1.03 * nominal.natural_frequency, rel_tol=1e-12)
    assert f3.mass == nominal.mass


@pytest.mark.slow
def test_local_cluster_reproduces_the_local_run(tiny_plan_dir, tmp_path):
    from distributed import LocalCluster

    spec = tmp_path / "huge.yaml"
    spec.write_text(HUGE)
    local = tmp_path / "local"
    res = _yield([tiny_plan_dir, "--chips", 6, "--seed", 11, "--out", local, "--spec", spec])
    assert res.exit_code == 0, res.output
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster:
        remote = tmp_path / "remote"
        res = _yield([tiny_plan_dir, "--chips", 6, "--seed", 11, "--out", remote, "--spec", spec,
                      "--scheduler", cluster.scheduler_address])
        assert res.exit_code == 0, res.output
    a, b = _read(local), _read(remote)
    assert a == b
    assert a["passed"] < a["chips"], "the comparison needs some failing chips to mean much"


@pytest.mark.parametrize("text, field, line", [
    ("fabrication:\n  line_width_um: {die: -0.1, device: 0}\n",
     "fabrication.line_width_um.die", 2),
    ("name: x\nfabrication:\n  gap_um:\n    device: 0.1\n    per_wafer: 0.2\n",
     "fabrication.gap_um.per_wafer", 5),
    ("fabrication:\n  line_width_um: {die: 0.1}\n  stress_pct: {die: 1}\n",
     "fabrication.stress_pct", 3),
])
def test_bad_tolerance_spec_exits_2_with_field_and_line(tiny_plan_dir, tmp_path, text, field, line):
    spec = tmp_path / "bad.yaml"
    spec.write_text(text)
    out = tmp_path / "y"
    res = _yield([tiny_plan_dir, "--chips", 2, "--out", out, "--spec", spec])
    assert res.exit_code == 2, res.output
    assert field in res.output and f"line {line}" in res.output
    assert not out.exists()


def test_output_folder_refused_when_it_is_the_cwd(tiny_plan_dir, tmp_path, monkeypatch):
    here = tmp_path / "here"
    here.mkdir()
    monkeypatch.chdir(here)
    res = _yield([tiny_plan_dir, "--chips", 2, "--out", "."])
    assert res.exit_code == 2
    assert "current directory" in res.output
    assert list(here.iterdir()) == []


def test_bad_arguments_exit_2(tiny_plan_dir, tmp_path):
    res = _yield([tiny_plan_dir, "--chips", 2, "--out", tmp_path / "y", "--sigma-scale", "1,-2"])
    assert res.exit_code == 2 and "--sigma-scale" in res.output
    res = _yield([tmp_path / "nowhere", "--chips", 2, "--out", tmp_path / "y"])
    assert res.exit_code == 2 and "no such file" in res.output


def test_wilson_interval_matches_its_definition():
    from planner.yield_ import Z95, wilson_interval

    for passed, n in [(0, 10), (3, 10), (97, 100), (200, 200)]:
        lo, hi = wilson_interval(passed, n)
        p = passed / n
        # the Wilson bounds are the two roots in p0 of |p - p0| = z sqrt(p0 (1 - p0) / n)
        for p0 in (lo, hi):
            if 0 < p0 < 1:
                assert math.isclose(abs(p - p0), Z95 * math.sqrt(p0 * (1 - p0) / n),
                                    rel_tol=1e-9)
        assert lo <= p <= hi


@pytest.mark.slow
def test_jobs_2_local_cluster_reproduces_the_local_run(tiny_plan_dir, tmp_path):
    """--jobs 2 (the engine's own LocalCluster) gives the in-process numbers."""
    spec = tmp_path / "huge.yaml"
    spec.write_text(HUGE)
    outs = []
    for jobs in (1, 2):
        out = tmp_path / f"j{jobs}"
        res = _yield([tiny_plan_dir, "--chips", 6, "--seed", 4, "--out", out, "--spec", spec,
                      "--sigma-scale", "0.5,1", "--jobs", jobs])
        assert res.exit_code == 0, res.output
        outs.append(_read(out))
    assert outs[0] == outs[1]


@pytest.mark.slow
def test_sigint_with_local_cluster_leaves_nothing(tiny_plan_dir, tmp_path):
    """Ctrl-C while the Dask workers run: exit 130, no output folder, no temporaries."""
    import os
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "y"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    proc = subprocess.Popen([sys.executable, "-m", "planner.cli", "yield", str(tiny_plan_dir),
                             "--chips", "5000", "--jobs", "2", "--out", str(out), "--quiet",
                             "--allow-zero"],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(12)
    assert proc.poll() is None, proc.communicate()
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "interrupted" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == []
