"""The on-disk design cache of ``vibroplan plan`` (planner.planning.design_store)."""

import dataclasses

import numpy as np
import pytest
from click.testing import CliRunner

from planner.cli import main
from planner.planning.design_store import DesignStore, default_cache_dir, task_digest
from tests.planner.test_pipeline import TINY


def _plan(*args):
    return CliRunner().invoke(main, ["plan", *map(str, args), "--no-figures", "--quiet"],
                              catch_exceptions=False)


def _designs_line(output):
    return next(line for line in output.splitlines() if line.startswith("designs:"))


@pytest.fixture
def tiny_spec(tmp_path):
    path = tmp_path / "tiny.yaml"
    path.write_text(TINY)
    return path


def test_a_second_plan_reads_every_design_from_the_cache(tiny_spec, tmp_path):
    cache = tmp_path / "cache"
    first = _plan(tiny_spec, "--out", tmp_path / "a", "--cache-dir", cache)
    assert first.exit_code == 0, first.output
    assert ", 0 read from the design cache" in _designs_line(first.output)
    stored = sorted((cache / "designs").glob("*.pkl"))
    assert len(stored) == 2 and "2 computed and stored" in _designs_line(first.output)

    second = _plan(tiny_spec, "--out", tmp_path / "b", "--cache-dir", cache)
    assert second.exit_code == 0, second.output
    assert "2 read from the design cache" in _designs_line(second.output)
    assert "0 computed" in _designs_line(second.output)
    assert ((tmp_path / "a" / "plan.json").read_bytes()
            == (tmp_path / "b" / "plan.json").read_bytes())
    assert ((tmp_path / "a" / "designs.csv").read_bytes()
            == (tmp_path / "b" / "designs.csv").read_bytes())


@pytest.mark.slow
def test_an_unreadable_entry_is_recomputed_and_rewritten(tiny_spec, tmp_path):
    cache = tmp_path / "cache"
    assert _plan(tiny_spec, "--out", tmp_path / "a", "--cache-dir", cache).exit_code == 0
    entry = sorted((cache / "designs").glob("*.pkl"))[0]
    entry.write_bytes(entry.read_bytes()[:20])          # a truncated write
    again = _plan(tiny_spec, "--out", tmp_path / "b", "--cache-dir", cache)
    assert again.exit_code == 0, again.output
    line = _designs_line(again.output)
    assert "1 read from the design cache" in line and "1 computed and stored" in line
    assert ((tmp_path / "a" / "plan.json").read_bytes()
            == (tmp_path / "b" / "plan.json").read_bytes())
    assert DesignStore(cache).get(entry.stem) is not None


@pytest.mark.slow
def test_the_default_cache_follows_the_environment_and_no_cache_writes_nothing(
        tiny_spec, tmp_path, monkeypatch):
    cache = tmp_path / "env-cache"
    monkeypatch.setenv("VIBROPLAN_CACHE_DIR", str(cache))
    assert default_cache_dir() == cache
    res = _plan(tiny_spec, "--out", tmp_path / "a", "--no-cache")
    assert res.exit_code == 0, res.output
    assert not cache.exists()
    assert not any(line.startswith("designs:") for line in res.output.splitlines())
    res = _plan(tiny_spec, "--out", tmp_path / "b")
    assert res.exit_code == 0 and len(list((cache / "designs").glob("*.pkl"))) == 2


def test_cache_dir_and_no_cache_exclude_each_other(tiny_spec, tmp_path):
    res = _plan(tiny_spec, "--out", tmp_path / "a", "--no-cache", "--cache-dir", tmp_path)
    assert res.exit_code == 2 and "exclude each other" in res.output
    assert not (tmp_path / "a").exists()


def test_the_digest_changes_with_any_input():
    from model import Drive
    from planner.designer import Ensemble

    drive = Drive(frequencies=np.array([1e4, 2e4]), amplitudes=np.array([1e-7, 2e-7]),
                  phases=np.array([0.0, 1.0]))
    kw = {"frequency": 5000.0, "forbidden": (6000.0, 7000.0), "seed": 3, "budget": "fast",
          "forbidden_drives": [Ensemble(drive, "s/a")]}
    same = {**kw, "forbidden_drives": [Ensemble(dataclasses.replace(drive), "s/a")]}
    assert task_digest(kw, 1e-4) == task_digest(same, 1e-4)
    nudged = Drive(frequencies=drive.frequencies, amplitudes=drive.amplitudes,
                   phases=np.array([0.0, np.nextafter(1.0, 2.0)]))
    changed = [{**kw, "forbidden_drives": [Ensemble(nudged, "s/a")]},
               {**kw, "seed": 4}, {**kw, "frequency": np.nextafter(5000.0, 0.0)},
               {**kw, "forbidden": (6000.0,)}, {**kw, "budget": "full"}]
    digests = {task_digest(c, 1e-4) for c in changed} | {task_digest(kw, 2e-4)}
    assert task_digest(kw, 1e-4) not in digests and len(digests) == len(changed) + 1
