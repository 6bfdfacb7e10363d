"""The drive chain (issue 46): the spec's ``drive.chain``, compensation to the amplifier
input, its limits, the exported volts passed back through the chain, and
``vibroplan calibrate --chain``'s round trip."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from planner.arrayspec import ArraySpec, load_spec
from planner.cli import main
from planner.core.errors import PlanningError, SpecError
from planner.lab.exporters import export, read_sidecar, read_waveform
from planner.core.nodes import Node
from planner.planning.chain import limit_input
from planner.planning.drives import synthesize_steps
from planner.planning.settings import resolve_settings
from planner.synthesis import synthesize
from planner.synthesis.chain import ModelTransfer, Nonlinearity, compensate

TINY = (Path(__file__).resolve().parents[2] / "configs" / "tiny_1x2.yaml").read_text()

# the "Done means" chain: a piezo resonance at 38 kHz, Q 20, over a flat 1 um/V
F_RES, Q_RES, GAIN_UM_PER_V = 38000.0, 20.0, 1.0


def _h(f, gain_um_per_v=GAIN_UM_PER_V, f_res=F_RES, q=Q_RES):
    """The test's own chain [m/V] (not the library's): gain / (1 - u^2 + j u / q)."""
    u = np.asarray(f, dtype=float) / f_res
    return gain_um_per_v * 1e-6 / (1.0 - u * u + 1j * u / q)


def _through_chain(volts, sample_rate, tones, h=_h):
    """The die displacement [m] of a played loop of input ``volts`` [V], by FFT (the loop
    is periodic: every tone makes whole cycles in it), and each tone's amplitude [m]
    and phase [rad] read off its own bin."""
    n = len(volts)
    spec = np.fft.rfft(volts)
    f = np.fft.rfftfreq(n, 1.0 / sample_rate)
    die = np.fft.rfft(np.fft.irfft(spec * h(f), n))
    out = []
    for ft in tones:
        k = int(round(ft * n / sample_rate))
        assert abs(k - ft * n / sample_rate) < 1e-6, "a tone off the loop's grid"
        c = die[k] * 2.0 / n
        out.append((abs(c), math.atan2(c.imag, c.real)))
    return out


def _phase_error_deg(a, b):
    return abs(math.degrees(math.atan2(math.sin(a - b), math.cos(a - b))))


# ----------------------------------------------------------------------------- spec


def test_without_chain_the_spec_dumps_as_before():
    # plan.json records the spec's dump: a spec without drive.chain must not gain a key
    assert "chain" not in json.loads(ArraySpec().model_dump_json())["drive"]


def test_transfer_table_csv_read_relative_to_the_spec(tmp_path):
    (tmp_path / "chain.csv").write_text(
        "frequency_hz,gain_um_per_v,phase_deg\n4000,1.0,0\n10000,2.0,-30\n20000,0.5,-170\n")
    spec = tmp_path / "s.yaml"
    spec.write_text(TINY.replace("  channels: {count: 60}\n",
                                 "  channels: {count: 60}\n  chain:\n    transfer: chain.csv\n"))
    loaded = load_spec(spec)
    table = loaded.spec.drive.chain.transfer
    assert table.file == "chain.csv" and table.gain_um_per_v == (1.0, 2.0, 0.5)
    chain = resolve_settings(loaded).chain
    # log-frequency interpolation of log gain and phase, at the geometric middle
    mid = math.sqrt(4000 * 10000)
    h = chain.response(mid)
    assert abs(abs(h) - math.sqrt(2.0) * 1e-6) < 1e-12
    assert abs(math.degrees(np.angle(h)) + 15.0) < 1e-9
    with pytest.raises(ValueError, match="outside the transfer table"):
        chain.response(25000.0)


def test_transfer_table_errors_name_file_row_and_line(tmp_path):
    (tmp_path / "chain.csv").write_text(
        "frequency_hz,gain_um_per_v,phase_deg\n4000,1.0,0\n10000,-2.0,-30\n")
    spec = tmp_path / "s.yaml"
    spec.write_text(TINY.replace("  channels: {count: 60}\n",
                                 "  channels: {count: 60}\n  chain:\n    transfer: chain.csv\n"))
    result = CliRunner().invoke(main, ["plan", str(spec), "--dry-run"])
    assert result.exit_code == 2, result.output
    assert "chain.csv: row 3, column gain_um_per_v" in result.output
    assert "drive.chain.transfer" in result.output and "(line 12)" in result.output
    assert "Traceback" not in result.output


@pytest.mark.parametrize("transfer, named", [
    ("{gain_um_per_v: -1.0}", "drive.chain.transfer.gain_um_per_v: Input should be greater than 0"),
    ("{gain_um_per_v: 1.0, bogus: 2}", "drive.chain.transfer.bogus: unknown key"),
    ("{frequency_hz: [4000, 20000], gain_um_per_v: [1, 1]}", "drive.chain.transfer.phase_deg"),
])
def test_a_chain_error_names_the_spec_key_not_pydantic_s_union_tag(tmp_path, transfer, named):
    """drive.chain.transfer is a tagged union (a model, a table or a file): its tag
    ("model", "table") is no key of the spec and is not in the name an error gives."""
    spec = tmp_path / "s.yaml"
    spec.write_text(TINY.replace("  channels: {count: 60}\n",
                                 f"  channels: {{count: 60}}\n  chain:\n    transfer: {transfer}\n"))
    result = CliRunner().invoke(main, ["plan", str(spec), "--dry-run"])
    assert result.exit_code == 2, result.output
    assert named in result.output and "(line 12)" in result.output
    assert ".model." not in result.output and ".table." not in result.output
    assert "Traceback" not in result.output


def test_table_not_covering_the_band_is_refused(tmp_path):
    spec = tmp_path / "s.yaml"
    spec.write_text(TINY.replace(
        "  channels: {count: 60}\n",
        "  channels: {count: 60}\n  chain:\n    transfer: {frequency_hz: [6000, 20000], "
        "gain_um_per_v: [1, 1], phase_deg: [0, 0]}\n"))
    result = CliRunner().invoke(main, ["plan", str(spec), "--dry-run"])
    assert result.exit_code == 2, result.output
    assert "covers 6000-20000 Hz, not the whole band 5000-14000 Hz" in result.output


def test_piezo_um_per_v_and_chain_refused_together():
    with pytest.raises(SpecError, match="piezo_um_per_v and chain"):
        load_spec(TINY.replace("  channels: {count: 60}\n",
                               "  channels: {count: 60}\n  piezo_um_per_v: 2\n  chain:\n"
                               "    transfer: {gain_um_per_v: 1}\n"))


# ----------------------------------------------------------------------------- compensation


@pytest.mark.filterwarnings("ignore::planner.lab.exporters.DriveWarning")
def test_compensated_file_through_the_chain_gives_the_designed_die_tones(tmp_path):
    # 25 tones across a band straddling the resonance, as a plan's multi-tone step
    freqs = np.geomspace(20000.0, 51000.0, 25)
    die = synthesize(freqs, None, 200000.0, seed=1)
    transfer = ModelTransfer(GAIN_UM_PER_V * 1e-6, ((F_RES, Q_RES),))
    volts = compensate(die, transfer)
    for fmt in ("csv", "wav", "arb"):
        path = export(volts, tmp_path / f"step.{fmt}", fmt, die=die)
        side = read_sidecar(path)
        assert side["signal"] == "amplifier_input_v" and "full_scale_v" in side
        samples, rate = read_waveform(path)
        got = _through_chain(samples, rate, die.frequencies)
        # 16-bit codes (arb) quantise to 1/32767 of the input's full scale
        for (a, p), za, zp in zip(got, die.amplitudes, die.phases):
            assert abs(a / za - 1) < 0.01
            assert _phase_error_deg(p, zp) < 1.0
    # the ideal sum played instead (no compensation) misses the die's tones by far
    raw = _through_chain(die.samples / (GAIN_UM_PER_V * 1e-6), die.sample_rate,
                         die.frequencies)
    assert max(abs(a / za - 1) for (a, _), za in zip(raw, die.amplitudes)) > 1.0


def _tiny_settings(extra):
    loaded = load_spec(TINY.replace("  channels: {count: 60}\n",
                                    "  channels: {count: 60}\n" + extra))
    return loaded, resolve_settings(loaded)


def test_a_tone_the_chain_cannot_deliver_is_named():
    # 13.5 kHz far above a 6 kHz resonance of Q 2: 1 um/V x (6/13.5)^2, so its 0.29 um
    # need ~1.5 V where the input may take 1 V; the 5.1 kHz tone needs far less
    _, settings = _tiny_settings("  chain:\n    transfer: {gain_um_per_v: 1.0, resonances: "
                                 "[{frequency_hz: 6000, q: 2}]}\n    max_input_v: 1.0\n")
    tones = {Node("A1", "forward"): 5093.0, Node("A2", "backward"): 13516.0}
    waveforms = synthesize_steps(settings, settings.steps, tones)
    with pytest.raises(PlanningError, match=r"cannot deliver the tone 1351\d\.\d Hz \(A2\.backward"):
        limit_input(settings, waveforms, settings.steps, tones)


def test_a_step_over_the_input_limit_is_lowered_by_one_factor():
    tones = {Node("A1", "forward"): 5093.0, Node("A2", "backward"): 13516.0}
    # one step playing both tones: each alone (1.24 and 0.29 um at 1 um/V) is within
    # 1.4 V, their sum (up to 1.52 V) is not
    text = TINY.replace("    - {name: pull, duration_ms: 5, backward: [A2]}",
                        "    - {name: pull, duration_ms: 5, backward: [A2]}\n"
                        "    - {name: both, duration_ms: 5, forward: [A1], backward: [A2]}")
    loaded = load_spec(text.replace("  channels: {count: 60}\n",
                                    "  channels: {count: 60}\n  chain:\n    transfer: "
                                    "{gain_um_per_v: 1.0}\n    max_input_v: 1.4\n"))
    settings = resolve_settings(loaded)
    waveforms = synthesize_steps(settings, settings.steps, tones)
    out, notes = limit_input(settings, waveforms, settings.steps, tones)
    both = "s/both"
    assert notes[both]["input_scale"] < 1.0
    assert notes[both]["input_peak_v"] <= 1.4
    assert np.allclose(out[both].amplitudes, waveforms[both].amplitudes
                       * notes[both]["input_scale"])
    assert notes["s/push"]["input_scale"] == 1.0


# ----------------------------------------------------------------------------- phases

#: One step playing six tones over the tiny band (the tiny spec on a 1 x 6 array), and
#: chains that scale and turn them: label -> (drive.chain.transfer, the resonance and Q
#: and low-pass of the test's own chain, the least relative fall of the amplifier
#: input's crest factor).  The power convention makes the 5.2 kHz tone ~1.2 um: 1.2 V
#: alone at 1 um/V, within the input limit of 1.5 V that the sum is above.
SIX_HZ = (5200.0, 6300.0, 7600.0, 9100.0, 10900.0, 13100.0)
SIX_MAX_INPUT_V = 1.5
INPUT_CHAINS = {
    "Q 3 at a tone": ("{gain_um_per_v: 1.0, resonances: [{frequency_hz: 9100, q: 3}]}",
                      (9100.0, 3.0, None), 0.04),
    "Q 20 in the band": ("{gain_um_per_v: 1.0, resonances: [{frequency_hz: 11000, q: 20}]}",
                         (11000.0, 20.0, None), 0.03),
    "Q 5 and a low-pass": ("{gain_um_per_v: 1.0, resonances: [{frequency_hz: 8000, q: 5}], "
                           "low_pass_hz: 9000}", (8000.0, 5.0, 9000.0), 0.08),
}


def _six(transfer, max_input_v=SIX_MAX_INPUT_V):
    """(settings, the six-tone step, its tones) of the tiny spec on a 1 x 6 array with
    ``transfer`` and the input limit."""
    from planner.arrayspec import Step

    text = TINY.replace("array: {rows: 1, cols: 2}", "array: {rows: 1, cols: 6}")
    limit = "" if max_input_v is None else f"    max_input_v: {max_input_v}\n"
    text = text.replace("  channels: {count: 60}\n",
                        f"  channels: {{count: 60}}\n  chain:\n    transfer: {transfer}\n"
                        + limit)
    settings = resolve_settings(load_spec(text))
    devices = tuple(f"A{i}" for i in range(1, 7))
    step = Step("s", "all", 0, 0.005, devices, ())
    return settings, step, {Node(d, "forward"): f for d, f in zip(devices, SIX_HZ)}


def _die_phases(settings, step, tones):
    """The step as a plan without a chain plays it: phases optimised for the die."""
    import dataclasses

    return synthesize_steps(dataclasses.replace(settings, chain=None), [step],
                            tones)[step.key]


@pytest.mark.parametrize("label", sorted(INPUT_CHAINS))
def test_phases_through_a_chain_hold_down_the_amplifier_input(label):
    """With a chain the plan's phases are chosen for the amplifier input: its crest
    factor is lower than that of the die's phases compensated afterwards, and where
    max_input_v binds the die keeps more of every tone."""
    from planner.planning.chain import input_waveform
    from planner.planning.chain import limit_drives

    transfer, _, fall = INPUT_CHAINS[label]
    settings, step, tones = _six(transfer)
    key = step.key
    before = _die_phases(settings, step, tones)
    after = synthesize_steps(settings, [step], tones)[key]
    # the same tones at the die: only the phases differ
    assert np.array_equal(after.frequencies, before.frequencies)
    assert np.array_equal(after.amplitudes, before.amplitudes)
    cf_before = input_waveform(settings, before).crest_factor
    cf_after = input_waveform(settings, after).crest_factor
    assert cf_after <= (1 - fall) * cf_before, (cf_before, cf_after)
    # the input limit binds both: one factor on every tone, larger for the new phases
    _, notes_before = limit_drives(settings, {key: before}, [step], tones)
    _, notes_after = limit_drives(settings, {key: after}, [step], tones)
    assert notes_before[key]["input_scale"] < 1.0
    assert notes_after[key]["input_scale"] > (1 + fall) * notes_before[key]["input_scale"]
    assert notes_after[key]["input_peak_v"] <= SIX_MAX_INPUT_V


def test_without_an_input_limit_a_chain_plays_the_dies_phases():
    """No input limit: nothing at the input sets a step's amplitude, so the step plays
    the phases a plan without a chain would (the die's), whatever the chain."""
    transfer, _, _ = INPUT_CHAINS["Q 3 at a tone"]
    settings, step, tones = _six(transfer, max_input_v=None)
    got = synthesize_steps(settings, [step], tones)[step.key]
    assert np.array_equal(got.phases, _die_phases(settings, step, tones).phases)


@pytest.mark.filterwarnings("ignore::planner.lab.exporters.DriveWarning")
def test_wav_of_phases_chosen_for_the_input_gives_the_designed_die_tones(tmp_path):
    """The six-tone step through the Q-3 chain, as the plan plays it (phases for the
    input, lowered to max_input_v): its WAV read back and passed through the test's own
    chain by FFT gives the die the step's tones within 1 % and 1 degree, and the file
    peaks within the limit at a lower crest factor than the die's phases give it."""
    from planner.planning.chain import input_waveform
    from planner.planning.chain import limit_drives

    transfer, (f_res, q, _), fall = INPUT_CHAINS["Q 3 at a tone"]
    settings, step, tones = _six(transfer)
    key = step.key
    played, _ = limit_drives(settings, synthesize_steps(settings, [step], tones), [step],
                             tones)
    die = played[key]
    path = export(input_waveform(settings, die), tmp_path / "all.wav", "wav", die=die)
    assert read_sidecar(path)["signal"] == "amplifier_input_v"
    samples, rate = read_waveform(path)

    def h(f):
        return _h(f, 1.0, f_res, q)

    for (a, p), za, zp in zip(_through_chain(samples, rate, die.frequencies, h),
                              die.amplitudes, die.phases):
        assert abs(a / za - 1) < 0.01
        assert _phase_error_deg(p, zp) < 1.0
    # float32 samples: the limit to 1e-6
    assert np.max(np.abs(samples)) <= SIX_MAX_INPUT_V * (1 + 1e-6)
    rms = math.sqrt(np.mean(samples[: die.loop_points] ** 2))
    before = input_waveform(settings, _die_phases(settings, step, tones)).crest_factor
    assert np.max(np.abs(samples)) / rms <= (1 - fall) * before


def test_redrawn_phases_are_held_to_the_input_limit(monkeypatch):
    """`redraw_slow` draws a slow step's phases anew: each draw is held to the chain's
    input limit (a new peak at the input), not only to the acceleration limit."""
    import planner.afterfab.drive as afterfab_drive
    from planner.afterfab.drive import RescuedDrive, redraw_slow
    from planner.planning.chain import input_waveform
    from planner.planning.chain import limit_drives
    from planner.planning.verify import TOO_SLOW, Failure

    transfer, _, _ = INPUT_CHAINS["Q 3 at a tone"]
    settings, step, tones = _six(transfer)
    key = step.key
    waveforms, notes = limit_drives(settings, synthesize_steps(settings, [step], tones),
                                    [step], tones)
    # the limit binds the step at its full amplitude, whatever its phases
    assert notes[key]["input_scale"] < 0.9
    drive = RescuedDrive((step,), waveforms, notes, {key: 0.0}, tones, [], {}, {})
    # a slider too slow in the step; the first new draw passes (no chip to simulate:
    # the burst keeps its length, the check is this stub)
    monkeypatch.setattr(afterfab_drive, "size_within",
                        lambda settings, steps, *args: (tuple(steps), {}))
    rows = [{"index": 0, "passed": False}]
    fails = [Failure(0, "A1", None, TOO_SLOW, 0.0)]
    got, rows, fails = redraw_slow(settings, drive, rows, fails, {}, {},
                                   lambda steps, w: ([{"index": 0, "passed": True}], []))
    assert got.notes[key]["phases_drawn"] == 1 and not fails
    redrawn = got.waveforms[key]
    assert got.notes[key]["input_scale"] < 1.0
    assert input_waveform(settings, redrawn).peak <= SIX_MAX_INPUT_V
    assert got.notes[key]["input_peak_v"] <= SIX_MAX_INPUT_V


# ----------------------------------------------------------------------------- calibrate


def _synthetic_sweep(path, seed=0):
    """A sweep of the issue's chain, 2 % gain and 0.5 deg phase noise, with the
    harmonics of -40 / -50 dB at 10 um (the Nonlinearity's polynomial)."""
    rng = np.random.default_rng(seed)
    nl = Nonlinearity.from_harmonics({2: -40.0, 3: -50.0}, 10e-6)
    rows = ["frequency_hz,input_v,displacement_um,phase_deg,harmonic2_um,harmonic3_um"]
    for f in np.geomspace(3000.0, 60000.0, 90):
        h = _h(f) * (1 + 0.02 * rng.standard_normal()) * np.exp(
            1j * math.radians(0.5) * rng.standard_normal())
        v = 2.0                                      # volts in; the die's stroke varies
        d = abs(h) * v
        h2, h3 = nl.a2 * d * d / 2, nl.a3 * d ** 3 / 4
        rows.append(f"{f:.3f},{v},{d * 1e6:.6g},{math.degrees(np.angle(h)):.4f},"
                    f"{h2 * 1e6:.6g},{h3 * 1e6:.6g}")
    path.write_text("\n".join(rows) + "\n")


def test_calibrate_chain_round_trip(tmp_path):
    sweep = tmp_path / "sweep.csv"
    _synthetic_sweep(sweep)
    out = tmp_path / "chain.yaml"
    result = CliRunner().invoke(main, ["calibrate", "--chain", str(sweep), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "chain.csv").exists()
    res = [line for line in result.output.splitlines() if line.startswith("resonance:")]
    assert len(res) == 1
    f_fit = float(res[0].split()[1])
    q_fit = float(res[0].split("Q = ")[1].split()[0])
    assert abs(f_fit / F_RES - 1) < 0.005 and abs(q_fit / Q_RES - 1) < 0.1
    # the block, as a spec takes it (the table beside the spec)
    block = out.read_text()
    spec = tmp_path / "s.yaml"
    spec.write_text(TINY.replace("drive:\n", "").replace(
        "  band_hz: [5000, 14000]\n  channels: {count: 60}\n", "") + "\n" + block.replace(
        "drive:\n", "drive:\n  band_hz: [5000, 50000]\n  channels: {count: 60}\n"))
    settings = resolve_settings(load_spec(spec))
    f = np.geomspace(5000.0, 50000.0, 200)
    h = settings.chain.response(f)
    # the table is the measurement: within its noise (2 %, 0.5 deg) plus the
    # interpolation between 90 points across a Q-20 peak
    assert np.max(np.abs(np.abs(h) / np.abs(_h(f)) - 1)) < 0.12
    assert np.median(np.abs(np.abs(h) / np.abs(_h(f)) - 1)) < 0.03
    assert np.max(np.abs(np.degrees(np.angle(h / _h(f))))) < 8.0
    # the levels are stated at the sweep's largest stroke (at the resonance), where a
    # polynomial's 2nd harmonic stands 20 log10(S / 10 um) dB higher, its 3rd twice that
    harm = load_spec(spec).spec.drive.chain
    up = 20 * math.log10(harm.at_stroke_um / 10.0)
    assert abs(harm.harmonics_db[2] - (-40.0 + up)) < 0.5
    assert abs(harm.harmonics_db[3] - (-50.0 + 2 * up)) < 0.5
    # at the sweep's largest stroke, stated as at_stroke_um and rescaled to it
    nl = settings.chain.nonlinearity
    ref = Nonlinearity.from_harmonics({2: -40.0, 3: -50.0}, 10e-6)
    assert abs(nl.a2 / ref.a2 - 1) < 0.06 and abs(nl.a3 / ref.a3 - 1) < 0.06


def test_calibrate_chain_bad_row_exit_2_nothing_written(tmp_path):
    sweep = tmp_path / "sweep.csv"
    sweep.write_text("frequency_hz,input_v,displacement_um,phase_deg\n1000,1,1,0\n"
                     "2000,1,-1,0\n3000,1,1,0\n4000,1,1,0\n")
    out = tmp_path / "chain.yaml"
    result = CliRunner().invoke(main, ["calibrate", "--chain", str(sweep), "--out", str(out)])
    assert result.exit_code == 2, result.output
    assert "row 3, column displacement_um" in result.output
    assert not out.exists() and not (tmp_path / "chain.csv").exists()


# ----------------------------------------------------------------------------- the plan


@pytest.mark.slow
def test_plan_with_chain_exports_the_amplifier_input(tmp_path):
    # the tiny plan through a chain with a resonance inside its band (9 kHz, Q 10)
    spec = tmp_path / "s.yaml"
    spec.write_text(TINY.replace(
        "  channels: {count: 60}\n",
        "  channels: {count: 60}\n  chain:\n    transfer: {gain_um_per_v: 1.0, resonances: "
        "[{frequency_hz: 9000, q: 10}]}\n    harmonics_db: {2: -40, 3: -50}\n"))
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "planner.cli", "plan", str(spec), "--out",
                           str(out), "--quiet", "--cache-dir", str(tmp_path / "cache")],
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr
    plan = json.loads((out / "plan.json").read_text())
    assert plan["chain"]["signal"] == "amplifier_input_v"
    assert (out / "figures" / "drive_chain.png").stat().st_size > 0

    def h(f):
        return _h(f, 1.0, 9000.0, 10.0)

    for step in plan["steps"]:
        for fmt, rel in step["files"].items():
            samples, rate = read_waveform(out / rel)
            assert read_sidecar(out / rel)["signal"] == "amplifier_input_v"
            freqs = [t["frequency_hz"] for t in step["tones"]]
            got = _through_chain(samples, rate, freqs, h)
            for (a, p), tone in zip(got, step["tones"]):
                assert abs(a / tone["amplitude_m"] - 1) < 0.01, (fmt, tone)
                assert _phase_error_deg(p, tone["phase_rad"]) < 1.0, (fmt, tone)


# ----------------------------------------------------------------------------- distortion


def test_distortion_products_at_the_stated_levels():
    from planner.synthesis.chain import distort

    nl = Nonlinearity.from_harmonics({2: -40.0, 3: -50.0}, 10e-6)
    # one tone at the stated stroke: its harmonics at the stated levels
    k, a, _, prod = distort([100], [10e-6], [0.3], nl, 1e-15)
    assert list(k) == [100, 200, 300] and list(prod) == [False, True, True]
    assert abs(20 * math.log10(a[1] / 10e-6) + 40.0) < 1e-9
    assert abs(20 * math.log10(a[2] / 10e-6) + 50.0) < 1e-9
    # two tones: the 2nd-order intermodulation f1 + f2 and f2 - f1 at a2 Y1 Y2, the
    # 3rd-order 2 f1 - f2 at 3/4 a3 Y1^2 Y2 (the polynomial expanded by hand)
    y1, y2 = 3e-6, 2e-6
    k, a, _, _ = distort([100, 130], [y1, y2], [0.0, 0.0], nl, 1e-15)
    amp = dict(zip(k.tolist(), a))
    assert abs(amp[230] / (nl.a2 * y1 * y2) - 1) < 1e-9
    assert abs(amp[30] / (nl.a2 * y1 * y2) - 1) < 1e-9
    assert abs(amp[70] / (0.75 * nl.a3 * y1 * y1 * y2) - 1) < 1e-9


def test_products_on_an_idle_impacters_band_are_named():
    from planner.planning.chain import die_drives, products_near_idle

    _, settings = _tiny_settings("  chain:\n    transfer: {gain_um_per_v: 1.0}\n"
                                 "    harmonics_db: {2: -30}\n")
    # A1's tone's 2nd harmonic lands 0.5 % from A2's own tone, idle in step push
    tones = {Node("A1", "forward"): 5000.0, Node("A2", "backward"): 10050.0}
    played = synthesize_steps(settings, settings.steps, tones)
    drives = die_drives(settings, played)
    near = products_near_idle(settings, settings.steps, drives, tones)
    assert [(r["step"], r["impacter"]) for r in near] == [("s/push", "A2.backward")]
    assert abs(near[0]["product_hz"] - 2 * played["s/push"].frequencies[0]) < 1e-6
    # -30 dB at the 10 um stroke: a2 Y^2 / 2 with Y the push tone's amplitude
    y = played["s/push"].amplitudes[0]
    expected = Nonlinearity.from_harmonics({2: -30.0}, 10e-6).a2 * y * y / 2
    assert abs(near[0]["amplitude_m"] / expected - 1) < 1e-9
