"""Drive files: written for real, read back, and checked against their tone tables.

The central invariant: the spectrum of every exported file reproduces each tone's amplitude
within 0.1 % and phase within 1 mrad, and its loop point is continuous.

Quantisation (16-bit formats): the error per sample is at most half a code, FS / 65534, so
a tone's projection is off by at most FS / 32767 (all errors aligned), i.e. relative
(FS / A) / 32767.  The equal-tone fixture has FS / A = crest factor * sqrt(n / 2) < 6, a
worst case of 2e-4 < 1e-3; the power-convention fixture relies on the rounding errors
being uncorrelated, ~sqrt(2 / N) of that.
"""

import json
import warnings

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.io import wavfile

from planner.lab.exporters import (
    EXPORTERS,
    INT16_FULL_SCALE,
    DriveWarning,
    export,
    measure_tones,
    read_sidecar,
    read_waveform,
    sidecar_path,
    verify_export,
)
from planner.synthesis import Waveform, synthesize, tones_from_power

FS = 200e3
FORMATS = list(EXPORTERS)


@pytest.fixture(scope="module")
def equal_tones():
    f = [2150.0, 3370.0, 5020.0, 7730.0, 11890.0, 17310.0]
    return synthesize(f, 1.5e-6, FS, seed=0)


@pytest.fixture(scope="module")
def power_tones():
    f = np.geomspace(2.1e3, 19e3, 9)
    return synthesize(f, tones_from_power(f), FS, seed=1)


def assert_holds_tones(samples, rate, wf):
    amp, ph = measure_tones(samples, rate, wf.frequencies)
    assert np.max(np.abs(amp / wf.amplitudes - 1)) <= 1e-3
    assert np.max(np.abs(np.angle(np.exp(1j * (ph - wf.phases))))) <= 1e-3


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("which", ["equal_tones", "power_tones"])
def test_every_format_reproduces_its_tones(tmp_path, fmt, which, request):
    wf = request.getfixturevalue(which)
    path = export(wf, tmp_path / f"drive{EXPORTERS[fmt].suffix}", fmt)
    samples, rate = read_waveform(path)
    assert rate == wf.sample_rate
    assert len(samples) == len(wf.samples)
    resolution = EXPORTERS[fmt].resolution * read_sidecar(path)["full_scale_m"]
    assert np.max(np.abs(samples - wf.samples)) <= resolution
    assert_holds_tones(samples, rate, wf)
    # loop point: the step from the last sample to the first is one a continuous signal of
    # these tones can make in one sample (sum 2 pi f A / fs), plus quantisation
    bound = np.sum(2 * np.pi * wf.frequencies * wf.amplitudes) / rate + 2 * resolution
    assert abs(samples[0] - samples[-1]) <= bound
    check = verify_export(path)
    assert check.ok, str(check)


@pytest.mark.parametrize("fmt", FORMATS)
def test_sidecar_holds_the_tone_table_and_scale(tmp_path, equal_tones, fmt):
    wf = equal_tones
    path = export(wf, tmp_path / "d", fmt, um_per_v=0.05, amplifier_gain=20.0)
    side = json.loads(sidecar_path(path).read_text())
    assert sidecar_path(path).name == "d.json"
    assert side["format"] == fmt and side["file"] == "d"
    np.testing.assert_array_equal([t["frequency_hz"] for t in side["tones"]], wf.frequencies)
    np.testing.assert_array_equal([t["amplitude_m"] for t in side["tones"]], wf.amplitudes)
    np.testing.assert_array_equal([t["phase_rad"] for t in side["tones"]], wf.phases)
    assert side["sample_rate_hz"] == FS
    assert side["loop_length_s"] == wf.loop_length
    assert side["points"] == len(wf.samples)
    assert side["full_scale_m"] >= np.abs(wf.samples).max()
    assert side["full_scale_m"] == pytest.approx(wf.peak)
    # 0.05 um/V through a gain of 20: 1 um per generator volt
    assert side["volts_full_scale"] == pytest.approx(side["full_scale_m"] / 1e-6)
    assert side["crest_factor"] == wf.crest_factor
    assert side["scale"] == 1.0
    assert side["warnings"] == []


