"""Fuzz the real CLI with mutated copies of its inputs.

Every mutation (a key dropped, duplicated or retyped, a wrong type, NaN, a huge or
negative number, unicode, a truncated file) must end in exit 0, 1 or 2 with no
traceback, and nothing may be written unless the command succeeded or reports a
failed verification (exit 0 / 1).  Array specs go through ``vibroplan assign`` (the
spec, steps, conflict graph and colouring: the whole input path of ``plan`` without
the minutes of designs), device configs through ``vibroplan simulate``, a lab's sweep
through ``vibroplan calibrate``, a measured.csv through ``vibroplan replan`` and
plan.json through ``vibroplan drive`` (the one plan.json reader that yield and replan
share).  Bounded example counts keep the whole module to about a minute.
"""

import json
import math
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from planner.cli import main

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
ARRAY_SPECS = ["array_5x5.yaml", "row_assembly.yaml"]
DEVICE_CONFIGS = ["paper_fig7.yaml", "paper_table3.yaml"]

ODD_VALUES = [None, True, "", "ünïcødé ✓", "1e3", [], {}, [1, 2], {"x": 1}, math.nan, math.inf,
              -math.inf, 0, -1, -1e300, 1e300, 10**30, 3.5, "nan", 2**63]


def _paths(data, prefix=()):
    """Every path to a value in a nested YAML structure."""
    out = [prefix] if prefix else []
    if isinstance(data, dict):
        for k, v in data.items():
            out += _paths(v, prefix + (k,))
    elif isinstance(data, list):
        for i, v in enumerate(data):
            out += _paths(v, prefix + (i,))
    return out


def _get_parent(data, path):
    for p in path[:-1]:
        data = data[p]
    return data


def _mutate(draw, data, path, kind, factors):
    """Change the value at ``path`` of ``data`` in place: drop it, give it an odd value,
    rename its key, or scale a number by one of ``factors``."""
    parent = _get_parent(data, path)
    key = path[-1]
    if kind == "drop":
        del parent[key]
    elif kind == "retype":
        parent[key] = draw(st.sampled_from(ODD_VALUES))
    elif kind == "rename" and isinstance(parent, dict):
        parent[draw(st.sampled_from(["bogus", "ünï", key + "_x" if isinstance(key, str) else 7]))] \
            = parent.pop(key)
    elif kind == "scale":
        v = parent[key]
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            parent[key] = v * draw(st.sampled_from(factors))


@st.composite
def mutated(draw, files):
    name = draw(st.sampled_from(files))
    text = (CONFIGS / name).read_text()
    kind = draw(st.sampled_from(["drop", "retype", "rename", "duplicate_line", "truncate",
                                 "insert_unicode", "scale"]))
    if kind == "truncate":
        return name, text[:draw(st.integers(0, len(text)))]
    lines = text.splitlines(keepends=True)
    if kind == "duplicate_line":
        i = draw(st.integers(0, len(lines) - 1))
        return name, "".join(lines[:i + 1] + [lines[i]] + lines[i + 1:])
    if kind == "insert_unicode":
        i = draw(st.integers(0, len(text)))
        junk = draw(st.text(min_size=1, max_size=8))
        return name, text[:i] + junk + text[i:]
    data = yaml.safe_load(text)
    _mutate(draw, data, draw(st.sampled_from(_paths(data))), kind, [-1, 0, 1e-9, 1e9, 1e300])
    return name, yaml.safe_dump(data, allow_unicode=True, sort_keys=False)


def _check(result, outputs):
    assert result.exit_code in (0, 1, 2), (result.exit_code, result.output)
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise AssertionError(f"uncaught {type(result.exception).__name__}: "
                             f"{result.exception}\n{result.output}")
    assert "Traceback" not in result.output
    if result.exit_code == 2:
        assert "error" in result.output.lower()
        assert not any(p.exists() for p in outputs), "wrote output on a rejected input"


FUZZ = settings(max_examples=40, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture,
                                       HealthCheck.too_slow])


@FUZZ
@given(case=mutated(ARRAY_SPECS))
def test_fuzzed_array_specs(tmp_path, case):
    name, text = case
    spec = tmp_path / f"fuzz_{name}"
    spec.write_text(text, encoding="utf-8")
    out = tmp_path / "assignment.json"
    out.unlink(missing_ok=True)
    result = CliRunner().invoke(main, ["assign", str(spec), "--out", str(out),
                                       "--time-limit", "2"])
    _check(result, [out])


