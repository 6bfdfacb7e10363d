"""Physically credible motion in the plan (issue 15): contact law and mass ratio in the
designs, bursts sized from a travel, settle dwells, carried state in the verification,
the drive's peaks and its acceleration limit."""

import json
import subprocess
import sys

import numpy as np
import pytest

from planner.core.nodes import Node

TRAVEL = """\
name: travel
array: {rows: 1, cols: 2}
independent: false
drive:
  band_hz: [5000, 14000]
  channels: {count: 60}
verification: {repair_rounds: 1, x0_points: 5}
scenes:
  s:
    - {name: push, travel_um: 20, forward: [A1]}
    - {name: pull, duration_ms: 5, backward: [A2]}
"""


@pytest.fixture(scope="module")
def travel_plan():
    from planner.planning import run_plan
    from planner.arrayspec import load_spec

    return run_plan(load_spec(TRAVEL))


def test_plan_json_has_the_pinned_keys(travel_plan):
    d = travel_plan.data
    assert d["spec"]["device"]["contact"] == "two_body"
    assert d["spec"]["design"]["max_mass_ratio"] == 0.4
    for imp in d["impacters"]:
        assert 0 < imp["mass_ratio"] <= 0.4 * (1 + 1e-9)
        assert imp["contact"] == "two_body"
    for st in d["steps"]:
        assert {"settle_s", "peak_displacement_m", "peak_acceleration_m_s2",
                "travel_m"} <= set(st)
        assert st["settle_s"] >= 0
        movers = set(st["forward"]) | set(st["backward"])
        assert movers <= set(st["travel_m"])
    assert isinstance(d["verification"]["passed"], bool)
    json.dumps(d)


def test_travel_step_duration_follows_from_the_predicted_speed(travel_plan):
    from planner.planning.motion import BURST_QUANTUM_S, PROBE_S, probe_speeds
    from planner.planning.drives import drive_of

    d = travel_plan.data
    push = next(st for st in d["steps"] if st["name"] == "push")
    assert push["requested_travel_m"] == pytest.approx(20e-6)
    # the burst is travel / (slowest speed over the probe window), re-derived here from
    # the model with the plan's designs and drive
    step = next(s for s in travel_plan.settings.steps if s.name == "push")
    impacters = {n: des.impacter for n, des in travel_plan.designs.items()}
    speeds = probe_speeds(travel_plan.settings, step, drive_of(travel_plan.waveforms["s/push"]),
                          impacters, travel_plan.settings.sliders)
    v = min(speeds.values())
    assert v > 0
    assert push["sizing"]["slowest_probe_speed_m_s"] == pytest.approx(v, rel=1e-9)
    assert push["sizing"]["probe_s"] == PROBE_S
    assert push["duration_s"] == pytest.approx(20e-6 / v, abs=BURST_QUANTUM_S)
    # and the slider then travels about that far (the probe includes the start-up)
    travel = push["travel_m"]["A1"]
    assert 0.5 * 20e-6 < travel < 2.0 * 20e-6


def test_drive_peaks_are_true_peaks(travel_plan):
    """The peak acceleration is the refined maximum of sum w^2 Z cos(w t + phi), between
    a dense brute-force sample's maximum and the all-in-phase bound sum w^2 Z."""
    for st in travel_plan.data["steps"]:
        w = travel_plan.waveforms[f"{st['scene']}/{st['name']}"]
        om = 2 * np.pi * w.frequencies
        t = np.linspace(0, w.loop_length, 400_001)
        acc = np.abs(np.cos(np.outer(t, om) + w.phases) @ (om**2 * w.amplitudes))
        assert acc.max() <= st["peak_acceleration_m_s2"] * (1 + 1e-9)
        assert st["peak_acceleration_m_s2"] <= np.sum(om**2 * w.amplitudes) * (1 + 1e-9)
        assert st["peak_acceleration_m_s2"] == pytest.approx(acc.max(), rel=1e-3)
        assert st["peak_displacement_m"] == pytest.approx(w.peak, rel=1e-6)


