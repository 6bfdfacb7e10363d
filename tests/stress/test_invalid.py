"""Invalid parameters raise a ValueError that names them.

Property: negative, zero, NaN or infinite values, restitution outside [0, 1], a
start beyond the wall and the like are refused at entry with a ValueError whose
message names the argument, for the value objects and every public entry point.
"""

import math

import pytest

import model
from model import Drive, Impacter, Slider
from model.mpref import reference

NAN = float("nan")
INF = float("inf")
FIG7 = Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6).with_natural_frequency(5200.0)
TONE = Drive.tone(6200.0)
GOOD = dict(mass=1e-10, stiffness=0.1, damping=0.0, gap=1e-6)


@pytest.mark.parametrize("field, bad", [
    ("mass", -1e-10), ("mass", 0.0), ("mass", NAN), ("mass", INF),
    ("stiffness", -0.1), ("stiffness", 0.0), ("stiffness", NAN), ("stiffness", INF),
    ("damping", -1e-9), ("damping", NAN), ("damping", INF),
    ("gap", 0.0), ("gap", -1e-6), ("gap", NAN), ("gap", INF),
    ("restitution", 1.0000001), ("restitution", -0.1), ("restitution", NAN),
    ("impact_angle", math.pi / 2), ("impact_angle", -0.1), ("impact_angle", NAN),
])
def test_impacter_fields(field, bad):
    with pytest.raises(ValueError, match=field):
        Impacter(**{**GOOD, field: bad})


@pytest.mark.parametrize("field, bad", [
    ("area", -1e-8), ("area", 0.0), ("width", NAN), ("length", INF), ("gap", 0.0),
    ("natural_frequency", 0.0), ("natural_frequency", NAN), ("restitution", 2.0),
])
def test_geometry_fields(field, bad):
    args = dict(area=1.5e-8, width=4e-6, length=1242e-6, gap=3e-6)
    if field in args:
        args[field] = bad
        with pytest.raises(ValueError, match=field):
            Impacter.from_geometry(**args)
    else:
        with pytest.raises(ValueError, match=field):
            Impacter.from_geometry(**args, **{field: bad})


@pytest.mark.parametrize("field, bad", [
    ("viscosity", -1.0), ("viscosity", NAN), ("density", 0.0), ("thickness", INF),
    ("beam_angle", math.pi / 2), ("beam_angle", -0.1), ("beam_angle", NAN),
    ("beam_height", 0.0), ("youngs_modulus", -1.0), ("substrate_gap", 0.0),
    ("impact_angle", math.pi / 2), ("density", "poly"),
])
def test_geometry_material_fields_are_named(field, bad):
    with pytest.raises(ValueError, match=field):
        Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6, **{field: bad})


@pytest.mark.parametrize("kwargs, name", [
    (dict(frequencies=[NAN], amplitudes=[1e-6]), "frequencies"),
    (dict(frequencies=[0.0], amplitudes=[1e-6]), "frequencies"),
    (dict(frequencies=[-5.0], amplitudes=[1e-6]), "frequencies"),
    (dict(frequencies=[INF], amplitudes=[1e-6]), "frequencies"),
    (dict(frequencies=[1e3], amplitudes=[-1e-6]), "amplitudes"),
    (dict(frequencies=[1e3], amplitudes=[INF]), "amplitudes"),
    (dict(frequencies=[1e3], amplitudes=[1e-6], phases=[NAN]), "phases"),
    (dict(frequencies=[1e3, 2e3], amplitudes=[1e-6]), "same length"),
])
def test_drive_fields(kwargs, name):
    with pytest.raises(ValueError, match=name):
        Drive(**kwargs)


@pytest.mark.parametrize("power", [-1.0, 0.0, NAN, INF, None])
@pytest.mark.parametrize("make", [
    lambda power: Drive.tone(1e3, power=power),
    lambda power: Drive.from_power([1e3, 2e3], power=power),
    lambda power: model.amplitude_from_power(1e3, power),
])
def test_drive_power_is_named(make, power):
    # checked before the sqrt, so no 'invalid value' warning and no blame on 'amplitudes'
    with pytest.raises(ValueError, match="power"):
        make(power)


@pytest.mark.parametrize("bad", [-1e3, 0.0, NAN])
def test_tone_frequency_is_named(bad):
    with pytest.raises(ValueError, match="frequency"):
        Drive.tone(bad)


@pytest.mark.parametrize("kwargs, name", [
    (dict(x0=NAN), "x0"), (dict(x0=INF), "x0"), (dict(x0=-INF), "x0"),
    (dict(x0=1.0), "x0"),                       # beyond the wall
    (dict(v0=NAN), "v0"), (dict(v0=INF), "v0"),
    (dict(duration=0.0), "duration"), (dict(duration=-1.0), "duration"),
    (dict(duration=NAN), "duration"), (dict(duration=INF), "duration"),
    (dict(max_events=0), "max_events"), (dict(method="euler"), "method"),
    (dict(method="rk4", step=0.0), "step"), (dict(method="rk4", step=NAN), "step"),
    (dict(trajectory=1), "trajectory"), (dict(trajectory=[0.0, NAN]), "trajectory"),
])
def test_simulate_arguments(kwargs, name):
    with pytest.raises(ValueError, match=name):
        model.simulate(FIG7, TONE, **kwargs)


@pytest.mark.parametrize("call, name", [
    (lambda: model.response(FIG7, TONE, x0=NAN), "x0"),
    (lambda: model.response(FIG7, TONE, duration=0.0), "duration"),
    (lambda: model.response("fig7", TONE), "impacter"),
    (lambda: model.response(FIG7, 6200.0), "drive"),
    (lambda: model.responses(FIG7, TONE, [0.0, NAN]), "x0s"),
    (lambda: model.responses(FIG7, TONE, [0.0, 1.0]), "x0s"),
    (lambda: model.responses(FIG7, TONE, [0.0], duration=INF), "duration"),
    (lambda: model.sweep(FIG7, [0.0], [0.0]), "frequencies"),
    (lambda: model.sweep(FIG7, [NAN], [0.0]), "frequencies"),
    (lambda: model.sweep(FIG7, [-1e3], [0.0]), "frequencies"),
    (lambda: model.sweep(FIG7, [1e3], [INF]), "x0s"),
    (lambda: model.sweep(FIG7, [1e3], [0.0], power=-1.0), "power"),
    (lambda: model.sweep(FIG7, [1e3], [0.0], power=NAN), "power"),
    (lambda: model.sweep(FIG7, [1e3], [0.0], duration=0.0), "duration"),
    (lambda: reference(FIG7, TONE, x0=NAN), "x0"),
    (lambda: reference(FIG7, TONE, x0=1.0), "x0"),
    (lambda: reference(FIG7, "tone"), "drive"),
])
def test_api_arguments(call, name):
    with pytest.raises(ValueError, match=name):
        call()


@pytest.mark.parametrize("field, bad", [
    ("mass", -1.0), ("mass", NAN), ("damping", -1.0), ("static_friction", NAN),
    ("dynamic_friction", -1e-6), ("dynamic_friction", INF),
])
def test_slider_fields(field, bad):
    with pytest.raises(ValueError, match=field):
        Slider(**{**dict(mass=1e-9), field: bad})


@pytest.mark.parametrize("field, bad", [
    ("thickness", 0.0), ("density", NAN), ("viscosity", -1.0), ("substrate_gap", INF),
])
def test_slider_geometry_fields(field, bad):
    with pytest.raises(ValueError, match=field):
        Slider.from_geometry(8.0e-8, **{field: bad})
