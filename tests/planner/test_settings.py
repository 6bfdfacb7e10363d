"""Every spec field reaches the resolved settings (or is refused); physics fields change
a design.  Table-driven: each row sets one field to a non-default value."""

from __future__ import annotations

import math

import pytest
import yaml

from planner.designer.config import DesignConfig
from planner.core.errors import SpecError
from planner.core.nodes import Node
from planner.planning.settings import resolve_settings
from planner.arrayspec import load_spec

BASE = {"name": "t", "array": {"rows": 1, "cols": 2},
        "environment": {"viscosity_mpa_s": 0.0179},
        "scenes": {"s": [{"name": "go", "duration_ms": 5, "forward": ["A1"]}]}}


def _set(data, path, value):
    node = data
    keys = path.split(".")
    for k in keys[:-1]:
        node = node.setdefault(k, {})
    node[keys[-1]] = value
    return data


def _settings(*changes):
    import copy

    data = copy.deepcopy(BASE)
    for path, value in changes:
        _set(data, path, value)
    return resolve_settings(load_spec(yaml.safe_dump(data, sort_keys=False) + "\n"))


def _sampled(s):
    """What the yield's Monte Carlo makes of one fixed design under the settings'
    tolerances (:func:`planner.fabrication.tolerances.sample_chip`, a fixed seed): every half's
    mass, stiffness, damping and gap, and every slider's mass."""
    import numpy as np

    import model
    from planner.fabrication.tolerances import ChipDesign, NodeDesign, sample_chip

    node = NodeDesign("A1.forward", "A1", "forward", 1.5e-8, 4e-6, 1.2e-3, 3e-6,
                      math.radians(45.0), 0.5)
    # the design's process from the base spec (these rows change only the tolerances;
    # reading s.chip_spec would count as reading every field)
    spec = _settings().chip_spec
    chip = sample_chip(ChipDesign(spec, (node,), ("A1",)), s.tolerances,
                       np.random.default_rng(0))
    return ([(h.mass, h.stiffness, h.damping, h.gap) for imp in chip.impacters.values()
             for h, _ in model.halves(imp)]
            + [sl.mass for sl in chip.sliders.values()])


def _imp(node, attr):
    return lambda s: getattr(s.impacters[node], attr)