def test_arb_file_format(tmp_path, equal_tones):
    path = export(equal_tones, tmp_path / "d.arb", "arb", um_per_v=0.1, amplifier_gain=10.0)
    lines = path.read_bytes().decode().split("\r\n")
    assert lines[0] == "File Format:1.10"
    header = dict(line.split(":", 1) for line in lines[:lines.index("Data:")])
    assert header["Channel Count"] == "1"
    assert float(header["Sample Rate"]) == FS
    assert header["Data Type"] == '"short"'
    assert int(header["Data Points"]) == len(equal_tones.samples)
    volts = equal_tones.peak / (0.1e-6 * 10.0)
    assert float(header["High Level"]) == pytest.approx(volts, abs=1e-6)
    assert float(header["Low Level"]) == pytest.approx(-volts, abs=1e-6)
    codes = np.array([int(v) for v in lines[lines.index("Data:") + 1:] if v])
    assert len(codes) == len(equal_tones.samples)
    assert np.abs(codes).max() <= INT16_FULL_SCALE
    # symmetric scale: the largest sample sits at its share of full scale
    share = np.abs(equal_tones.samples).max() / equal_tones.peak
    assert np.abs(codes).max() == round(share * INT16_FULL_SCALE)
    assert read_sidecar(path)["level_unit"] == "V"


def test_arb_levels_in_um_without_piezo_data(tmp_path, equal_tones):
    path = export(equal_tones, tmp_path / "d.arb", "arb")
    assert f"High Level:{equal_tones.peak * 1e6:.6f}" in path.read_text()
    side = read_sidecar(path)
    assert side["level_unit"] == "um" and side["volts_full_scale"] is None


def test_wav_data_types(tmp_path, equal_tones):
    rate, data = wavfile.read(export(equal_tones, tmp_path / "a.wav", "wav"))
    assert rate == 200000 and data.dtype == np.float32 and np.abs(data).max() <= 1.0
    rate, data = wavfile.read(export(equal_tones, tmp_path / "b.wav", "wav16"))
    assert data.dtype == np.int16 and np.abs(data.astype(int)).max() <= INT16_FULL_SCALE


def test_wav_needs_a_whole_sample_rate(tmp_path):
    wf = synthesize([3000.0, 4000.0], 1e-6, 100000.5, seed=0)
    with pytest.raises(ValueError, match="sample_rate"):
        export(wf, tmp_path / "x.wav", "wav")
    assert list(tmp_path.iterdir()) == []   # atomic: nothing half-written left behind


def test_no_temporary_files_left(tmp_path, equal_tones):
    for fmt in FORMATS:
        export(equal_tones, tmp_path / f"d_{fmt}", fmt)
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == sorted([f"d_{f}" for f in FORMATS] + [f"d_{f}.json" for f in FORMATS])


def test_band_warning_for_sound_cards(tmp_path):
    wf = synthesize([5000.0, 30000.0], 1e-6, 96000.0, seed=0)
    with pytest.warns(DriveWarning, match="20000 Hz band"):
        path = export(wf, tmp_path / "d.wav", "wav")
    assert any("band" in w for w in read_sidecar(path)["warnings"])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        export(wf, tmp_path / "d.csv", "csv")   # a CSV has no player band


def test_memory_warning(tmp_path, equal_tones):
    with pytest.warns(DriveWarning, match="memory"):
        path = export(equal_tones, tmp_path / "d.arb", "arb", memory_points=100)
    assert any("memory" in w for w in read_sidecar(path)["warnings"])


def test_nyquist_warning(tmp_path):
    # synthesize refuses such tones; a hand-made Waveform can still carry one
    n = 100
    wf = Waveform(samples=np.cos(np.pi * 0.6 * np.arange(n)), sample_rate=1000.0,
                  frequencies=[600.0], amplitudes=[1.0], phases=[0.0], crest_factor=1.0,
                  loop_length=0.1, peak=1.0, rms=0.7)
    with pytest.warns(DriveWarning, match="Nyquist"):
        export(wf, tmp_path / "d.csv", "csv")


