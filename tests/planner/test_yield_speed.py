"""The lab's loop made faster without changing what it finds (issue 43, item 7).

A chip of ``vibroplan yield --replan --tune --trim`` is checked many times over; the
checks now share what they simulate alike (a device's runs from rest and from its x0
grid, a device checked again with the same models and drive), a re-plan sizes its
travel bursts within its travel limit before it verifies them, and a re-plan's record
no longer depends on the process's string hash.  Each test holds a shortcut against the
simulation it replaces, on the real solver (the tiny 1 x 2 plan, planned once).
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def tiny(tiny_plan_dir):
    """(settings, steps, waveforms, impacters by node, sliders) of the tiny plan's
    nominal chip."""
    from planner.afterfab.checks import drive_of
    from planner.afterfab.replan import chip_models
    from planner.planfile.reader import read_plan
    from planner.planning.settings import plan_settings

    record = read_plan(tiny_plan_dir)
    built = chip_models(record, {}, 0.0)
    impacters = {r.node: built.impacters[r.id] for r in record.impacters}
    steps, waveforms, _ = drive_of(record)
    return plan_settings(record), steps, waveforms, impacters, dict(built.sliders)


def test_a_checks_shared_runs_give_the_simulations_own_numbers(tiny):
    """Every row of check_step (which shares the runs from rest and the x0 = 0 start
    between a device's travel and its speed check) equals the runs made one by one,
    each simulated afresh: the worst speed over the x0 grid and the travel from rest."""
    from planner.planning.drives import program_of
    from planner.planning.motion import device_travel
    from planner.planning.verify import check_step, device_motion, pair_starts

    settings, steps, waveforms, impacters, sliders = tiny
    checked = 0
    for st in steps:
        rows, _ = check_step(settings, st, waveforms[st.key], impacters, sliders)
        program = program_of(waveforms[st.key], st.duration_s)
        (duration, drive), = program
        active = st.active_nodes()
        for row in rows:
            dev = row["device"]
            own = {n: m for n, m in impacters.items() if n.device == dev}
            contact = settings.contacts[dev]
            alone = device_travel(own, dev, sliders[dev], contact, program,
                                  settings.max_settle_s)
            assert row["predicted_displacement_m"] == alone[0]
            assert row["travel_m"] == alone[1] and row["settle_s"] == alone[2]
            moving = [n for n in own if n in active]
            if moving:
                n = moving[0]
                speeds = [n.sign * device_motion(own, sliders[dev], drive, duration,
                                                 {n: start}, contact)[0] / duration
                          for start in pair_starts(own[n], settings.x0_points)]
                assert row["min_speed_m_s"] == min(speeds)
                # the grid's starts really differ: a memo keyed without the start
                # would give one speed for all of them
                assert len(set(speeds)) > 1
                checked += 1
    assert checked == len(steps)


def test_shared_device_checks_answer_only_what_was_checked_with_the_same_inputs(tiny):
    """Inside shared_device_checks a device checked again is answered from memory; a
    device whose slider changed is simulated again; the rows are those of the checks
    run outside it."""
    from planner.planning.verify import _DEVICE_CHECKS, check_step, shared_device_checks

    settings, steps, waveforms, impacters, sliders = tiny
    st = steps[0]
    dev = sorted(sliders)[0]
    heavier = {**sliders, dev: dataclasses.replace(sliders[dev],
                                                   mass=1.5 * sliders[dev].mass)}
    outside = [check_step(settings, st, waveforms[st.key], impacters, s)
               for s in (sliders, heavier)]
    assert outside[0][0] != outside[1][0], "a heavier slider must change the rows"
    with shared_device_checks():
        inside = [check_step(settings, st, waveforms[st.key], impacters, s)
                  for s in (sliders, heavier, sliders)]
        assert len(_DEVICE_CHECKS.get()) == len(sliders) + 1   # one device changed
    assert _DEVICE_CHECKS.get() is None
    assert inside[0] == outside[0] and inside[1] == outside[1] and inside[2] == outside[0]
    # a row answered from memory is a copy: changing it changes no later answer
    with shared_device_checks():
        first = check_step(settings, st, waveforms[st.key], impacters, sliders)[0]
        first[0]["passed"] = "changed"
        again = check_step(settings, st, waveforms[st.key], impacters, sliders)[0]
    assert again == outside[0][0]


def test_a_replans_travel_burst_is_held_within_its_travel_limit(tiny):
    """size_within: the burst the slowest slider asks for, at most 0.8 x the limit over
    the fastest probe speed (floored to the burst quantum); a generous limit leaves the
    sizing's burst as it was."""
    from planner.afterfab.drive import PRESIZE_FACTOR, size_within
    from planner.planning.motion import BURST_QUANTUM_S, size_bursts

    settings, steps, waveforms, impacters, sliders = tiny
    st = dataclasses.replace(steps[0], travel_m=200e-6, max_duration_s=0.06)
    (sized,), notes = size_bursts(settings, (st,), waveforms, impacters, sliders)
    fastest = max(abs(v) for v in notes[st.key]["probe_speeds_m_s"].values())
    assert fastest > 0
    (free,), _ = size_within(settings, (st,), waveforms, impacters, sliders, 1.0)
    assert free.duration_s == sized.duration_s
    limit = 0.5 * fastest * sized.duration_s       # half what the sized burst travels
    (held,), held_notes = size_within(settings, (st,), waveforms, impacters, sliders, limit)
    want = BURST_QUANTUM_S * (PRESIZE_FACTOR * limit / fastest // BURST_QUANTUM_S)
    assert held.duration_s == pytest.approx(want, abs=1e-12)
    assert held.duration_s < sized.duration_s
    assert held_notes[st.key]["travel_limited_s"] == held.duration_s
    # a step without a travel is left alone
    (plain,), _ = size_within(settings, (steps[1],), waveforms, impacters, sliders, 1e-9)
    assert plain == steps[1]


_GUARD_SCRIPT = """
import sys
from pathlib import Path
from planner.arrayspec import load_spec
from planner.afterfab.replan import _assignment
from planner.core.nodes import Node
from planner.planning.settings import resolve_settings

settings = resolve_settings(load_spec(Path(sys.argv[1])))
grid = list(settings.channel_grid_hz)
nodes = sorted({Node(d, r) for st in settings.steps for d, r in st.active_nodes()})
chosen = {n: float(grid[(7 * k) % len(grid)]) for k, n in enumerate(nodes)}
for v in _assignment(settings.steps, settings, chosen, 0).violations:
    print(v)
"""


# slow (~5 s): two interpreters with different hash seeds re-plan the same chip
@pytest.mark.slow
def test_a_replans_guard_warnings_do_not_depend_on_the_string_hash():
    """The re-plan's guard warnings (plan.json's assignment) came out in the order of a
    set of nodes, which follows the process's string hash: two runs of one re-plan
    wrote two plan.json.  Two processes with different hash seeds must print the same."""
    outs = []
    for seed in ("1", "2"):
        env = {**os.environ, "PYTHONHASHSEED": seed, "PYTHONPATH": str(ROOT)}
        proc = subprocess.run([sys.executable, "-c", _GUARD_SCRIPT,
                               str(ROOT / "configs" / "array_5x5.yaml")],
                              capture_output=True, text=True, env=env, timeout=600)
        assert proc.returncode == 0, proc.stderr[-2000:]
        outs.append(proc.stdout)
    assert outs[0].count("\n") > 5, "the tones must give warnings for the test to mean anything"
    assert outs[0] == outs[1]


def _worker_settings():
    """A task's view of its worker: the malloc setting distributed would give it and
    whether the worker's statistical profiler runs."""
    import dask

    return (os.environ.get("MALLOC_TRIM_THRESHOLD_"),
            dask.config.get("distributed.worker.profile.enabled"))


def test_a_local_clusters_workers_map_no_buffer_afresh_and_profile_nothing(monkeypatch):
    """distributed sets MALLOC_TRIM_THRESHOLD_ in a worker's environment, which turns
    glibc's dynamic mmap threshold off: every event buffer of every run was mapped and
    unmapped afresh (a fifth of a chip worker's CPU in system time).  The engine's
    local workers run without it and without the 10 ms stack sampler; the tasks'
    results are those of the plain loop."""
    from planner.runtime.engine import run_tasks

    monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_", raising=False)
    got = run_tasks(_worker_settings_task, None, [(0,), (1,)], jobs=2)
    assert got == [(None, False), (None, False)]
    assert run_tasks(pow, 3, [(2,), (4,)], jobs=2) == run_tasks(pow, 3, [(2,), (4,)])


def _worker_settings_task(_shared, _index):
    return _worker_settings()


def _kicks_by_hand(records):
    """Kicks.concatenate's general path: every field concatenated, empty records too."""
    import numpy as np

    from model import Kicks

    fields = ("times", "velocities", "chatter", "direction", "mass_ratio", "impact_angle",
              "restitution", "velocity_changes")
    return Kicks(slider_mass=records[0].slider_mass,
                 **{f: np.concatenate([getattr(k, f) for k in records]) for f in fields})


def test_kicks_without_impacts_add_nothing_to_a_sliders_run():
    """A run without impacts gives the record of no kick (the general path's empty
    arrays, same dtypes); concatenating drops such records, and the slider's run on
    the result has the digits of its run on every record concatenated."""
    import numpy as np

    import model
    from model import Drive, Impacter, Kicks, Slider

    imp = Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6).with_natural_frequency(5200)
    sl = Slider.from_geometry(8.0e-8)
    near, far = Drive.tone(6200.0), Drive.tone(60000.0, 1e-9)
    silent = model.simulate(imp, far, 0.0, 0.0, 3e-3)
    assert silent.n_impacts == 0 and silent.chatter_times.size == 0
    for arr in (silent.times, silent.velocities, silent.chatter_times, silent.chatter_sums):
        assert arr.dtype == np.float64 and arr.shape == (0,)
    loud = model.simulate(imp, near, 0.0, 0.0, 3e-3)
    assert loud.n_impacts > 0
    for share in (1.0, 0.5):
        none = Kicks.from_impacts(imp, sl, silent, -1.0, share)
        some = Kicks.from_impacts(imp, sl, loud, 1.0, share)
        for name in ("times", "velocities", "chatter", "direction", "mass_ratio",
                     "impact_angle", "restitution", "velocity_changes"):
            ref = np.concatenate([getattr(some, name)[:0], getattr(some, name)[:0]])
            got = getattr(none, name)
            assert got.dtype == ref.dtype and got.shape == (0,), name
        for records in ([some, none], [none, some], [none, none], [some, none, some]):
            fast, slow = Kicks.concatenate(records), _kicks_by_hand(records)
            for contact in ("paper", "two_body"):
                a = model.slider_motion(sl, near, fast, duration=3e-3, contact=contact)
                b = model.slider_motion(sl, near, slow, duration=3e-3, contact=contact)
                assert a[2:] == b[2:]
            assert np.array_equal(fast.times, slow.times)
            assert np.array_equal(fast.velocity_changes, slow.velocity_changes)


def test_the_x0_grid_is_linspaces_and_a_fresh_array_each_time():
    import numpy as np

    from model import Impacter
    from planner.planning.verify import x0_grid

    imp = Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6)
    for n in (1, 5, 9):
        first = x0_grid(imp, n)
        assert first.tobytes() == np.linspace(-imp.gap, imp.gap, n).tobytes()
        first[:] = 7.0
        assert x0_grid(imp, n).tobytes() == np.linspace(-imp.gap, imp.gap, n).tobytes()
