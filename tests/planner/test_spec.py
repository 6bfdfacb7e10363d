"""Array spec validation (errors name the field and YAML line) and the assigner's invariants."""

from pathlib import Path

import pytest
from click.testing import CliRunner

from planner.assignment.assign import activity, assign, conflict_graph, plan_steps, verify_assignment
from planner.cli import main
from planner.core.errors import SpecError
from planner.core.nodes import Node
from planner.planning.settings import resolve_settings
from planner.arrayspec import default_spec_path, load_spec, separation_for_bandwidth

ROOT = Path(__file__).resolve().parents[2]

GOOD = """\
name: t
array: {rows: 2, cols: 3}
scenes:
  s:
    - name: a
      duration_ms: 5
      forward: [A1, B]
    - name: b
      duration_ms: 5
      backward: ["2"]
"""


def test_embedded_default_equals_configs_copy():
    assert default_spec_path().read_text() == (ROOT / "configs" / "array_5x5.yaml").read_text()
    loaded = load_spec(default_spec_path())
    assert len(loaded.device_ids) == 25 and loaded.spec.all_independent
    position = loaded.steps[0]
    assert len(position.forward) == 25 and not position.backward
    assert loaded.steps[1].backward == ("C1", "C2", "C3", "C4", "C5")


def test_selectors_resolve():
    loaded = load_spec(GOOD)
    a, b = loaded.steps
    assert a.forward == ("A1", "B1", "B2", "B3")
    assert b.backward == ("A2", "B2")
    assert not loaded.spec.all_independent


@pytest.mark.parametrize("text, path, line", [
    ("drive:\n  band_hz: [20000, 2000]\n", "drive.band_hz", 2),
    ("array:\n  rows: 2\n  colour: 3\n", "array.colour", 3),
    ("drive:\n  band_khz: [2, 20]\n", "drive.band_khz", 2),
    (GOOD.replace("duration_ms: 5\n      forward", "duration_ms: -5\n      forward"),
     "scenes.s[0].duration_ms", 6),
    (GOOD.replace("forward: [A1, B]", "forward: [A1, Z9]"), "scenes.s[0].forward[1]", 7),
    (GOOD.replace("backward: [\"2\"]", "backward: [\"2\"]\n      forward: [A2]"),
     "scenes.s[1].backward", 10),
    ("devices:\n  Q7: {}\n", "devices.Q7", 2),
])
def test_bad_spec_names_field_and_line(text, path, line):
    with pytest.raises(SpecError) as err:
        load_spec(text)
    assert err.value.path == path
    assert err.value.line == line


def test_several_bad_fields_each_name_their_own_line():
    """Every failing field is named with its own YAML line, the first one's right after
    it (the first line used to come last: "... > 0 (line 5) (line 3)")."""
    with pytest.raises(SpecError) as err:
        load_spec("array:\n  rows: 2\n  cols: 0\ndrive:\n  power_m2_s3: -5\n")
    assert (err.value.path, err.value.line) == ("array.cols", 3)
    first, also = str(err.value).split("; also ")
    assert first.endswith("array.cols: Input should be greater than or equal to 1 (line 3)")
    assert also == "drive.power_m2_s3: Input should be greater than 0 (line 5)"


@pytest.mark.parametrize("text, needle", [
    ("drive:\n  band_hz: [20000, 2000]\n", "drive.band_hz: band_hz[1] must be greater"),
    (GOOD.replace("forward: [A1, B]", "forward: [A1, Z9]"), "unknown device 'Z9'"),
])
def test_bad_spec_cli_exit_2(tmp_path, text, needle):
    spec = tmp_path / "bad.yaml"
    spec.write_text(text)
    out = tmp_path / "out"
    for cmd in (["assign", str(spec)], ["plan", str(spec), "--out", str(out), "--quiet"]):
        res = CliRunner().invoke(main, cmd)
        assert res.exit_code == 2, res.output
        assert needle in res.output and "line" in res.output
        assert "Traceback" not in res.output
    assert not out.exists()


def test_conflict_graph_rules():
    loaded = load_spec(GOOD)
    steps = plan_steps(loaded, 0.01)
    act = activity(steps)
    graph, groups = conflict_graph(steps, 3)
    # A1, B1, B2 and B3 move forward together in every step they move: one channel group
    shared = [g for g, members in groups.items() if Node("B1", "forward") in members][0]
    assert {n.text for n in groups[shared]} == {"A1.forward", "B1.forward", "B2.forward",
                                                 "B3.forward"}
    # a device's forward and backward always conflict when both are used
    fwd = [g for g, m in groups.items() if Node("B2", "forward") in m][0]
    bwd = [g for g, m in groups.items() if Node("B2", "backward") in m][0]
    assert graph.has_edge(fwd, bwd) and graph.edges[fwd, bwd]["sep"] == 3
    assert Node("A3", "forward") not in act  # never driven: not in the graph


