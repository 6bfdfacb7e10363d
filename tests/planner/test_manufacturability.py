"""Design for yield (issue 25): matched sensitivities, the tolerance grid, the predicted
collision-free yield, and the refusal of an array the band cannot hold."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import yaml
from click.testing import CliRunner
from scipy import integrate, stats

from planner.config import EnvironmentConfig, ProcessConfig
from planner.designer.design import _impacter_factory
from planner.designer.sensitivity import LineWidthModel
from planner.fabrication.tolerances import (
    ERRORS,
    ChipDesign,
    NodeDesign,
    Tolerances,
    frequency_sensitivities,
    sample_chip,
)
from planner.manufacturability import (
    DIE_SHIFT_SIGMAS,
    collision_free_yield,
    die_shift_rel,
    pair_sigma_rel,
    predict_from_channels,
    prediction_lines,
    tolerance_grid,
    z_for,
)
from planner.arrayspec import ArraySpec, FabricationSpec

AIR = EnvironmentConfig(viscosity_mpa_s=0.0179)
ANGLE, E = math.pi / 4, 0.5


def _line_width():
    return LineWidthModel(_impacter_factory(ProcessConfig(), AIR, ANGLE, E))


def _node(k, area, width, length, gap=4e-6):
    return NodeDesign(f"A{k + 1}.forward", f"A{k + 1}", "forward", area, width, length, gap,
                      ANGLE, E)


@pytest.mark.parametrize("area, width, length", [(3e-8, 5e-6, 4e-4), (5e-9, 2e-6, 1.2e-3),
                                                 (4.5e-8, 9e-6, 2e-4)])
def test_closed_form_sensitivity_is_the_fabrication_models(area, width, length):
    """The designer's closed form of d ln nu_n / dw agrees with central differences
    through the designer's factory and through the as-built equations of
    planner.fabrication.tolerances (an independent path: the chip builder)."""
    lw = _line_width()
    s = lw.sensitivity(area, width, length)
    assert s == pytest.approx(lw.check(area, width, length), rel=1e-6)
    fab = frequency_sensitivities(ArraySpec(), _node(0, area, width, length))
    assert s * 1e-6 == pytest.approx(fab[0], rel=1e-5)
    # beam-dominated mass: S -> 1/w; plate-dominated: S -> 3/(2w) - 1/sqrt(A)
    assert 1.0 / width < s < 1.5 / width


def test_matched_designs_keep_their_frequency_ratios_under_a_die_error():
    """Designs of one line-width sensitivity, at frequencies 6-60 kHz, sampled as real
    chips (planner.fabrication.tolerances.sample_chip, the full equations) with a die-level error
    only: every pairwise ratio of as-built natural frequencies stays as designed to
    second order, while designs of unmatched widths are reshuffled by the same error."""
    lw = _line_width()
    target = 0.22e6          # 1/m
    matched, unmatched = [], []
    for k, (nu, area) in enumerate([(6e3, 3e-8), (15e3, 2e-8), (30e3, 1e-8), (60e3, 3e-8)]):
        w, l = lw.width_for(area, nu, target, (2e-6, 10e-6), (8e-6, 1.5e-3))
        assert lw.sensitivity(area, w, l) == pytest.approx(target, rel=1e-9)
        matched.append(_node(k, area, w, l))
        w2 = (2.2e-6, 9e-6, 3e-6, 7e-6)[k]
        unmatched.append(_node(k, area, w2, lw.length_for(area, w2, nu, (8e-6, 1.5e-3))))
    spec = ArraySpec.model_validate({"fabrication": {"line_width_um": {"die": 0.05}}})

    def ratio_change(nodes):
        design = ChipDesign(spec, tuple(nodes), tuple(n.device for n in nodes))
        nominal = sample_chip(design, spec.fabrication, np.random.default_rng(0), scale=0.0)
        worst = 0.0
        for seed in range(20):
            chip = sample_chip(design, spec.fabrication, np.random.default_rng(seed))
            for a, b in itertools.combinations([n.id for n in nodes], 2):
                r0 = (nominal.impacters[a].natural_frequency
                      / nominal.impacters[b].natural_frequency)
                r1 = (chip.impacters[a].natural_frequency
                      / chip.impacters[b].natural_frequency)
                worst = max(worst, abs(r1 / r0 - 1.0))
        return worst

    # a 0.05 um die sigma moves every resonance by ~1.1 % per sigma; matched designs keep
    # their ratios to second order (measured ~1e-4), unmatched ones lose them by ~1 %
    assert ratio_change(matched) < 5e-4
    assert ratio_change(unmatched) > 5e-3


def test_the_designer_keeps_a_design_inside_the_sensitivity_band():
    """A real (fast) design with a sensitivity band returns a design inside it."""
    from planner.config import SliderConfig
    from planner.designer import design_impacter

    band = (0.22e6 * 0.95, 0.22e6 * 1.05)
    res = design_impacter(25000.0, (24000.0, 26000.0), environment=AIR, budget="fast",
                          slider=SliderConfig(area_um2=1.6e5), max_mass_ratio=0.4,
                          contact="two_body", guard=0.004, sensitivity=band, seed=1)
    g = res.geometry
    s = _line_width().sensitivity(g.area, g.width, g.length)
    assert band[0] * (1 - 1e-9) <= s <= band[1] * (1 + 1e-9)
    assert res.checks["line_width_sensitivity_per_um"] == pytest.approx(s * 1e-6)
    # and a fixed beam width is kept, the area solved for the sensitivity instead
    from planner.designer import DesignBounds

    res = design_impacter(25000.0, (24000.0, 26000.0), environment=AIR, budget="fast",
                          slider=SliderConfig(area_um2=1.6e5), max_mass_ratio=0.4,
                          contact="two_body", guard=0.004, seed=1,
                          bounds=DesignBounds(width=(6e-6, 6e-6)))
    assert res.geometry.width == 6e-6


def test_tolerance_grid_widens_with_the_scatter():
    """Channels are separation_hz + z sigma f apart: uniform without scatter, wider at
    the top than at the bottom with it, and fewer when the scatter grows."""
    flat = tolerance_grid((5000.0, 20000.0), 500.0, 0.0, 3.0)
    assert np.allclose(np.diff(flat), 500.0)
    g = tolerance_grid((5000.0, 60000.0), 400.0, 0.006, 3.0)
    steps = np.diff(g)
    assert np.all(np.diff(steps) > 0)
    assert steps[0] == pytest.approx(400.0 + 3.0 * 0.006 * 5000.0)
    assert steps[-1] == pytest.approx(400.0 + 3.0 * 0.006 * g[-2])
    assert g[-1] <= 60000.0 < g[-1] + 400.0 + 3.0 * 0.006 * g[-1]
    wider = tolerance_grid((5000.0, 60000.0), 400.0, 0.012, 3.0)
    assert len(wider) < len(g)
    # sub-channels: 4 channels make one separation
    fine = tolerance_grid((5000.0, 60000.0), 400.0, 0.006, 3.0, sub=4)
    assert fine[4] - fine[0] == pytest.approx(g[1] - g[0], rel=0.02)


def test_spec_grid_follows_the_fabrication_section():
    """drive.channels.spacing: tolerance reads the sigmas and the target yield: a larger
    sigma or a higher target gives fewer channels in the same band."""
    from planner.manufacturability import channel_grid

    def spec(device, target=0.95):
        return ArraySpec.model_validate({
            "array": {"rows": 2, "cols": 2},
            "drive": {"band_hz": [5000, 60000], "channels": {"spacing": "tolerance"},
                      "guard": {"separation_channels": 1}},
            "fabrication": {"line_width_um": {"die": 0.05, "device": device},
                            "target_yield": target}})

    base = channel_grid(spec(0.02))
    assert len(channel_grid(spec(0.04))) < len(base)
    assert len(channel_grid(spec(0.02, 0.99))) < len(base)
    s = spec(0.02)
    # matched (the default): sqrt(2) S* sigma_device, plus the die error times the
    # matched band's spread
    assert pair_sigma_rel(s) == pytest.approx(
        math.sqrt(2 * (0.28 * 0.02) ** 2 + (2 * 0.05 * 0.28 * 0.05) ** 2 / 6), rel=1e-3)
    z = z_for(0.95, 7)            # 8 impacters of a 2 x 2 array, all told apart
    # the grid keeps 3 sigmas of a die's common shift (0.28/um x 0.05 um) from the ends
    m = 1 + DIE_SHIFT_SIGMAS * die_shift_rel(s)
    assert m == pytest.approx(1 + 3 * 0.28 * 0.05)
    assert base[0] == pytest.approx(5000 * m) and base[-1] <= 60000 / m
    assert base[1] - base[0] == pytest.approx(400 + z * pair_sigma_rel(s) * base[0])


def _exact_pair_yield(nu1, nu2, a, d):
    """P(|nu1 exp(a z1) - nu2 exp(a z2)| >= d), z1, z2 standard normal: the inner
    probability in closed form, the outer by quadrature."""
    def inner(z1):
        x = nu1 * math.exp(a * z1)
        hi = stats.norm.cdf(math.log((x + d) / nu2) / a)
        lo = stats.norm.cdf(math.log((x - d) / nu2) / a) if x > d else 0.0
        return stats.norm.pdf(z1) * (hi - lo)

    collide, _ = integrate.quad(inner, -9, 9, epsabs=1e-12, limit=200)
    return 1.0 - collide


def test_monte_carlo_yield_of_two_impacters_matches_the_exact_value():
    """Two impacters 600 Hz apart at 30 kHz, 1 % device-level scatter each, colliding
    when their resonances come within 400 Hz: the Monte Carlo's interval holds the
    exact probability."""
    nu = np.array([30000.0, 30600.0])
    sens = np.zeros((2, len(ERRORS)))
    sens[:, ERRORS.index("natural_frequency_pct")] = 0.01       # 1/%
    sd_dev = np.zeros(len(ERRORS))
    sd_dev[ERRORS.index("natural_frequency_pct")] = 1.0          # 1 %
    pred = collision_free_yield(["a", "b"], nu, nu, sens, np.zeros(len(ERRORS)), sd_dev,
                                [[0, 1]], silent_below=[400, 400], silent_above=[400, 400],
                                chips=40000, seed=3)
    exact = _exact_pair_yield(30000.0, 30600.0, 0.01, 400.0)
    assert 0.4 < exact < 0.8
    assert pred.ci95[0] <= exact <= pred.ci95[1]
    assert pred.die_only == 1.0 and pred.device_only == pred.value
    assert pred.limiting_pairs[0]["pair"] == ["a", "b"]
    assert pred.nominal_collisions == []


def test_monte_carlo_against_chips_sampled_through_the_full_equations():
    """The first-order Monte Carlo against chips built by planner.fabrication.tolerances.sample_chip
    (the full equations, its own draws): the same collision rule on both gives yields
    within their intervals."""
    lw = _line_width()
    nodes = []
    for k, nu in enumerate((20000.0, 20800.0, 21700.0)):
        w, l = lw.width_for(2e-8, nu, 0.25e6, (2e-6, 10e-6), (8e-6, 1.5e-3))
        nodes.append(_node(k, 2e-8, w, l))
    spec = ArraySpec.model_validate(
        {"fabrication": {"line_width_um": {"die": 0.05, "device": 0.06}}})
    design = ChipDesign(spec, tuple(nodes), tuple(n.device for n in nodes))
    nominal = sample_chip(design, spec.fabrication, np.random.default_rng(0), scale=0.0)
    nu0 = np.array([nominal.impacters[n.id].natural_frequency for n in nodes])
    pairs = [[0, 1], [1, 2], [0, 2]]
    chips, ok = 4000, 0
    for i in range(chips):
        chip = sample_chip(design, spec.fabrication, np.random.default_rng(1000 + i))
        f = np.array([chip.impacters[n.id].natural_frequency for n in nodes])
        ok += all(abs(f[a] - f[b]) >= 400.0 for a, b in pairs)
    sens = np.array([frequency_sensitivities(spec, n) for n in nodes])
    tol = Tolerances.from_spec(spec.fabrication)
    pred = collision_free_yield([n.id for n in nodes], nu0, nu0, sens,
                                tol.die, tol.device, pairs,
                                silent_below=[400] * 3, silent_above=[400] * 3, chips=20000)
    from planner.yield_ import wilson_interval

    lo, hi = wilson_interval(ok, chips)
    assert 0.2 < pred.value < 0.95
    # the two estimates' intervals overlap
    assert pred.ci95[0] <= hi and lo <= pred.ci95[1]


def test_an_array_the_band_cannot_hold_is_refused_in_seconds(tmp_path):
    """A 5 x 5 independently addressable array on a 5-20 kHz tolerance grid: refused by
    the CLI with exit 2 before any design, saying how many fit and what would help."""
    from planner.cli import main

    spec = tmp_path / "big.yaml"
    spec.write_text(yaml.safe_dump({
        "name": "big", "array": {"rows": 5, "cols": 5},
        "drive": {"band_hz": [5000, 20000], "channels": {"spacing": "tolerance"}},
        "fabrication": {"line_width_um": {"die": 0.05, "device": 0.02}}}))
    res = CliRunner().invoke(main, ["plan", str(spec), "--out", str(tmp_path / "out")])
    assert res.exit_code == 2, res.output
    fit = int(res.output.split("holds only ")[1].split(":")[0])
    assert 10 < fit < 50
    assert "drive.band_hz" in res.output and "fabrication.target_yield" in res.output
    assert "independent: false" in res.output
    assert not (tmp_path / "out").exists()


def test_dry_run_predicts_the_yield_from_the_grid(tmp_path):
    """--dry-run prints the collision-free yield of the channel grid before any design;
    a grid sized for 0.95 predicts about 0.95, an old 500 Hz linear grid far less.  The
    prediction is the dry run's own (an assignment on the grid, its chips sampled; it
    does not depend on the reach, so the probes are not run here: the CLI's line is
    read by test_pipeline's plan)."""
    from planner.arrayspec import load_spec
    from planner.assignment.assign import assign
    from planner.planning.settings import resolve_settings

    def dry(drive):
        design = {"guard": 0.019, "bounds": {"gap_um": [2.0, 16.0]}, **drive.pop("design", {})}
        text = yaml.safe_dump({
            "name": "s", "array": {"rows": 2, "cols": 2}, "drive": drive, "design": design,
            "environment": {"viscosity_mpa_s": 0.0179},
            "device": {"slider": {"area_um2": 1.6e5}, "contact": "two_body"},
            "verification": {"min_speed_mm_s": 0.1},
            "fabrication": {"line_width_um": {"die": 0.05, "device": 0.02}}})
        settings = resolve_settings(load_spec(text))
        a = assign(settings, settings.steps)
        pred = predict_from_channels(settings.chip_spec, a, seed=settings.seed)
        line = next(x for x in prediction_lines(pred, settings.target_yield,
                                                before_designs=True)
                    if "collision-free yield" in x)
        return float(line.split("yield ")[1].split()[0])

    spec = ArraySpec.model_validate({"fabrication": {"line_width_um": {"die": 0.05,
                                                                       "device": 0.02}}})
    # a band that holds the 8 impacters of a 2 x 2 array exactly (no spare room for the
    # assigner to spread the tones over): the grid's own yield, about 0.95
    m = 1 + DIE_SHIFT_SIGMAS * die_shift_rel(spec)     # the die-shift room at the ends
    top = tolerance_grid((20000.0, 1e6), 400.0, pair_sigma_rel(spec), z_for(0.95, 7))[7]
    tol = dry({"band_hz": [20000 / m, float(top) * m + 1.0],
               "channels": {"spacing": "tolerance"}, "guard": {"separation_channels": 1}})
    assert 0.93 <= tol <= 0.97
    # spare room: the assigner spreads the tones (stride), and the yield rises
    assert dry({"band_hz": [20000, 2 * float(top)], "channels": {"spacing": "tolerance"},
                "guard": {"separation_channels": 1}}) > 0.99
    lin = dry({"band_hz": [36000, 40000], "channels": {"spacing": "linear", "count": 41},
               "guard": {"separation_channels": 5}, "design": {"guard": 0.004}})
    assert lin < 0.5