def test_acceleration_limit_lowers_the_amplitudes_and_says_so(travel_plan, tmp_path):
    from planner.planning import run_plan, write_outputs
    from planner.arrayspec import load_spec

    peaks = {st["name"]: st["peak_acceleration_m_s2"] / 9.80665
             for st in travel_plan.data["steps"]}
    limit = 0.8 * max(peaks.values())
    spec = TRAVEL.replace("  channels: {count: 60}",
                          f"  channels: {{count: 60}}\n  max_acceleration_g: {limit:.6g}")
    res = run_plan(load_spec(spec))
    for st in res.data["steps"]:
        assert st["peak_acceleration_g"] <= limit * (1 + 1e-6)
        if peaks[st["name"]] > limit:
            assert st["acceleration_scale"] < 1
            ref = next(s for s in travel_plan.data["steps"] if s["name"] == st["name"])
            ratio = [a["amplitude_m"] / b["amplitude_m"] for a, b in zip(st["tones"], ref["tones"])]
            assert ratio == pytest.approx([st["acceleration_scale"]] * len(ratio), rel=1e-6)
        else:
            assert st["acceleration_scale"] == 1
    write_outputs(res, tmp_path, figures=False)
    report = (tmp_path / "report.md").read_text()
    assert "to meet drive.max_acceleration_g" in report


def test_travel_over_limit_is_a_failure_and_repair_shortens_the_burst():
    from planner.planning import run_plan
    from planner.arrayspec import load_spec

    # a 40 ms push against a 5 um limit: the first verification fails on travel; the
    # repair shortens the burst and says so
    spec = TRAVEL.replace("{repair_rounds: 1, x0_points: 5}",
                          "{repair_rounds: 2, x0_points: 5, max_travel_um: 5,"
                          " min_speed_mm_s: 0.05}")
    spec = spec.replace("{name: push, travel_um: 20,", "{name: push, duration_ms: 40,")
    res = run_plan(load_spec(spec))
    d = res.data
    actions = [a for r in d["verification"]["motion_repairs"] for a in r["actions"]]
    assert any(a.startswith("s/push: burst 40 ->") for a in actions), actions
    push = next(st for st in d["steps"] if st["name"] == "push")
    assert push["duration_s"] < 0.04
    # whatever the outcome, the headline agrees with the rows
    rows = [r for s in d["verification"]["steps"].values() for r in s.values()]
    assert d["verification"]["passed"] == all(r["passed"] for r in rows)
    over = [r for r in rows if abs(r.get("travel_m", 0.0)) > 5e-6]
    assert all(not r["passed"] for r in over)


def test_carried_state_failure_counts_in_the_verification():
    """Fig. 7's device in vacuum keeps swinging into its wall after its tone stops; with
    the dwell capped short, the scene's carried state is a failure of the step (and of
    ``verification.passed``), not only a note."""
    import model
    from planner.assignment.assign import plan_steps
    from planner.config import build_slider
    from planner.planning.repair import merge_carried
    from planner.planning.scenes import scene_failures, simulate_scenes
    from planner.planning.settings import SINGLE_STEP_S, resolve_settings
    from planner.planning.verify import CARRIED_IDLE, UNSETTLED
    from planner.arrayspec import load_spec
    from planner.synthesis import synthesize
    import dataclasses

    spec_text = """\
name: two
array: {rows: 1, cols: 2}
independent: false
environment: {viscosity_mpa_s: 0.0}
drive:
  band_hz: [5000, 14000]
  channels: {count: 60}
scenes:
  s:
    - {name: go, duration_ms: 3, forward: [A1]}
    - {name: other, duration_ms: 3, forward: [A2]}
"""
    loaded = load_spec(spec_text)
    settings = dataclasses.replace(resolve_settings(loaded), max_settle_s=1e-3)
    steps = plan_steps(loaded, SINGLE_STEP_S)
    imp = model.Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6).with_natural_frequency(5200)
    slider = build_slider(loaded.spec.slider_config("A1"), loaded.spec.process,
                          loaded.spec.environment)
    w = synthesize([6200.0], model.amplitude_from_power([6200.0], 50.0), 200_000, seed=0)
    quiet = synthesize([11000.0], [1e-12], 200_000, seed=0)
    # A2's impacter is far off the 6.2 kHz tone: it stays silent
    impacters = {"A1.forward": imp, "A2.forward": imp.with_natural_frequency(20000)}
    sliders = {"A1": slider, "A2": slider}
    rows = simulate_scenes(settings, steps, {"s/go": w, "s/other": quiet}, impacters, sliders)
    go = rows[0]
    # an undamped impacter (vacuum) never stops hitting: the dwell reaches its cap
    assert go["settle_s"] == pytest.approx(1e-3) and go["settled"] is False
    assert go["dwell_hits"].get("A1.forward", 0) >= 1
    fails = scene_failures(settings, steps, rows)
    kinds = {(f.step, f.kind) for f in fails}
    assert (0, UNSETTLED) in kinds
    # A1 is idle in "other" but its impacter still rings into the wall (the carried
    # state); its slider's motion then is a carried-state failure exactly when it is
    # beyond the idle tolerance
    other = rows[1]
    assert other["idle_hits"].get("A1.forward", 0) >= 1
    moved = abs(other["travel_m"]["A1"]) > settings.idle_tolerance_m
    assert ((1, CARRIED_IDLE) in kinds) == moved
    assert not any(f.device == "A2" for f in fails)
    ver_rows = [{"scene": "s", "step": st.name, "index": st.index, "device": dev,
                 "expected": "forward" if dev in st.forward else "idle", "passed": True,
                 "cause": "", "settle_s": 0.0} for st in steps for dev in ("A1", "A2")]
    merged, settle = merge_carried(ver_rows, fails, steps, rows, {})
    bad = {(r["step"], r["device"]) for r in merged if not r["passed"]}
    assert ("go", "A1") in bad and (("other", "A1") in bad) == moved
    assert ("go", "A2") not in bad
    assert all("carried state" in r["cause"] for r in merged if not r["passed"])
    assert settle["s/go"] == pytest.approx(1e-3)


