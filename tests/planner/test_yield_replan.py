"""vibroplan yield --replan: every chip measured, re-planned, and verified on its true models.

The tiny 1 x 2 plan of the plan tests is planned once for the module (real designer,
real verification); every test runs the real CLI on it and reads yield.json back.
"""

from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from planner.cli import main

#: Natural frequencies scattered by a few per cent: a die shift of sigma 4 % moves both
#: resonances together, the device part apart; the plan's fixed tones then miss.
SHIFT = """\
name: a few per cent
fabrication:
  natural_frequency_pct: {die: 4, device: 2}
"""


@pytest.fixture(scope="module")
def shift_spec(tmp_path_factory):
    path = tmp_path_factory.mktemp("spec") / "shift.yaml"
    path.write_text(SHIFT)
    return path


def _yield(*args):
    return CliRunner().invoke(main, ["yield", *[str(a) for a in args], "--quiet"])


def _read(out):
    return json.loads((out / "yield.json").read_text())


def test_replan_rescues_chips_the_nominal_drive_fails(tiny_plan_dir, shift_spec, tmp_path):
    out = tmp_path / "y"
    res = _yield(tiny_plan_dir, "--chips", 6, "--seed", 0, "--out", out, "--spec", shift_spec,
                 "--replan", "--sigma-scale", "0,1", "--allow-zero")
    assert res.exit_code == 0, res.output
    d = _read(out)
    # the existing keys are all still there, the nominal numbers unchanged in meaning
    assert {"chips", "passed", "yield", "ci95", "ci95_method", "seed", "tolerance",
            "failures", "impacters", "carried_state", "nominal", "failed_chips",
            "by_sigma_scale", "plan"} <= set(d)
    rp = d["replan"]
    # without --measure-noise, the spec's own fabrication.measurement_noise_pct
    assert rp["measure_noise_pct"] == 0.05
    assert rp["nominal_drive"] == {"passed": d["passed"], "yield": d["yield"],
                                   "ci95": d["ci95"]}
    assert d["passed"] < d["chips"], "the shifted chips must defeat the plan's own drive"
    assert rp["rescued"] >= 1 and rp["yield"] > d["yield"]
    lo, hi = rp["ci95"]
    assert lo <= rp["yield"] <= hi
    # per chip: the nominal verdict is the nominal run's, the re-plan's is its own
    per = {c["chip"]: c for c in rp["per_chip"]}
    assert sorted(per) == list(range(6))
    assert [c for c in per if not per[c]["nominal_passed"]] == d["failed_chips"]
    assert [c for c in per if not per[c]["replan_passed"]] == rp["failed_chips"]
    assert rp["rescued"] == sum(1 for c in per.values()
                                if c["replan_passed"] and not c["nominal_passed"])
    for c in per.values():
        assert c["replan_passed"] == (c["causes"] == [] and c["failures"] == {})
    # the design-exact chip re-plans to a passing drive; zero scale: nothing to rescue
    assert rp["nominal"]["replan_passed"] is True
    assert d["by_sigma_scale"]["0"]["replan"]["yield"] == 1.0
    assert d["by_sigma_scale"]["1"]["replan"]["yield"] == rp["yield"]
    report = (out / "report.md").read_text()
    assert "Re-planned per chip" in report and f"{rp['yield']:.3f}" in report
    assert "re-planned yield" in res.output and "re-plan cost" in res.output


def test_replanned_drive_is_verified_on_the_true_models(tiny_plan_dir, shift_spec, tmp_path):
    """The same chips measured with 10 % noise: the re-plans are made for the wrong
    resonances, verify on the models they were made for, and fail on the chips."""
    got = {}
    for noise in (0, 10):
        out = tmp_path / f"n{noise}"
        res = _yield(tiny_plan_dir, "--chips", 6, "--seed", 1, "--out", out, "--spec", shift_spec,
                     "--replan", "--measure-noise", noise)
        assert res.exit_code == 0, res.output
        got[noise] = _read(out)
    clean, noisy = got[0]["replan"], got[10]["replan"]
    # the chips and the plan's drive on them do not depend on the measurement
    assert got[0]["failed_chips"] == got[10]["failed_chips"]
    assert noisy["measure_noise_pct"] == 10.0
    assert noisy["yield"] < clean["yield"]
    # a re-plan that verifies on its (measured) models but fails on the chip's true ones
    assert any(c["measured_passed"] and not c["replan_passed"] for c in noisy["per_chip"])
    assert noisy["causes"].get("fails only on the true models", 0) >= 1