def test_no_tolerance_no_yield():
    """Without fabrication tolerances nothing is predicted (a yield of 1 would be a
    claim about nothing)."""
    from planner.manufacturability import prediction_lines

    assert FabricationSpec().zero
    assert "not predicted" in prediction_lines(None, 0.95, before_designs=True)[0]


def test_plan_records_its_manufacturability(tmp_path):
    """A real plan of the tiny spec with a fabrication section: plan.json carries the
    pinned manufacturability keys (every design's sensitivities and separations, the
    yield with its interval), the CLI prints it and report.md shows it with a figure."""
    import json

    from planner.cli import main
    from tests.planner.test_pipeline import TINY

    spec = tmp_path / "tiny.yaml"
    spec.write_text(TINY + "fabrication:\n  line_width_um: {die: 0.05, device: 0.02}\n")
    out = tmp_path / "plan"
    res = CliRunner().invoke(main, ["plan", str(spec), "--out", str(out), "--jobs", "1"])
    assert res.exit_code == 0, res.output
    assert "predicted collision-free yield" in res.output
    d = json.loads((out / "plan.json").read_text())
    m = d["manufacturability"]
    ids = [r["id"] for r in d["impacters"]]
    assert set(m["sensitivity"]) == set(m["separation_hz"]) == set(ids)
    for n in ids:
        assert set(m["sensitivity"][n]) == set(ERRORS)
        assert 0.266 <= m["sensitivity"][n]["line_width_um"] <= 0.294   # the matched band
        sep = m["separation_hz"][n]
        assert sep["silent_beyond"] > 0 and sep["responds_within"] >= 0
    y = m["collision_free_yield"]
    assert set(y) == {"value", "ci95", "chips"} and y["chips"] == 10000
    assert y["ci95"][0] <= y["value"] <= y["ci95"][1]
    assert isinstance(m["limiting_pairs"], list)
    report = (out / "report.md").read_text()
    assert "## Manufacturability" in report and "Predicted collision-free yield" in report
    assert (out / "figures" / "manufacturability.png").stat().st_size > 10000


