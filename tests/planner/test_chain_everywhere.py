"""The drive chain everywhere (issue 46, the rest of item 3): `vibroplan drive` and
`vibroplan replan` of a plan with a chain play the amplifier input, a gated burst is
verified through the distortion, the assigner weighs the products by the chain's
stated distortion, the CSV's column is stated, not guessed, and the figure marks the
products near idle impacters."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
from click.testing import CliRunner

from planner.cli import main
from planner.lab.exporters import export, read_sidecar, read_waveform
from tests.planner.test_chain import _phase_error_deg, _through_chain

#: The issue's chain: 38 kHz, Q 20 over 1 um/V; the tiny plan's tones (5-14 kHz) sit
#: below it, where the gain rises by up to 15 % and the phase turns by up to 2 deg.
CHAIN = {"transfer": {"gain_um_per_v": 1.0, "resonances": [{"frequency_hz": 38000.0,
                                                            "q": 20.0}]},
         "harmonics_db": {"2": -40.0, "3": -50.0}, "at_stroke_um": 10.0}


@pytest.fixture
def chain_plan(tiny_plan_dir, tmp_path):
    """The tiny plan with the issue's chain in its spec (the plan a lab would re-drive)."""
    data = json.loads((tiny_plan_dir / "plan.json").read_text())
    data = copy.deepcopy(data)
    data["spec"]["drive"]["chain"] = copy.deepcopy(CHAIN)
    path = tmp_path / "chain_plan.json"
    path.write_text(json.dumps(data))
    return path, data


def _die_tones_of(path, freqs):
    samples, rate = read_waveform(path)
    return _through_chain(samples, rate, freqs)


# ----------------------------------------------------------------------------- item 4


@pytest.mark.filterwarnings("ignore::planner.lab.exporters.DriveWarning")
def test_csv_column_is_stated_not_guessed(tmp_path, tiny_plan_dir):
    from planner.synthesis import synthesize
    from planner.synthesis.chain import ModelTransfer, compensate

    die = synthesize(np.array([5000.0, 7000.0]), None, 200000.0, seed=0)
    # um/V x gain = 1e6 makes the volts' full scale equal the metres': still metres
    path = export(die, tmp_path / "d.csv", "csv", um_per_v=1000.0, amplifier_gain=1000.0)
    assert path.read_text().splitlines()[0] == "time_s,displacement_m"
    assert read_sidecar(path)["columns"] == ["time_s", "displacement_m"]
    volts = compensate(die, ModelTransfer(1e-6, ((38000.0, 20.0),)))
    path = export(volts, tmp_path / "v.csv", "csv", die=die)
    assert path.read_text().splitlines()[0] == "time_s,input_v"
    # and at the command line, on a plan without a chain
    out = tmp_path / "push.csv"
    res = CliRunner().invoke(main, ["drive", str(tiny_plan_dir), "--step", "push", "--format",
                                    "csv", "--out", str(out), "--um-per-v", "1000",
                                    "--amplifier-gain", "1000"])
    assert res.exit_code == 0, res.output
    assert out.read_text().splitlines()[0] == "time_s,displacement_m"
    assert read_sidecar(out).get("signal") is None


# ----------------------------------------------------------------------------- item 3


@pytest.mark.filterwarnings("ignore::planner.lab.exporters.DriveWarning")
@pytest.mark.parametrize("fmt", ["csv", "wav", "arb"])
def test_drive_of_a_chain_plan_plays_the_amplifier_input(chain_plan, tmp_path, fmt):
    path, data = chain_plan
    suffix = {"csv": ".csv", "wav": ".wav", "arb": ".arb"}[fmt]
    for step in data["steps"]:
        out = tmp_path / f"{step['name']}{suffix}"
        res = CliRunner().invoke(main, ["drive", str(path), "--step", step["name"],
                                        "--format", fmt, "--out", str(out)])
        assert res.exit_code == 0, res.output
        assert "the amplifier input" in res.output
        side = read_sidecar(out)
        assert side["signal"] == "amplifier_input_v" and "full_scale_v" in side
        if fmt == "csv":
            assert out.read_text().splitlines()[0] == "time_s,input_v"
        # the file through the test's own chain gives the plan's die tones
        freqs = [t["frequency_hz"] for t in step["tones"]]
        for (a, p), tone in zip(_die_tones_of(out, freqs), step["tones"]):
            assert abs(a / tone["amplitude_m"] - 1) < 0.01, (fmt, tone)
            assert _phase_error_deg(p, tone["phase_rad"]) < 1.0, (fmt, tone)
        # played as displacement volts at 1 um/V instead, the tones would be off by the
        # resonance's rise (the test can tell compensated from not)
        raw = read_sidecar(out)["tones"][0]
        assert abs(raw["amplitude_v"] * 1e-6 / tone["amplitude_m"] - 1) > 0.005