# (spec field, non-default value, what of the settings must change[, the changes the
# field needs first]).  Each getter reads Settings attributes that some stage reads
# (test_every_case_reads_what_a_stage_reads), never the spec record or chip_spec.
CASES = [
    ("name", "other", lambda s: s.name),
    ("array.rows", 2, lambda s: tuple(s.sliders)),
    ("array.cols", 3, lambda s: tuple(s.sliders)),
    ("array.pitch_um", 500.0, lambda s: s.array_pitch_m),
    ("process.density_kg_m3", 2000.0, lambda s: s.impacters[Node("A1", "forward")].process),
    ("process.mass_thickness_um", 3.0, lambda s: s.impacters[Node("A1", "forward")].process),
    ("process.slider_thickness_um", 3.0, lambda s: s.sliders["A1"].mass),
    # the layout's rules reach the designer through its bounds (issue 30); the layer map
    # and the anchor enclosure only the layout (LAYOUT_ONLY)
    ("process.min_line_um", 3.0, lambda s: s.bounds),
    ("process.min_space_um", 2.0, lambda s: s.bounds),
    ("environment.viscosity_mpa_s", 0.01, lambda s: s.environment),
    ("device.impacter.restitution", 0.7, _imp(Node("A1", "forward"), "restitution")),
    ("device.impacter.impact_angle_deg", 30.0, _imp(Node("A2", "backward"), "impact_angle_rad")),
    ("device.impacter.mass_thickness_um", 3.0, _imp(Node("A1", "forward"), "process")),
    ("device.forward.restitution", 0.7, _imp(Node("A1", "forward"), "restitution")),
    ("device.backward.impact_angle_deg", 30.0, _imp(Node("A1", "backward"), "impact_angle_rad")),
    ("devices.A2.impacter.restitution", 0.7, _imp(Node("A2", "forward"), "restitution")),
    ("devices.A2.backward.restitution", 0.7, _imp(Node("A2", "backward"), "restitution")),
    ("device.slider.area_um2", 5e4, lambda s: s.sliders["A1"].mass),
    ("device.slider.static_friction_un", 10.0, lambda s: s.sliders["A2"].static_friction),
    ("devices.A2.slider.dynamic_friction_un", 2.0, lambda s: s.sliders["A2"].dynamic_friction),
    ("device.slider.thickness_um", 3.0, _imp(Node("A1", "forward"), "slider")),
    ("drive.band_hz", [3000.0, 20000.0], lambda s: s.band_hz),
    ("drive.power_m2_s3", 30.0, lambda s: s.power_m2_s3),
    ("drive.amplitude_um", 0.1, lambda s: s.amplitude_m),
    ("drive.peak_limit_um", 5.0, lambda s: s.peak_limit_m),
    ("drive.sample_rate_hz", 100000.0, lambda s: s.sample_rate_hz),
    ("drive.piezo_um_per_v", 0.1, lambda s: s.um_per_v),
    ("drive.amplifier_gain", 10.0, lambda s: s.amplifier_gain),
    ("drive.guard.separation_channels", 3, lambda s: s.separation_channels),
    ("drive.guard.ensemble_separation_channels", 20,
     lambda s: s.ensemble_separation_channels),
    ("drive.guard.relative_bandwidth", 0.05, lambda s: s.tone_rules),
    ("drive.guard.harmonics", False, lambda s: s.tone_rules),
    ("drive.guard.intermodulation", False, lambda s: s.tone_rules),
    ("drive.max_acceleration_g", 500.0, lambda s: s.max_acceleration_m_s2),
    ("drive.channels.spacing", "linear", lambda s: (s.channel_spacing, s.channel_grid_hz)),
    ("drive.channels.count", 100, lambda s: s.channel_grid_hz),
    ("drive.channels.placement", "neighbours", lambda s: s.channel_placement),
    ("drive.channels.separation_hz", 600.0,
     lambda s: (s.resonance_separation_hz, s.channel_grid_hz),
     [("drive.channels.spacing", "tolerance"),
      ("fabrication.line_width_um", {"die": 0.05, "device": 0.02})]),
    ("trim.range_pct", 5.0, lambda s: s.trim),
    ("trim.direction", "down", lambda s: s.trim),
    ("trim.precision_pct", 0.5, lambda s: s.trim),
    ("trim.passes", 1, lambda s: s.trim),
    ("design.tone_window_pct", 0.3, lambda s: s.tone_window),
    # the as-built models' and a yield's noise, and the default tone window
    ("fabrication.measurement_noise_pct", 0.1, lambda s: (s.measurement_noise, s.tone_window)),
    ("design.bounds.gap_um", [2.0, 4.0], lambda s: s.bounds),
    ("design.window_ms", 2.0, lambda s: s.window_s),
    ("design.seed", 3, lambda s: s.seed),
    ("design.budget", "full", lambda s: s.budget),
    ("design.guard", 0.05, lambda s: s.guard),
    ("design.match_sensitivity", False, lambda s: s.sensitivity_band),
    ("design.sensitivity_tolerance", 0.1, lambda s: s.sensitivity_band),
    ("design.sensitivity_per_um", 0.2, lambda s: s.sensitivity_band),
    ("design.beam_width_um", 6.0, lambda s: (s.bounds, s.sensitivity_band)),
    # the target sets the tolerance grid's z (and what the prediction is held to)
    ("fabrication.target_yield", 0.9, lambda s: (s.channel_grid_hz, s.target_yield),
     [("drive.channels.spacing", "tolerance"),
      ("fabrication.line_width_um", {"die": 0.05, "device": 0.02})]),
    ("fabrication.line_width_um", {"die": 0.05}, lambda s: _sampled(s)),
    ("verification.x0_points", 5, lambda s: s.x0_points),
    ("verification.min_speed_mm_s", 1.0, lambda s: s.min_speed_m_s),
    ("verification.idle_tolerance_um", 0.1, lambda s: s.idle_tolerance_m),
    ("verification.repair_rounds", 1, lambda s: s.repair_rounds),
    ("process.youngs_modulus_gpa", 150.0, lambda s: s.impacters[Node("A1", "forward")].process),
    ("process.beam_height_um", 3.0, lambda s: s.impacters[Node("A1", "forward")].process),
    ("process.substrate_gap_um", 3.0, lambda s: s.impacters[Node("A1", "forward")].process),
    ("process.beam_angle_deg", 30.0, lambda s: s.impacters[Node("A1", "forward")].process),
    ("device.forward.mass_thickness_um", 3.0, _imp(Node("A1", "forward"), "process")),
    ("device.forward.impact_angle_deg", 30.0, _imp(Node("A1", "forward"), "impact_angle_rad")),
    ("device.backward.mass_thickness_um", 3.0, _imp(Node("A1", "backward"), "process")),
    ("device.contact", "paper", lambda s: s.contacts),
    ("devices.A2.contact", "paper", lambda s: s.contacts),
    ("design.bounds.area_um2", [100.0, 40000.0], lambda s: s.bounds),
    ("design.bounds.width_um", [3.0, 9.0], lambda s: s.bounds),
    ("design.bounds.length_um", [100.0, 1400.0], lambda s: s.bounds),
    ("design.max_mass_ratio", 0.3, lambda s: s.max_mass_ratio),
    ("verification.max_travel_um", 50.0, lambda s: s.max_travel_m),
    ("verification.position_tolerance_um", 1.0, lambda s: s.position_tolerance_m),
    # every sigma must reach a chip the yield's Monte Carlo draws (not only the spec
    # arrays it was read into: a row reading s.tolerances back would be circular)
    *[(f"fabrication.{p}.{level}", 0.01, _sampled)
      for p in ("line_width_um", "thickness_um", "gap_um", "youngs_modulus_pct",
                "natural_frequency_pct") for level in ("die", "device", "pair")],
    # the drive chain (issue 46): each field reaches the chain the stages read
    ("drive.chain.transfer", {"gain_um_per_v": 2.0}, lambda s: repr(s.chain)),
    *[(f"drive.chain.{k}", v, lambda s: repr(s.chain),
       [("drive.chain.transfer", {"gain_um_per_v": 1.0})] + extra)
      for k, v, extra in (("harmonics_db", {2: -40.0}, []),
                          ("at_stroke_um", 5.0, [("drive.chain.harmonics_db", {2: -40.0})]),
                          ("max_input_v", 5.0, []),
                          ("max_output_v", 100.0, [("drive.amplifier_gain", 10.0)]))],
    ("independent", True, lambda s: len(s.steps)),
    ("scenes.s", [{"name": "b", "duration_ms": 7, "backward": ["A2"]}],
     lambda s: [(st.name, st.duration_s, st.backward) for st in s.steps]),
]


