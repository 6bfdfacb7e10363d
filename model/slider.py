"""The slider API: kicks of impacter pairs, the contact laws, and the slider's motion.

The slider's stick-slip motion between kicks (eqs. 6-7) is solved exactly by the kernel
:func:`model.kernels.slider.run_slider`; the kicks come from the impacts of
:mod:`model.impacter` through a contact law of :mod:`model.kernels.contact`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from model._arguments import check_drive, check_float, check_impacter, check_slider, sample_times
from model.impacter import STATUS, ImpactResult, simulate, warn_status
from model.kernels import contact as _kc
from model.kernels import impacter as _k
from model.kernels.slider import run_slider


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



def _check_direction(direction, contact="paper"):
    """direction as a float; the two-body law reads it as a sign, so it must be +1 or -1."""
    direction = check_float("direction", direction)
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
        check_impacter(impacter)
        check_slider(slider)
        if not isinstance(impacts, ImpactResult):
            raise ValueError(f"impacts must be a model.ImpactResult, {type(impacts).__name__} "
                             "was given")
        direction = _check_direction(direction)
        share = float(share)
        if not 0.0 < share <= 1.0:
            raise ValueError(f"share must be in (0, 1], {share!r} was given")
        if not impacts.times.size and not impacts.chatter_times.size:
            # no impact (an idle impacter's usual run): the record of no kick
            return cls(times=np.empty(0), velocities=np.empty(0),
                       chatter=np.zeros(0, dtype=bool), direction=np.empty(0),
                       mass_ratio=np.empty(0), impact_angle=np.empty(0),
                       restitution=np.empty(0), velocity_changes=np.empty(0),
                       slider_mass=slider.mass)
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
        # records without a kick add nothing; one record left is the concatenation
        # (itself: its arrays are never written, and a copy would hold their very values)
        live = [k for k in kicks if k.times.size]
        if len(live) <= 1:
            return live[0] if live else kicks[0]
        kicks = live
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
    check_slider(slider)
    check_drive(drive)
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
            if not (np.abs(kick_times.direction) == 1.0).all():
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
    sample_t = sample_times(trajectory, duration)
    sample_z = np.zeros(sample_t.size)
    w = np.ascontiguousarray(drive.omegas)
    a = np.ascontiguousarray(drive.acceleration_amplitudes())
    phi = np.ascontiguousarray(drive.phases, dtype=float)
    status, z_end, v_end, _ = run_slider(
        code, slider.damping / slider.mass, slider.static_friction / slider.mass,
        slider.dynamic_friction / slider.mass, w, a, phi, kt, kd, rec, 0.0, float(duration),
        float(z0), float(v0), _k.MAX_STEPS, sample_t, sample_z,
        _peak_bound(w, a, phi, float(duration)))
    warn_status(status, f"slider: {STATUS[status]}")
    return (sample_t if sample_t.size else None, sample_z if sample_t.size else None,
            z_end, v_end, STATUS[status])


#: Most sample points of :func:`forcing_peak_bound`'s grid: a window that would need
#: more gets the plain bound sum |a_i| (0 returned).
PEAK_BOUND_POINTS = 20000
#: The grid's share of the bound: samples h apart miss the peak by at most
#: M2 h^2 / 8, held to this fraction of sum |a_i| [-].
PEAK_BOUND_SLACK = 0.01
_peak_bounds: dict = {}
_EPS = float(np.finfo(float).eps)


def forcing_peak_bound(drive, duration):
    """An upper bound of the slider's inertial forcing |sum a_i cos(w_i t + phi_i)|
    (per unit mass, a_i = w_i^2 Z_i) over [0, duration] [m/s^2].

    The largest sample of a grid h apart, plus M2 h^2 / 8 (M2 = sum a_i w_i^2 bounds
    |f''|: within h / 2 of its peak, where f' = 0, some sample is at most that lower),
    plus the samples' rounding: never below the true peak.  A summed drive whose tones
    were phased for a low crest factor peaks well under sum |a_i|, which is all the
    kernel knows by itself; below the slider's static friction, a stuck slider then
    stays stuck between kicks without being stepped through
    (:func:`model.kernels.slider.run_slider`'s ``f_bound``).  One tone: exactly |a|.
    0 (no bound) when the grid would exceed :data:`PEAK_BOUND_POINTS`.  Kept per drive
    and duration (the checks of a step run every device with one drive).
    """
    return _peak_bound(np.asarray(drive.omegas, dtype=float),
                       np.asarray(drive.acceleration_amplitudes(), dtype=float),
                       np.asarray(drive.phases, dtype=float), float(duration))


def _peak_bound(w, a, phi, duration):
    """:func:`forcing_peak_bound` of the forcing's arrays [rad/s, m/s^2, rad]."""
    if w.size <= 1:
        return float(np.abs(a).sum())
    key = (w.tobytes(), a.tobytes(), phi.tobytes(), duration)
    hit = _peak_bounds.get(key)
    if hit is not None:
        return hit
    fmax = float(np.sum(np.abs(a)))
    if duration <= 0.0 or fmax == 0.0:
        return fmax
    m2 = float(np.sum(np.abs(a) * w * w))
    h = math.sqrt(8.0 * PEAK_BOUND_SLACK * fmax / m2)
    n = int(math.ceil(duration / h)) + 1
    if n > PEAK_BOUND_POINTS:
        bound = 0.0
    else:
        t = np.linspace(0.0, duration, n)
        h = duration / (n - 1)
        f = np.cos(np.outer(t, w) + phi) @ a
        bound = min(fmax, float(np.max(np.abs(f))) + m2 * h * h / 8.0
                    + 8.0 * (w.size + 1) * _EPS * fmax)
    if len(_peak_bounds) > 256:
        _peak_bounds.clear()
    _peak_bounds[key] = bound
    return bound


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
    check_slider(slider)
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
