"""Fuzz the real CLI with mutated copies of the shipped configs.

Every mutation (a key dropped, duplicated or retyped, a wrong type, NaN, a huge or
negative number, unicode, a truncated file) must end in exit 0, 1 or 2 with no
traceback, and nothing may be written unless the command succeeded or reports a
failed verification (exit 0 / 1).  Array specs go through ``vibroplan assign`` (the
spec, steps, conflict graph and colouring: the whole input path of ``plan`` without
the minutes of designs), device configs through ``vibroplan simulate``.
"""

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
    path = draw(st.sampled_from(_paths(data)))
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
            parent[key] = v * draw(st.sampled_from([-1, 0, 1e-9, 1e9, 1e300]))
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


@FUZZ
@given(case=mutated(DEVICE_CONFIGS))
def test_fuzzed_device_configs(tmp_path, case):
    name, text = case
    cfg = tmp_path / f"fuzz_{name}"
    cfg.write_text(text, encoding="utf-8")
    plot = tmp_path / "sim.png"
    plot.unlink(missing_ok=True)
    result = CliRunner().invoke(main, ["simulate", str(cfg), "--freq", "6200", "--duration", "1"])
    _check(result, [plot])


@pytest.mark.parametrize("name", ARRAY_SPECS + DEVICE_CONFIGS)
def test_shipped_configs_are_not_rejected(tmp_path, name):
    """The fuzz's starting points are themselves valid (else the fuzz tests nothing)."""
    if name in ARRAY_SPECS:
        result = CliRunner().invoke(main, ["assign", str(CONFIGS / name), "--time-limit", "2"])
    else:
        result = CliRunner().invoke(main, ["simulate", str(CONFIGS / name), "--freq", "6200"])
    assert result.exit_code == 0, result.output