def test_dwell_repair_lengthens_the_previous_steps_dwell():
    from planner.planning.repair import repair_motion
    from planner.planning.settings import resolve_settings
    from planner.planning.verify import CARRIED_IDLE, Failure
    from planner.arrayspec import load_spec

    loaded = load_spec(TRAVEL)
    settings = resolve_settings(loaded)
    steps = settings.steps
    longer = {}
    out = repair_motion(settings, steps, [Failure(1, "A1", None, CARRIED_IDLE, 1e-6)],
                        {"s/push": 1e-3}, longer)
    assert out is not None
    _, actions, redo = out
    assert longer == {"s/push": 2e-3} and not redo
    assert actions == ["s/push: dwell 1 -> 2 ms (idle sliders move in s/pull from the state "
                       "it leaves)"]
    # at the cap nothing more can be done
    assert repair_motion(settings, steps, [Failure(1, "A1", None, CARRIED_IDLE, 1e-6)],
                         {"s/push": settings.max_settle_s}, {}) is None


def test_seed_reaches_the_designs():
    from planner.planning.settings import resolve_settings
    from planner.arrayspec import load_spec

    loaded = load_spec(TRAVEL)
    assert resolve_settings(loaded).seed == 0
    s = resolve_settings(loaded, 3)
    assert s.seed == 3          # one seed: the colouring's, the designs' and the phases'
    assert s.design_kwargs(Node("A1", "forward"))["seed"] == 3


def test_spec_keys_are_validated():
    from planner.core.errors import SpecError
    from planner.planning.settings import resolve_settings
    from planner.arrayspec import load_spec

    with pytest.raises(SpecError, match="duration_ms, travel_um or targets_um"):
        load_spec(TRAVEL.replace("travel_um: 20,", ""))
    with pytest.raises(SpecError, match="contact"):
        load_spec(TRAVEL + "device: {contact: wall}\n")
    loaded = load_spec(TRAVEL + "device: {contact: paper}\ndevices: {A2: {contact: two_body}}\n")
    s = resolve_settings(loaded)
    assert s.contacts == {"A1": "paper", "A2": "two_body"}
    assert s.design_kwargs(Node("A1", "forward"))["contact"] == "paper"
    assert s.max_travel_m == pytest.approx(0.5e-3)   # half the default 1000 um pitch


