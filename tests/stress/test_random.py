"""Random parameters across the valid ranges (hypothesis): never NaN, never a hang.

Property: for any valid impacter, drive and start the solver returns, with one of
its statuses, finite numbers, impacts in time order at the wall, and x never beyond
the wall; the API paths agree with the kernel.  "Never a hang" is made checkable by
a step cap: every run ends within it or says so (STEP_CAP).
"""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

import model
from model import Drive, Impacter
from model.kernels import impacter as kernel
from model.kernels.closed_form import tone_coefficients
from model.impacter import impacter_forcing

STEP_CAP = 2_000_000
STATUSES = {kernel.OK, kernel.EVENT_CAP, kernel.STEP_CAP}


@st.composite
def problems(draw):
    fn = draw(st.floats(10.0, 1e6))                           # natural frequency [Hz]
    gap = draw(st.floats(1e-7, 1e-4))                         # [m]
    zeta = draw(st.one_of(st.just(0.0), st.just(1.0), st.floats(0.0, 2.0),
                          st.floats(1e-12, 1e-6)))
    e = draw(st.one_of(st.sampled_from([0.0, 1.0]), st.floats(0.0, 1.0)))
    n = draw(st.integers(1, 4))
    ratios = draw(st.lists(st.one_of(st.just(1.0), st.floats(0.1, 10.0)),
                           min_size=n, max_size=n))
    # amplitude of each tone's free steady response, in gaps
    reach = draw(st.lists(st.floats(0.01, 10.0), min_size=n, max_size=n))
    phases = draw(st.lists(st.floats(-math.pi, math.pi), min_size=n, max_size=n))
    x0 = draw(st.one_of(st.sampled_from([-1.0, 0.0, 1.0]), st.floats(-1.0, 1.0)))
    periods = draw(st.floats(2.0, 50.0))
    wn = 2 * math.pi * fn
    imp = Impacter(1e-10, 1e-10 * wn**2, 1e-10 * 2 * zeta * wn, gap, restitution=e)
    w = wn * np.array(ratios)
    h = np.abs((wn**2 - w**2) + 2j * zeta * wn * w)
    a = np.array(reach) * gap * np.maximum(h, 1e-3 * wn**2)
    z = a / (math.cos(imp.impact_angle) * w**2)
    # within what model.Drive accepts as a physical drive in SI units (tones from 10 Hz,
    # die displacement up to 1 cm); beyond it a Drive is refused as given in kHz or um
    assume(np.all(w / (2 * math.pi) >= model.devices.MIN_FREQUENCY)
           and np.all(z <= model.devices.MAX_AMPLITUDE))
    drive = Drive(w / (2 * math.pi), z, phases)
    return imp, drive, x0 * gap, periods / fn


def check(imp, drive, x0, duration):
    w, a, phi = impacter_forcing(imp, drive)
    coef = tone_coefficients(imp.omega_n, imp.sigma, w, a, phi)
    cap = 20_000
    imp_t, imp_v = np.zeros(cap), np.zeros(cap)
    kinds = np.zeros(cap, dtype=np.int64)
    sample_t = np.linspace(0.0, duration, 257)
    sample_x = np.full(257, np.nan)
    stuck0 = x0 == imp.gap
    status, n, sum_v, t_stop, x_end, v_end, stuck, steps = kernel.run_impacter(
        imp.omega_n, imp.sigma, imp.gap, imp.restitution, w, a, phi, coef, 0.0, duration,
        x0, 0.0, stuck0, 0, cap, STEP_CAP, imp_t, imp_v, kinds, sample_t, sample_x)
    assert status in STATUSES                      # never NONFINITE, always a status
    assert steps <= STEP_CAP + 1                   # never a hang
    assert all(math.isfinite(z) for z in (sum_v, t_stop, x_end, v_end))
    assert sum_v >= 0.0 and 0.0 <= t_stop <= duration
    m = min(n, cap)
    assert np.all(np.isfinite(imp_t[:m])) and np.all(imp_v[:m] >= 0.0)
    assert np.all(np.diff(imp_t[:m]) >= 0.0)
    if status == kernel.OK:
        assert t_stop == duration
        assert np.all(np.isfinite(sample_x))
        # never beyond the wall (within the rounding of x)
        assert np.all(sample_x <= imp.gap * (1 + 1e-9))
    return status, n, sum_v


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(problems())
def test_random_problems_end_clean(problem):
    imp, drive, x0, duration = problem
    status, n, sum_v = check(imp, drive, x0, duration)
    if status == kernel.OK:
        # the response-only path gives the same r
        r = model.response(imp, drive, x0=x0, duration=duration)
        assert r == pytest.approx(imp.mass * sum_v / duration, rel=1e-12, abs=1e-300)


@pytest.mark.slow
@settings(max_examples=1500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(problems())
def test_many_random_problems_end_clean(problem):
    check(*problem)
