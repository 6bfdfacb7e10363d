"""``vibroplan layout`` (issue 30): the GDSII file read back with gdstk, its geometry
against plan.json through eqs. (2)-(4), and the KLayout design-rule check.

The 5 x 5 chip is a synthetic plan made from the tiny planned one (its spec and
records) with 50 designs of varied geometry whose m, k and b follow from eqs. (2)-(4)
(so ``design_from_plan`` takes it), on a pitch they fit; the tiny plan itself is drawn
as the planner made it.
"""

from __future__ import annotations

import json
import math
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

import model
from planner.cli import main
from planner.core.units import UM

PITCH_UM = 1500.0


def _layout(*args):
    return CliRunner().invoke(main, ["layout", *map(str, args)])


def _graded(i):
    """Impacter i of the synthetic 5 x 5: A = 1.5e4 + 700 i um^2, w = 2.5 + 0.07 i um,
    l = 180 + 6 i um, c = 3 + 0.05 i um."""
    return 1.5e4 + 700 * i, 2.5 + 0.07 * i, 180 + 6 * i, 3.0 + 0.05 * i


def _synthetic_plan(tiny_plan_dir, folder, *, edit=None, geometry=_graded, rows=5, cols=5,
                    pitch_um=PITCH_UM):
    """A consistent plan.json made from the tiny plan's: impacter i (two per device, in
    device order) gets ``geometry(i)`` = (A um^2, w um, l um, c um); its m, k, b and
    nu_n follow from eqs. (2)-(4)."""
    from planner.fabrication.tolerances import NodeDesign, nominal_impacter
    from planner.arrayspec import ArraySpec

    import numpy as np

    from planner.manufacturability import channel_grid

    data = json.loads((tiny_plan_dir / "plan.json").read_text(encoding="utf-8"))
    data["spec"]["array"] = {"rows": rows, "cols": cols, "pitch_um": pitch_um}
    # a band holding every synthetic design's tone: each tone on its channel of the grid,
    # as plan.json's reader checks
    data["spec"]["drive"]["band_hz"] = [1000.0, 200000.0]
    data["spec"]["drive"]["sample_rate_hz"] = 500000.0
    if edit is not None:
        edit(data["spec"])
    spec = ArraySpec.model_validate({k: v for k, v in data["spec"].items() if k != "trim"})
    grid = channel_grid(spec)
    template = data["impacters"][0]
    records = []
    for k, device in enumerate(spec.array.device_ids()):
        for j, direction in enumerate(("forward", "backward")):
            area, width, length, gap = geometry(2 * k + j)
            g = {"area_m2": area * UM**2, "width_m": width * UM, "length_m": length * UM,
                 "gap_m": gap * UM}
            nid = f"{device}.{direction}"
            imp = nominal_impacter(spec, NodeDesign(
                nid, device, direction, g["area_m2"], g["width_m"], g["length_m"], g["gap_m"],
                template["impact_angle_rad"], template["restitution"]))
            channel = int(np.argmin(np.abs(grid - 1.02 * imp.natural_frequency)))
            records.append({**template, "id": nid, "device": device, "direction": direction,
                            "geometry": g, "gap_m": g["gap_m"], "mass_kg": imp.mass,
                            "stiffness_n_per_m": imp.stiffness,
                            "damping_ns_per_m": imp.damping,
                            "natural_frequency_hz": imp.natural_frequency,
                            "channel": channel, "frequency_hz": float(grid[channel])})
    data["impacters"] = records
    # the tiny designs' separations do not describe these (the layout reads none)
    data.pop("manufacturability", None)
    tone = {r["id"]: r["frequency_hz"] for r in records}
    for st in data["steps"]:      # each step plays its impacters' tones
        st["tones"] = [{**st["tones"][0], "frequency_hz": tone[f"{d}.{way}"]}
                       for way in ("forward", "backward") for d in st[way]]
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "plan.json").write_text(json.dumps(data, indent=1), encoding="utf-8")
    return folder