def test_robust_design_reaches_the_designer_or_is_refused():
    """design.robust / robust_k (issue 16): k sigma of each candidate's own natural
    frequency under the fabrication tolerances goes to the designer."""
    fab = ("fabrication.line_width_um", {"die": 0.05, "device": 0.02})
    s = _settings(("design.robust", True), ("design.robust_k", 3.0), fab)
    shift = s.design_kwargs(Node("A1", "forward"))["robust_shift"]
    assert s.robust_k == 3.0 and shift.k == 3.0
    # 3 sigma of a 4.6 um beam's line width error: about 4.7 % (1.6 % per sigma)
    assert 0.03 < shift((1.5e-8, 4.6e-6, 1.2e-3, 3e-6)) < 0.07
    assert "robust_shift" not in _settings(fab).design_kwargs(Node("A1", "forward"))
    # robust design without tolerances to be robust against is refused
    with pytest.raises(SpecError) as err:
        _settings(("design.robust", True))
    assert "design.robust" in str(err.value) and err.value.line is not None
    # robust_k alone is inert (a spec read back from plan.json carries every default)
    assert _settings(("design.robust_k", 3.0)).robust_k is None


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_every_field_changes_the_settings(case):
    path, value, get, *first = case
    first = first[0] if first else []
    base, changed = _settings(*first), _settings(*first, (path, value))
    assert get(changed) != get(base), path


