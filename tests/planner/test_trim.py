"""Trim (issue 26): one-way moves that make a chip's resonances separable, and what to cut."""

from __future__ import annotations

import math

import numpy as np
import pytest

from model import Impacter
from planner.config import ProcessConfig
from planner.afterfab.separations import MARGIN_SIGMAS, Separations
from planner.afterfab.trim import cut_for, plan_trim


def _seps(n, band=400.0, window=100.0, rho=1.002):
    ids = tuple(f"A{k + 1}.forward" for k in range(n))
    ones = np.ones(n)
    return Separations(ids, rho * ones, band * ones, band * ones, window * ones,
                       window * ones)


def test_separable_is_the_collision_rule():
    """i below j: j must sit above rho_i nu_i - lo_i + a_j and (nu_i + b_i - hi_j)/rho_j."""
    s = _seps(2)
    nu_i = 30000.0
    need = max(1.002 * nu_i - 100 + 400, (nu_i + 400 - 100) / 1.002)
    assert s.needed(0, 1, nu_i) == pytest.approx(need)
    assert s.separable(0, 1, nu_i, need + 1e-6)
    assert not s.separable(0, 1, nu_i, need - 1.0)
    assert s.separable(1, 0, need + 1e-6, nu_i)        # symmetric in its arguments


def test_up_raises_only_the_upper_of_a_colliding_pair_by_just_enough():
    s = _seps(3)
    measured = {"A1.forward": 30000.0, "A2.forward": 30200.0, "A3.forward": 32000.0}
    pairs = [("A1.forward", "A2.forward"), ("A1.forward", "A3.forward"),
             ("A2.forward", "A3.forward")]
    tp = plan_trim(s, measured, pairs, range_pct=1.0, direction="up", precision_pct=0.1)
    assert tp.ok and tp.moved == ["A2.forward"]
    want = s.needed(0, 1, 30000.0, 0.001)
    assert tp.target["A2.forward"] == pytest.approx(want)
    # the margin: MARGIN_SIGMAS sigmas of the trim precision on both
    assert want == pytest.approx(s.needed(0, 1, 30000.0) * (1 + MARGIN_SIGMAS * 0.001
                                                            * math.sqrt(2)))
    assert tp.target["A1.forward"] == 30000.0 and tp.target["A3.forward"] == 32000.0
    assert 0 < tp.change_pct("A2.forward") < 1.0
    # every pair is separable at the targets
    for a, b in pairs:
        assert s.separable(s.ids.index(a), s.ids.index(b), tp.target[a], tp.target[b])


def test_a_cascade_moves_each_upper_neighbour_and_down_mirrors_it():
    """Up, raising A2 off A1 brings it near A3, which moves too; down, one move does."""
    s = _seps(3)
    measured = {"A1.forward": 30000.0, "A2.forward": 30100.0, "A3.forward": 30500.0}
    pairs = [("A1.forward", "A2.forward"), ("A2.forward", "A3.forward"),
             ("A1.forward", "A3.forward")]
    up = plan_trim(s, measured, pairs, range_pct=5.0, direction="up", precision_pct=0.0)
    assert up.ok and up.moved == ["A2.forward", "A3.forward"]
    assert up.target["A3.forward"] == pytest.approx(s.needed(1, 2, up.target["A2.forward"]))
    # down: A2 and A3 are already 400 Hz apart (separable), so lowering A1 alone does it
    down = plan_trim(s, measured, pairs, range_pct=5.0, direction="down", precision_pct=0.0)
    assert down.ok and down.moved == ["A1.forward"]
    assert all(down.target[n] <= measured[n] for n in measured)
    for a, b in pairs:
        assert s.separable(s.ids.index(a), s.ids.index(b), down.target[a], down.target[b])


def test_a_chip_no_trim_in_range_can_fix_is_named():
    """Two resonances 50 Hz apart at 30 kHz need a ~2.3 % move; 1 % cannot."""
    s = _seps(2)
    measured = {"A1.forward": 30000.0, "A2.forward": 30050.0}
    tp = plan_trim(s, measured, [("A1.forward", "A2.forward")], range_pct=1.0)
    assert not tp.ok
    f = tp.failures[0]
    assert f["impacter"] == "A2.forward" and f["needed_pct"] > 1.0
    assert "trim.range_pct 1" in f["why"]
    # pairs that need not be told apart are left alone
    assert plan_trim(s, measured, [], range_pct=1.0).moved == []