@pytest.mark.parametrize("section, message", [
    ({"drive": {"channels": {"spacing": "tolerance", "count": 100}}}, "count cannot be given"),
    ({"drive": {"channels": {"spacing": "linear", "separation_hz": 300}}},
     "separation_hz applies to spacing: tolerance only"),
    ({"design": {"beam_width_um": 6, "bounds": {"width_um": [3, 8]}}}, "beam_width_um fixes"),
    ({"design": {"match_sensitivity": False, "sensitivity_per_um": 0.2}},
     "sensitivity_per_um needs match_sensitivity"),
    ({"fabrication": {"target_yield": 1.0}}, "target_yield"),
])
def test_contradicting_design_for_yield_fields_are_refused_with_their_line(section, message):
    from planner.core.errors import SpecError
    from planner.arrayspec import load_spec

    text = yaml.safe_dump({"name": "t", "array": {"rows": 1, "cols": 2}, **section})
    with pytest.raises(SpecError) as err:
        load_spec(text + "\n")
    assert message in str(err.value)
    assert err.value.line is not None


def test_a_spec_read_back_from_plan_json_validates():
    """plan.json records every default; a tolerance grid's record (count: null) and a
    linear grid's (separation_hz: null) both validate again (yield and replan read it)."""
    import json

    for channels in ({"spacing": "tolerance"}, {"spacing": "linear", "count": 50}):
        spec = ArraySpec.model_validate({"drive": {"band_hz": [5000, 60000],
                                                   "channels": channels}})
        again = ArraySpec.model_validate(json.loads(spec.model_dump_json()))
        assert again == spec