def test_tolerances_are_the_specs_sigmas_read_once():
    """Settings.tolerances: every sigma of ``fabrication:`` at its level, in ERRORS order
    and the errors' own units (those of the sensitivities and of plan.json's keys)."""
    import numpy as np

    from planner.fabrication.tolerances import ERROR_UNITS, ERRORS, Tolerances

    sigmas = {"line_width_um": {"die": 0.05, "device": 0.02, "pair": 0.01},
              "youngs_modulus_pct": {"die": 1.5}, "natural_frequency_pct": {"device": 0.3}}
    s = _settings(*((f"fabrication.{k}", v) for k, v in sigmas.items()))
    for level in ("die", "device", "pair"):
        want = [sigmas.get(k, {}).get(level, 0.0) for k in ERRORS]
        assert getattr(s.tolerances, level).tolist() == want, level
    assert s.tolerances.units == ERROR_UNITS
    assert [k.rsplit("_", 1)[1].replace("pct", "%") for k in ERRORS] == list(ERROR_UNITS)
    assert not s.tolerances.zero and _settings().tolerances.zero
    assert s.tolerances == Tolerances(*(np.array(getattr(s.tolerances, level))
                                        for level in ("die", "device", "pair")))
    with pytest.raises(ValueError, match="die"):
        Tolerances(np.zeros(4), np.zeros(5), np.zeros(5))


def test_pair_and_device_overrides_stay_local():
    s = _settings(("devices.A2.forward.restitution", 0.8))
    assert s.impacters[Node("A2", "forward")].restitution == 0.8
    assert s.impacters[Node("A2", "backward")].restitution == s.impacters[Node("A1", "forward")].restitution == 0.5
    s = _settings(("device.impacter.impact_angle_deg", 30.0))
    assert s.impacters[Node("A1", "forward")].impact_angle_rad == pytest.approx(math.radians(30.0))


@pytest.mark.parametrize("path", ["device.impacter.area_um2", "device.forward.gap_um",
                                  "devices.A2.backward.width_um", "device.impacter.length_um",
                                  "devices.A1.impacter.natural_frequency_hz"])
def test_designed_geometry_is_refused_with_its_line(path):
    with pytest.raises(SpecError) as err:
        _settings((path, 12.0))
    assert path in str(err.value)
    assert err.value.line is not None
    assert "designs" in str(err.value)


@pytest.mark.slow
def test_restitution_changes_the_design_and_its_verification():
    """The designer gets the spec's restitution: the as-designed impacter (which the
    verification simulates) carries it, and its response differs."""
    import numpy as np

    import model
    from planner.designer import design_impacter

    results = []
    for e in (0.5, 0.9):
        s = _settings(("device.impacter.restitution", e), ("design.budget", "fast"))
        res = design_impacter(6000.0, (9000.0,), **s.design_kwargs(Node("A1", "forward")))
        assert res.impacter.restitution == e
        x0s = np.linspace(-res.impacter.gap, res.impacter.gap, 5)
        results.append(model.responses(res.impacter, model.Drive.tone(6000.0, 50.0), x0s,
                                       duration=3e-3))
    # relative only: r is ~7e-8 N, and np.allclose's default atol (1e-8 N) a seventh of it
    assert not np.allclose(results[0], results[1], rtol=1e-3, atol=0.0)


# ------------------------------------------------------------------ vibroplan design configs