def test_paper_contact_is_the_old_kick_path():
    """contact: paper in a plan gives the slider motion of model.kick + slider_motion
    (the path of vibroplan before the contact option), bit for bit."""
    import model
    from planner.planning.motion import run_phase
    from planner.planning.verify import kicks

    imp = model.Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6).with_natural_frequency(5200)
    sl = model.Slider.from_geometry(8.0e-8)
    drive = model.Drive.tone(6200.0)
    res = model.simulate(imp, drive, 0.0, 0.0, 3e-3, max_events=1_000_000)
    t, dv = kicks(imp, sl, res, 1.0)
    _, _, z_old, v_old, _ = model.slider_motion(sl, drive, t, dv, 3e-3)
    states, sl_states = {}, {}
    run_phase({Node("A1", "forward"): imp}, {"A1": sl}, {"A1": "paper"}, drive, 3e-3, states,
              sl_states)
    assert sl_states["A1"] == (z_old, v_old)
    run_phase({Node("A1", "forward"): imp}, {"A1": sl}, {"A1": "two_body"}, drive, 3e-3, {},
              sl_states)


def _tip_speeds(step_rec, imp_recs):
    """Node -> fastest impact speed v- [m/s] of each mover's impacter under the step's
    summed drive (from rest, the step's burst)."""
    import model

    drive = model.Drive([t["frequency_hz"] for t in step_rec["tones"]],
                        [t["amplitude_m"] for t in step_rec["tones"]],
                        [t["phase_rad"] for t in step_rec["tones"]])
    out = {}
    for rec in imp_recs:
        dev, direction = rec["device"], rec["direction"]
        if dev not in step_rec[direction]:
            continue
        imp = model.Impacter(rec["mass_kg"], rec["stiffness_n_per_m"], rec["damping_ns_per_m"],
                             rec["gap_m"], rec["impact_angle_rad"], rec["restitution"])
        res = model.simulate(imp, drive, 0.0, 0.0, step_rec["duration_s"], max_events=1_000_000)
        out[dev] = float(res.velocities.max()) if res.velocities.size else 0.0
    return out


def test_slider_slower_than_the_tips_that_push_it(travel_plan):
    d = travel_plan.data
    for st in d["steps"]:
        tips = _tip_speeds(st, d["impacters"])
        for dev, v in tips.items():
            speed = abs(st["travel_m"][dev]) / (st["duration_s"] + st["settle_s"])
            assert 0 < speed < v


#: Seeds of the default spec that do not verify yet (measured 2026-11-23 with independent
@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4])
def test_default_plan_is_credible(seed, tmp_path):
    """`vibroplan plan --seed N` verifies with the new semantics; every mover's slider
    is slower than the impacter tips that push it, its travel per step well under the
    pitch, and every design within the mass-ratio cap."""
    out = tmp_path / "plan"
    proc = subprocess.run([sys.executable, "-m", "planner.cli", "plan", "--seed", str(seed),
                           "--out", str(out), "--no-figures"],
                          capture_output=True, text=True, timeout=3600, cwd=tmp_path)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    d = json.loads((out / "plan.json").read_text())
    assert d["verification"]["passed"] is True
    pitch = d["spec"]["array"]["pitch_um"] * 1e-6
    for imp in d["impacters"]:
        assert imp["mass_ratio"] <= 0.4 * (1 + 1e-9)
    for st in d["steps"]:
        for dev, z in st["travel_m"].items():
            assert abs(z) <= 0.1 * pitch
        if st["scene"] != "independent":
            tips = _tip_speeds(st, d["impacters"])
            for dev, v in tips.items():
                assert abs(st["travel_m"][dev]) / st["duration_s"] < v


