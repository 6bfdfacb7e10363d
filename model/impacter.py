"""The impacter API: impacts of one impacter, the response r of eq. (12), sweeps.

Public functions validate their arguments, convert the value objects to floats and
arrays in SI units, and call the numba kernels of :mod:`model.kernels.impacter` (the
exact solver) and :mod:`model.kernels.rk4` (the paper's reference).  The slider that
the impacts drive is :mod:`model.slider`'s.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from model._arguments import check_drive, check_float, check_impacter, check_state, sample_times
from model.drive import POWER, amplitude_from_power
from model.kernels import impacter as _k
from model.kernels.closed_form import tone_coefficients
from model.kernels.rk4 import run_rk4

#: Names of the kernels' statuses, as :attr:`ImpactResult.status` reports them.
STATUS = {
    _k.OK: "ok",
    _k.EVENT_CAP: "event cap reached",
    _k.STEP_CAP: "step cap reached",
    _k.NONFINITE: "non-finite state",
}
#: Default RK4 step, as a fraction of the shortest period in the problem.
RK4_STEPS_PER_PERIOD = 200


class SolverWarning(RuntimeWarning):
    """A run ended on a cap or a non-finite state; its result is incomplete."""


@dataclass(frozen=True)
class ImpactResult:
    """Outcome of :func:`simulate`.

    Attributes
    ----------
    times : ndarray, shape (n_impacts,)
        Impact times [s].
    velocities : ndarray, shape (n_impacts,)
        Impacter velocity just before each impact, v- [m/s].
    chatter_times, chatter_sums : ndarray
        Accumulation times [s] of chatter sequences summed in closed form and
        the sum of their v- [m/s] (each ends in sticking at the wall).
    response : float
        r of eq. (12) [N]: m times the sum of v- from the second impact on
        (chatter sums included), over the duration.
    status : str
        "ok", "event cap reached", "step cap reached" or "non-finite state".
    message : str
        Human-readable account of the status.
    x_end, v_end : float
        Final impacter state [m, m/s].
    stuck_end : bool
        Whether the run ended with the impacter stuck at the wall.
    n_steps : int
        Root-finding (or RK4) steps taken.
    t, x : ndarray or None
        The trajectory, if requested: sample times [s] and positions [m].
    """

    times: np.ndarray
    velocities: np.ndarray
    chatter_times: np.ndarray
    chatter_sums: np.ndarray
    response: float
    status: str
    message: str
    x_end: float
    v_end: float
    stuck_end: bool
    n_steps: int
    t: np.ndarray | None = None
    x: np.ndarray | None = None

    @property
    def success(self):
        return self.status == "ok"

    @property
    def n_impacts(self):
        return int(self.times.size)


def impacter_forcing(impacter, drive):
    """Tone arrays (w [rad/s], a [m/s^2], phi [rad]) of the forcing per unit mass, eq. (5).

    All three are fresh writable arrays: a frozen Drive's read-only phases are another
    numba type, and would compile the exact kernel once more beside the specialisation
    the parallel response kernel already compiled (:func:`model.kernels.impacter.response_grid`).
    """
    w = 2.0 * math.pi * drive.frequencies
    a = math.cos(impacter.impact_angle) * (w * w * drive.amplitudes)
    return w, a, np.array(drive.phases, dtype=float)


def _message(status, n, duration, t_stop):
    if status == _k.OK:
        return f"{n} impacts in {duration:.6g} s"
    return f"{STATUS[status]} after {n} events at t = {t_stop:.6g} s of {duration:.6g} s"


def warn_status(status, message):
    """A :class:`SolverWarning` with ``message`` unless ``status`` is OK."""
    if status != _k.OK:
        warnings.warn(message, SolverWarning, stacklevel=3)


def simulate(impacter, drive, x0=0.0, v0=0.0, duration=3e-3, *, method="exact",
             trajectory=None, step=None, max_events=100_000, stuck=None):
    """Simulate an impacter under a drive and return its impacts.

    Parameters
    ----------
    impacter : Impacter
    drive : Drive
        Substrate displacement; the impacter feels m cos(theta) (-zeta'').
    x0, v0 : float
        Initial position [m] (<= gap) and velocity [m/s].
    duration : float
        t_f - t_0 [s], the paper's window is 3 ms.
    method : {"exact", "rk4"} or callable
        "exact": the event-driven closed-form solver; "rk4": the paper's
        fixed-step RK4 with per-step impact detection (reference only).
    trajectory : bool, int or array_like, optional
        Record x at 2001 evenly spaced times (True), at n of them (int) or at
        the given sorted times [s].
    step : float, optional
        RK4 step [s]; default 1/200 of the shortest period.
    max_events : int
        Cap on impacts; a run that reaches it ends with status "event cap reached".
    stuck : bool, optional
        Start stuck at the wall (needs x0 == gap and v0 == 0); by default a run
        started at rest on the wall sticks if the net force presses on it.

    Returns
    -------
    ImpactResult

    Examples
    --------
    >>> from model import Impacter, Drive
    >>> imp = Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6).with_natural_frequency(5200)
    >>> res = simulate(imp, Drive.tone(6200.0))
    >>> res.n_impacts, res.status
    (17, 'ok')
    """
    check_impacter(impacter)
    check_drive(drive)
    x0, v0, duration = check_state(impacter, x0, v0, duration)
    solver = METHODS.get(method, method)
    if not callable(solver):
        raise ValueError(f"method must be one of {sorted(METHODS)} or a callable, {method!r} was given")
    if max_events < 1:
        raise ValueError(f"max_events must be >= 1, {max_events!r} was given")
    sample_t = sample_times(trajectory, duration)
    return solver(impacter, drive, x0, v0, duration, sample_t=sample_t, step=step,
                  max_events=int(max_events), stuck=stuck)


def _simulate_exact(impacter, drive, x0, v0, duration, *, sample_t, step, max_events, stuck):
    w, a, phi = impacter_forcing(impacter, drive)
    coef = tone_coefficients(impacter.omega_n, impacter.sigma, w, a, phi)
    cap = min(max_events, 100_000)
    # written before read (only the first n are read back): np.empty, as zeroing three
    # 100 000-event buffers cost more than a short run's kernel (6 % of a yield's chip)
    imp_t = np.empty(cap)
    imp_v = np.empty(cap)
    kinds = np.empty(cap, dtype=np.int64)
    sample_x = np.zeros(sample_t.size)
    stuck0 = (x0 == impacter.gap and v0 == 0.0) if stuck is None else bool(stuck)
    status, n, sum_v, t_stop, x_end, v_end, stuck_end, steps = _k.run_impacter(
        impacter.omega_n, impacter.sigma, impacter.gap, impacter.restitution,
        w, a, phi, coef, 0.0, duration, x0, v0, stuck0, 0, max_events, _k.MAX_STEPS,
        imp_t, imp_v, kinds, sample_t, sample_x)
    n_rec = min(n, cap)
    if n_rec:
        kinds = kinds[:n_rec]
        real = kinds == _k.IMPACT
        times, velocities = imp_t[:n_rec][real], imp_v[:n_rec][real]
        chatter_times, chatter_sums = imp_t[:n_rec][~real], imp_v[:n_rec][~real]
    else:   # no impact (most runs of an idle impacter): four empty arrays, as indexed
        times, velocities, chatter_times, chatter_sums = (np.empty(0), np.empty(0),
                                                          np.empty(0), np.empty(0))
    res = ImpactResult(
        times=times, velocities=velocities,
        chatter_times=chatter_times, chatter_sums=chatter_sums,
        response=impacter.mass * sum_v / duration, status=STATUS[status],
        message=_message(status, n, duration, t_stop), x_end=x_end, v_end=v_end,
        stuck_end=bool(stuck_end), n_steps=int(steps),
        t=sample_t if sample_t.size else None, x=sample_x if sample_t.size else None)
    warn_status(status, res.message)
    return res


def _simulate_rk4(impacter, drive, x0, v0, duration, *, sample_t, step, max_events, stuck):
    w, a, phi = impacter_forcing(impacter, drive)
    if step is None:
        fmax = max(float(np.max(drive.frequencies)), impacter.natural_frequency)
        step = 1.0 / (RK4_STEPS_PER_PERIOD * fmax)
    step = check_float("step", step)
    if step <= 0:
        raise ValueError(f"step must be > 0, {step!r} was given")
    cap = min(max_events, 100_000)
    imp_t = np.zeros(cap)
    imp_v = np.zeros(cap)
    status, n, sum_v, x_end, v_end, steps = run_rk4(
        impacter.omega_n, impacter.sigma, impacter.gap, impacter.restitution, w, a, phi,
        0.0, duration, x0, v0, step, max_events, imp_t, imp_v)
    n_rec = min(n, cap)
    res = ImpactResult(
        times=imp_t[:n_rec], velocities=imp_v[:n_rec], chatter_times=np.empty(0),
        chatter_sums=np.empty(0), response=impacter.mass * sum_v / duration,
        status=STATUS[status], message=_message(status, n, duration, duration),
        x_end=x_end, v_end=v_end, stuck_end=False, n_steps=int(steps))
    warn_status(status, res.message)
    return res


#: Solvers selectable by ``simulate(method=...)``.
METHODS = {"exact": _simulate_exact, "rk4": _simulate_rk4}


def response(impacter, drive, x0=0.0, v0=0.0, duration=3e-3, *, stop_at_first=False):
    """The response r of eq. (12) [N].

    r = m sum_{k>=2} v-(t_k) / (t_f - t_0): the first impact, due to the initial
    position, is excluded.  Only the impacter is simulated and no event list or
    trajectory is kept.

    Parameters
    ----------
    impacter, drive, x0, v0, duration
        As in :func:`simulate`.
    stop_at_first : bool
        Stop at the first counted (second) impact: the result is then > 0 exactly
        when the full r is, which is all constraint (14) needs to know.

    Examples
    --------
    >>> from model import Impacter, Drive
    >>> imp = Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6).with_natural_frequency(5200)
    >>> round(response(imp, Drive.tone(6200.0)) * 1e9, 2)
    114.62
    """
    check_impacter(impacter)
    check_drive(drive)
    x0, v0, duration = check_state(impacter, x0, v0, duration)
    w, a, phi = impacter_forcing(impacter, drive)
    status, n, sum_v = _k.response_single(
        impacter.omega_n, impacter.sigma, impacter.gap, impacter.restitution, w, a, phi,
        duration, x0, v0, 2 if stop_at_first else 0, _k.MAX_EVENTS, _k.MAX_STEPS)
    warn_status(status, _message(status, n, duration, float("nan")))
    return impacter.mass * sum_v / duration


def responses(impacter, drive, x0s, v0s=None, duration=3e-3, *, stop_at_first=False,
              return_status=False, check_input=True):
    """r of eq. (12) from many initial states at once (parallel kernel).

    Parameters
    ----------
    x0s : array_like, shape (n,)
        Initial positions [m].
    v0s : array_like, shape (n,), optional
        Initial velocities [m/s]; zeros by default.
    check_input : bool, default True
        Validate the arguments.  An optimiser that calls this thousands of times with
        arguments it built itself (finite x0s inside the gap, a positive duration) may
        pass False to skip the checks, as scipy's ``check_finite=False``; invalid input
        then gives undefined results.

    Returns
    -------
    r : ndarray, shape (n,)
        [N].  With ``return_status``, also the status codes (0 = ok).
    """
    x0s = np.array(x0s, dtype=float, ndmin=1)       # a writable C copy: one kernel type
    v0s = np.zeros(x0s.shape) if v0s is None else np.array(
        np.broadcast_to(np.asarray(v0s, dtype=float), x0s.shape))
    if check_input:
        check_impacter(impacter)
        check_drive(drive)
        duration = check_float("duration", duration)
        if duration <= 0:
            raise ValueError(f"duration must be > 0, {duration!r} was given")
        if not (np.all(np.isfinite(x0s)) and np.all(np.isfinite(v0s))):
            raise ValueError("x0s and v0s must be finite")
        if np.any(x0s > impacter.gap):
            raise ValueError(f"x0s must be <= the gap {impacter.gap!r} m")
    else:
        duration = float(duration)     # one kernel specialisation, whatever was passed
    w, a, phi = impacter_forcing(impacter, drive)
    # the grid kernel with one drive, its arguments normalised above (the designer calls
    # this ~10^5 times a design)
    sum_v, _, status = _k.response_grid(
        impacter.omega_n, impacter.sigma, impacter.gap, impacter.restitution, w, a, phi,
        np.array([0, w.size], dtype=np.int64), x0s, v0s, duration,
        2 if stop_at_first else 0, _k.MAX_EVENTS, _k.MAX_STEPS)
    return _responses_from(impacter, sum_v[0], status[0], duration, return_status)


def _responses_from(impacter, sum_v, status, duration, return_status):
    """r = m sum v- / duration [N] of the kernel's runs (eq. 12), with a SolverWarning
    for the caller of :func:`responses` or :func:`sweep` when some run ended on a cap."""
    bad = int(np.count_nonzero(status))
    if bad:
        warnings.warn(f"{bad} of {status.size} runs ended on a cap or non-finite state",
                      SolverWarning, stacklevel=3)
    r = impacter.mass * sum_v / duration
    return (r, status) if return_status else r


def sweep(impacter, frequencies, x0s, power=POWER, duration=3e-3, *, stop_at_first=False,
          return_status=False):
    """r of eq. (12) for one tone at each frequency, from each initial position.

    Parameters
    ----------
    impacter : Impacter
    frequencies : array_like, shape (n_freq,)
        Drive frequencies [Hz]; each tone has Z0^2 w^3 = power.
    x0s : array_like, shape (n_x0,)
        Initial positions [m] (v0 = 0), each <= gap.
    power : float
        Z0^2 w^3 [m^2/s^3], 50 in the paper.
    duration : float
        Window [s].

    Returns
    -------
    r : ndarray, shape (n_freq, n_x0)
        [N].  Runs in parallel over the grid; constants of each frequency are
        computed once.  With ``return_status`` also the status codes.

    Examples
    --------
    Fig. 9 of the paper:

    >>> import numpy as np
    >>> from model import Impacter
    >>> imp = Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6).with_natural_frequency(5200)
    >>> r = sweep(imp, np.arange(4000, 8001, 10.0), [0.0, 1e-6, 2e-6, 3e-6])
    >>> r.shape
    (401, 4)
    """
    check_impacter(impacter)
    f = np.ascontiguousarray(np.atleast_1d(np.asarray(frequencies, dtype=float)))
    x0s = np.ascontiguousarray(np.atleast_1d(np.asarray(x0s, dtype=float)))
    if f.ndim != 1 or not np.all(np.isfinite(f)) or np.any(f <= 0):
        raise ValueError("frequencies must be a one-dimensional array of finite values > 0")
    if not np.all(np.isfinite(x0s)) or np.any(x0s > impacter.gap):
        raise ValueError(f"x0s must be finite and <= the gap {impacter.gap!r} m")
    power = check_float("power", power)
    if power <= 0:
        raise ValueError(f"power must be > 0, {power!r} was given")
    duration = check_float("duration", duration)
    if duration <= 0:
        raise ValueError(f"duration must be > 0, {duration!r} was given")
    w = 2.0 * np.pi * f
    a = math.cos(impacter.impact_angle) * w**2 * amplitude_from_power(f, power)
    sum_v, status = _k.sweep_batch(
        impacter.omega_n, impacter.sigma, impacter.gap, impacter.restitution, w, a, x0s,
        duration, 2 if stop_at_first else 0, _k.MAX_EVENTS, _k.MAX_STEPS)
    return _responses_from(impacter, sum_v, status, duration, return_status)
