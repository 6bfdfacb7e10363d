"""Simulation API: impacts, the response r of eq. (12), sweeps and slider motion.

Public functions validate their arguments, convert the value objects to floats
and arrays in SI units, and call the numba kernels of :mod:`model.kernels`.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from model.devices import Impacter, Slider
from model.drive import POWER, Drive, amplitude_from_power
from model.kernels import contact as _kc
from model.kernels import impacter as _k
from model.kernels.closed_form import tone_coefficients
from model.kernels.rk4 import run_rk4
from model.kernels.slider import run_slider

STATUS = {
    _k.OK: "ok",
    _k.EVENT_CAP: "event cap reached",
    _k.STEP_CAP: "step cap reached",
    _k.NONFINITE: "non-finite state",
}
#: Samples of a trajectory requested with ``trajectory=True``.
TRAJECTORY_SAMPLES = 2001
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


@dataclass(frozen=True)
class SliderResult:
    """Outcome of :func:`simulate_slider`.

    Attributes
    ----------
    t : ndarray or None
        Sample times [s].
    position : ndarray or None
        Slider position zeta at those times [m].
    displacement : float
        zeta(t_end) - zeta(t0) [m].
    mean_velocity : float
        displacement / duration [m/s].
    v_end : float
        Final slider velocity [m/s].
    impacts : ImpactResult
        The impacter run that produced the kicks.
    status : str
    """

    t: np.ndarray | None
    position: np.ndarray | None
    displacement: float
    mean_velocity: float
    v_end: float
    impacts: ImpactResult
    status: str


def _check_float(name, value):
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, {value!r} was given")
    return value


def _check_state(impacter, x0, v0, duration):
    x0 = _check_float("x0", x0)
    v0 = _check_float("v0", v0)
    duration = _check_float("duration", duration)
    if duration <= 0:
        raise ValueError(f"duration must be > 0, {duration!r} was given")
    if x0 > impacter.gap:
        raise ValueError(f"x0 must be <= the gap {impacter.gap!r} m (the wall), {x0!r} was given")
    return x0, v0, duration


def _check_impacter(impacter):
    if not isinstance(impacter, Impacter):
        raise ValueError(f"impacter must be a model.Impacter, {type(impacter).__name__} was given")


def _check_drive(drive):
    if not isinstance(drive, Drive):
        raise ValueError(f"drive must be a model.Drive, {type(drive).__name__} was given")


def impacter_forcing(impacter, drive):
    """Tone arrays (w [rad/s], a [m/s^2], phi [rad]) of the forcing per unit mass, eq. (5)."""
    w = np.ascontiguousarray(drive.omegas)
    a = np.ascontiguousarray(math.cos(impacter.impact_angle) * drive.acceleration_amplitudes())
    return w, a, np.ascontiguousarray(drive.phases, dtype=float)


def _sample_times(trajectory, duration):
    if trajectory is None or trajectory is False:
        return np.empty(0)
    if trajectory is True:
        return np.linspace(0.0, duration, TRAJECTORY_SAMPLES)
    if isinstance(trajectory, (int, np.integer)):
        if trajectory < 2:
            raise ValueError(f"trajectory must be >= 2 samples, {trajectory!r} was given")
        return np.linspace(0.0, duration, int(trajectory))
    t = np.asarray(trajectory, dtype=float)
    if t.ndim != 1 or np.any(np.diff(t) < 0) or not np.all(np.isfinite(t)):
        raise ValueError("trajectory times must be a sorted one-dimensional array of finite times")
    return t


def _message(status, n, duration, t_stop):
    if status == _k.OK:
        return f"{n} impacts in {duration:.6g} s"
    return f"{STATUS[status]} after {n} events at t = {t_stop:.6g} s of {duration:.6g} s"


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
    _check_impacter(impacter)
    _check_drive(drive)
    x0, v0, duration = _check_state(impacter, x0, v0, duration)
    solver = METHODS.get(method, method)
    if not callable(solver):
        raise ValueError(f"method must be one of {sorted(METHODS)} or a callable, {method!r} was given")
    if max_events < 1:
        raise ValueError(f"max_events must be >= 1, {max_events!r} was given")
    sample_t = _sample_times(trajectory, duration)
    return solver(impacter, drive, x0, v0, duration, sample_t=sample_t, step=step,
                  max_events=int(max_events), stuck=stuck)


def _simulate_exact(impacter, drive, x0, v0, duration, *, sample_t, step, max_events, stuck):
    w, a, phi = impacter_forcing(impacter, drive)
    coef = tone_coefficients(impacter.omega_n, impacter.sigma, w, a, phi)
    cap = min(max_events, 100_000)
    imp_t = np.zeros(cap)
    imp_v = np.zeros(cap)
    kinds = np.zeros(cap, dtype=np.int64)
    sample_x = np.zeros(sample_t.size)
    stuck0 = (x0 == impacter.gap and v0 == 0.0) if stuck is None else bool(stuck)
    status, n, sum_v, t_stop, x_end, v_end, stuck_end, steps = _k.run_impacter(
        impacter.omega_n, impacter.sigma, impacter.gap, impacter.restitution,
        w, a, phi, coef, 0.0, duration, x0, v0, stuck0, 0, max_events, _k.MAX_STEPS,
        imp_t, imp_v, kinds, sample_t, sample_x)
    n_rec = min(n, cap)
    kinds = kinds[:n_rec]
    real = kinds == _k.IMPACT
    res = ImpactResult(
        times=imp_t[:n_rec][real], velocities=imp_v[:n_rec][real],
        chatter_times=imp_t[:n_rec][~real], chatter_sums=imp_v[:n_rec][~real],
        response=impacter.mass * sum_v / duration, status=STATUS[status],
        message=_message(status, n, duration, t_stop), x_end=x_end, v_end=v_end,
        stuck_end=bool(stuck_end), n_steps=int(steps),
        t=sample_t if sample_t.size else None, x=sample_x if sample_t.size else None)
    _warn_status(status, res.message)
    return res


def _simulate_rk4(impacter, drive, x0, v0, duration, *, sample_t, step, max_events, stuck):
    w, a, phi = impacter_forcing(impacter, drive)
    if step is None:
        fmax = max(float(np.max(drive.frequencies)), impacter.natural_frequency)
        step = 1.0 / (RK4_STEPS_PER_PERIOD * fmax)
    step = _check_float("step", step)
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
    _warn_status(status, res.message)
    return res


#: Solvers selectable by ``simulate(method=...)``.
METHODS = {"exact": _simulate_exact, "rk4": _simulate_rk4}


def _warn_status(status, message):
    if status != _k.OK:
        warnings.warn(message, SolverWarning, stacklevel=3)


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
    _check_impacter(impacter)
    _check_drive(drive)
    x0, v0, duration = _check_state(impacter, x0, v0, duration)
    w, a, phi = impacter_forcing(impacter, drive)
    status, n, sum_v = _k.response_single(
        impacter.omega_n, impacter.sigma, impacter.gap, impacter.restitution, w, a, phi,
        duration, x0, v0, 2 if stop_at_first else 0, _k.MAX_EVENTS, _k.MAX_STEPS)
    _warn_status(status, _message(status, n, duration, float("nan")))
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
    x0s = np.ascontiguousarray(np.atleast_1d(np.asarray(x0s, dtype=float)))
    v0s = np.zeros_like(x0s) if v0s is None else np.ascontiguousarray(
        np.broadcast_to(np.asarray(v0s, dtype=float), x0s.shape))
    if check_input:
        _check_impacter(impacter)
        _check_drive(drive)
        duration = _check_float("duration", duration)
        if duration <= 0:
            raise ValueError(f"duration must be > 0, {duration!r} was given")
        if not (np.all(np.isfinite(x0s)) and np.all(np.isfinite(v0s))):
            raise ValueError("x0s and v0s must be finite")
        if np.any(x0s > impacter.gap):
            raise ValueError(f"x0s must be <= the gap {impacter.gap!r} m")
    else:
        duration = float(duration)     # one kernel specialisation, whatever was passed
    w, a, phi = impacter_forcing(impacter, drive)
    sum_v, n, status = _k.response_batch(
        impacter.omega_n, impacter.sigma, impacter.gap, impacter.restitution, w, a, phi,
        x0s, v0s, duration, 2 if stop_at_first else 0, _k.MAX_EVENTS, _k.MAX_STEPS)
    bad = int(np.count_nonzero(status))
    if bad:
        warnings.warn(f"{bad} of {status.size} runs ended on a cap or non-finite state",
                      SolverWarning, stacklevel=2)
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
    _check_impacter(impacter)
    f = np.ascontiguousarray(np.atleast_1d(np.asarray(frequencies, dtype=float)))
    x0s = np.ascontiguousarray(np.atleast_1d(np.asarray(x0s, dtype=float)))
    if f.ndim != 1 or not np.all(np.isfinite(f)) or np.any(f <= 0):
        raise ValueError("frequencies must be a one-dimensional array of finite values > 0")
    if not np.all(np.isfinite(x0s)) or np.any(x0s > impacter.gap):
        raise ValueError(f"x0s must be finite and <= the gap {impacter.gap!r} m")
    power = _check_float("power", power)
    if power <= 0:
        raise ValueError(f"power must be > 0, {power!r} was given")
    duration = _check_float("duration", duration)
    if duration <= 0:
        raise ValueError(f"duration must be > 0, {duration!r} was given")
    w = 2.0 * np.pi * f
    a = math.cos(impacter.impact_angle) * w**2 * amplitude_from_power(f, power)
    sum_v, status = _k.sweep_batch(
        impacter.omega_n, impacter.sigma, impacter.gap, impacter.restitution, w, a, x0s,
        duration, 2 if stop_at_first else 0, _k.MAX_EVENTS, _k.MAX_STEPS)
    bad = int(np.count_nonzero(status))
    if bad:
        warnings.warn(f"{bad} of {status.size} runs ended on a cap or non-finite state",
                      SolverWarning, stacklevel=2)
    r = impacter.mass * sum_v / duration
    return (r, status) if return_status else r


#: Contact laws selectable by ``contact=`` in :func:`kick`, :func:`slider_motion` and
#: :func:`simulate_slider`: the slider's velocity change at an impact (docs/contact.md).
#: "paper": eq. (10) as printed, the slider as a wall that does not recoil (the
#: small-m/M limit; it creates energy for 2 (m/M) cos^2(theta) > (1 - e)/(1 + e)).
#: "two_body": the pair and the slider as a two-body collision along the impacter
#: axis, restitution on their relative velocity, with the slider's velocity at the
#: instant of the impact; it never creates energy and tends to eq. (10) as m/M -> 0.
CONTACTS = {"paper": _kc.PAPER, "two_body": _kc.TWO_BODY}


def _check_contact(contact):
    """The kernel code of a contact-law name, or a ValueError naming the allowed ones."""
    if not isinstance(contact, str) or contact not in CONTACTS:
        raise ValueError(f"contact must be one of {sorted(CONTACTS)}, {contact!r} was given")
    return CONTACTS[contact]


def _check_slider(slider):
    if not isinstance(slider, Slider):
        raise ValueError(f"slider must be a model.Slider, {type(slider).__name__} was given")


def _check_direction(direction, contact="paper"):
    """direction as a float; the two-body law reads it as a sign, so it must be +1 or -1."""
    direction = _check_float("direction", direction)
    if contact != "paper" and direction not in (1.0, -1.0):
        raise ValueError(f"direction must be +1 or -1 with contact={contact!r}, "
                         f"{direction!r} was given")
    return direction


@dataclass(frozen=True)
class Kicks:
    """The impacts that kick one slider, with what each contact law needs per kick.

    Build it with :meth:`from_impacts` (one impacter pair) and join pairs with
    :meth:`concatenate`; pass it to :func:`slider_motion` with either contact law.

    Attributes
    ----------
    times : ndarray, shape (n,)
        Impact times [s] (a chatter tail: its accumulation time).
    velocities : ndarray, shape (n,)
        Impacter velocity v- along its axis just before each impact [m/s]; for a
        chatter tail, the sum of the tail's v- (as ``ImpactResult.chatter_sums``).
    chatter : ndarray of bool, shape (n,)
        Whether the kick is a chatter tail: the geometric sequence
        v-_{k+1} = e v-_k summed in closed form by the impacter solver.
    direction : ndarray, shape (n,)
        +1 where the pair pushes zeta up, -1 where down.
    mass_ratio : ndarray, shape (n,)
        m/M, one impacter's mass over the slider's [-].
    impact_angle : ndarray, shape (n,)
        theta [rad].
    restitution : ndarray, shape (n,)
        e [-].
    velocity_changes : ndarray, shape (n,)
        The kicks of eq. (10), exactly as :func:`kick` with contact="paper" gives
        them [m/s].
    slider_mass : float
        M of the slider the kicks were built for [kg].
    """

    times: np.ndarray
    velocities: np.ndarray
    chatter: np.ndarray
    direction: np.ndarray
    mass_ratio: np.ndarray
    impact_angle: np.ndarray
    restitution: np.ndarray
    velocity_changes: np.ndarray
    slider_mass: float

    @classmethod
    def from_impacts(cls, impacter, slider, impacts, direction=1.0, share=1.0):
        """Kicks of every impact of ``impacts`` (chatter tails included) on ``slider``.

        Parameters
        ----------
        impacter : Impacter
            The impacter that produced ``impacts`` (one of its pair).
        slider : Slider
        impacts : ImpactResult
            From :func:`simulate`.
        direction : float
            +1 for the forward pair, -1 for the backward pair.
        share : float
            The fraction of the pair that strikes: 1 for the symmetric pair (both
            cantilevers together, eq. (10)'s factor 2), 1/2 for one half of a
            :class:`PairHalves` striking alone.  The kicks' mass ratio is scaled by it.

        Examples
        --------
        >>> from model import Impacter, Slider, Drive, simulate
        >>> imp = Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6).with_natural_frequency(5200)
        >>> sl = Slider.from_geometry(8.0e-8)
        >>> kicks = Kicks.from_impacts(imp, sl, simulate(imp, Drive.tone(6200.0)))
        >>> kicks.times.size
        17
        """
        _check_impacter(impacter)
        _check_slider(slider)
        if not isinstance(impacts, ImpactResult):
            raise ValueError(f"impacts must be a model.ImpactResult, {type(impacts).__name__} "
                             "was given")
        direction = _check_direction(direction)
        share = float(share)
        if not 0.0 < share <= 1.0:
            raise ValueError(f"share must be in (0, 1], {share!r} was given")
        times = np.concatenate([impacts.times, impacts.chatter_times])
        speeds = np.concatenate([impacts.velocities, impacts.chatter_sums])
        n = times.size
        chatter = np.zeros(n, dtype=bool)
        chatter[impacts.times.size:] = True
        dv = kick(impacter, slider, speeds, direction)
        return cls(times=times, velocities=speeds, chatter=chatter,
                   direction=np.full(n, direction),
                   mass_ratio=np.full(n, share * impacter.mass / slider.mass),
                   impact_angle=np.full(n, impacter.impact_angle),
                   restitution=np.full(n, impacter.restitution),
                   velocity_changes=dv if share == 1.0 else share * dv,
                   slider_mass=slider.mass)

    @classmethod
    def concatenate(cls, kicks):
        """One record of the kicks of several pairs on the same slider (in the given order)."""
        kicks = list(kicks)
        if not kicks or not all(isinstance(k, Kicks) for k in kicks):
            raise ValueError("kicks must be a non-empty sequence of model.Kicks")
        masses = {k.slider_mass for k in kicks}
        if len(masses) != 1:
            raise ValueError(f"kicks were built for sliders of different masses {sorted(masses)}")
        cat = {name: np.concatenate([getattr(k, name) for k in kicks])
               for name in ("times", "velocities", "chatter", "direction", "mass_ratio",
                            "impact_angle", "restitution", "velocity_changes")}
        return cls(slider_mass=kicks[0].slider_mass, **cat)

    def record(self):
        """The per-kick record of the two-body kernel, shape (n, N_COLS) (model.kernels.contact)."""
        rec = np.empty((self.times.size, _kc.N_COLS))
        cos = np.cos(self.impact_angle)
        rec[:, _kc.COL_SPEED] = self.velocities
        rec[:, _kc.COL_SIGN] = self.direction
        rec[:, _kc.COL_GAIN] = 2.0 * self.mass_ratio * cos
        rec[:, _kc.COL_COS] = cos
        rec[:, _kc.COL_E] = self.restitution
        rec[:, _kc.COL_TAIL] = self.chatter
        return rec


def kick(impacter, slider, velocities, direction=1.0, *, contact="paper", slider_velocity=0.0):
    """Slider velocity change of each impact of the pair [m/s].

    Parameters
    ----------
    impacter : Impacter
        One impacter of the pair (both hit together, eq. 9).
    slider : Slider
    velocities : array_like
        Impacter velocity v- along its axis just before each impact [m/s].
    direction : float
        +1 for the forward pair, -1 for the backward pair.
    contact : {"paper", "two_body"}
        "paper": eq. (10), 2 (m/M)(1+e) v- cos(theta), whatever the slider does.
        "two_body": each impact alone as a two-body collision (docs/contact.md)
        with the slider moving at ``slider_velocity`` just before it.
    slider_velocity : float or array_like
        V- along zeta [m/s], broadcast against ``velocities``; only "two_body"
        reads it.

    Returns
    -------
    ndarray
        V+ - V- [m/s].

    Notes
    -----
    With "two_body", u = v- - s V- cos(theta) (s = direction) and q = 2 (m/M) cos^2(theta):
    dV = s (1+e) 2 (m/M) cos(theta) u / (1 + q) if u > 0, else 0.  Chatter tails
    (sums of v-) are not single impacts: :func:`slider_motion` with a :class:`Kicks`
    record applies them impact by impact.

    Examples
    --------
    >>> from model import Impacter, Slider
    >>> imp = Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6)
    >>> sl = Slider.from_geometry(8.0e-8)
    >>> paper = kick(imp, sl, 0.1)
    >>> two = kick(imp, sl, 0.1, contact="two_body")
    >>> round(float(two / paper), 4)          # 1 / (1 + 2 (m/M) cos^2(theta))
    0.6886
    """
    code = _check_contact(contact)
    if code == _kc.PAPER:
        return (direction * 2.0 * impacter.mass / slider.mass * (1.0 + impacter.restitution)
                * math.cos(impacter.impact_angle) * np.asarray(velocities, dtype=float))
    direction = _check_direction(direction, contact)
    v, V = np.broadcast_arrays(np.asarray(velocities, dtype=float),
                               np.asarray(slider_velocity, dtype=float))
    c = math.cos(impacter.impact_angle)
    g = 2.0 * impacter.mass / slider.mass * c
    out = np.empty(v.shape)
    for i in np.ndindex(v.shape):
        out[i] = _kc.two_body_impact(float(V[i]), float(v[i]), direction, g, c,
                                     impacter.restitution)[0]
    return out if out.ndim else out[()]


def slider_motion(slider, drive, kick_times, kick_dv=None, duration=None, z0=0.0, v0=0.0,
                  trajectory=None, *, contact="paper"):
    """Slider motion under the drive and given kicks (eqs. 6, 7 and a contact law).

    Parameters
    ----------
    slider : Slider
    drive : Drive
        The slider feels M (-zeta'').
    kick_times : array_like, shape (n,), or Kicks
        Kick times [s] with ``kick_dv``; or a :class:`Kicks` record (then
        ``kick_dv`` is None), which either contact law can use.
    kick_dv : array_like, shape (n,), optional
        Velocity changes [m/s], e.g. from :func:`kick` (contact="paper" only:
        the two-body kick depends on the slider's velocity at the impact, which
        only this simulation knows).
    duration : float
        [s].  Required.
    z0, v0 : float
        Initial position [m] and velocity [m/s].
    trajectory : bool, int or array_like, optional
        As in :func:`simulate`.
    contact : {"paper", "two_body"}
        Contact law, see :data:`CONTACTS` and docs/contact.md.

    Returns
    -------
    t, position, z_end, v_end, status

    Examples
    --------
    >>> from model import Impacter, Slider, Drive, simulate
    >>> imp = Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6).with_natural_frequency(5200)
    >>> sl, drive = Slider.from_geometry(8.0e-8), Drive.tone(6200.0)
    >>> kicks = Kicks.from_impacts(imp, sl, simulate(imp, drive))
    >>> _, _, z_paper, _, _ = slider_motion(sl, drive, kicks, duration=3e-3)
    >>> _, _, z_two, _, _ = slider_motion(sl, drive, kicks, duration=3e-3, contact="two_body")
    >>> bool(0 < z_two < z_paper)
    True
    """
    code = _check_contact(contact)
    _check_slider(slider)
    _check_drive(drive)
    if duration is None:
        raise ValueError("duration must be given")
    if isinstance(kick_times, Kicks):
        if kick_dv is not None:
            raise ValueError("kick_dv must be None when kick_times is a model.Kicks record "
                             "(the record carries the kicks)")
        if kick_times.slider_mass != slider.mass:
            raise ValueError(f"the kicks were built for a slider of mass {kick_times.slider_mass!r} "
                             f"kg, slider has mass {slider.mass!r} kg")
        kt = kick_times.times
        kd = kick_times.velocity_changes
        if code == _kc.TWO_BODY:
            if not np.all(np.abs(kick_times.direction) == 1.0):
                raise ValueError(f"contact={contact!r} needs every kick's direction to be +1 or -1")
            rec = kick_times.record()
        else:
            rec = np.empty((kt.size, _kc.N_COLS))
    else:
        if code != _kc.PAPER:
            raise ValueError(f"contact={contact!r} computes each kick from the impacter's v- and "
                             "the slider's velocity at the impact: pass a model.Kicks record "
                             "(Kicks.from_impacts) as kick_times instead of velocity changes")
        if kick_dv is None:
            raise ValueError("kick_dv must be given with kick times (or pass a model.Kicks record)")
        kt = np.asarray(kick_times, dtype=float)
        kd = np.asarray(kick_dv, dtype=float)
        rec = np.empty((kt.size, _kc.N_COLS))
    order = np.argsort(kt, kind="stable")
    kt = np.ascontiguousarray(kt[order])
    kd = np.ascontiguousarray(kd[order])
    rec = np.ascontiguousarray(rec[order])
    sample_t = _sample_times(trajectory, duration)
    sample_z = np.zeros(sample_t.size)
    status, z_end, v_end, _ = run_slider(
        code, slider.damping / slider.mass, slider.static_friction / slider.mass,
        slider.dynamic_friction / slider.mass, np.ascontiguousarray(drive.omegas),
        np.ascontiguousarray(drive.acceleration_amplitudes()),
        np.ascontiguousarray(drive.phases, dtype=float), kt, kd, rec, 0.0, float(duration),
        float(z0), float(v0), _k.MAX_STEPS, sample_t, sample_z)
    _warn_status(status, f"slider: {STATUS[status]}")
    return (sample_t if sample_t.size else None, sample_z if sample_t.size else None,
            z_end, v_end, STATUS[status])


def simulate_slider(impacter, slider, drive, x0=0.0, v0=0.0, duration=3e-3, *,
                    direction=1.0, trajectory=None, method="exact", contact="paper"):
    """Slider motion driven by one impacter pair (eqs. 1-10).

    The impacter runs first (its dynamics do not depend on the slider: the wall
    moves along its own axis, and the tip rebounds at -e v-, eq. 8); every impact,
    the first included, kicks the slider by the contact law; the slider's
    stick-slip motion between kicks is then solved exactly.

    Parameters
    ----------
    impacter : Impacter
    slider : Slider
    drive : Drive
    x0, v0 : float
        Initial impacter state [m, m/s].
    duration : float
        [s].
    direction : float
        +1 for the forward pair (kicks push zeta up), -1 for the backward pair.
    trajectory : bool, int or array_like, optional
        Slider (and impacter) positions at sample times.
    method : {"exact", "rk4"} or callable
        Impacter solver, as in :func:`simulate`.
    contact : {"paper", "two_body"}
        Contact law (:data:`CONTACTS`, docs/contact.md): "paper" is eq. (10) as
        printed (it creates energy for m/M above about 1/3); "two_body" kicks by a
        two-body collision with the slider's velocity at each impact.

    Returns
    -------
    SliderResult

    Examples
    --------
    >>> from model import Impacter, Slider, Drive
    >>> imp = Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6).with_natural_frequency(5200)
    >>> sl = Slider.from_geometry(8.0e-8)
    >>> res = simulate_slider(imp, sl, Drive.tone(6200.0))
    >>> res.displacement > 0
    True
    >>> round(res.mean_velocity * 1e3, 2)     # [mm/s]
    3.4
    >>> two = simulate_slider(imp, sl, Drive.tone(6200.0), contact="two_body")
    >>> round(two.mean_velocity * 1e3, 2)
    1.62
    """
    _check_contact(contact)
    _check_slider(slider)
    direction = _check_direction(direction, contact)
    imp = simulate(impacter, drive, x0, v0, duration, trajectory=trajectory, method=method)
    kicks = Kicks.from_impacts(impacter, slider, imp, direction)
    t, pos, z_end, v_end, status = slider_motion(slider, drive, kicks, duration=duration,
                                                 trajectory=imp.t if imp.t is not None else None,
                                                 contact=contact)
    if imp.status != "ok":
        status = imp.status
    return SliderResult(t=t, position=pos, displacement=z_end, mean_velocity=z_end / duration,
                        v_end=v_end, impacts=imp, status=status)
