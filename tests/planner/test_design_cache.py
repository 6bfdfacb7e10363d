"""The on-disk design cache of ``vibroplan plan`` (planner.planning.design_store)."""

import dataclasses
import re

import numpy as np
import pytest
from click.testing import CliRunner

from planner.cli import main
from planner.planning.design_store import (DesignStore, default_cache_dir, stage_digest,
                                           task_digest)
from tests.planner.test_pipeline import TINY


def _plan(*args):
    return CliRunner().invoke(main, ["plan", *map(str, args), "--no-figures", "--quiet"],
                              catch_exceptions=False)


def _design_entries(cache):
    """The design cache's entries that hold a design (the others: the reach's probes)."""
    import pickle

    from planner.designer.result import DesignResult

    return [p for p in sorted((cache / "designs").glob("*.pkl"))
            if isinstance(pickle.loads(p.read_bytes()), DesignResult)]


def _designs_line(output):
    return next(line for line in output.splitlines() if line.startswith("designs:"))


@pytest.fixture
def tiny_spec(tmp_path):
    path = tmp_path / "tiny.yaml"
    path.write_text(TINY)
    return path


@pytest.fixture(scope="module")
def two_plans(tmp_path_factory):
    """The tiny spec planned twice into one cache (figures drawn): the first run's and
    the second run's outputs, for the tests that read what a re-run takes from the
    cache (one pair of runs for all of them: each plan is a few seconds)."""
    tmp = tmp_path_factory.mktemp("two_plans")
    spec = tmp / "tiny.yaml"
    spec.write_text(TINY)
    cache = tmp / "cache"

    def run(out):
        res = CliRunner().invoke(main, ["plan", str(spec), "--out", str(tmp / out),
                                        "--cache-dir", str(cache), "--quiet"],
                                 catch_exceptions=False)
        assert res.exit_code == 0, res.output
        # what the first run stored, counted before the second can store more
        return res, {d: sorted(p.name for p in (cache / d).iterdir())
                     for d in ("designs", "verify", "figures")}

    first, stored = run("a")
    second, _ = run("b")
    return {"cache": cache, "a": tmp / "a", "b": tmp / "b", "first": first.output,
            "second": second.output, "stored": stored}


def test_a_second_plan_reads_every_design_from_the_cache(two_plans):
    first, second = two_plans["first"], two_plans["second"]
    a, b = two_plans["a"], two_plans["b"]
    assert ", 0 read from the design cache" in _designs_line(first)
    # the two designs and the reach's two probes, the probes counted apart (stored even
    # when this process probed the spec before, for another cache)
    stored = [n for n in two_plans["stored"]["designs"] if n.endswith(".pkl")]
    assert len(stored) == 4
    assert re.search(r"2 distinct, 0 read from the design cache \(.*\), 2 computed and "
                     r"stored; reach probes: 0 read, 2 computed and stored$",
                     _designs_line(first)), _designs_line(first)
    # the designs from the cache; the probes too, unless this process probed the spec
    # (then from its memory: neither read nor written)
    assert re.search(r"2 distinct, 2 read from the design cache \(.*\), 0 computed and "
                     r"stored(; reach probes: 2 read, 0 computed and stored)?$",
                     _designs_line(second)), _designs_line(second)
    assert (a / "plan.json").read_bytes() == (b / "plan.json").read_bytes()
    assert (a / "designs.csv").read_bytes() == (b / "designs.csv").read_bytes()


def _stages(output):
    """{stage: (read, computed)} of the CLI's "from the same cache:" line."""
    line = next(x for x in output.splitlines() if x.startswith("from the same cache:"))
    return {m[0]: (int(m[1]), int(m[2]))
            for m in re.findall(r"(\w+) (\d+) read, (\d+) computed and stored", line)}


def _without_timings(report):
    return report.read_text(encoding="utf-8").split("## Timings")[0]


def test_a_second_plan_reads_verification_and_manufacturability_from_the_cache(two_plans):
    """Issue 43: a re-run verified every step and predicted the yield again from the
    designs it read from the cache.  The first run stores each step's checks, the
    coupling matrix and the manufacturability block beside the designs; the second
    reads all of them, simulates nothing, and writes the same files byte for byte
    (report.md but its timings)."""
    a, b = two_plans["a"], two_plans["b"]
    stored = _stages(two_plans["first"])
    steps = stored["verify"][1]
    assert steps >= 2        # push and pull, and any re-check of the motion repair
    assert stored == {"coupling": (0, 1), "manufacturability": (0, 1), "verify": (0, steps)}
    assert len([n for n in two_plans["stored"]["verify"] if n.endswith(".pkl")]) == steps

    assert _stages(two_plans["second"]) == {"coupling": (1, 0), "manufacturability": (1, 0),
                                            "verify": (steps, 0)}
    for name in ("plan.json", "designs.csv", "coupling.csv"):
        assert (a / name).read_bytes() == (b / name).read_bytes()
    assert _without_timings(a / "report.md") == _without_timings(b / "report.md")
    assert sorted(p.name for p in (a / "waveforms").iterdir()) == sorted(
        p.name for p in (b / "waveforms").iterdir())
    for wav in (a / "waveforms").iterdir():
        assert wav.read_bytes() == (b / "waveforms" / wav.name).read_bytes()