def _record(area=3e-8, width=5.5e-6, length=5e-4):
    p = ProcessConfig()
    imp = Impacter.from_geometry(area, width, length, 4e-6, viscosity=1.79e-5)
    return {"mass_kg": imp.mass, "geometry": {"area_m2": area, "width_m": width,
                                              "length_m": length, "gap_m": 4e-6}}, imp, p


def test_cut_plate_area_raises_the_resonance_to_the_target():
    """The cut area, taken off the plate and rebuilt through eqs. (2)-(4), gives the
    target (an independent path: model.Impacter.from_geometry)."""
    rec, imp, p = _record()
    nu = imp.natural_frequency
    area, length = cut_for(rec, nu, nu * 1.008, p, "up")
    assert length == 0.0 and area > 0
    g = rec["geometry"]
    trimmed = Impacter.from_geometry(g["area_m2"] - area, g["width_m"], g["length_m"], 4e-6,
                                     viscosity=1.79e-5)
    assert trimmed.natural_frequency == pytest.approx(nu * 1.008, rel=1e-9)
    with pytest.raises(ValueError):
        cut_for(rec, nu, nu * 0.99, p, "up")


def test_cut_beam_length_lowers_the_resonance_to_the_target():
    rec, imp, p = _record()
    nu = imp.natural_frequency
    area, dl = cut_for(rec, nu, nu * 0.992, p, "down")
    assert area == 0.0 and dl > 0
    g = rec["geometry"]
    trimmed = Impacter.from_geometry(g["area_m2"], g["width_m"], g["length_m"] + dl, 4e-6,
                                     viscosity=1.79e-5)
    assert trimmed.natural_frequency == pytest.approx(nu * 0.992, rel=1e-9)


def _measured_csv(path, freqs):
    path.write_text("impacter,natural_frequency_hz\n"
                    + "".join(f"{n},{f:.6f}\n" for n, f in freqs.items()))
    return path


def _neighbours(plan):
    """The two impacters nearest in resonance (lower first) and their indices."""
    recs = sorted(plan.impacters, key=lambda r: r.natural_frequency_hz)
    lo, hi = min(zip(recs, recs[1:]), key=lambda p: p[1].natural_frequency_hz
                 - p[0].natural_frequency_hz)
    return lo, hi


#: Seeds of the colliding chip's trim (:func:`_colliding_chip`): at the plan's own seed
#: (0) the first draw of the cut's error leaves A1.forward 0.70 sigma above its target,
#: where the drive works, but 6 of the 100 draws are too slow: the odds, 0.94, are below
#: the target 0.95; at 171 the first draw is 2.46 sigmas above, too slow, and 97 of 100
#: draws work (the drive's window ends about 1.6 sigmas above the target).
ONE_DRAW_PASSES, ONE_DRAW_FAILS = 0, 171


@pytest.fixture(scope="module")
def colliding_chip(close_plan_dir, tmp_path_factory):
    """A chip of the close plan whose two nearest impacters came 30 Hz closer than they
    can be told apart (the rest as designed), and a runner of `vibroplan trim` on it
    (each seed run once per module): ``run(seed) -> (click result, out folder)``."""
    from click.testing import CliRunner

    from planner.cli import main
    from planner.planfile.reader import read_plan
    from planner.afterfab.separations import separations_of
    from planner.planning.settings import resolve_settings

    plan = read_plan(close_plan_dir)
    seps = separations_of(plan, resolve_settings(plan.loaded))
    lo, hi = _neighbours(plan)
    i, j = seps.ids.index(lo.id), seps.ids.index(hi.id)
    need = seps.needed(i, j, lo.natural_frequency_hz)
    freqs = {r.id: r.natural_frequency_hz for r in plan.impacters}
    freqs[hi.id] = need - 30.0
    assert abs(freqs[hi.id] / hi.natural_frequency_hz - 1) < 0.03     # a chip's scatter
    root = tmp_path_factory.mktemp("colliding")
    csv = _measured_csv(root / "measured.csv", freqs)
    runs = {}

    def run(seed, name=None):
        key = name or f"seed{seed}"
        if key not in runs:
            out = root / key
            res = CliRunner().invoke(main, ["trim", str(close_plan_dir), "--measured",
                                            str(csv), "--out", str(out), "--no-figures",
                                            "--quiet", "--seed", str(seed)])
            runs[key] = (res, out)
        return runs[key]

    return {"plan": plan, "seps": seps, "lo": lo, "hi": hi, "i": i, "j": j, "run": run}


