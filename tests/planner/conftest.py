"""Fixtures shared by the planner tests."""

import pytest


@pytest.fixture(scope="session")
def tiny_plan_dir(tmp_path_factory):
    """The tiny 1 x 2 plan (``test_pipeline.TINY``), planned once for the re-plan and
    yield tests, which only read it."""
    from planner.planning import plan
    from tests.planner.test_pipeline import TINY

    out = tmp_path_factory.mktemp("tiny") / "plan"
    result = plan(TINY, out_dir=out, figures=False, jobs=1)
    assert result.passed, "the tiny plan must verify for the tests that use it to mean anything"
    return out


@pytest.fixture(autouse=True)
def _own_design_cache(tmp_path_factory, monkeypatch):
    """Every test gets an empty design cache of its own (``vibroplan plan`` reads and
    writes one by default): no test sees another's designs, none writes to ~/.cache.
    It lives outside the test's tmp_path, whose contents some tests check."""
    monkeypatch.setenv("VIBROPLAN_CACHE_DIR", str(tmp_path_factory.mktemp("design-cache")))


#: Four impacters on a tolerance grid 0.8 kHz apart around 21-23 kHz, designed for the
#: default tolerance: a fabricated chip's neighbours can come too close (trim, re-plan).
CLOSE = """\
name: close
array: {rows: 1, cols: 2}
device:
  slider: {area_um2: 1.6e5}
drive:
  band_hz: [19500, 25500]
  channels: {spacing: tolerance}
  guard: {separation_channels: 1}
design: {guard: 0.019}
verification: {repair_rounds: 1, x0_points: 5, min_speed_mm_s: 0.1}
fabrication:
  line_width_um: {die: 0.05, device: 0.02}
"""


@pytest.fixture(scope="session")
def close_plan_dir(tmp_path_factory):
    """The CLOSE plan (every impacter independent, neighbours one tolerance spacing
    apart), planned once for the trim tests."""
    from planner.planning import plan

    out = tmp_path_factory.mktemp("close") / "plan"
    result = plan(CLOSE, out_dir=out, figures=False, jobs=1)
    assert result.passed, "the close plan must verify for the trim tests to mean anything"
    return out