def test_the_width_solve_takes_the_closed_form_bracket_and_matches_the_nested_solve():
    """width_for solves S = target and nu_n together with l in closed form on the widths
    whose l lies inside its bounds (_width_at inverts _length_at); the nested solve (l
    from nu_n by Newton inside a root search in w) finds the same design.  Before the
    closed-form bracket every call of the default plan fell back to the nested solve,
    a quarter of a design's time."""
    lw = _line_width()
    rng = np.random.default_rng(3)
    wb, lb = (2e-6, 10e-6), (40e-6, 2e-3)
    pair = 0
    for _ in range(300):
        area = math.exp(rng.uniform(math.log(3e-9), math.log(6e-8)))
        nu = math.exp(rng.uniform(math.log(4e3), math.log(6e4)))
        target = rng.uniform(0.22e6, 0.32e6)
        for length in (lb[0], 3e-4, lb[1]):
            w = lw._width_at(area, target, length)
            assert lw._length_at(area, w, target) == pytest.approx(length, rel=1e-12)
        hit = lw._solve_pair("w", area, nu, target, wb, lb, True)

        def g(log_w):
            w = math.exp(log_w)
            return math.log(lw.sensitivity(area, w, lw.length_for(area, w, nu, lb)) / target)

        w_ref = lw._solve(g, *wb)
        l_ref = lw.length_for(area, w_ref, nu, lb)
        if hit is None:
            continue
        pair += 1
        _, w, l = hit
        assert (w, l) == pytest.approx((w_ref, l_ref), rel=1e-8)
        # the roots are exact to ~1e-12 in ln w; nu_n moves up to ~100x that along the
        # curve of equal sensitivity
        assert lw.natural_frequency(area, w, l) == pytest.approx(nu, rel=1e-8)
        assert lw.sensitivity(area, w, l) == pytest.approx(target, rel=1e-8)
        assert lb[0] <= l <= lb[1] and wb[0] <= w <= wb[1]
    assert pair >= 250