def test_drive_of_a_chain_plan_refuses_um_per_v(chain_plan, tmp_path):
    path, _ = chain_plan
    out = tmp_path / "push.csv"
    res = CliRunner().invoke(main, ["drive", str(path), "--step", "push", "--format", "csv",
                                    "--out", str(out), "--um-per-v", "2",
                                    "--amplifier-gain", "10"])
    assert res.exit_code == 2, res.output
    assert "drive.chain" in res.output and "Traceback" not in res.output
    assert not out.exists()


@pytest.mark.filterwarnings("ignore::planner.lab.exporters.DriveWarning")
def test_replan_of_a_chain_plan_compensates_its_new_tones(chain_plan, tmp_path):
    path, data = chain_plan
    shifts = [1.03, 0.97]
    rows = ["impacter,natural_frequency_hz"]
    rows += [f"{r['id']},{s * r['natural_frequency_hz']!r}"
             for r, s in zip(data["impacters"], shifts)]
    measured = tmp_path / "measured.csv"
    measured.write_text("\n".join(rows) + "\n")
    out = tmp_path / "out"
    res = CliRunner().invoke(main, ["replan", str(path), "--measured", str(measured),
                                    "--out", str(out)], catch_exceptions=False)
    assert res.exit_code in (0, 1), res.output
    d = json.loads((out / "plan.json").read_text())
    assert d["chain"]["signal"] == "amplifier_input_v"
    assert "Drive chain" in (out / "report.md").read_text()
    old = {t["frequency_hz"] for st in data["steps"] for t in st["tones"]}
    for step in d["steps"]:
        freqs = [t["frequency_hz"] for t in step["tones"]]
        assert not set(freqs) & old            # the tones moved with the chip
        for fmt, rel in step["files"].items():
            assert read_sidecar(out / rel)["signal"] == "amplifier_input_v"
            for (a, p), tone in zip(_die_tones_of(out / rel, freqs), step["tones"]):
                assert abs(a / tone["amplitude_m"] - 1) < 0.01, (fmt, tone)
                assert _phase_error_deg(p, tone["phase_rad"]) < 1.0, (fmt, tone)


# ----------------------------------------------------------------------------- item 2


def _burst():
    from planner.synthesis import synthesize
    from planner.synthesis.gating import gate

    w = synthesize(np.array([5000.0, 7300.0, 11000.0]), None, 200000.0, seed=0)
    return gate(w, np.array([0.0, 0.0, 0.0]), np.array([2e-3, 3e-3, 4e-3]), 2e-4)


def test_a_gated_burst_is_distorted_stretch_by_stretch():
    """Each stretch the die feels is the chain's polynomial of the burst itself (up to
    its static offset and the products under the floor, here 0)."""
    import planner.planning.chain as pc
    from planner.synthesis.chain import Nonlinearity

    burst = _burst()
    nl = Nonlinearity.from_harmonics({2: -40.0, 3: -50.0}, 10e-6)
    floor = pc.PRODUCT_FLOOR_REL
    try:
        pc.PRODUCT_FLOOR_REL = 0.0
        die = pc._die_burst(burst, nl)
    finally:
        pc.PRODUCT_FLOOR_REL = floor
    assert len(die.program()) == len(burst.program())
    t0 = 0.0
    for duration, drive in die.program():
        t = np.linspace(0.0, duration, 64, endpoint=False)
        z = sum(a * np.cos(2 * np.pi * f * t + p)
                for f, a, p in zip(drive.frequencies, drive.amplitudes, drive.phases))
        err = z - nl(burst.evaluate(t0 + t))
        # the static offset (DC and products under 10 Hz) is left out: near constant,
        # within a thousandth of the strongest product
        assert np.ptp(err) < 1e-3 * float(die.products_m.max())
        t0 += duration
    # the 2nd harmonic of the lowest tone (5 kHz, snapped to its loop)
    assert np.any(np.isclose(die.products_hz, 2 * burst.frequencies[0], atol=1e-3))