@pytest.fixture(scope="module")
def chip(tiny_plan_dir, tmp_path_factory):
    """The synthetic 5 x 5 plan, drawn and checked by the CLI."""
    root = tmp_path_factory.mktemp("layout")
    plan = _synthetic_plan(tiny_plan_dir, root / "plan")
    out = root / "chip.gds"
    result = _layout(plan, "--out", out, "--check")
    return {"plan": plan, "out": out, "result": result,
            "data": json.loads((plan / "plan.json").read_text(encoding="utf-8"))}


def _cells(path):
    import gdstk

    lib = gdstk.read_gds(str(path))
    return lib, {c.name: c for c in lib.cells}


def test_25_device_cells_on_the_pitch(chip):
    assert chip["result"].exit_code == 0, chip["result"].output
    lib, cells = _cells(chip["out"])
    assert lib.unit == pytest.approx(1e-6) and lib.precision == pytest.approx(1e-9)
    (top,) = lib.top_level()
    refs = {r.cell.name: r.origin for r in top.references}
    ids = [f"{r}{c}" for r in "ABCDE" for c in range(1, 6)]
    assert sorted(refs) == sorted(ids)
    for name, origin in refs.items():
        row, col = "ABCDE".index(name[0]), int(name[1:]) - 1
        assert origin == pytest.approx((col * PITCH_UM, -row * PITCH_UM), abs=1e-6)
        inside = sorted(r.cell.name for r in cells[name].references)
        assert inside == sorted([f"{name}.slider", f"{name}.forward", f"{name}.backward"])
        for pair in (f"{name}.forward", f"{name}.backward"):
            halves = [r.cell.name for r in cells[pair].references]
            assert halves == [f"{pair}.cantilever"] * 2
            labels = [t.text for t in cells[pair].labels]
            assert len(labels) == 1 and labels[0].startswith(pair + " ")


def test_50_impacters_reproduce_the_plan(chip):
    """Every impacter's geometry measured on the polygons gives its natural frequency
    (eqs. (2)-(4) here, straight from model.Impacter) within 0.5 % of plan.json's."""
    from planner.layout.measure import measure
    from planner.layout.rules import LayoutRules
    from planner.arrayspec import ArraySpec

    spec = ArraySpec.model_validate(chip["data"]["spec"])
    p = spec.process
    lib, _ = _cells(chip["out"])
    measured = measure(lib, LayoutRules.from_process(p).layers)
    records = {r["id"]: r for r in chip["data"]["impacters"]}
    assert sorted(measured.impacters) == sorted(records) and len(records) == 50
    for nid, halves in measured.impacters.items():
        rec, g = records[nid], records[nid]["geometry"]
        assert len(halves) == 2
        for m in halves:
            assert m.legs == 4
            assert m.area == pytest.approx(g["area_m2"], rel=1e-5)
            assert m.width == pytest.approx(g["width_m"], abs=2e-9)
            assert m.length == pytest.approx(g["length_m"], rel=1e-5)
            assert m.gap == pytest.approx(g["gap_m"], abs=2e-9)
            assert math.degrees(m.beam_angle) == pytest.approx(p.beam_angle_deg, abs=0.01)
            assert m.impact_angle == pytest.approx(rec["impact_angle_rad"], abs=1e-4)
            imp = model.Impacter.from_geometry(
                m.area, m.width, m.length, m.gap, thickness=p.mass_thickness_um * UM,
                beam_height=p.beam_height_um * UM, density=p.density_kg_m3,
                youngs_modulus=p.youngs_modulus_gpa * 1e9,
                beam_angle=math.radians(p.beam_angle_deg))
            assert imp.natural_frequency == pytest.approx(rec["natural_frequency_hz"],
                                                          rel=0.005)