def _collisions_numpy(nu, tone, below, above, lo, hi, g, pairs, split=None):
    """The Monte Carlo's collision test as NumPy wrote it before the numba kernel."""
    i, j = pairs[:, 0], pairs[:, 1]
    nu_c, t_c = nu * g, tone * g
    wide = np.zeros((1, nu.size)) if split is None else np.abs(split) * nu_c
    b_lo, b_hi = below + wide, above + wide
    w_lo, w_hi = lo - wide, hi - wide
    win_lo, win_hi = t_c - w_lo, t_c + w_hi
    band_lo, band_hi = nu_c - b_lo, nu_c + b_hi

    def inside(a, b):
        return ((win_lo.take(a, axis=1) > band_lo.take(b, axis=1))
                & (win_hi.take(a, axis=1) < band_hi.take(b, axis=1)))

    return inside(i, j) | inside(j, i)


@pytest.mark.parametrize("case", range(24))
def test_the_collision_kernel_gives_numpys_booleans_bit_for_bit(case):
    """planner.manufacturability.kernels.collisions_kernel (issue 43: the plan's yield
    prediction took 0.8 s of a 5 s re-run) against the NumPy expression it replaced,
    on random arrays with and without a pair split and a die factor, many of the pairs
    near the edge of colliding."""
    from planner.manufacturability.monte_carlo import _collisions

    rng = np.random.default_rng(case)
    n, m, chips = int(rng.integers(2, 60)), int(rng.integers(1, 200)), int(rng.integers(1, 300))
    nu = rng.uniform(4e3, 5e4, n)
    tone = nu * (1 + rng.normal(0, 0.01, n))
    below, above = rng.uniform(0, 3000, n), rng.uniform(0, 3000, n)
    lo, hi = rng.uniform(0, 500, n), rng.uniform(0, 500, n)
    g = np.exp(rng.normal(0, 0.01, (chips, n))) if case % 3 else np.ones((1, n))
    pairs = rng.integers(0, n, (m, 2))
    split = None if case % 2 else rng.normal(0, 0.005, (g.shape[0], n))
    want = _collisions_numpy(nu, tone, below, above, lo, hi, g, pairs, split)
    got = _collisions(nu, tone, below, above, lo, hi, g, pairs, split)
    assert got.dtype == bool and got.shape == want.shape
    assert np.array_equal(got, want)
    assert 0 < want.sum() < want.size or want.size < 50


