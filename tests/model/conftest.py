import pytest

from model import Impacter, Slider


@pytest.fixture(scope="session")
def fig7():
    """The Fig. 7 device: A = 1.5e4 um^2, w = 4 um, l = 1242 um, c = 3 um, nu_n = 5.2 kHz."""
    return Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6).with_natural_frequency(5200.0)


@pytest.fixture(scope="session")
def fig7_slider():
    """Fig. 7 slider: 8.0e4 um^2 of Poly1 (2.0 um), F_s = 20 uN, F_d = 5 uN."""
    return Slider.from_geometry(8.0e-8, 2.0e-6)