# half FUZZ's examples: each accepted config simulates a second and draws a plot
@settings(FUZZ, max_examples=20)
@given(case=mutated(DEVICE_CONFIGS))
def test_fuzzed_device_configs(tmp_path, case):
    """The plot is asked for: a rejected config writes none, an accepted one writes it
    (a PNG read back)."""
    name, text = case
    cfg = tmp_path / f"fuzz_{name}"
    cfg.write_text(text, encoding="utf-8")
    plot = tmp_path / "sim.png"
    plot.unlink(missing_ok=True)
    result = CliRunner().invoke(main, ["simulate", str(cfg), "--freq", "6200", "--duration",
                                       "1", "--plot", str(plot), "--force"])
    _check(result, [plot])
    if result.exit_code == 0:
        assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", result.output


@pytest.mark.parametrize("name", ARRAY_SPECS + DEVICE_CONFIGS)
def test_shipped_configs_are_not_rejected(tmp_path, name):
    """The fuzz's starting points are themselves valid (else the fuzz tests nothing)."""
    if name in ARRAY_SPECS:
        result = CliRunner().invoke(main, ["assign", str(CONFIGS / name), "--time-limit", "2"])
    else:
        result = CliRunner().invoke(main, ["simulate", str(CONFIGS / name), "--freq", "6200"])
    assert result.exit_code == 0, result.output


# --------------------------------------------------------------------------- lab CSVs

CSV_CELLS = ["", " ", "nan", "inf", "-inf", "1e300", "-1", "0", "abc", "ünï", "1,5", '"',
             "99999999999999999999999", "1e-300", "\x00", "A1.forward", "Z9.forward"]


@st.composite
def mutated_csv(draw, text):
    """``text`` (a valid CSV) with a line, a cell or the header changed, or truncated."""
    lines = text.splitlines()
    kind = draw(st.sampled_from(["cell", "header", "drop_line", "duplicate_line",
                                 "truncate", "junk", "bom", "extra_column"]))
    if kind == "truncate":
        return text[:draw(st.integers(0, len(text)))]
    if kind == "bom":
        return "\ufeff" + text
    if kind == "junk":
        i = draw(st.integers(0, len(text)))
        return text[:i] + draw(st.text(min_size=1, max_size=6)) + text[i:]
    i = draw(st.integers(0, len(lines) - 1))
    cells = lines[i].split(",")
    if kind == "cell":
        cells[draw(st.integers(0, len(cells) - 1))] = draw(st.sampled_from(CSV_CELLS))
        lines[i] = ",".join(cells)
    elif kind == "header":
        head = lines[0].split(",")
        head[draw(st.integers(0, len(head) - 1))] = draw(st.sampled_from(
            ["", "bogus", "frequency_khz", "impacter", "natural_frequency_hz", "gap_um"]))
        lines[0] = ",".join(head)
    elif kind == "drop_line":
        del lines[i]
    elif kind == "duplicate_line":
        lines.insert(i, lines[i])
    elif kind == "extra_column":
        lines[i] += ",1"
    return "\n".join(lines) + "\n"


def _sweep_text():
    import numpy as np

    from planner.lab.calibrate import transmissibility

    f = np.linspace(4000.0, 4600.0, 24)
    a = 0.1 * transmissibility(f, 4300.0, 40.0)
    return "impacter,frequency_hz,amplitude_um\n" + "".join(
        f"A1.forward,{float(x)!r},{float(y)!r}\n" for x, y in zip(f, a))


CSV_FUZZ = settings(max_examples=25, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.function_scoped_fixture,
                                           HealthCheck.too_slow])


@CSV_FUZZ
@given(text=mutated_csv(_sweep_text()))
def test_fuzzed_sweeps(tmp_path, text):
    sweep = tmp_path / "sweep.csv"
    sweep.write_text(text, encoding="utf-8")
    out = tmp_path / "measured.csv"
    out.unlink(missing_ok=True)
    _check(CliRunner().invoke(main, ["calibrate", str(sweep), "--out", str(out)]), [out])


MEASURED = ("impacter,natural_frequency_hz,quality_factor,gap_um\n"
            "A1.forward,4400.5,30,2.5\nA2.backward,{nu},,\n")


