"""Eqs. (2)-(5) and the value objects' validation."""

import math

import numpy as np
import pytest

from model import Drive, Impacter, Slider, amplitude_from_power
from model import devices as d


def test_eq2_3_4_as_printed_fig7_device():
    # Fig. 7 device: A = 1.5e4 um^2, w = 4 um, l = 1242 um (paper Section III-B)
    imp = Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6, viscosity=0.0179e-3)
    m = 2330 * (1.5e-8 * 3.5e-6) + 2 * 2330 * 2e-6 * 4e-6 * 1242e-6          # (2)
    b = 0.0179e-3 * 1.5e-8 / 0.75e-6                                          # (3)
    c = math.cos(math.radians(15))
    k = 169e9 * 2e-6 * (4e-6 / 1242e-6) ** 3 * (4 / c) * (2 / c + 1)           # (4)
    assert imp.mass == pytest.approx(m, rel=1e-14)
    assert imp.damping == pytest.approx(b, rel=1e-14)
    assert imp.stiffness == pytest.approx(k, rel=1e-14)
    # paper-notes: "(2) and (4) give about 4.6 kHz, the paper says 5.2 kHz"
    assert 4.5e3 < imp.natural_frequency < 4.7e3


def test_table2_inconsistency_documented_values():
    # paper-notes: Table II's designs give 16.1 kHz and 6.0 kHz with (2)-(4), the table says 5.82 / 2.04
    fwd = Impacter.from_geometry(13544e-12, 5.6774e-6, 795.74e-6, 5.2046e-6)
    bwd = Impacter.from_geometry(45446e-12, 4.0354e-6, 795.27e-6, 2.6676e-6)
    assert fwd.natural_frequency == pytest.approx(16.1e3, rel=0.01)
    assert bwd.natural_frequency == pytest.approx(6.0e3, rel=0.02)


def test_natural_frequency_override():
    imp = Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6)
    tuned = imp.with_natural_frequency(5200.0)
    assert tuned.natural_frequency == pytest.approx(5200.0, rel=1e-14)
    assert tuned.stiffness == pytest.approx(tuned.mass * (2 * math.pi * 5200) ** 2, rel=1e-14)
    assert tuned.mass == imp.mass and imp.natural_frequency != tuned.natural_frequency
    direct = Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6, natural_frequency=5200.0)
    assert direct.stiffness == pytest.approx(tuned.stiffness, rel=1e-14)


def test_power_convention_footnote3():
    # footnote 3: Z0^2 w^3 = 50 gives Z0 = 1.27 um at 5 kHz
    assert amplitude_from_power(5000.0) == pytest.approx(1.27e-6, abs=0.005e-6)
    drive = Drive.tone(5000.0)
    w = 2 * math.pi * 5000
    assert drive.amplitudes[0] ** 2 * w**3 == pytest.approx(50.0, rel=1e-12)


def test_drive_displacement_sum_of_tones():
    drive = Drive([1000.0, 3000.0], [1e-6, 2e-6], [0.1, -0.4])
    t = np.linspace(0, 1e-3, 7)
    expected = 1e-6 * np.cos(2 * np.pi * 1000 * t + 0.1) + 2e-6 * np.cos(2 * np.pi * 3000 * t - 0.4)
    np.testing.assert_allclose(drive.displacement(t), expected, rtol=1e-13, atol=1e-22)
    both = Drive.tone(1000.0) + Drive.tone(2000.0)
    assert len(both) == 2


def test_slider_from_geometry():
    sl = Slider.from_geometry(8.0e-8)
    assert sl.mass == pytest.approx(2330 * 8.0e-8 * 2.0e-6, rel=1e-14)
    assert sl.static_friction == d.STATIC_FRICTION and sl.dynamic_friction == d.DYNAMIC_FRICTION


@pytest.mark.parametrize("kwargs, name", [
    (dict(mass=-1.0, stiffness=1.0, damping=0.0, gap=1e-6), "mass"),
    (dict(mass=1.0, stiffness=float("nan"), damping=0.0, gap=1e-6), "stiffness"),
    (dict(mass=1.0, stiffness=1.0, damping=-1.0, gap=1e-6), "damping"),
    (dict(mass=1.0, stiffness=1.0, damping=0.0, gap=0.0), "gap"),
    (dict(mass=1.0, stiffness=1.0, damping=0.0, gap=float("inf")), "gap"),
    (dict(mass=1.0, stiffness=1.0, damping=0.0, gap=1e-6, restitution=1.5), "restitution"),
    (dict(mass=1.0, stiffness=1.0, damping=0.0, gap=1e-6, impact_angle=2.0), "impact_angle"),
])
def test_invalid_impacter_names_the_parameter(kwargs, name):
    with pytest.raises(ValueError, match=name):
        Impacter(**kwargs)


@pytest.mark.parametrize("args, name", [
    (([-1.0], [1e-6]), "frequencies"),
    (([1.0], [float("nan")]), "amplitudes"),
    (([1.0, 2.0], [1e-6]), "same length"),
])
def test_invalid_drive(args, name):
    with pytest.raises(ValueError, match=name):
        Drive(*args)
