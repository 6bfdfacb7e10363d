"""The import contracts of pyproject.toml hold, with no import excused: the packages of
planner stand on floors (``planner-layers``) and import only what lies below them, and
no module imports one that imports it back (the layers leave no room for a circle).

``lint-imports`` reads every import statement, function-local ones included; CI runs it
too (.ci/run), this puts it beside the other tests.
"""

import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _contracts():
    with (ROOT / "pyproject.toml").open("rb") as f:
        return tomllib.load(f)["tool"]["importlinter"]["contracts"]


def test_no_contract_excuses_an_import():
    """An ``ignore_imports`` is a known wrong import kept: mend the code instead."""
    excused = {c["id"]: c["ignore_imports"] for c in _contracts() if c.get("ignore_imports")}
    assert excused == {}


def test_every_module_of_planner_has_its_floor():
    layers = {c["id"]: c for c in _contracts()}["planner-layers"]
    assert layers["type"] == "layers" and layers["containers"] == ["planner"]
    assert layers.get("exhaustive") is True


def test_the_import_contracts_hold(monkeypatch):
    cli = pytest.importorskip("importlinter.cli")
    monkeypatch.chdir(ROOT)
    assert cli.lint_imports(config_filename=str(ROOT / "pyproject.toml"), no_cache=True,
                            no_logo=True) == 0