DESIGN_CASES = [
    ("process.youngs_modulus_gpa", 150.0, "process"),
    ("environment.viscosity_mpa_s", 0.01, "environment"),
    ("slider.area_um2", 5e4, "slider"),
    ("drive.power_m2_s3", 30.0, "power"),
    ("drive.amplitude_um", 0.1, "amplitude"),
    ("design.area_um2", [30.0, 40000.0], "bounds"),
    ("design.width_um", [3.0, 9.0], "bounds"),
    ("design.length_um", [10.0, 1400.0], "bounds"),
    ("design.gap_um", [3.0, 9.0], "bounds"),
    ("process.min_line_um", 3.0, "bounds"),
    ("process.min_space_um", 2.0, "bounds"),
    ("design.window_ms", 2.0, "window"),
    ("design.budget", "fast", "budget"),
    ("design.x0_points", 7, "x0_points"),
    ("design.guard", 0.05, "guard"),
    ("design.impact_angle_deg", 30.0, "impact_angle"),
    ("design.restitution", 0.7, "restitution"),
]


@pytest.mark.parametrize("path, value, key", DESIGN_CASES, ids=[c[0] for c in DESIGN_CASES])
def test_every_design_config_field_reaches_the_designer(path, value, key):
    base = DesignConfig().design_kwargs()
    changed = DesignConfig(**_set({}, path, value)).design_kwargs()
    if key == "slider":
        assert changed[key].mass != base[key].mass
    else:
        assert changed[key] != base[key], path


# ------------------------------------------------------------------ process rules (issue 30)

def test_unset_rules_leave_the_default_bounds_alone():
    """The default spec's designer bounds are the paper's (17) and the documented upper
    bounds, exactly: a plan without rules is the plan it was before the rules existed."""
    from planner.designer import DesignBounds

    assert _settings().bounds == DesignBounds()


def _default_spec_text():
    from planner.arrayspec import default_spec_path

    return default_spec_path().read_text(encoding="utf-8")


def test_the_default_spec_sets_its_rules_and_gap_bound():
    """The default spec sets the 2 um rules (issue 30) and gaps up to 16 um (issue 25):
    its bounds are the defaults but the gap, from 2 um / sin(45 deg) to 16 um."""
    import math

    from planner.designer import DesignBounds

    b = resolve_settings(load_spec(_default_spec_text())).bounds
    assert b.gap == pytest.approx((2e-6 / math.sin(math.pi / 4), 16e-6))
    assert (b.area, b.width, b.length) == (DesignBounds().area, DesignBounds().width,
                                           DesignBounds().length)


def test_rules_narrow_the_bounds_to_what_the_layout_can_draw():
    # w >= min_line; the tip clears its wall by c sin(theta): c >= min_space / sin(theta)
    s = _settings(("process.min_line_um", 3.0), ("process.min_space_um", 2.5),
                  ("device.forward.impact_angle_deg", 30.0))
    assert s.bounds.width[0] == pytest.approx(3e-6)
    # the smallest impact angle (30 deg, the forward impacters) sets the gap bound
    assert s.bounds.gap[0] == pytest.approx(2.5e-6 / math.sin(math.radians(30.0)))
    # a rule below the paper's bounds leaves them
    assert _settings(("process.min_line_um", 1.0)).bounds.width[0] == pytest.approx(2e-6)


@pytest.mark.parametrize("path, value, bound", [
    ("process.min_line_um", 12.0, "design.bounds.width_um"),
    ("process.min_space_um", 8.0, "design.bounds.gap_um"),
])
def test_rules_no_design_can_meet_are_refused_with_their_line(path, value, bound):
    with pytest.raises(SpecError) as err:
        _settings((path, value))
    assert path in str(err.value) and bound in str(err.value)
    assert err.value.line is not None


