"""The real CLI (click's runner): simulate, sweep and config errors."""

import json
from pathlib import Path

import pandas as pd
import pytest
from click.testing import CliRunner

from planner.cli import main

ROOT = Path(__file__).resolve().parents[2]
FIG7 = str(ROOT / "configs" / "paper_fig7.yaml")


def run(*args):
    return CliRunner().invoke(main, list(args), catch_exceptions=False)


def test_simulate_json_reproduces_fig7_ratio():
    fast = json.loads(run("simulate", FIG7, "--freq", "6200", "--json").output)
    slow = json.loads(run("simulate", FIG7, "--freq", "5200", "--json").output)
    for key in ("natural_frequency_hz", "impacts", "response_n", "slider_displacement_m",
                "slider_mean_velocity_m_s"):
        assert key in fast
    assert fast["natural_frequency_hz"] == pytest.approx(5200.0)
    assert {"t_s", "v_minus_m_s"} <= set(fast["impacts"][0])
    assert len(fast["impacts"]) == 17
    assert 3.0 < fast["slider_mean_velocity_m_s"] / slow["slider_mean_velocity_m_s"] < 5.0


def test_simulate_table_and_plot(tmp_path):
    png = tmp_path / "fig7.png"
    res = run("simulate", FIG7, "--freq", "6200", "--freq", "5200", "--plot", str(png))
    assert res.exit_code == 0
    assert "6200.0" in res.output and "5200.0" in res.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_simulate_rk4_method_agrees():
    exact = json.loads(run("simulate", FIG7, "--freq", "6200", "--json").output)
    rk4 = json.loads(run("simulate", FIG7, "--freq", "6200", "--json", "--method", "rk4").output)
    assert rk4["response_n"] == pytest.approx(exact["response_n"], rel=1e-5)


def test_sweep_writes_csv(tmp_path):
    out = tmp_path / "fig9.csv"
    res = run("sweep", FIG7, "--from", "5000", "--to", "7000", "--step", "100", "--x0", "0,3",
              "--out", str(out), "--quiet")
    assert res.exit_code == 0, res.output
    frame = pd.read_csv(out)
    assert list(frame.columns) == ["frequency_hz", "r_n_x0_0um", "r_n_x0_3um"]
    assert len(frame) == 21 and frame["r_n_x0_0um"].max() > 0


@pytest.mark.parametrize("yaml_text, needle", [
    ("impacter:\n  area_um2: 1.5e4\n  gap_um: -3\n", "impacter.gap_um"),
    ("impacter:\n  area_um2: 1.5e4\n  colour: red\n", "impacter.colour: unknown key"),
    ("environment:\n  viscosity_mpa_s: [1, 2\n", "not valid YAML"),
])
def test_bad_config_exit_2_with_field_and_line(tmp_path, yaml_text, needle):
    cfg = tmp_path / "bad.yaml"
    cfg.write_text(yaml_text)
    res = CliRunner().invoke(main, ["simulate", str(cfg), "--freq", "6000"])
    assert res.exit_code == 2
    assert needle in res.output
    assert "line" in res.output
    assert "Traceback" not in res.output


def test_bad_config_line_number(tmp_path):
    cfg = tmp_path / "bad.yaml"
    cfg.write_text("name: x\nimpacter:\n  area_um2: 1.5e4\n  gap_um: -3\n")
    res = CliRunner().invoke(main, ["simulate", str(cfg), "--freq", "6000"])
    assert res.exit_code == 2 and "(line 4)" in res.output


def test_missing_config_exit_2(tmp_path):
    res = CliRunner().invoke(main, ["simulate", str(tmp_path / "nope.yaml"), "--freq", "6000"])
    assert res.exit_code == 2 and "no such file" in res.output


def test_sweep_bad_range_exit_2(tmp_path):
    res = CliRunner().invoke(main, ["sweep", FIG7, "--from", "7000", "--to", "5000", "--step",
                                    "10", "--out", str(tmp_path / "x.csv")])
    assert res.exit_code == 2 and "--to" in res.output
    assert not (tmp_path / "x.csv").exists()