def _odds(out):
    import json

    return json.loads((out / "plan.json").read_text())


def test_trim_cli_moves_a_colliding_impacter_and_the_odds_decide_not_one_draw(
        colliding_chip):
    """`vibroplan trim` raises the upper of the colliding pair just enough (plus the
    precision margin), trim.csv says what to cut, and the drive re-planned for the
    trimmed chip verifies on the targets.  The verdict is the odds (issue 45): at this
    seed the first draw of the cut's error leaves the slider too slow (issue 26 exited 1
    on it), but 97 of 100 draws work, above fabrication.target_yield 0.95: exit 0.  The
    re-plan measures the trimmed impacter's silent band again on its trimmed model: with
    the band taken from the nominal design, A2.backward answered A1.forward's re-planned
    tone 304 Hz away with one grazing impact, just outside its nominal band widened to
    300 Hz."""
    import csv as csvmod

    c = colliding_chip
    plan, seps, lo, hi = c["plan"], c["seps"], c["lo"], c["hi"]
    res, out = c["run"](ONE_DRAW_FAILS)
    assert res.exit_code == 0, res.output
    rows = list(csvmod.DictReader((out / "trim.csv").open()))
    assert [r["impacter"] for r in rows] == plan.impacter_ids
    moved = [r for r in rows if float(r["change_pct"]) != 0.0]
    assert [r["impacter"] for r in moved] == [hi.id]
    target = float(moved[0]["target_hz"])
    assert target == pytest.approx(seps.needed(c["i"], c["j"], lo.natural_frequency_hz,
                                               0.001))
    assert 0 < float(moved[0]["change_pct"]) < 1.0
    assert float(moved[0]["cut_area_um2"]) > 0 and float(moved[0]["cut_length_um"]) == 0
    d = _odds(out)
    odds = d["trim"]["odds"]
    assert d["verification"]["passed"] is True
    # the first draw alone fails (a slider too slow), the odds pass
    assert d["trim"]["trimmed_models"]["passed"] is False
    assert d["trim"]["trimmed_models"]["failures"] == {"too slow": 1}
    assert odds["draws"] == 100 and 0.0 <= odds["share"] <= 1.0
    assert odds["share"] == odds["passed"] / odds["draws"]
    assert odds["target_yield"] == 0.95 and odds["meets_target"] is True
    assert odds["share"] >= 0.95 and odds["passed"] < 100     # some draws do fail
    lo95, hi95 = odds["ci95"]
    assert 0.0 <= lo95 < odds["share"] <= hi95 <= 1.0
    # the failing draws implicate the trimmed impacter, as trim.csv says
    assert odds["implicated"] == {hi.id: 100 - odds["passed"]}
    assert [int(r["failed_draws"]) for r in rows] == [
        100 - odds["passed"] if r["impacter"] == hi.id else 0 for r in rows]
    assert d["trim"]["moved"][0]["trimmed_hz"] != target        # the precision error
    assert f"works on {odds['passed']} of 100 draws" in res.output
    assert "vibroplan replan" in res.output                     # the lab's next step
    # report.md is one report: the re-plan's title, then the trim's section first, the
    # re-plan's before the frequency assignment, the timings last (issue 44: no splicing)
    report = (out / "report.md").read_text()
    assert report.startswith("# vibroplan replan: close\n")
    heads = [x[3:] for x in report.splitlines() if x.startswith("## ")]
    assert heads[:4] == ["Trim", "As-built re-plan", "Frequency assignment", "Designs"]
    assert heads[-1] == "Timings" and report.endswith("|\n")
    trim = report.split("## Trim\n")[1].split("\n## ")[0]
    assert f"works on {odds['passed']} of 100 draws" in trim and "meets it" in trim
    assert "**Next step:**" in trim and "vibroplan replan" in trim