def test_a_gated_burst_is_verified_through_the_chain(tiny_plan_dir):
    """A burst whose tone's 2nd harmonic sits on an idle impacter's resonance: without
    distortion the idle impacter stays silent, through a strongly distorting chain the
    verification finds it answering."""
    import dataclasses

    from planner.afterfab.replan import chip_models
    from planner.core.nodes import Node
    from planner.planning.chain import die_drives
    from planner.planfile.reader import read_plan
    from planner.planning.settings import plan_settings
    from planner.planning.verify import IDLE_RESPONSE, check_step
    from planner.synthesis import synthesize
    from planner.synthesis.chain import DriveChain, ModelTransfer, Nonlinearity
    from planner.synthesis.gating import gate

    record = read_plan(tiny_plan_dir)
    settings = plan_settings(record)
    built = chip_models(record, {})
    models = {r.node: built.impacters[r.id] for r in record.impacters}
    idle = Node("A2", "backward")
    nu = models[idle].natural_frequency
    w = synthesize(np.array([nu / 2.0]), np.array([2e-6]), 200000.0, seed=0,
                   frequency_tolerance=np.array([nu / 2.0 * 1e-3]))
    burst = gate(w, np.array([0.0]), np.array([4e-3]), 2e-4)
    step = next(st.step for st in record.steps if st.key == "s/push")
    step = dataclasses.replace(step, targets_m=None)

    def idle_answers(chain):
        s = dataclasses.replace(settings, chain=chain)
        felt = die_drives(s, {step.key: burst})[step.key]
        _, fails = check_step(s, step, felt, models, built.sliders)
        return any(f.kind == IDLE_RESPONSE and f.impacter == idle for f in fails)

    linear = DriveChain(ModelTransfer(1e-6), Nonlinearity())
    distorting = DriveChain(ModelTransfer(1e-6),
                            Nonlinearity.from_harmonics({2: -6.0}, 10e-6))
    assert not idle_answers(None)
    assert not idle_answers(linear)
    assert idle_answers(distorting)


# ----------------------------------------------------------------------------- item 1


def _rule_settings(tiny_plan_dir, harmonics_db):
    import dataclasses

    from planner.planfile.reader import read_plan
    from planner.planning.settings import plan_settings
    from planner.synthesis.chain import DriveChain, ModelTransfer, Nonlinearity

    record = read_plan(tiny_plan_dir)
    settings = plan_settings(record)
    chain = DriveChain(ModelTransfer(1e-6), Nonlinearity.from_harmonics(harmonics_db, 10e-6))
    # the reference designs: the tiny plan's own, as a reach's family ((A, w, l, c), tone)
    family = []
    for r in record.impacters:
        g = json.loads((tiny_plan_dir / "plan.json").read_text())
        rec = next(i for i in g["impacters"] if i["id"] == r.id)
        geo = rec["geometry"]
        family.append(((geo["area_m2"], geo["width_m"], geo["length_m"], geo["gap_m"]),
                       rec["frequency_hz"]))

    class Reach:
        constrained = False

    reach = Reach()
    reach.family = tuple(sorted(family, key=lambda d: d[1]))
    return dataclasses.replace(settings, chain=chain), reach


# the reference (the tiny plan's A2 design) is moved by a product of ~97 nm at its
# resonance: A1's 1.27 um tone makes 128 nm at -2 dB, 0.13 nm at -62 dB
@pytest.mark.parametrize("level, moves", [(-2.0, True), (-62.0, False)])
def test_a_product_is_a_conflict_only_when_it_can_move_the_idle_impacter(
        tiny_plan_dir, level, moves):
    from planner.assignment.assign import guard_violations
    from planner.assignment.distortion import product_rule
    from planner.core.nodes import Node

    settings, reach = _rule_settings(tiny_plan_dir, {2: level})
    rule = product_rule(settings, reach)
    # A1's tone's 2nd harmonic 0.5 % from A2's tone, idle in step push
    tones = {Node("A1", "forward"): 5000.0, Node("A2", "backward"): 10050.0}
    (v,) = [v for v in guard_violations(settings.steps, tones, settings.tone_rules, rule)
            if v.kind == "harmonic" and v.product_hz == 10000.0]
    y = rule.tone_amplitude(5000.0)
    assert v.amplitude_m == pytest.approx(settings.chain.nonlinearity.a2 * y * y / 2)
    assert v.moves is moves
    assert ("can move it" if moves else "too weak to move it") in str(v)
    # without a chain: the warning as it was, no amplitude
    (w,) = [w for w in guard_violations(settings.steps, tones, settings.tone_rules)
            if w.kind == "harmonic" and w.product_hz == 10000.0]
    assert w.amplitude_m is None and "at the die" not in str(w)


def test_assign_cli_states_each_products_amplitude(tmp_path):
    from tests.planner.test_chain import TINY

    spec = tmp_path / "s.yaml"
    spec.write_text(TINY.replace(
        "  channels: {count: 60}\n",
        "  channels: {count: 60}\n  guard: {relative_bandwidth: 0.2}\n  chain:\n"
        "    transfer: {gain_um_per_v: 1.0}\n    harmonics_db: {2: -40}\n"))
    out = tmp_path / "a.json"
    res = CliRunner().invoke(main, ["assign", str(spec), "--out", str(out)])
    assert res.exit_code == 0, res.output
    # no reach measured here: every product with an amplitude counts, each stated
    lines = [ln for ln in res.output.splitlines() if "lands in" in ln]
    assert lines and all("nm at the die at drive.chain's distortion" in ln for ln in lines)
    saved = json.loads(out.read_text())["violations"]
    assert saved and all("nm at the die" in v for v in saved)