def test_scaling_is_reported_in_the_sidecar(tmp_path):
    wf = synthesize([3000.0, 4100.0, 5300.0], 2e-6, FS, seed=0, peak_limit=3e-6)
    assert wf.scale < 1
    side = read_sidecar(export(wf, tmp_path / "d.csv", "csv"))
    assert side["scale"] == wf.scale and side["peak_m"] <= 3e-6
    assert any("scaled by" in w for w in side["warnings"])


def test_export_validation(tmp_path, equal_tones):
    with pytest.raises(ValueError, match="format must be one of wav, wav16, csv, arb"):
        export(equal_tones, tmp_path / "d", "mp3")
    with pytest.raises(ValueError, match="amplifier_gain"):
        export(equal_tones, tmp_path / "d", "csv", um_per_v=0.1)
    with pytest.raises(ValueError, match="um_per_v"):
        export(equal_tones, tmp_path / "d", "csv", um_per_v=-1.0, amplifier_gain=2.0)


def test_read_needs_the_sidecar(tmp_path, equal_tones):
    path = export(equal_tones, tmp_path / "d.wav", "wav")
    sidecar_path(path).unlink()
    with pytest.raises(FileNotFoundError, match="sidecar"):
        read_waveform(path)


def test_measure_tones_separates_tones_over_part_of_a_loop():
    # 1.37 periods of the slowest tone: not orthogonal, least squares still exact
    rate, n = 50e3, 300
    f = np.array([230.0, 310.0, 4400.0])
    a = np.array([1.0, 0.5, 0.25])
    ph = np.array([0.4, -2.0, 3.0])
    t = np.arange(n) / rate
    x = sum(ai * np.cos(2 * np.pi * fi * t + pi) for fi, ai, pi in zip(f, a, ph))
    amp, phase = measure_tones(x, rate, f)
    np.testing.assert_allclose(amp, a, rtol=1e-8)
    np.testing.assert_allclose(phase, ph, atol=1e-8)


# --------------------------------------------------------------------------- the CLI


def write_plan(tmp_path, plan_dir, *, extra_step=False):
    """The tiny plan's plan.json made a 1 x 4 array with one step of four known tones
    (on a 1 ms grid at FS), one per device, written to ``tmp_path``: a real plan, read by
    the one plan.json reader (each tone its impacter's, on its channel of a linear grid
    3100-9300 Hz, 516.7 Hz apart; every impacter the tiny plan's A1.forward design)."""
    f = [3100.0, 4650.0, 6200.0, 9300.0]
    channels = [0, 3, 6, 12]
    z = tones_from_power(f)
    ph = [0.3, -1.1, 2.0, -2.9]
    data = json.loads((plan_dir / "plan.json").read_text())
    devices = ["A1", "A2", "A3", "A4"]
    data["spec"]["array"].update(rows=1, cols=4)
    data["spec"]["drive"].update(band_hz=[3100.0, 9300.0],
                                 channels={"spacing": "linear", "count": 13})
    design = next(r for r in data["impacters"] if r["id"] == "A1.forward")
    data["impacters"] = [{**design, "id": f"{d}.forward", "device": d, "channel": ch,
                          "frequency_hz": fi} for d, ch, fi in zip(devices, channels, f)]
    data["devices"] = [{**data["devices"][0], "id": d} for d in devices]
    data.pop("manufacturability", None)   # the tiny designs' separations, not these tones'
    step = {**data["steps"][0], "scene": "demo", "name": "forward", "index": 0,
            "forward": devices, "backward": [],
            "tones": [{"frequency_hz": fi, "amplitude_m": float(zi), "phase_rad": pi}
                      for fi, zi, pi in zip(f, z, ph)]}
    data["steps"] = [step] + ([{**step, "scene": "other", "index": 1}] if extra_step else [])
    data["spec"]["drive"].update(peak_limit_um=10.0, sample_rate_hz=FS)
    path = tmp_path / "plan.json"
    path.write_text(json.dumps(data))
    return path, np.array(f), np.array(ph)