@pytest.mark.slow
def test_trim_cli_exits_1_when_the_odds_fall_short_though_one_draw_passes(colliding_chip):
    """The reverse: at the plan's seed the first draw works (issue 26 exited 0 on it),
    but 6 of 100 draws leave the slider too slow: 0.94 < 0.95, exit 1, the re-planned
    drive still verifying on the targets, and the lab told to measure again and re-plan
    after the cut (which can tell every pair apart on nearly every draw)."""
    res, out = colliding_chip["run"](ONE_DRAW_PASSES)
    assert res.exit_code == 1, res.output
    d = _odds(out)
    odds = d["trim"]["odds"]
    assert d["verification"]["passed"] is True
    assert d["trim"]["trimmed_models"]["passed"] is True
    assert odds["meets_target"] is False and 0.0 <= odds["share"] < odds["target_yield"]
    assert odds["failures"] == {"too slow": 100 - odds["passed"]}
    again = odds["after_measuring_again"]
    assert again["separable"] >= 95 and again["separable_after_second_pass"] >= \
        again["separable"]
    # a smaller move would be worse here (the lower neighbour is then within reach of
    # the cut's error): none is offered, and the output says so
    assert d["trim"]["raise_odds"] == []
    assert "BELOW it" in res.output and "no smaller move raises the odds" in res.output
    assert "vibroplan replan" in d["trim"]["next_step"]


@pytest.mark.slow
def test_trim_cli_odds_are_the_same_bytes_for_a_seed_and_follow_it(colliding_chip):
    """Same inputs and seed, the same plan.json and trim.csv byte for byte (the odds'
    100 draws included); another seed draws other errors."""
    run = colliding_chip["run"]
    (res, out), (res2, out2) = run(ONE_DRAW_PASSES), run(ONE_DRAW_PASSES, name="again")
    assert res.exit_code == res2.exit_code == 1
    for f in ("plan.json", "trim.csv"):
        assert (out / f).read_bytes() == (out2 / f).read_bytes(), f
    other = _odds(run(ONE_DRAW_FAILS)[1])["trim"]
    mine = _odds(out)["trim"]
    assert other["moved"][0]["trimmed_hz"] != mine["moved"][0]["trimmed_hz"]
    assert other["odds"]["passed"] != mine["odds"]["passed"]


def test_trim_cli_names_a_chip_no_trim_in_range_can_fix(close_plan_dir, tmp_path):
    """Two neighbours measured 5 Hz apart need a move of several per cent: beyond the
    1 % range, named with the move, exit 1, trim.csv and report.md only."""
    from click.testing import CliRunner

    from planner.cli import main
    from planner.planfile.reader import read_plan

    plan = read_plan(close_plan_dir)
    lo, hi = _neighbours(plan)
    freqs = {r.id: r.natural_frequency_hz for r in plan.impacters}
    freqs[hi.id] = lo.natural_frequency_hz + 5.0
    csv = _measured_csv(tmp_path / "measured.csv", freqs)
    out = tmp_path / "trim"
    res = CliRunner().invoke(main, ["trim", str(close_plan_dir), "--measured", str(csv),
                                    "--out", str(out), "--quiet"])
    assert res.exit_code == 1, res.output
    assert "cannot be trimmed" in res.output and "trim.range_pct 1" in res.output
    assert not (out / "plan.json").exists()
    # trim.csv read back: one row per impacter in the plan's order, the chip as measured
    # (not the design's values), nothing cut, since no trim in range helps
    import csv as csvmod
    import re

    from planner.afterfab.trim import TRIM_COLUMNS

    with (out / "trim.csv").open() as fh:
        reader = csvmod.DictReader(fh)
        assert tuple(reader.fieldnames) == TRIM_COLUMNS
        rows = list(reader)
    assert [r["impacter"] for r in rows] == plan.impacter_ids
    for r in rows:
        # trim.csv keeps 9 significant digits
        assert float(r["measured_hz"]) == pytest.approx(freqs[r["impacter"]], rel=1e-8)
        assert float(r["target_hz"]) == pytest.approx(float(r["measured_hz"]))
        assert float(r["change_pct"]) == 0.0 and float(r["cut_area_um2"]) == 0.0
    # the failure names the impacter and a move beyond the 1 % range
    line = next(x for x in res.output.splitlines() if "cannot be trimmed" in x)
    assert hi.id in line or lo.id in line
    needed = float(re.search(r"needs a ([+-][0-9.]+) % move", line).group(1))
    assert abs(needed) > 1.0
    # the report is titled, says what cannot be trimmed, and does not say that no
    # impacter needs a trim (it did, under the failure)
    report = (out / "report.md").read_text()
    assert report.startswith("# vibroplan trim: close\n\n## Trim\n")
    assert "cannot be trimmed" in report and "No impacter needs a trim" not in report