def test_a_plan_inside_the_rules_checks_clean(chip):
    out = chip["out"]
    report = out.with_suffix(".md").read_text(encoding="utf-8")
    drc = json.loads((out.parent / "chip_drc.json").read_text(encoding="utf-8"))
    assert drc["clean"] and drc["violations"] == []
    assert {"POLY1.width", "POLY1.space", "ANCHOR1.in.POLY1", "device.pitch"} <= set(
        drc["rules_um"])
    assert "**clean**" in report and "**PASSED**" in report
    assert "![The chip](chip.png)" in report and "![Device A1](chip_A1.png)" in report
    for png in ("chip.png", "chip_A1.png"):
        assert (out.parent / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "design-rule check: clean" in chip["result"].output


def _expected_breakers(data, min_line_um, min_space_um):
    """Impacters whose beams are narrower than the line rule, and whose tips sit nearer
    their wall than the space rule (c sin(theta))."""
    narrow = {r["id"] for r in data["impacters"] if r["geometry"]["width_m"] < min_line_um * UM}
    close = {r["id"] for r in data["impacters"]
             if r["gap_m"] * math.sin(r["impact_angle_rad"]) < min_space_um * UM}
    return narrow, close


def _check_breakers(result, folder, data, line, space):
    assert result.exit_code == 1, result.output
    drc = json.loads((folder / "chip_drc.json").read_text(encoding="utf-8"))
    narrow, close = _expected_breakers(data, line, space)
    assert narrow and close                # the case breaks both rules
    by_rule = {}
    for v in drc["violations"]:
        by_rule.setdefault(v["rule"], set()).update(v["impacters"])
    assert set(by_rule) == {"POLY1.width", "POLY1.space"}
    assert by_rule["POLY1.width"] == narrow
    assert by_rule["POLY1.space"] == close
    assert set(drc["impacters"]) == narrow | close
    report = (folder / "chip.md").read_text(encoding="utf-8")
    assert all(i in report for i in narrow | close)
    assert "impacters in a violation: " in result.output


def test_a_plan_breaking_its_rules_is_reported_by_impacter(chip, tmp_path):
    """plan.json's spec asks for 4 um lines and 2.2 um spaces: the 22 narrower beams
    and the 3 tips nearer their walls are reported by id, exit 1."""
    line, space = 4.0, 2.2
    data = json.loads(json.dumps(chip["data"]))
    data["spec"]["process"].update(min_line_um=line, min_space_um=space)
    (tmp_path / "plan").mkdir()
    (tmp_path / "plan" / "plan.json").write_text(json.dumps(data), encoding="utf-8")
    result = _layout(tmp_path / "plan", "--out", tmp_path / "chip.gds", "--check")
    _check_breakers(result, tmp_path, data, line, space)


def test_another_specs_rules_check_the_plan(chip, tmp_path):
    """--spec: the same rules from a spec file give the same report; rules no design
    inside the spec's bounds can meet are refused (exit 2, field and line)."""
    from tests.planner.test_pipeline import TINY

    spec = tmp_path / "fab.yaml"
    spec.write_text(TINY + "process: {min_line_um: 4.0, min_space_um: 2.2}\n", encoding="utf-8")
    result = _layout(chip["plan"], "--out", tmp_path / "chip.gds", "--check", "--spec", spec)
    _check_breakers(result, tmp_path, chip["data"], 4.0, 2.2)

    bad = tmp_path / "bad.yaml"
    bad.write_text(TINY + "process:\n  min_line_um: 12.0\n", encoding="utf-8")
    result = _layout(chip["plan"], "--out", tmp_path / "bad.gds", "--spec", bad)
    assert result.exit_code == 2
    assert "process.min_line_um" in result.output and "line" in result.output
    assert not (tmp_path / "bad.gds").exists()


def test_trim_tabs_raise_the_frequency_by_the_range(tiny_plan_dir, tmp_path):
    """trim: up 10 % in steps of at most 2.5 %: four tabs per plate, part of the
    designed area; cutting them all raises nu_n by 10 % through eq. (2)."""
    from planner.layout.rules import LayoutRules
    from planner.arrayspec import ArraySpec

    def add_trim(spec):
        spec["trim"] = {"range_pct": 10.0, "direction": "up", "precision_pct": 2.5}

    plan = _synthetic_plan(tiny_plan_dir, tmp_path / "plan", edit=add_trim)
    result = _layout(plan, "--out", tmp_path / "chip.gds", "--check")
    assert result.exit_code == 0, result.output
    data = json.loads((plan / "plan.json").read_text(encoding="utf-8"))
    spec = ArraySpec.model_validate({k: v for k, v in data["spec"].items() if k != "trim"})
    p = spec.process
    layers = LayoutRules.from_process(p).layers
    _, cells = _cells(tmp_path / "chip.gds")

    def nu(area, g):
        return model.Impacter.from_geometry(
            area, g["width_m"], g["length_m"], g["gap_m"], thickness=p.mass_thickness_um * UM,
            beam_height=p.beam_height_um * UM, density=p.density_kg_m3,
            youngs_modulus=p.youngs_modulus_gpa * 1e9,
            beam_angle=math.radians(p.beam_angle_deg)).natural_frequency

    for rec in data["impacters"]:
        cell = cells[rec["id"] + ".cantilever"]
        tabs = [q.area() * 1e-12 for q in cell.polygons if (q.layer, q.datatype) == layers["TRIM"]]
        area = sum(q.area() for q in cell.polygons
                   if (q.layer, q.datatype) == layers["POLY2"]) * 1e-12
        assert len(tabs) == 4
        g = rec["geometry"]
        assert area == pytest.approx(g["area_m2"], rel=1e-5)
        steps = [nu(area - sum(tabs[:k]), g) for k in range(5)]
        assert steps[-1] / steps[0] == pytest.approx(1.10, rel=1e-4)
        ratios = np.array(steps[1:]) / np.array(steps[:-1])
        assert np.all(ratios <= 1.025 + 1e-6) and np.all(ratios > 1.0)
    assert "## Trim tabs" in (tmp_path / "chip.md").read_text(encoding="utf-8")

    def trim_down(spec):
        spec["trim"] = {"range_pct": 5.0, "direction": "down", "precision_pct": 1.0}

    plan = _synthetic_plan(tiny_plan_dir, tmp_path / "down", edit=trim_down)
    assert _layout(plan, "--out", tmp_path / "down.gds").exit_code == 0
    lib, _ = _cells(tmp_path / "down.gds")
    assert not any((q.layer, q.datatype) == layers["TRIM"] for c in lib.cells
                   for q in c.polygons)
    assert "no tabs drawn" in (tmp_path / "down.md").read_text(encoding="utf-8")


def test_the_planned_tiny_array_round_trips(tiny_plan_dir, tmp_path):
    """The real planner's output: its two impacters reproduce plan.json (exit 0); checked
    on the plan's 1000 um pitch its two devices (1.1 x 1.8 and 0.8 x 1.2 mm footprints)
    do not fit: the check names both (exit 1), exactly the devices the report's
    footprint table says do not fit; on a 2500 um pitch both fit and no pitch
    violation is left."""
    plan = tmp_path / "plan"
    shutil.copytree(tiny_plan_dir, plan)
    result = _layout(plan, "--out", tmp_path / "tiny.gds")
    assert result.exit_code == 0, result.output
    assert "(passed)" in result.output

    def checked(folder, name):
        res = _layout(folder, "--out", tmp_path / f"{name}.gds", "--check")
        drc = json.loads((tmp_path / f"{name}_drc.json").read_text(encoding="utf-8"))
        out_of_pitch = {d for v in drc["violations"] if v["rule"] == "device.pitch"
                        for d in v["devices"]}
        report = (tmp_path / f"{name}.md").read_text(encoding="utf-8")
        rows = [line.split("|") for line in report.splitlines()
                if line.startswith("| A") and "fits" not in line and len(line.split("|")) == 6]
        not_fitting = {r[1].strip() for r in rows if "no" in r[4]}
        return res, drc, out_of_pitch, not_fitting, {r[1].strip() for r in rows}

    res, drc, out_of_pitch, not_fitting, listed = checked(plan, "tiny")
    assert res.exit_code == 1 and not drc["clean"], res.output
    assert out_of_pitch == not_fitting == listed == {"A1", "A2"}
    assert "devices in a violation: A1, A2" in res.output
    data = json.loads((plan / "plan.json").read_text(encoding="utf-8"))
    data["spec"]["array"]["pitch_um"] = 2500.0
    wide = tmp_path / "wide"
    wide.mkdir()
    (wide / "plan.json").write_text(json.dumps(data), encoding="utf-8")
    res, drc, out_of_pitch, not_fitting, listed = checked(wide, "wide")
    assert out_of_pitch == not_fitting == set() and listed == {"A1", "A2"}, res.output
    assert res.exit_code == (0 if drc["clean"] else 1)


def test_same_plan_same_bytes(chip, tmp_path):
    for run in ("a", "b"):
        (tmp_path / run).mkdir()
        assert _layout(chip["plan"], "--out", tmp_path / run / "chip.gds",
                       "--check").exit_code == 0
    # (and the record of what vibroplan wrote there, planner.files's registry)
    names = sorted(p.name for p in (tmp_path / "a").iterdir() if not p.name.startswith("."))
    assert names == ["chip.gds", "chip.md", "chip.png", "chip_A1.png", "chip_drc.json"]
    for name in names:
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()


@pytest.mark.parametrize("case", ["suffix", "no plan", "device", "plan folder"])
def test_bad_input_is_refused_and_nothing_written(chip, tmp_path, case):
    plan = tmp_path / "plan"
    shutil.copytree(chip["plan"], plan)
    (plan / "report.md").write_text("the plan's own report\n", encoding="utf-8")
    args = {"suffix": [plan, "--out", tmp_path / "chip.txt"],
            "no plan": [tmp_path / "nowhere", "--out", tmp_path / "chip.gds"],
            "device": [plan, "--out", tmp_path / "chip.gds", "--device", "Z9"],
            "plan folder": [plan, "--out", plan / "report.gds"]}[case]
    # one line each, the house's "error: <what>: <why>", never click's "Error:" usage text
    said = {"suffix": f"error: --out {tmp_path / 'chip.txt'}: name a .gds file",
            "no plan": f"error: {tmp_path / 'nowhere'}: no such file\n",
            "device": "error: --device Z9: the plan has no designed device 'Z9' "
                      "(devices A1 ... E5)\n",
            "plan folder": f"error: --out {plan / 'report.md'}: the file exists, not written "
                           "by vibroplan"}[case]
    before = sorted(p.name for p in plan.iterdir())
    result = _layout(*args)
    assert result.exit_code == 2, result.output
    assert result.output.startswith(said) and result.output.count("\n") == 1, result.output
    assert "Traceback" not in result.output
    assert sorted(p.name for p in plan.iterdir()) == before
    assert (plan / "report.md").read_text(encoding="utf-8") == "the plan's own report\n"
    assert not list(tmp_path.glob("chip*"))


def test_a_plan_made_otherwise_is_refused(chip, tmp_path):
    data = json.loads(json.dumps(chip["data"]))
    data["impacters"][3]["geometry"]["width_m"] *= 1.1   # m and k no longer follow
    (tmp_path / "plan.json").write_text(json.dumps(data), encoding="utf-8")
    result = _layout(tmp_path / "plan.json", "--out", tmp_path / "chip.gds")
    assert result.exit_code == 2
    assert data["impacters"][3]["id"] in result.output


def test_designs_across_the_bounds_are_drawn_inside_the_rules(tiny_plan_dir, tmp_path):
    """The corners of the designer's box (w 2-10 um, l 150-1500 um, A 5e3-5e4 um^2,
    c from 2 um / sin 45 deg, the rules' bound, to 10 um) whose natural frequency a drive
    can reach (below 100 kHz; the default band ends at 42 kHz) are drawn clean: only
    the designed w and c meet a rule, and inside the bounds they keep it."""
    def nu(a, w, l):
        return model.Impacter.from_geometry(a * UM**2, w * UM, l * UM, 3 * UM).natural_frequency

    corners = [(a, w, l, c) for a in (5e3, 5e4) for w in (2.0, 10.0) for l in (150.0, 1500.0)
               for c in (2.0 / math.sin(math.pi / 4), 10.0)]
    grid = [g for g in corners if nu(*g[:3]) < 1e5]
    grid += [(2e4, 5.0, 400.0, 4.0), (1e4, 7.0, 600.0, 3.0)]
    assert len(grid) == 14                 # 12 corners a drive can reach, 2 inside

    def rules(spec):
        spec["process"].update(min_line_um=2.0, min_space_um=2.0)

    plan = _synthetic_plan(tiny_plan_dir, tmp_path / "plan", edit=rules,
                           geometry=lambda i: grid[i], rows=1, cols=7, pitch_um=3500.0)
    result = _layout(plan, "--out", tmp_path / "chip.gds", "--check")
    assert result.exit_code == 0, result.output
    assert "design-rule check: clean" in result.output


# ------------------------------------------------------------------ the geometry, pure

def _rules(**process):
    from planner.config import ProcessConfig
    from planner.layout.rules import LayoutRules

    return LayoutRules.from_process(ProcessConfig(**process))


def test_a_cantilever_is_drawn_to_its_design():
    """Legs of width w and length l/2 at +-phi from the beams' axis, a mass of area A,
    and its tip nearer the wall than anything else."""
    from planner.layout.cantilever import cantilever
    from planner.layout.shapes import polygon_area

    phi, theta = math.radians(15.0), math.radians(45.0)
    half = cantilever("A1.forward", 2.5e4 * UM**2, 3.3e-6, 400e-6, phi, theta, _rules())
    mass = [s.points for s in half.shapes if s.layer == "POLY2"]
    assert len(mass) == 1 and polygon_area(mass[0]) == pytest.approx(2.5e4 * UM**2, rel=1e-12)
    legs = [s.points for s in half.shapes if s.layer == "POLY1" and len(s.points) == 4]
    assert len(legs) == 4
    for leg in legs:
        sides = np.hypot(*(np.roll(leg, -1, axis=0) - leg).T)
        assert sorted(sides) == pytest.approx([3.3e-6, 3.3e-6, 200e-6, 200e-6], rel=1e-12)
        along = leg[2] - leg[1]
        assert math.degrees(math.atan2(abs(along[0]), along[1])) == pytest.approx(15.0)
    normal = np.array([math.sin(theta), -math.cos(theta)])
    reach = max(float(np.max(s.points @ normal)) for s in half.shapes)
    assert reach == pytest.approx(float(half.tip @ normal))


@pytest.mark.parametrize("area, length, angle, match", [
    (400 * UM**2, 400e-6, 15.0, "too small"),
    (2.5e4 * UM**2, 400e-6, 0.0, "beam angle"),
    (2.5e4 * UM**2, 10e-6, 15.0, "too short"),
])
def test_undrawable_designs_are_refused_by_name(area, length, angle, match):
    from planner.layout.cantilever import cantilever

    with pytest.raises(ValueError, match=match) as err:
        cantilever("B2.backward", area, 3e-6, length, math.radians(angle),
                   math.radians(45.0), _rules())
    assert "B2.backward" in str(err.value) or match == "beam angle"