def test_repair_redesigns_a_too_slow_impacter_alone():
    """A too-slow failure re-seeds the design of the impacter driven in that step (and
    only it); the offset enters the design's key, so the other designs are cached."""
    from planner.planning.designs import DESIGN_RETRIES, design_all
    from planner.planning.drives import synthesize_steps
    from planner.planning.repair import reseed_slow
    from planner.planning.settings import resolve_settings
    from planner.planning.verify import TOO_SLOW, Failure
    from planner.assignment.assign import assign
    from planner.arrayspec import load_spec

    settings = resolve_settings(load_spec(TRAVEL), 0)
    steps = settings.steps
    a = assign(settings, steps)
    waveforms = synthesize_steps(settings, steps, a)
    cache = {}
    first = design_all(settings, steps, a, cache, waveforms=waveforms)
    push = next(st for st in steps if st.name == "push")
    (dev, direction), = sorted(push.active_nodes())
    node = Node(dev, direction)
    reseed = {}
    fails = [Failure(push.index, dev, None, TOO_SLOW, 1e-6)]
    assert reseed_slow(fails, first, steps, reseed) == [node]
    assert reseed == {node: 1 + DESIGN_RETRIES}
    n_cached = len(cache)
    again = design_all(settings, steps, a, cache, waveforms=waveforms, reseed=reseed)
    assert len(cache) == n_cached + 1          # one new design, the rest from the cache
    # its tries continue the first round's stream where it could have ended
    from planner.core.rng import try_seed

    base = settings.design_kwargs(node)["seed"]
    assert first[node].seed in [try_seed(base, k) for k in range(1 + DESIGN_RETRIES)]
    assert again[node].seed in [try_seed(base, 1 + DESIGN_RETRIES + k)
                                for k in range(1 + DESIGN_RETRIES)]
    assert all(again[n] is first[n] for n in first if n != node)
    # a failure of another kind re-seeds nothing
    assert reseed_slow([Failure(push.index, dev, None, "travel_over_limit", 1e-3)],
                       first, steps, {}) == []


def test_an_infeasible_design_is_given_up_after_a_few_tries():
    """Another seed rarely makes an infeasible target feasible: the planner stops after
    INFEASIBLE_TRIES tries (and reports the impacter) instead of retrying for minutes;
    a feasible but slow design is retried up to 1 + DESIGN_RETRIES times."""
    from planner.core.rng import try_seed
    from planner.planning.designs import INFEASIBLE_TRIES, _design_task

    calls = []
    import planner.designer as designer

    real = designer.design_impacter

    budgets = []

    def counting(**kw):
        calls.append(kw["seed"])
        budgets.append(kw["budget"])
        return real(**kw)

    # a target 1.2 % from a forbidden tone with a 1 % guard: in air no design responds
    # at one and not the other
    kw = dict(frequency=6000.0, forbidden=(6075.0,), budget="fast", seed=5,
              window=1e-3, guard=0.01)
    designer.design_impacter = counting
    try:
        res = _design_task(kw, min_speed=1e-4)
    finally:
        designer.design_impacter = real
    assert not res.feasible
    assert calls == [try_seed(5, k) for k in range(INFEASIBLE_TRIES)]
    assert calls[0] == 5 and len(set(calls)) == INFEASIBLE_TRIES
    # after each infeasible try the next searches wider, not only from another seed
    from planner.designer.budget import BUDGETS, widened

    fast = BUDGETS["fast"]
    assert budgets == ["fast"] + [widened("fast", k) for k in range(1, INFEASIBLE_TRIES)]
    assert widened("fast", 1).chains == 3 * fast.chains
    assert widened("fast", 2).initial == 8 * fast.initial == widened("fast", 3).initial
    assert widened(fast, 0) is fast


def test_designs_are_silent_at_the_tones_as_played():
    """A single tone plays snapped to its loop's grid (up to 0.1 % off its channel); the
    designer is given that frequency, so the centre of each guard band it checks is the
    tone that plays (seed 1 of the default plan answered 13407.8 Hz, its channel 13400 Hz
    silent).  An infeasible design's offender is found from the played tone too."""
    import dataclasses

    from planner.assignment.assign import assign
    from planner.planning.designs import design_all
    from planner.planning.exposure import design_offenders, forbidden_tones, played_tones
    from planner.planning.drives import synthesize_steps
    from planner.planning.settings import resolve_settings
    from planner.arrayspec import load_spec

    settings = resolve_settings(load_spec(TRAVEL), 0)
    steps = settings.steps
    a = assign(settings, steps)
    waveforms = synthesize_steps(settings, steps, a)
    push, pull = (next(st for st in steps if st.name == k) for k in ("push", "pull"))
    (pusher,), (puller,) = ([Node(d, dr) for d, dr in st.active_nodes()] for st in (push, pull))
    played = float(waveforms[pull.key].frequencies[0])
    channel = a.frequencies[puller]
    assert played != channel and abs(played / channel - 1) <= 1e-3
    assert forbidden_tones(steps, a.frequencies)[pusher] == (channel,)
    assert played_tones(steps, a.frequencies, waveforms)[pusher] == (played,)
    designs = design_all(settings, steps, a, {}, waveforms=waveforms)
    assert designs[pusher].forbidden_hz == (played,)
    # an infeasible design that answers the played tone points at the impacter playing it
    bad = dataclasses.replace(designs[pusher], feasible=False, r_max_forbidden_n=(1e-9,))
    assert design_offenders({pusher: bad}, steps, a) == [(pusher, (pusher, puller))]