def test_remeasured_replaces_only_the_trimmed_rows_by_simulation(close_plan_dir):
    """rescue.remeasured: the trimmed impacter's silent band and tone window measured on
    its trimmed model (widened as the plan's are), every other impacter's row as the
    plan recorded it."""
    from planner.manufacturability import BAND_MARGIN, measure_separation
    from planner.planfile.reader import read_plan
    from planner.afterfab import Measurement
    from planner.afterfab.replan import chip_models
    from planner.afterfab.separations import remeasured, separations_of
    from planner.planning.settings import resolve_settings

    plan = read_plan(close_plan_dir)
    settings = resolve_settings(plan.loaded)
    seps = separations_of(plan, settings)
    hi = _neighbours(plan)[1].id
    moved = {r.id: Measurement.of(r.natural_frequency_hz * (1.02 if r.id == hi else 1.0))
             for r in plan.impacters}
    models = chip_models(plan, moved).impacters
    tones = {r.id: r.frequency_hz * (1.02 if r.id == hi else 1.0) for r in plan.impacters}
    again = remeasured(seps, [hi], models, tones, settings)
    k = seps.ids.index(hi)
    got = measure_separation(models[hi], tones[hi], power=settings.power_m2_s3,
                             amplitude=settings.amplitude_m, window=settings.window_s,
                             silent_window=max(settings.single_step_s, settings.window_s))
    assert again.below[k] == (1 + BAND_MARGIN) * got.silent_below_hz
    assert again.above[k] == (1 + BAND_MARGIN) * got.silent_above_hz
    assert (again.lo[k], again.hi[k]) == (got.responds_below_hz, got.responds_above_hz)
    others = [i for i in range(len(seps.ids)) if i != k]
    for name in ("below", "above", "lo", "hi", "rho"):
        assert np.array_equal(getattr(again, name)[others], getattr(seps, name)[others])
    assert np.array_equal(again.rho, seps.rho)


def test_a_draw_rechecks_only_the_trimmed_devices_and_gets_their_rows_exactly(
        close_plan_dir):
    """The odds re-check, per draw, only the devices that hold a trimmed impacter
    (``check_drive(devices=)``): each device's rows are those of the whole chip's check,
    digit for digit (a device's checks read only its own impacters and slider), and the
    other devices are not simulated."""
    from planner.afterfab import Measurement
    from planner.afterfab.checks import check_drive, drive_of
    from planner.afterfab.replan import chip_models
    from planner.planfile.reader import read_plan
    from planner.planning.settings import plan_settings

    plan = read_plan(close_plan_dir)
    settings = plan_settings(plan)
    models = chip_models(plan, {r.id: Measurement.of(r.natural_frequency_hz * 1.001)
                                for r in plan.impacters})
    steps, waves, dwells = drive_of(plan)
    imps = {r.node: models.impacters[r.id] for r in plan.impacters}
    full = check_drive(settings, steps, waves, dwells, imps, models.sliders)
    assert len(models.sliders) > 1 and len({r["device"] for r in full["rows"]}) > 1
    for dev in models.sliders:
        part = check_drive(settings, steps, waves, dwells, imps, models.sliders,
                           devices=[dev], scenes=False)
        assert part["rows"] == [r for r in full["rows"] if r["device"] == dev]
