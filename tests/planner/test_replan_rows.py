"""A re-plan of rows that shared one tone in the plan (impacters driven together).

A 2 x 4 whose scenes drive rows together (the spec below, planned once by the real
designer): the B row's four backward impacters share one tone in the plan, the A row's
forward ones another.  On a chip each follows its own measured resonance; the step then
plays a tone per member where the plan played one, their beats reach four times the
plan's amplitude at the idle impacters, and B1.forward (41.6 kHz) answered the B row's
four tones at 25.4 kHz.  Found by ``vibroplan yield --replan`` on this spec (2026-11-30):
0 of 20 chips re-planned, the nominal chip included.
"""

import pytest

from planner.afterfab import Measurement

MID_2X4 = """\
name: mid_2x4
array: {rows: 2, cols: 4}
drive:
  band_hz: [8000, 50000]
  max_acceleration_g: 1500
fabrication:
  line_width_um: {die: 0.05, device: 0.02}
scenes:
  shuffle:
    - {name: top_out, travel_um: 10, forward: [A]}
    - {name: bottom_back, travel_um: 10, backward: [B]}
    - {name: col1_out, travel_um: 5, forward: ["1"]}
"""


@pytest.fixture(scope="module")
def rows_plan(tmp_path_factory):
    from planner.planfile.reader import read_plan
    from planner.planning import plan

    out = tmp_path_factory.mktemp("rows") / "plan"
    result = plan(MID_2X4, out_dir=out, figures=False, jobs=1)
    assert result.passed, "the rows plan must verify for these tests to mean anything"
    return read_plan(out)


def _measured(plan, scale):
    return {r.id: Measurement(halves_hz=(r.natural_frequency_hz * scale.get(r.id, 1.0),))
            for r in plan.impacters}


def test_the_plan_shares_a_tone_per_row(rows_plan):
    by_tone = {}
    for r in rows_plan.impacters:
        by_tone.setdefault(r.frequency_hz, []).append(r.id)
    assert sorted(by_tone.values(), key=len)[-1] == ["B1.backward", "B2.backward",
                                                     "B3.backward", "B4.backward"]


def test_a_row_within_its_windows_keeps_one_tone(rows_plan):
    """Measured within 0.05 % of each other (the measurement's noise on a perfect chip):
    the row plays one tone, and the re-plan verifies."""
    from planner.afterfab.replan import replan

    noise = {"B1.backward": 1.0004, "B2.backward": 0.9995, "B3.backward": 1.0002,
             "B4.backward": 0.9999, "A2.forward": 1.0003, "A3.forward": 0.9996}
    got = replan(rows_plan, _measured(rows_plan, noise))
    assert got.passed
    b_row = {t for n, t in got.assignment.frequencies.items()
             if n.text.startswith("B") and n.text.endswith("backward")}
    assert len(b_row) == 1


@pytest.mark.parametrize("reunited", [True, False], ids=["reunited", "a tone each"])
def test_a_row_spread_beyond_its_windows_is_played_on_one_tone_where_that_passes(
        rows_plan, monkeypatch, reunited):
    """Spread by +-0.4 % (beyond the 0.15 % designed windows): each member first gets its
    own tone, B1.forward answers the row's beating sum, and the repair plays the row on
    its mean tone again, which drives every member and passes (without the repair the
    re-plan fails there)."""
    import planner.afterfab.replan as rp

    if not reunited:
        monkeypatch.setattr(rp, "reunite", lambda plan, s, drive, rows, fails, *a:
                            (drive, rows, fails))
    spread = {"B1.backward": 1.004, "B2.backward": 0.996, "B3.backward": 1.002,
              "B4.backward": 0.998, "A2.forward": 1.003, "A3.forward": 0.997}
    got = rp.replan(rows_plan, _measured(rows_plan, spread))
    if reunited:
        assert got.passed
        b_row = {t for n, t in got.assignment.frequencies.items()
                 if n.text.startswith("B") and n.text.endswith("backward")}
        assert len(b_row) == 1
    else:
        v = got.verification
        assert not got.passed
        assert any("B1.forward responds" in c for c in v[~v.passed]["cause"])