def test_repair_redesigns_an_idle_responder_once_then_widens():
    """An idle impacter that answers a step although its design was feasible is
    re-designed alone from further seeds (no re-colouring); if it answers again, its
    separation from the step's nearest tone is widened instead."""
    from planner.assignment.assign import assign
    from planner.planning.designs import DESIGN_RETRIES, design_all
    from planner.planning.drives import synthesize_steps
    from planner.planning.repair import reseed_idle, widen_separations
    from planner.planning.settings import resolve_settings
    from planner.planning.verify import IDLE_RESPONSE, TOO_SLOW, Failure
    from planner.arrayspec import load_spec

    settings = resolve_settings(load_spec(TRAVEL), 0)
    steps = settings.steps
    a = assign(settings, steps)
    waveforms = synthesize_steps(settings, steps, a)
    designs = design_all(settings, steps, a, {}, waveforms=waveforms)
    pull = next(st for st in steps if st.name == "pull")
    idle = next(n for n in designs if n.direction == "forward")
    assert designs[idle].feasible
    fails = [Failure(pull.index, idle.device, idle, IDLE_RESPONSE, 1e-10),
             Failure(pull.index, "A2", None, TOO_SLOW, 1e-6)]
    reseed, tried, pair_sep = {}, set(), {}
    answered = reseed_idle(fails, designs, reseed, tried)
    assert answered == [idle] and reseed == {idle: 1 + DESIGN_RETRIES} and tried == {idle}
    assert not widen_separations(fails, designs, steps, a, pair_sep, 1, skip=answered)
    assert pair_sep == {}
    # the second time it answers: no second re-seed, the separation widens
    assert reseed_idle(fails, designs, reseed, tried) == []
    assert reseed == {idle: 1 + DESIGN_RETRIES}
    assert widen_separations(fails, designs, steps, a, pair_sep, 1, skip=())
    (pair,) = pair_sep
    assert idle in pair


def test_report_says_which_impacters_a_design_round_redesigned(travel_plan):
    """The report's "What the planner changed" names the impacters each design round
    re-designed, and why, besides the motion repairs."""
    import copy

    from planner.planning.report import _motion_notes

    d = copy.deepcopy(travel_plan.data)
    assert not any("design round" in line for line in _motion_notes(d).lines)
    d["verification"]["repair_rounds"] = [
        {"round": 0, "span": 10, "failures": 2, "redesigned_slow": ["A1.forward"],
         "redesigned_idle": ["A2.forward"]},
        {"round": 1, "span": 10, "failures": 0}]
    text = "\n".join(_motion_notes(d).lines)
    assert "design round 0: re-designed from further seeds (too slow in a step): A1.forward" in text
    assert "(answered a step it sits out): A2.forward" in text


def _travel_step(travel_um, burst_ms, cap_ms=60.0):
    from planner.arrayspec.steps import Step

    return Step("s", "go", 0, burst_ms * 1e-3, ("A1", "A2"), (), travel_m=travel_um * 1e-6,
                max_duration_s=cap_ms * 1e-3)


def _mover_rows(travels_um):
    return [{"index": 0, "device": dev, "expected": "forward", "travel_m": t * 1e-6}
            for dev, t in zip(("A1", "A2"), travels_um)]