def test_chip_results_with_replan_do_not_depend_on_order(tiny_plan_dir, shift_spec):
    import dataclasses

    from planner.planfile.reader import read_plan
    from planner.arrayspec import load_spec
    from planner.yield_ import make_payload, verify_chip

    payload = make_payload(read_plan(tiny_plan_dir), 2, load_spec(shift_spec).spec.fabrication,
                           replan=True,
                           measure_noise_pct=3.0)

    def strip(r):   # wall times are the only thing allowed to differ
        return dataclasses.replace(r, seconds=None)

    forward = [strip(verify_chip(payload, 0, i, 1.0)) for i in range(3)]
    backward = [strip(verify_chip(payload, 0, i, 1.0)) for i in reversed(range(3))][::-1]
    assert forward == backward
    assert all(r.replan is not None for r in forward)


@pytest.mark.slow
def test_jobs_1_and_2_write_byte_identical_yield_json(tiny_plan_dir, shift_spec, tmp_path):
    """~20 s, most of it the two-worker LocalCluster starting."""
    outs = []
    for jobs in (1, 2):
        out = tmp_path / f"j{jobs}"
        res = _yield(tiny_plan_dir, "--chips", 4, "--seed", 7, "--out", out, "--spec", shift_spec,
                     "--replan", "--measure-noise", 1.5, "--jobs", jobs)
        assert res.exit_code == 0, res.output
        outs.append((out / "yield.json").read_bytes())
    assert outs[0] == outs[1]
    assert b'"per_chip"' in outs[0]


@pytest.mark.parametrize("args, needle", [
    (["--replan", "--measure-noise", "-1"], "--measure-noise"),
    (["--replan", "--measure-noise", "nan"], "--measure-noise"),
    (["--replan", "--measure-noise", "lots"], "--measure-noise"),
    (["--measure-noise", "2"], "--replan"),
])
def test_bad_measure_noise_exits_2_naming_the_option(tiny_plan_dir, tmp_path, args, needle):
    out = tmp_path / "y"
    res = _yield(tiny_plan_dir, "--chips", 2, "--out", out, *args)
    assert res.exit_code == 2, res.output
    assert needle in res.output and "--measure-noise" in res.output
    assert not out.exists()


#: Line width scatter of the default's device part, doubled: on the close plan's four
#: impacters (0.8 kHz apart at 21-23 kHz) some chips' neighbours come too close to be
#: told apart, and a 1 % trim moves them apart again.
SCATTER = """\
name: scatter
fabrication:
  line_width_um: {die: 0.05, device: 0.04}
trim: {range_pct: 1.0, direction: up, precision_pct: 0.1}
"""


@pytest.mark.slow
def test_trim_rescues_chips_the_replan_cannot_and_jobs_do_not_change_it(close_plan_dir,
                                                                       tmp_path):
    """yield --replan --trim on the close plan: chips whose neighbours collide are
    trimmed, measured again, re-planned and verified on their trimmed true models; the
    trimmed yield is at least the re-planned one, and --jobs 1 and --jobs 2 (a local
    Dask cluster) write byte-identical yield.json."""
    spec = tmp_path / "scatter.yaml"
    spec.write_text(SCATTER)
    outs = []
    for jobs in (1, 2):
        out = tmp_path / f"y{jobs}"
        res = _yield(close_plan_dir, "--chips", 12, "--seed", 3, "--out", out, "--spec", spec,
                     "--replan", "--trim", "--measure-noise", 0.05, "--jobs", jobs)
        assert res.exit_code == 0, res.output
        outs.append(out)
    assert (outs[0] / "yield.json").read_bytes() == (outs[1] / "yield.json").read_bytes()
    d = _read(outs[0])
    rp, tr = d["replan"], d["trim"]
    assert {"yield", "ci95", "passed", "failures"} <= set(tr)
    assert tr["passed"] >= rp["passed"]
    collided = [c for c in rp["per_chip"] if "cannot be told apart" in c["causes"]]
    assert collided, "the doubled device scatter must make some neighbours collide"
    trimmed = [c for c in rp["per_chip"] if c.get("trimmed")]
    assert {c["chip"] for c in trimmed} <= {c["chip"] for c in collided}
    assert tr["rescued"] == sum(1 for c in rp["per_chip"]
                                if c["trim_passed"] and not c["replan_passed"])
    assert "Trimmed where needed" in (outs[0] / "report.md").read_text()


def test_trim_needs_replan(tiny_plan_dir, shift_spec, tmp_path):
    res = _yield(tiny_plan_dir, "--chips", 2, "--out", tmp_path / "y", "--spec", shift_spec,
                 "--trim")
    assert res.exit_code == 2 and "--trim needs --replan" in res.output
    res = _yield(tiny_plan_dir, "--chips", 2, "--out", tmp_path / "y", "--spec", shift_spec,
                 "--replan", "--trim", "--trim-precision", "-1")
    assert res.exit_code == 2 and "--trim-precision" in res.output
