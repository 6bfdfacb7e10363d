"""Fixtures shared by the planner tests."""

import pytest


@pytest.fixture(scope="session")
def tiny_plan_dir(tmp_path_factory):
    """The tiny 1 x 2 plan (``test_pipeline.TINY``), planned once for the re-plan and
    yield tests, which only read it."""
    from planner.pipeline import plan
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