@pytest.mark.parametrize("travel_um, burst_ms, cap_ms, travels_um, want_ms, said", [
    # over the limit, and the burst that moves the slowest its travel keeps the fastest
    # within 95 % of it: re-sized from the verified travels (a 3 x 5 of our own: 51.6 ->
    # 46.6 ms, its slowest 40 um as asked; the blind 0.8 cut left it 33.9 um)
    (25, 50, 60, (30, 110), 41.7, "41.7 ms moves the slowest slider about the step's 25 um"),
    # ... but never below the 0.8 cut (seed 70590 of the default: 10 -> 6.5 ms left its
    # slowest 14 um, where the cut's 7.5 ms gives it more)
    (20, 10, 60, (30.8, 106.2), 7.5, "a slider travels 106.2 um > 100 um)"),
    # over the limit, sliders too far apart for both: the 0.8 cut, and it says so
    (20, 50, 60, (10, 120), 33.3, "the slowest slider then travels under 6.66 um of the "
                                  "step's 20 um"),
    # the slowest fell short (its predicted speed was too high): lengthened
    (50, 82, 120, (45, 45), 91.2, "its slowest slider travelled 45 um of the step's 50 um"),
    # ... but not past the step's longest burst
    (50, 82, 85, (45, 45), None, None),
    # ... nor where the fastest would go over 95 % of the limit
    (50, 82, 120, (45, 90), None, None),
    # within the position tolerance (2 um) of its travel: left alone
    (50, 82, 120, (48.5, 60), None, None),
])
def test_a_travel_step_is_sized_again_from_its_verified_travels(travel_um, burst_ms, cap_ms,
                                                                 travels_um, want_ms, said):
    """A ``travel_um`` step is sized from predicted speeds before it is verified; the
    motion repair re-sizes it from the travels the verification found (issue 43's own
    specs: a 3 x 5 got 45 of its 50 um and 33.9 of its 40 um, and the plan said neither)."""
    from planner.arrayspec import default_spec_path, load_spec
    from planner.planning.repair import repair_motion
    from planner.planning.settings import resolve_settings
    from planner.planning.verify import TRAVEL_OVER, Failure

    settings = resolve_settings(load_spec(default_spec_path()))
    assert settings.max_travel_m == pytest.approx(100e-6)
    st = _travel_step(travel_um, burst_ms, cap_ms)
    fastest = max(travels_um) * 1e-6
    fails = ([Failure(0, "A2", None, TRAVEL_OVER, fastest)]
             if fastest > settings.max_travel_m else [])
    out = repair_motion(settings, (st,), fails, {}, {}, _mover_rows(travels_um))
    if want_ms is None:
        assert out is None
        return
    steps, actions, redo = out
    assert redo == {0}
    assert steps[0].duration_s == pytest.approx(want_ms * 1e-3)
    assert len(actions) == 1 and said in actions[0], actions


def test_a_lengthened_travel_step_that_goes_over_goes_back_to_the_burst_that_passed():
    """Seed 70590 of the default (drawn at random): the repair lengthened its positioning
    step from 6.5 to 9.4 ms in proportion to its slowest slider's travel, the fastest went
    to 100.07 um of 100 (travel grows faster than the burst once the impacters ring up),
    and the plan ended FAILED 1299/1300.  A lengthening is tentative: over the limit, the
    step goes back to the burst that passed, and is not lengthened again."""
    from planner.arrayspec import default_spec_path, load_spec
    from planner.planning.repair import repair_motion
    from planner.planning.settings import resolve_settings
    from planner.planning.verify import TRAVEL_OVER, Failure

    settings = resolve_settings(load_spec(default_spec_path()))
    lengthened = {}
    st = _travel_step(20, 6.5)
    steps, actions, _ = repair_motion(settings, (st,), [], {}, {}, _mover_rows((14, 60)),
                                      lengthened)
    assert steps[0].duration_s == pytest.approx(9.3e-3)
    assert lengthened == {0: pytest.approx(6.5e-3)}
    over = [Failure(0, "A2", None, TRAVEL_OVER, 100.07e-6)]
    steps, actions, redo = repair_motion(settings, steps, over, {}, {},
                                         _mover_rows((20.1, 100.07)), lengthened)
    assert steps[0].duration_s == pytest.approx(6.5e-3) and redo == {0}
    assert "back to the burst that passed" in actions[0]
    # short again at the burst that passed: left so
    assert repair_motion(settings, steps, [], {}, {}, _mover_rows((14, 60)),
                         lengthened) is None
    # and in the last repair round (none left to take it back) no step is lengthened
    assert repair_motion(settings, (st,), [], {}, {}, _mover_rows((14, 60)), {},
                         may_lengthen=False) is None