def test_a_stage_digest_changes_with_the_seed_a_tolerance_and_a_step():
    """The cached verification and Monte Carlo are keyed by the settings as a whole:
    another seed (the Monte Carlo's), another line-width sigma or another step is
    another entry; the same inputs, the same digest."""
    from planner.arrayspec import load_spec
    from planner.planning.settings import resolve_settings

    fab = TINY + "fabrication:\n  line_width_um: {die: 0.05, device: 0.02}\n"
    s0 = resolve_settings(load_spec(fab), 0)
    assert stage_digest("manufacturability", s0) == stage_digest(
        "manufacturability", resolve_settings(load_spec(fab), 0))
    wider = fab.replace("die: 0.05", "die: 0.06")
    others = [resolve_settings(load_spec(fab), 1), resolve_settings(load_spec(wider), 0)]
    digests = {stage_digest("manufacturability", s) for s in others}
    digests.add(stage_digest("verify", s0))
    step = s0.steps[0]
    digests.add(stage_digest("manufacturability", s0, step))
    digests.add(stage_digest("manufacturability", s0, dataclasses.replace(
        step, duration_s=np.nextafter(step.duration_s, 1.0))))
    assert stage_digest("manufacturability", s0) not in digests and len(digests) == 5


@pytest.mark.slow
def test_an_unreadable_entry_is_recomputed_and_rewritten(tiny_spec, tmp_path):
    cache = tmp_path / "cache"
    assert _plan(tiny_spec, "--out", tmp_path / "a", "--cache-dir", cache).exit_code == 0
    # a design's entry, not a reach probe's (the store keeps both; a probe this process
    # measured before is read from its memory, not the file)
    entry = _design_entries(cache)[0]
    entry.write_bytes(entry.read_bytes()[:20])          # a truncated write
    again = _plan(tiny_spec, "--out", tmp_path / "b", "--cache-dir", cache)
    assert again.exit_code == 0, again.output
    line = _designs_line(again.output)
    # the other design (the two probes, unless this process probed the spec before,
    # counted apart)
    assert re.search(r"2 distinct, 1 read from the design cache \(.*\), 1 computed and "
                     r"stored(; reach probes: 2 read, 0 computed and stored)?$", line), line
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
    # the two designs and the reach's two probes
    assert res.exit_code == 0 and len(_design_entries(cache)) == 2
    assert len(list((cache / "designs").glob("*.pkl"))) == 4


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


def test_a_second_plan_reads_its_figures_from_the_cache(two_plans):
    """Issue 43, a re-run in 5 s: the figures (matplotlib's rendering and the response
    curves' simulations, ~4 s of the default's re-run) are kept in the cache by the
    plan's record, settings and drives; a re-run writes the same PNG bytes without
    drawing them."""
    first, second = ({p.name: p.read_bytes() for p in (two_plans[k] / "figures").iterdir()}
                     for k in ("a", "b"))
    assert "response_curves.png" in first and len(two_plans["stored"]["figures"]) == 1
    assert second == first
    assert len(list((two_plans["cache"] / "figures").iterdir())) == 1
    # keyed by what they are drawn from: another seed's plan (its own designs, drives
    # and record) has another key (stage_digest, as test_a_stage_digest_changes_...)
    assert stage_digest("figures", {"seed": 0}) != stage_digest("figures", {"seed": 7})


def test_a_plan_read_wholly_from_the_cache_starts_no_worker(tiny_spec, tmp_path, monkeypatch):
    """Issue 43: a re-run spawned the worker pool (two processes importing the planner and
    loading the kernels beside the main one) though every design, probe and stage came
    from the cache.  A plan the cache saw through starts its workers only for a task;
    a first plan starts them at once (they load the kernels while it assigns)."""
    from planner.planning import plan
    from planner.runtime import workers

    started = []
    real = workers.WarmPool.start

    def start(self):
        if self.pool is None:
            started.append(self.jobs)
        return real(self)

    monkeypatch.setattr(workers.WarmPool, "start", start)
    cache = tmp_path / "cache"
    first = plan(tiny_spec, jobs=2, cache_dir=cache, seed=3)
    assert started == [2]
    again = plan(tiny_spec, jobs=2, cache_dir=cache, seed=3)
    assert started == [2]                  # none for the re-run
    assert again.data == first.data