def test_assignment_meets_every_separation():
    loaded = load_spec(GOOD)
    steps = plan_steps(loaded, 0.01)
    result = assign(resolve_settings(loaded), steps, separation=5)
    assert verify_assignment(result) == []
    lo, hi = loaded.spec.drive.band_hz
    assert all(lo <= f <= hi for f in result.frequencies.values())
    # nodes sharing a group share a frequency; conflicting ones do not
    f = result.frequencies
    assert f[Node("B1", "forward")] == f[Node("B3", "forward")]
    assert f[Node("B2", "forward")] != f[Node("B2", "backward")]


def test_band_too_small_says_what_fails_and_fixes(tmp_path):
    spec = tmp_path / "tight.yaml"
    spec.write_text("array: {rows: 5, cols: 5}\ndrive:\n  channels: {count: 40}\n")
    res = CliRunner().invoke(main, ["assign", str(spec)])
    assert res.exit_code == 2
    assert "holds 40 channels" in res.output and "wider band" in res.output


def test_separation_for_bandwidth_log_grid():
    loaded = load_spec("drive:\n  channels: {count: 241}\n")
    # 240 log steps over a decade: ratio 10^(1/240); +-2% needs ln(1.02/0.98)/ln(rho) = 4.2 -> 5
    assert separation_for_bandwidth(loaded.spec, 0.02) == 5


def test_ensemble_separation_between_a_steps_tones_and_its_idle_impacters():
    loaded = load_spec(GOOD + """\
    - name: c
      duration_ms: 5
      forward: [A1]
      backward: [B3]
""")
    steps = plan_steps(loaded, 0.01)
    plain, groups = conflict_graph(steps, 3)
    wide, _ = conflict_graph(steps, 3, ensemble_separation=9)
    member_of = {n: g for g, ms in groups.items() for n in ms}
    multi = [st for st in steps
             if len({member_of[Node(d, r)] for d, r in st.active_nodes()}) >= 2]
    assert multi, "the fixture must have a step playing several tones"
    st = multi[0]
    playing = {member_of[Node(d, r)] for d, r in st.active_nodes()}
    for idle in set(groups) - playing:
        for p in playing:
            assert wide.edges[idle, p]["sep"] == 9
            assert plain.edges[idle, p]["sep"] == 3


def _separations_hold(graph, coloring):
    return all(abs(coloring[a] - coloring[b]) >= d["sep"] for a, b, d in graph.edges(data=True))


def test_block_layouts_keep_every_separation_and_the_span():
    from planner.assignment.assign import _block_layouts
    from planner.coloring import solve_bandwidth

    loaded = load_spec(default_spec_path())
    steps = plan_steps(loaded, 0.01)
    graph, _ = conflict_graph(steps, 5, ensemble_separation=40)
    result = solve_bandwidth(graph, "sep", seed=0)
    layouts = _block_layouts(graph, result.coloring, result.span)
    # three blocks (the forward cluster, the row-C release cluster, the other backward
    # impacters): 3! orders x 2^3 mirrors, several coincide with the given two
    assert len(layouts) > 2
    for col in layouts:
        assert _separations_hold(graph, col)
        assert min(col.values()) == 0 and max(col.values()) + 1 <= result.span


def test_default_layout_puts_multi_tone_steps_below_their_idle_impacters():
    """The 25-tone positioning step and the 5-tone release of row C: the chosen layout
    has no idle impacter of either step below one of its tones except the row-C
    backward impacters under the positioning cluster, at a wide relative gap."""
    from planner.assignment.assign import _ensemble_severity

    loaded = load_spec(default_spec_path())
    steps = plan_steps(loaded, 0.01)
    a = assign(resolve_settings(loaded), steps)
    assert verify_assignment(a) == []
    f = a.frequencies
    position, release = steps[0], steps[1]
    pos_tones = [f[Node(d, "forward")] for d in position.forward]
    rel_tones = [f[Node(d, "backward")] for d in release.backward]
    others = [f[n] for n in f if n.direction == "backward" and not n.device.startswith("C")]
    assert max(rel_tones) < min(pos_tones) and max(pos_tones) < min(others)
    # the wide gaps (ensemble_separation_channels) around the positioning cluster:
    # >= 1.3x below it and >= 1.15x above it on the default's tolerance grid
    assert min(pos_tones) / max(rel_tones) >= 1.3
    assert min(others) / max(pos_tones) >= 1.15
    # and the choice is less severe than the colouring's mirror image
    from planner.manufacturability import channel_grid

    grid = channel_grid(loaded.spec)
    top = max(a.coloring.values())
    freq = lambda col: {g: float(grid[a.offset + a.stride * c]) for g, c in col.items()}  # noqa: E731
    mirror = {g: top - c for g, c in a.coloring.items()}
    assert (_ensemble_severity(steps, a.groups, freq(a.coloring))
            < _ensemble_severity(steps, a.groups, freq(mirror)))