@settings(max_examples=15, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(data=st.data())
def test_fuzzed_measured_csv(tiny_plan_dir, tmp_path, data):
    plan = json.loads((tiny_plan_dir / "plan.json").read_text())
    nu = {r["id"]: r["natural_frequency_hz"] for r in plan["impacters"]}["A2.backward"]
    text = data.draw(mutated_csv(MEASURED.format(nu=nu)))
    measured = tmp_path / "measured.csv"
    measured.write_text(text, encoding="utf-8")
    out = tmp_path / "replan_out"
    import shutil

    shutil.rmtree(out, ignore_errors=True)
    _check(CliRunner().invoke(main, ["replan", str(tiny_plan_dir), "--measured", str(measured),
                                     "--out", str(out), "--no-figures", "--quiet"]), [out])


# --------------------------------------------------------------------------- plan.json


@st.composite
def mutated_plan(draw, data):
    """plan.json with one value dropped or retyped, or its text truncated."""
    kind = draw(st.sampled_from(["drop", "retype", "retype", "scale", "truncate"]))
    if kind == "truncate":
        text = json.dumps(data)
        return text[:draw(st.integers(0, len(text) - 1))]
    data = json.loads(json.dumps(data))
    # the keys the reader declares, and a few it ignores
    paths = [p for p in _paths(data)
             if p[0] in ("format_version", "seed", "spec", "impacters", "devices", "steps",
                         "verification", "assignment")
             and not (p[0] == "verification" and len(p) > 3)]
    _mutate(draw, data, draw(st.sampled_from(paths)), kind, [-1, 0, 1.5, 1e9, 1e300])
    return json.dumps(data, allow_nan=True)


@settings(max_examples=40, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(data=st.data())
def test_fuzzed_plan_json(tiny_plan_dir, tmp_path, data):
    original = json.loads((tiny_plan_dir / "plan.json").read_text())
    plan = tmp_path / "plan.json"
    plan.write_text(data.draw(mutated_plan(original)), encoding="utf-8")
    out = tmp_path / "drive.wav"
    for p in (out, tmp_path / "drive.wav.json"):
        p.unlink(missing_ok=True)
    _check(CliRunner().invoke(main, ["drive", str(plan), "--step", "pull", "--out", str(out)]),
           [out])


# --------------------------------------------------------------------------- plan.json blocks

#: Every block of plan.json a command reads (the reader's, and a re-plan's own).
PLAN_BLOCKS = ("assignment", "impacters", "devices", "steps", "manufacturability", "spec",
               "verification", "as_built", "replan", "seed", "format_version")


@pytest.fixture(scope="module")
def replanned_tiny(tiny_plan_dir, tmp_path_factory):
    """The tiny plan re-planned for a chip 1 % off its design (a plan with as_built and
    replan blocks), by the CLI."""
    plan = json.loads((tiny_plan_dir / "plan.json").read_text())
    root = tmp_path_factory.mktemp("replanned")
    csv = root / "measured.csv"
    csv.write_text("impacter,natural_frequency_hz\n" + "".join(
        f"{r['id']},{1.01 * r['natural_frequency_hz']!r}\n" for r in plan["impacters"]))
    res = CliRunner().invoke(main, ["replan", str(tiny_plan_dir), "--measured", str(csv),
                                    "--out", str(root / "r"), "--quiet", "--no-figures"])
    assert res.exit_code in (0, 1), res.output
    return root / "r"


@st.composite
def mutated_block(draw, data):
    """plan.json with one value of one block dropped, retyped, renamed or scaled."""
    data = json.loads(json.dumps(data))
    kind = draw(st.sampled_from(["drop", "retype", "retype", "rename", "scale"]))
    blocks = [b for b in PLAN_BLOCKS if b in data]
    block = draw(st.sampled_from(blocks))
    paths = [p for p in _paths(data) if p[0] == block and len(p) <= 5]
    _mutate(draw, data, draw(st.sampled_from(paths)), kind, [-1, 0, 1.003, 1e3, 1e300])
    return json.dumps(data, allow_nan=True)


@settings(max_examples=16, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(data=st.data())
def test_fuzzed_plan_json_blocks(tiny_plan_dir, replanned_tiny, tmp_path, data):
    """Every block of plan.json that any command reads, mutated, through the command that
    reads it (drive, layout, replan, trim, yield): exit 0, 1 or 2, never a traceback,
    nothing written on a refusal."""
    import shutil

    base = data.draw(st.sampled_from([tiny_plan_dir, replanned_tiny]), label="plan")
    original = json.loads((base / "plan.json").read_text())
    folder = tmp_path / "plan"
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir()
    (folder / "plan.json").write_text(data.draw(mutated_block(original)), encoding="utf-8")
    measured = tmp_path / "measured.csv"
    measured.write_text("impacter,natural_frequency_hz\n" + "".join(
        f"{r['id']},{r['natural_frequency_hz']!r}\n" for r in original["impacters"]))
    out = tmp_path / "out"
    shutil.rmtree(out, ignore_errors=True)
    for p in tmp_path.glob("chip*"):
        p.unlink()
    command = data.draw(st.sampled_from(["drive", "layout", "replan", "trim", "yield"]),
                        label="command")
    args = {"drive": ["drive", folder, "--step", "pull", "--out", tmp_path / "chip.wav"],
            "layout": ["layout", folder, "--out", tmp_path / "chip.gds"],
            "replan": ["replan", folder, "--measured", measured, "--out", out,
                       "--no-figures", "--quiet"],
            "trim": ["trim", folder, "--measured", measured, "--out", out, "--no-figures",
                     "--quiet"],
            "yield": ["yield", folder, "--out", out, "--chips", "1", "--allow-zero",
                      "--quiet"]}[command]
    result = CliRunner().invoke(main, [str(a) for a in args])
    _check(result, [out, tmp_path / "chip.wav", tmp_path / "chip.gds"])