def test_the_layer_map_does_not_reach_the_designs():
    """The designer gets the process without its layout-only fields: a new layer map
    (or enclosure) leaves every design task, and so its cache key, as it was."""
    from planner.planning.design_store import task_digest

    base = _settings().design_kwargs(Node("A1", "forward"))
    other = _settings(("process.layers", {"POLY2": [50, 1]}),
                      ("process.anchor_enclosure_um", 4.0)).design_kwargs(Node("A1", "forward"))
    assert task_digest(base) == task_digest(other)
    narrowed = _settings(("process.min_line_um", 3.0)).design_kwargs(Node("A1", "forward"))
    assert task_digest(narrowed) != task_digest(base)


def test_two_masks_on_one_layer_are_refused():
    with pytest.raises(SpecError) as err:
        _settings(("process.layers", {"POLY2": [45, 0]}))
    assert "process.layers" in str(err.value) and "POLY1" in str(err.value)


# ------------------------------------------------------------------ every field, from the schema

#: Array-spec fields no planning stage reads: plan.json records them (``spec``) and the
#: command named reads them from there.
LAYOUT_ONLY = {
    "process.layers": "planner/layout (the GDS layer of each mask)",
    "process.anchor_enclosure_um": "planner/layout (the anchors' overlap)",
    # where a die sat: read with the as-built models (chip_spec) by the manufacturability
    # prediction and the yield's sampler only; tests/planner/test_wafer.py
    # (test_the_gradient_costs_far_tone_neighbours_yield, test_a_yield_on_wafers_maps_every_die)
    "fabrication.wafer": "the as-built models: manufacturability and yield on wafers",
}
#: Fields a plan refuses, each with the test that shows the refusal and its line.
REFUSED = {
    "drive.over_limit": "test_split_over_the_limit_is_refused_with_its_line",
}
#: Geometry a plan designs: refused in an array spec
#: (test_designed_geometry_is_refused_with_its_line).
DESIGNED = ("area_um2", "width_um", "length_um", "gap_um", "natural_frequency_hz")
#: Settings attributes a getter may not stand on: every field reaches them.
NOT_A_STAGE = ("spec_record", "chip_spec")


def _schema_leaves(model, prefix=""):
    """Every leaf field of a pydantic model, as a dotted path (aliases; a dict of
    models, such as ``devices``, by its value model; the other dicts are leaves)."""
    import typing

    import pydantic

    out = []
    for name, field in model.model_fields.items():
        key = prefix + (field.alias or name)
        args = typing.get_args(field.annotation) or (field.annotation,)
        if typing.get_origin(field.annotation) is dict:
            args = typing.get_args(field.annotation)[1:]
        sub = [a for a in args if isinstance(a, type) and issubclass(a, pydantic.BaseModel)]
        out += _schema_leaves(sub[0], key + ".") if sub else [key]
    return out


def test_every_spec_field_has_a_case():
    """Generated from the schema, not written by hand: every leaf field of ArraySpec has a
    CASES row (it changes a setting a stage reads), or is designed geometry or another
    refused field (REFUSED), or reaches plan.json for a later command only (LAYOUT_ONLY).
    A device override (``devices.A2``) is the same model as ``device`` and counts as
    covered by either."""
    import re

    from planner.arrayspec import ArraySpec

    covered = {re.sub(r"^devices\.[A-Z]+\d+\.", "device.", c[0]) for c in CASES}
    missing = []
    for leaf in _schema_leaves(ArraySpec):
        path = re.sub(r"^devices\.", "device.", leaf)
        if any(path == c or path.startswith(c + ".") for c in covered):
            continue
        if path.split(".")[0] == "scenes" and "scenes.s" in covered:
            continue
        if re.fullmatch(r"device\.(impacter|forward|backward)\.(%s)" % "|".join(DESIGNED),
                        path):
            continue
        if (leaf in REFUSED or any(leaf == k or leaf.startswith(k + ".") for k in LAYOUT_ONLY)
                or leaf in ("design.robust", "design.robust_k")):
            # robust design needs a tolerance: test_robust_design_reaches_the_designer...
            continue
        missing.append(leaf)
    assert missing == [], f"spec fields with no case: {missing}"
    # and the lists name no field that is gone, and tests that exist
    leaves = _schema_leaves(ArraySpec)
    for name in [*REFUSED, *LAYOUT_ONLY]:
        assert any(leaf == name or leaf.startswith(name + ".") for leaf in leaves), name
    assert all(name in globals() for name in REFUSED.values())