# ----------------------------------------------------------------------------- item 5


def test_chain_figure_marks_products_near_idle_impacters(tiny_plan_dir, tmp_path):
    import matplotlib.image as mpimg

    from planner.planning.chain import chain_figure
    from planner.planning.drives import synthesize_steps
    from planner.core.nodes import Node

    settings, _ = _rule_settings(tiny_plan_dir, {2: -30.0})
    tones = {Node("A1", "forward"): 5000.0, Node("A2", "backward"): 10050.0}
    played = synthesize_steps(settings, settings.steps, tones)
    near = [{"step": "s/push", "impacter": "A2.backward", "impacter_hz": 10050.0,
             "product_hz": 10000.0, "amplitude_m": 3e-9}]
    chain_figure(settings, played, tmp_path / "with.png", near=near)
    chain_figure(settings, played, tmp_path / "none.png", near=[])
    a, b = mpimg.imread(tmp_path / "with.png"), mpimg.imread(tmp_path / "none.png")
    # four panels (the products' own), and the product drawn on it
    assert a.shape == b.shape and a.shape[0] >= 1300
    assert not np.array_equal(a, b)


def _guard_violations_loop(steps, frequencies, rules):
    """The products of planner.assignment.assign.guard_violations as its loop made them
    before it was vectorised (issue 43: 2.1 s of a 5 s dry run): (step, node, kind,
    product, node's tone, sources) in order."""
    import itertools

    from planner.core.nodes import Node

    out = []
    bw = rules.relative_bandwidth
    for st in steps:
        active = {Node(d, dr) for d, dr in st.active_nodes()}
        tones = np.array(sorted({frequencies[n] for n in active if n in frequencies}))
        idle = {n: f for n, f in frequencies.items() if n not in active}
        if tones.size == 0 or not idle:
            continue
        names = list(idle)
        idle_f = np.array([idle[n] for n in names])
        prods = []
        if rules.harmonics:
            for nh in (2, 3):
                prods += [("harmonic", nh * f, (f,)) for f in tones]
                prods += [("harmonic", f / nh, (f,)) for f in tones]
        if rules.intermodulation and tones.size >= 2:
            for i, j in itertools.permutations(range(tones.size), 2):
                prods.append(("intermodulation", 2 * tones[i] - tones[j], (tones[i], tones[j])))
            if 3 <= tones.size <= 40:
                for i, j in itertools.combinations(range(tones.size), 2):
                    for k in range(tones.size):
                        if k != i and k != j:
                            prods.append(("intermodulation", tones[i] + tones[j] - tones[k],
                                          (tones[i], tones[j], tones[k])))
        if not prods:
            continue
        pf = np.array([p[1] for p in prods])
        near = np.abs(pf[:, None] - idle_f[None, :]) <= bw * idle_f[None, :]
        for pi, ni in zip(*np.nonzero(near)):
            kind, f, src = prods[pi]
            out.append((st.key, names[ni], kind, float(f), float(idle_f[ni]),
                        tuple(float(x) for x in src)))
    return out


@pytest.mark.parametrize("seed", range(6))
def test_guard_violations_are_the_loops_products_in_its_order(seed):
    """The vectorised product search gives the very violations of the loop it replaced,
    in the same order, on random steps of 1-30 tones among 40 impacters."""
    from planner.arrayspec.steps import Step
    from planner.assignment.assign import guard_violations
    from planner.core.nodes import Node
    from planner.planning.settings import ToneRules

    rng = np.random.default_rng(seed)
    devices = [f"D{i}" for i in range(20)]
    freqs = {Node(d, dr): float(f) for (d, dr), f in zip(
        [(d, dr) for d in devices for dr in ("forward", "backward")],
        rng.uniform(4e3, 5e4, 40).round(1))}
    steps = [Step("scene", f"s{s}", s, 0.01,
                  tuple(sorted(rng.choice(devices, int(rng.integers(1, 16)), replace=False))),
                  tuple(sorted(rng.choice(devices, int(rng.integers(0, 15)), replace=False))))
             for s in range(4)]
    rules = ToneRules(float(rng.uniform(0.002, 0.02)), True, True)
    got = [(v.step, v.node, v.kind, v.product_hz, v.node_hz, tuple(float(x) for x in v.sources))
           for v in guard_violations(steps, freqs, rules)]
    want = _guard_violations_loop(steps, freqs, rules)
    assert got == want and len(want) > 0