def test_the_measurement_noise_gives_the_share_a_re_plan_can_tell_apart():
    """Two impacters 700 Hz apart at 30 kHz, each moved by 150 Hz (one sigma) of device
    error and read with 60 Hz (0.2 %) of measurement error; silent bands 400 Hz and tone
    windows 80 Hz, so a pair collides when its resonances (as built, or as measured) sit
    within 320 Hz.  First order, the difference is normal: the collision-free yield is
    1 - P(|N(700, 2 x 150^2)| < 320) = 0.963 and the told-apart share
    1 - P(|N(700, 2 x 150^2 + 2 x 60^2)| < 320) = 0.952; the noise is drawn after every
    other draw, so the collision-free yield is the same number with and without it."""
    from scipy.stats import norm

    from planner.fabrication.tolerances import ERRORS
    from planner.manufacturability import collision_free_yield

    nu = np.array([30000.0, 30700.0])
    sens = np.zeros((2, len(ERRORS)))
    sens[:, 0] = 0.25                                      # 1/um
    zero = np.zeros(len(ERRORS))
    dev = zero.copy()
    dev[0] = 0.02                                          # um: 150 Hz at 30 kHz
    kw = dict(silent_below=[400, 400], silent_above=[400, 400], responds_below=[80, 80],
              responds_above=[80, 80], chips=40000, seed=3)
    base = collision_free_yield(["a", "b"], nu, nu, sens, zero, dev, [[0, 1]], **kw)
    noisy = collision_free_yield(["a", "b"], nu, nu, sens, zero, dev, [[0, 1]],
                                 sigma_measure=0.002, **kw)
    assert base.told_apart is None
    assert noisy.value == base.value and noisy.die_only == base.die_only

    def free(sd):
        return 1.0 - (norm.cdf((320 - 700) / sd) - norm.cdf((-320 - 700) / sd))

    sd_built = np.sqrt(2) * 30000 * 0.25 * 0.02
    sd_read = np.sqrt(sd_built ** 2 + 2 * (30000 * 0.002) ** 2)
    assert base.value == pytest.approx(free(sd_built), abs=0.005)
    assert noisy.told_apart == pytest.approx(free(sd_read), abs=0.005)
    assert noisy.told_apart < base.value - 0.005


def test_the_cli_says_the_told_apart_share_a_plan_records():
    """`vibroplan plan` prints plan.json's told-apart share under the collision-free
    yield (read back through YieldPrediction.from_block); a plan made before it has none
    and prints the lines it printed."""
    from planner.manufacturability import YieldPrediction, prediction_lines

    block = {"collision_free_yield": {"value": 0.969, "ci95": [0.966, 0.972], "chips": 10000},
             "die_only_yield": 1.0, "device_only_yield": 0.969,
             "closest_pair_hz": {"p5": 339.0, "median": 395.0, "p95": 427.0},
             "limiting_pairs": [], "nominal_collisions": []}
    old = prediction_lines(YieldPrediction.from_block(block), 0.95, before_designs=False)
    told = {**block, "told_apart_yield": {"value": 0.9675, "ci95": [0.964, 0.971],
                                          "chips": 10000, "measurement_noise_pct": 0.05}}
    new = prediction_lines(YieldPrediction.from_block(told), 0.95, before_designs=False)
    assert new[:len(old)] == old and len(new) == len(old) + 1
    assert "0.968 of the chips told apart" in new[-1]