def _stage_reads():
    """Settings attributes some stage reads: ``settings.NAME`` (or ``self.settings.NAME``)
    anywhere in planner/ outside settings.py, and what the designer's keyword arguments
    (:meth:`Settings.design_kwargs`, read by the design stage) read."""
    import inspect
    import re
    from pathlib import Path

    import planner
    from planner.planning import settings as settings_module

    root = Path(planner.__file__).parent
    names = set()
    for f in root.rglob("*.py"):
        if f.name == "settings.py" and f.parent.name == "planning":
            continue
        names |= set(re.findall(r"\bsettings\.(\w+)", f.read_text(encoding="utf-8")))
    if "design_kwargs" in names:
        cls = settings_module.Settings
        for method in (cls.design_kwargs, cls._robust_kwargs):
            names |= set(re.findall(r"\bself\.(\w+)", inspect.getsource(method)))
    return names


class _Reads:
    """Settings, recording which of its attributes are read."""

    def __init__(self, settings):
        self._settings, self.names = settings, set()

    def __getattr__(self, name):
        self.names.add(name)
        return getattr(self._settings, name)


def test_every_case_reads_what_a_stage_reads():
    """A field that reaches only a setting no stage reads is as good as ignored: each
    CASES getter reads attributes that planner code reads (never the spec record or
    chip_spec, which every field reaches), and every Settings attribute is read by
    some stage."""
    import dataclasses

    from planner.planning.settings import Settings

    reads = _stage_reads()
    base = _Reads(_settings())
    for path, _, get, *_ in CASES:
        base.names.clear()
        get(base)
        assert base.names, f"{path}: its getter reads no setting"
        assert not base.names & set(NOT_A_STAGE), f"{path}: reads {base.names}"
        assert base.names <= reads, f"{path}: no stage reads {base.names - reads}"
    unread = {f.name for f in dataclasses.fields(Settings)} - reads
    assert unread == set(), f"Settings attributes no stage reads: {unread}"


def test_split_over_the_limit_is_refused_with_its_line(tmp_path):
    """drive.over_limit: split cannot take effect in a plan (the designs are made for the
    steps as written): refused, naming the field and its line, exit 2, nothing written."""
    from click.testing import CliRunner

    from planner.cli import main

    with pytest.raises(SpecError) as err:
        _settings(("drive.over_limit", "split"))
    assert "drive.over_limit" in str(err.value) and err.value.line is not None
    assert "steps" in str(err.value)
    assert _settings(("drive.over_limit", "scale")) == _settings()
    import copy

    data = _set(copy.deepcopy(BASE), "drive.over_limit", "split")
    spec = tmp_path / "split.yaml"
    spec.write_text(yaml.safe_dump(data, sort_keys=False))
    out = tmp_path / "out"
    res = CliRunner().invoke(main, ["plan", str(spec), "--out", str(out), "--quiet"])
    assert res.exit_code == 2, res.output
    assert "drive.over_limit" in res.output and "Traceback" not in res.output
    assert not out.exists()


def test_layout_only_fields_reach_plan_json_and_the_layout():
    """The layer map and the anchor enclosure change no setting a stage reads, but
    plan.json's spec (which vibroplan layout reads), and the layout reads them."""
    from pathlib import Path

    import planner

    layout = "".join(f.read_text(encoding="utf-8") for f in
                     (Path(planner.__file__).parent / "layout").glob("*.py"))
    base = _settings()
    for path, value in (("process.layers", {"POLY2": [50, 1]}),
                        ("process.anchor_enclosure_um", 4.0)):
        changed = _settings((path, value))
        assert changed.spec_record != base.spec_record, path
        assert path.split(".")[-1] in layout, path