def run(*args):
    from planner.cli import main

    return CliRunner().invoke(main, ["drive", *map(str, args)])


def test_cli_formats_match_the_registry():
    from planner.cli.drive import FORMATS as CLI_FORMATS

    assert tuple(CLI_FORMATS) == tuple(EXPORTERS)


@pytest.mark.parametrize("fmt", FORMATS)
def test_cli_writes_a_verified_file(tmp_path, tiny_plan_dir, fmt):
    plan, f, ph = write_plan(tmp_path, tiny_plan_dir)
    out = tmp_path / "out" / f"fwd{EXPORTERS[fmt].suffix}"
    out.parent.mkdir()  # vibroplan creates no missing parent folders (issue 13)
    res = run(plan, "--step", "forward", "--format", fmt, "--out", out)
    assert res.exit_code == 0, res.output
    assert "read back: ok" in res.output and "crest factor" in res.output
    assert verify_export(out).ok
    # the plan's tones sit on a 1 ms grid already: same frequencies, the plan's phases
    side = read_sidecar(out)
    np.testing.assert_allclose([t["frequency_hz"] for t in side["tones"]], f, rtol=1e-12)
    np.testing.assert_allclose([t["phase_rad"] for t in side["tones"]], ph, atol=1e-12)
    samples, rate = read_waveform(out)
    _, measured = measure_tones(samples, rate, f)
    assert np.max(np.abs(np.angle(np.exp(1j * (measured - ph))))) <= 1e-3


def test_cli_plot_and_folder_argument(tmp_path, tiny_plan_dir, monkeypatch):
    plan, *_ = write_plan(tmp_path, tiny_plan_dir)
    monkeypatch.chdir(tmp_path)
    res = run(tmp_path, "--step", "demo/forward", "--format", "csv", "--plot", "p.png",
              "--reoptimise")
    assert res.exit_code == 0, res.output
    assert (tmp_path / "demo__forward.csv").exists()
    assert (tmp_path / "p.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_cli_bad_step_exits_2_without_traceback(tmp_path, tiny_plan_dir):
    plan, *_ = write_plan(tmp_path, tiny_plan_dir)
    res = run(plan, "--step", "sideways")
    assert res.exit_code == 2
    assert "error: --step 'sideways': no such step" in res.output
    assert "demo/forward" in res.output and "Traceback" not in res.output


def test_cli_ambiguous_step_lists_the_scenes(tmp_path, tiny_plan_dir):
    plan, *_ = write_plan(tmp_path, tiny_plan_dir, extra_step=True)
    res = run(plan, "--step", "forward")
    assert res.exit_code == 2
    assert "demo/forward" in res.output and "other/forward" in res.output


def test_cli_rejects_a_file_that_is_not_a_plan(tmp_path):
    bad = tmp_path / "plan.json"
    bad.write_text(json.dumps({"stages": []}))
    res = run(bad, "--step", "x")
    assert res.exit_code == 2 and "steps" in res.output and "Traceback" not in res.output


def test_cli_split_keeps_every_sub_step_within_the_limit(tmp_path, tiny_plan_dir):
    plan, f, _ = write_plan(tmp_path, tiny_plan_dir)
    out = tmp_path / "s.csv"
    res = run(plan, "--step", "forward", "--format", "csv", "--out", out,
              "--peak-limit-um", "3", "--over-limit", "split", "--reoptimise")
    assert res.exit_code == 0, res.output
    parts = sorted(tmp_path.glob("s.sub*.csv"))
    assert len(parts) >= 2
    tones = []
    for p in parts:
        side = read_sidecar(p)
        assert side["peak_m"] <= 3e-6 and side["scale"] == 1.0
        assert verify_export(p).ok
        tones += [t["frequency_hz"] for t in side["tones"]]
    np.testing.assert_allclose(sorted(tones), f, rtol=1e-3)
