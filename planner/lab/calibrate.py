"""Measured natural frequencies and quality factors from a lab's frequency sweep.

A fabricated impacter's natural frequency differs from its design by a few
percent (the paper's Section V), and the planner's drive tones need the as-built
value.  A lab measures each impacter's vibration amplitude relative to the die
(fibre-optic sensor, laser vibrometer or a camera, as in the paper's Section IV)
while it sweeps the drive frequency with an amplitude small enough that the
impacter never reaches its slider.  In that linear regime eq. (1) with the
forcing of eq. (5) has the steady amplitude

    |X|(w) = Z cos(theta) w^2 / sqrt((wn^2 - w^2)^2 + (wn w / Q)^2),

and this module fits wn = 2 pi nu_n and Q (and the overall scale) to each
impacter's sweep, with standard errors, and says plainly when a sweep cannot
pin them down.

The functions take and return SI units; :func:`read_sweep` converts the lab's
micrometres once, at the file boundary.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import pandas as pd
from scipy.optimize import least_squares

from model.devices import MIN_FREQUENCY
from planner.lab.csv_files import csv_number, read_csv_rows, row_values
from planner.core.units import UM

#: Columns of a sweep file: required, then optional.
SWEEP_COLUMNS = ("impacter", "frequency_hz", "amplitude_um")
SWEEP_OPTIONAL = ("drive_amplitude_um", "half")
#: The halves of a pair in a sweep's (and measured.csv's) ``half`` column: one cantilever
#: of the pair each; blank for a pair measured as a whole.
HALVES = ("a", "b")

#: Columns of the measured file, in order.  ``vibroplan replan --measured`` reads
#: ``impacter, natural_frequency_hz`` and optionally ``quality_factor``; the std
#: columns are extra.
MEASURED_COLUMNS = ("impacter", "natural_frequency_hz", "quality_factor",
                    "natural_frequency_std_hz", "quality_factor_std")

#: Fewest distinct frequencies per impacter: three parameters are fitted, and two
#: more points are the least that leave a residual to estimate the noise from.
MIN_POINTS = 5

#: Fewest measured frequencies inside the half-power band nu_n (1 +- 1/(2Q)): with
#: fewer the peak's width (hence Q) rests on the flanks' shape alone, and a
#: coarse sweep can step right over a sharp peak.
MIN_PEAK_POINTS = 3

#: Largest relative standard error of Q accepted [-]; beyond it Q is not
#: determined by the data (e.g. a peak sharper than the frequency spacing).
MAX_Q_REL_STD = 0.25

#: Largest relative standard error of nu_n accepted [-].
MAX_NU_REL_STD = 0.01

#: Largest rms of the log-amplitude residual accepted [-] (about 10 % scatter):
#: more means the linear resonance does not describe the data (impacts, a second
#: mode, a drifting drive), whatever the parameters' formal errors say.
MAX_RESIDUAL_RMS = 0.10

#: Lowest z-score accepted for the number of runs of equal residual sign along the
#: sweep (Wald-Wolfowitz): independent noise gives z ~ N(0, 1), so below -3.5
#: (about 2e-4 by chance) the misfit is systematic: a peak clipped by impacts,
#: bent by them (hardening), or a second mode, however small the scatter.
MIN_RUNS_Z = -3.5
#: Below this residual rms [-] the fit matches to better than any instrument reads,
#: and residual signs are rounding noise: the runs test is skipped.
RUNS_MIN_RMS = 1e-6

#: Q is searched in [Q_MIN, Q_MAX]; a fit that ends on a bound has no finite Q.
Q_MIN = 0.5
Q_MAX = 1e6

#: Statuses of :class:`ResonanceFit`, the most severe first.
STATUSES = ("fit_failed", "peak_outside_sweep", "peak_unresolved", "q_unbounded",
            "poor_fit", "ok")


@dataclass(frozen=True)
class ResonanceFit:
    """One impacter's fitted linear resonance.

    Attributes
    ----------
    natural_frequency_hz : float
        Undamped natural frequency nu_n = wn / (2 pi) [Hz] (NaN if the fit failed).
    quality_factor : float
        Q = m wn / b [-].
    natural_frequency_std_hz : float
        Standard error of nu_n [Hz], from the Jacobian scaled by the residual variance.
    quality_factor_std : float
        Standard error of Q [-].
    scale : float
        The amplitude far above resonance: Z cos(theta) [m] when no drive amplitude
        was given (constant drive assumed), cos(theta) [-] when it was.
    scale_std : float
        Standard error of ``scale`` (same unit).
    residual_rms : float
        Rms of log(measured / fitted amplitude) [-], about the relative scatter.
    n_points : int
        Measurements used (positive amplitudes).
    n_peak_points : int
        Of those, how many lie in the half-power band nu_n (1 +- 1/(2Q)).
    status : str
        "ok", or the most severe problem: "fit_failed", "peak_outside_sweep",
        "peak_unresolved", "q_unbounded" or "poor_fit".
    message : str
        Every problem found, in words, with what to measure to fix it.
    """

    natural_frequency_hz: float
    quality_factor: float
    natural_frequency_std_hz: float
    quality_factor_std: float
    scale: float
    scale_std: float
    residual_rms: float
    n_points: int
    n_peak_points: int
    status: str
    message: str

    @property
    def ok(self) -> bool:
        """Whether the fit is usable as it stands."""
        return self.status == "ok"


def transmissibility(frequency_hz, natural_frequency_hz, quality_factor):
    """|X| / (Z cos theta) of the base-excited oscillator, eqs. (1) and (5) [-].

    Parameters
    ----------
    frequency_hz : array_like
        Drive frequency nu [Hz].
    natural_frequency_hz : float
        nu_n [Hz].
    quality_factor : float
        Q [-].

    Returns
    -------
    ndarray
        u^2 / sqrt((1 - u^2)^2 + (u / Q)^2) with u = nu / nu_n: 1 far above
        resonance, about Q at it.

    Notes
    -----
    m x'' + b x' + k x = m w^2 Z cos(theta) cos(w t) (eqs. 1, 5) has the steady
    amplitude Z cos(theta) w^2 / sqrt((wn^2 - w^2)^2 + (wn w / Q)^2), Q = m wn / b;
    dividing through by wn^2 gives this form.

    Examples
    --------
    >>> round(float(transmissibility(1000.0, 1000.0, 30.0)), 6)
    30.0
    """
    u = np.asarray(frequency_hz, dtype=float) / natural_frequency_hz
    return u**2 / np.sqrt((1.0 - u**2) ** 2 + (u / quality_factor) ** 2)


def _initial_guess(f, y):
    """(nu_n, Q) from the peak and its half-power width, on a log-amplitude sweep."""
    i = int(np.argmax(y))
    f_pk = f[i]
    half = y[i] - 0.5 * math.log(2.0)   # the half-power level, in log amplitude

    def crossing(indices):
        # first point past the peak that falls below the half-power level,
        # interpolated linearly in log amplitude
        prev = i
        for j in indices:
            if y[j] <= half:
                return f[prev] + (half - y[prev]) * (f[j] - f[prev]) / (y[j] - y[prev])
            prev = j
        return None

    lo = crossing(range(i - 1, -1, -1))
    hi = crossing(range(i + 1, f.size))
    if lo is not None and hi is not None:
        width = hi - lo
    elif lo is not None or hi is not None:
        width = 2.0 * abs((hi if hi is not None else lo) - f_pk)
    else:
        width = f.max() - f.min()
    q0 = float(np.clip(f_pk / max(width, 1e-12 * f_pk), 1.0, 1e4))
    return f_pk, q0


def _log_model(p, f):
    """log amplitude for p = (log nu_n, log Q, log scale)."""
    nu, q = math.exp(p[0]), math.exp(p[1])
    u2 = (f / nu) ** 2
    return p[2] + np.log(u2) - 0.5 * np.log((1.0 - u2) ** 2 + u2 / q**2)


def fit_resonance(frequency_hz, amplitude_m, drive_amplitude_m=None) -> ResonanceFit:
    """Fit nu_n and Q of one impacter to its linear-regime frequency sweep.

    Parameters
    ----------
    frequency_hz : array_like, shape (n,)
        Drive frequencies [Hz], finite and > 0.
    amplitude_m : array_like, shape (n,)
        The impacter's steady vibration amplitude relative to the die (half the
        peak-to-peak) [m], finite and >= 0.  Zeros (below the instrument's floor)
        carry no log and are left out.
    drive_amplitude_m : array_like, shape (n,), optional
        The die's (substrate's) vibration amplitude Z at each frequency [m], > 0.
        If given the fit is to |X| / Z and ``scale`` estimates cos(theta); if not,
        the drive amplitude is assumed the same at every frequency and
        ``scale`` = Z cos(theta) [m] is fitted.

    Returns
    -------
    ResonanceFit
        With ``status`` "ok" or the most severe problem; a fit that cannot be
        trusted says so, it does not return silent nonsense.

    Raises
    ------
    ValueError
        Naming the argument, if the arrays are not one-dimensional, of equal
        length, finite, and in range.

    Notes
    -----
    The model is |X| = s u^2 / sqrt((1 - u^2)^2 + (u / Q)^2), u = nu / nu_n
    (:func:`transmissibility`, from eqs. 1 and 5), fitted by least squares on
    log amplitude (so every point weighs by its relative error, the usual case
    for a vibrometer or a camera) in log parameters (so nu_n, Q and s stay
    positive).  Standard errors come from the Jacobian, cov = (J^T J)^-1 times the
    residual variance, and are carried to nu_n and Q by the delta method.  The
    starting point is the peak's frequency and its half-power width (Q = nu / width),
    with a few other Q tried so a poor first guess does not end in a local minimum.

    Examples
    --------
    >>> f = np.linspace(900.0, 1100.0, 41)
    >>> fit = fit_resonance(f, 1e-8 * transmissibility(f, 1000.0, 40.0))
    >>> fit.status, round(fit.natural_frequency_hz, 3), round(fit.quality_factor, 3)
    ('ok', 1000.0, 40.0)
    """
    f, a = _checked(frequency_hz, amplitude_m, drive_amplitude_m)
    problems = []
    used = a > 0
    if not np.all(used):
        problems.append(f"{int(np.sum(~used))} zero amplitudes left out")
    f, y = f[used], np.log(a[used])
    order = np.argsort(f, kind="stable")
    f, y = f[order], y[order]
    n = f.size
    if np.unique(f).size < MIN_POINTS:
        return _failed(n, f"{np.unique(f).size} distinct frequencies with a positive "
                          f"amplitude; the fit needs at least {MIN_POINTS}")
    best = _least_squares(f, y)
    if best is None:
        return _failed(n, "the least-squares fit did not converge")

    est = _estimate(f, best)
    status = _judge(f, y, best.fun, est, problems)
    worst = min(status, key=STATUSES.index) if status else "ok"
    message = "; ".join(problems) if problems else f"fitted {n} points"
    return ResonanceFit(est.nu, est.q, est.nu_std, est.q_std, est.s, est.s_std,
                        est.residual_rms, n, est.n_peak, worst, message)


def _checked(frequency_hz, amplitude_m, drive_amplitude_m):
    """(frequencies [Hz], amplitudes [m], or relative to the drive [-]) as float arrays,
    checked as :func:`fit_resonance` says (ValueError naming the argument)."""
    f = _array("frequency_hz", frequency_hz)
    a = _array("amplitude_m", amplitude_m)
    if a.shape != f.shape:
        raise ValueError(f"amplitude_m must have the length of frequency_hz ({f.size}), "
                         f"{a.size} was given")
    if np.any(f <= 0):
        raise ValueError(f"frequency_hz must be > 0, {f[f <= 0].tolist()!r} was given")
    if np.any(a < 0):
        raise ValueError(f"amplitude_m must be >= 0, {a[a < 0].tolist()!r} was given")
    if drive_amplitude_m is not None:
        z = _array("drive_amplitude_m", drive_amplitude_m)
        if z.shape != f.shape:
            raise ValueError(f"drive_amplitude_m must have the length of frequency_hz "
                             f"({f.size}), {z.size} was given")
        if np.any(z <= 0):
            raise ValueError(f"drive_amplitude_m must be > 0, {z[z <= 0].tolist()!r} was given")
        a = a / z
    return f, a


def _least_squares(f, y):
    """The best least-squares fit of :func:`_log_model` to log amplitudes ``y`` at the
    sorted frequencies ``f`` [Hz], from the peak's guess and Q three times higher and
    lower (scipy's ``OptimizeResult``), or None if no start converged."""
    nu0, q0 = _initial_guess(f, y)
    best = None
    for q_start in (q0, q0 * 3.0, q0 / 3.0):
        q_start = float(np.clip(q_start, Q_MIN * 2, Q_MAX / 2))
        p0 = np.array([math.log(nu0), math.log(q_start), 0.0])
        p0[2] = float(np.mean(y - _log_model(p0, f)))   # the scale is linear in log
        # nu_n may lie outside the sweep (then it is flagged), but not absurdly far
        lo = [math.log(f[0] / 10.0), math.log(Q_MIN), -np.inf]
        hi = [math.log(f[-1] * 10.0), math.log(Q_MAX), np.inf]
        try:
            sol = least_squares(lambda p: _log_model(p, f) - y, p0, bounds=(lo, hi),
                                x_scale=[1e-3, 1e-1, 1e-1], method="trf")
        except ValueError:   # the model is not finite at this start: try the next
            continue
        if sol.success and np.all(np.isfinite(sol.fun)) and (best is None or sol.cost < best.cost):
            best = sol
    return best


@dataclass(frozen=True)
class _Estimate:
    """What a least-squares solution says: nu_n [Hz], Q [-], the scale s and their
    standard errors, the residual rms [-], the points in the half-power band, whether
    Q ended on its search bound and whether the data leave nu_n and Q undetermined
    (J^T J singular, or Q on the bound)."""

    nu: float
    q: float
    s: float
    nu_std: float
    q_std: float
    s_std: float
    residual_rms: float
    n_peak: int
    q_bound: bool
    undetermined: bool


def _estimate(f, best) -> _Estimate:
    """The parameters of the solution ``best`` on the frequencies ``f`` [Hz], with
    their standard errors (the Jacobian's, scaled by the residual variance)."""
    p = best.x
    nu, q, s = (math.exp(v) for v in p)
    dof = f.size - p.size
    residual_rms = float(np.sqrt(np.mean(best.fun**2)))
    variance = float(2.0 * best.cost / dof) if dof > 0 else math.nan
    std_log, singular = _parameter_std(best.jac, variance)
    nu_std, q_std, s_std = (float(v * e) for v, e in zip((nu, q, s), std_log))
    half_band = nu / (2.0 * q)
    n_peak = int(np.sum(np.abs(f - nu) <= half_band))
    q_bound = p[1] >= math.log(Q_MAX) - 1e-6 or p[1] <= math.log(Q_MIN) + 1e-6
    return _Estimate(nu, q, s, nu_std, q_std, s_std, residual_rms, n_peak, q_bound,
                     singular or q_bound)


def _judge(f, y, residuals, est: _Estimate, problems) -> list:
    """The problems of a fit (:data:`STATUSES` but ``ok`` and ``fit_failed``), in the
    order they are checked; each is also said in words, with what to measure to fix
    it, on ``problems``."""
    nu, q, nu_std, q_std = est.nu, est.q, est.nu_std, est.q_std
    residual_rms, n = est.residual_rms, f.size
    half_band = nu / (2.0 * q)
    status = []
    i_max = int(np.argmax(y))
    # the largest amplitude on the sweep's first or last point means the peak may lie
    # beyond it, whatever the fitted nu_n says
    if not (f[0] < nu < f[-1]) or i_max in (0, n - 1):
        low = nu <= f[0] or (f[0] < nu < f[-1] and i_max == 0)
        status.append("peak_outside_sweep")
        problems.append(f"the resonance lies at or beyond the sweep's "
                        f"{'lower' if low else 'upper'} end ({f[0]:.6g}-{f[-1]:.6g} Hz, "
                        f"fitted nu_n {nu:.6g} Hz): extend the sweep "
                        f"{'down' if low else 'up'}")
    if est.n_peak < MIN_PEAK_POINTS:
        status.append("peak_unresolved")
        problems.append(f"only {est.n_peak} points within the half-power band "
                        f"{nu - half_band:.6g}-{nu + half_band:.6g} Hz (need "
                        f"{MIN_PEAK_POINTS}): sweep more finely around the peak")
    if est.undetermined or not q_std <= MAX_Q_REL_STD * q or not nu_std <= MAX_NU_REL_STD * nu:
        status.append("q_unbounded")
        problems.append(f"the data do not determine nu_n and Q (nu_n = {nu:.6g} +- "
                        f"{nu_std:.3g} Hz, Q = {q:.4g} +- {q_std:.3g}"
                        + (", on the search bound" if est.q_bound else "") + ")")
    runs_z = _runs_z(residuals) if residual_rms > RUNS_MIN_RMS else 0.0
    if residual_rms > MAX_RESIDUAL_RMS or runs_z < MIN_RUNS_Z:
        status.append("poor_fit")
        why = (f"residual scatter {residual_rms:.1%} exceeds {MAX_RESIDUAL_RMS:.0%}"
               if residual_rms > MAX_RESIDUAL_RMS else
               f"the residuals keep their sign over long stretches (runs z = {runs_z:.1f})")
        problems.append(f"{why}: the data are not a linear resonance (impacting? then lower "
                        f"the drive; a second mode? a drifting drive?)")
    return status


def _parameter_std(jac, variance):
    """Standard errors of the fitted parameters, and whether J^T J was singular."""
    _, sv, vt = np.linalg.svd(jac, full_matrices=False)
    # singular values below this relative size carry no information from the data
    tol = np.finfo(float).eps * max(jac.shape) * (sv[0] if sv.size else 0.0)
    if sv.size == 0 or sv[-1] <= tol or not math.isfinite(variance):
        return np.full(jac.shape[1], math.inf), True
    cov = (vt.T / sv**2) @ vt * variance
    return np.sqrt(np.diag(cov)), False


def _runs_z(residuals):
    """z-score of the number of runs of equal sign in ``residuals`` (Wald-Wolfowitz)."""
    sign = residuals > 0
    n_pos, n = int(sign.sum()), sign.size
    n_neg = n - n_pos
    if n_pos == 0 or n_neg == 0:
        return -math.inf if n > 1 else 0.0
    runs = 1 + int(np.count_nonzero(sign[1:] != sign[:-1]))
    mean = 2.0 * n_pos * n_neg / n + 1.0
    var = (mean - 1.0) * (mean - 2.0) / (n - 1.0)
    return (runs - mean) / math.sqrt(var) if var > 0 else 0.0


def _failed(n, message):
    nan = math.nan
    return ResonanceFit(nan, nan, nan, nan, nan, nan, nan, int(n), 0, "fit_failed", message)


def _array(name, values):
    try:
        arr = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be numbers, {values!r} was given") from None
    if arr.ndim != 1:
        raise ValueError(f"{name} must be one-dimensional, shape {arr.shape} was given")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, {arr.tolist()!r} was given")
    return arr


def calibrate(sweep: pd.DataFrame) -> pd.DataFrame:
    """Fit every impacter of a sweep table.

    Parameters
    ----------
    sweep : pandas.DataFrame
        Columns ``impacter`` (name), ``frequency_hz`` [Hz], ``amplitude_m`` [m] and
        optionally ``drive_amplitude_m`` [m], one row a measurement, as
        :func:`read_sweep` returns.

    Returns
    -------
    pandas.DataFrame
        One row per impacter, in order of first appearance: ``impacter``,
        ``natural_frequency_hz``, ``quality_factor``, ``natural_frequency_std_hz``,
        ``quality_factor_std`` (:data:`MEASURED_COLUMNS`), then ``scale``,
        ``scale_std``, ``residual_rms``, ``n_points``, ``n_peak_points``, ``status``
        and ``message`` (see :class:`ResonanceFit`).

    Raises
    ------
    ValueError
        If a column is missing, or an impacter's values are out of range (see
        :func:`fit_resonance`; the message names the impacter).
    """
    if not isinstance(sweep, pd.DataFrame):
        raise ValueError(f"sweep must be a pandas.DataFrame, {type(sweep).__name__} was given")
    missing = [c for c in ("impacter", "frequency_hz", "amplitude_m") if c not in sweep.columns]
    if missing:
        raise ValueError(f"sweep is missing the column(s) {', '.join(missing)}")
    has_drive = "drive_amplitude_m" in sweep.columns
    halves = "half" in sweep.columns and bool(sweep["half"].astype(str).str.len().any())
    keys = ["impacter", "half"] if halves else ["impacter"]
    rows = []
    for key, group in sweep.groupby(keys, sort=False):
        name, half = (key if halves else (key[0] if isinstance(key, tuple) else key, ""))
        label = f"{name} half {half}" if half else f"{name}"
        try:
            fit = fit_resonance(group["frequency_hz"].to_numpy(), group["amplitude_m"].to_numpy(),
                                group["drive_amplitude_m"].to_numpy() if has_drive else None)
        except ValueError as exc:
            raise ValueError(f"impacter {label}: {exc}") from None
        rows.append({"impacter": name, **({"half": half} if halves else {}), **asdict(fit)})
    columns = list(MEASURED_COLUMNS) + (["half"] if halves else [])
    extra = [c for c in rows[0] if c not in columns] if rows else []
    return pd.DataFrame(rows, columns=columns + extra)


def read_sweep(path) -> pd.DataFrame:
    """Read and check a lab's sweep CSV; amplitudes converted to metres.

    Parameters
    ----------
    path : str or os.PathLike
        A CSV file with the header ``impacter,frequency_hz,amplitude_um`` and
        optionally ``drive_amplitude_um`` and ``half`` (``a``/``b``: one cantilever of
        the pair, each fitted on its own; any column order); one row a
        measurement: the impacter's name, the drive frequency [Hz], the impacter's
        steady amplitude relative to the die [um] (half the peak-to-peak) and the
        die's own amplitude at that frequency [um].  Blank lines and lines starting
        with ``#`` are skipped.

    Returns
    -------
    pandas.DataFrame
        Columns ``impacter`` (str), ``frequency_hz`` [Hz], ``amplitude_m`` [m] and,
        if the file has it, ``drive_amplitude_m`` [m], plus ``line`` (the row's
        1-based line in the file).

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    planner.core.errors.SpecError
        ``FILE: row N, column C: ...`` (N the 1-based line in the file) for a
        missing or unknown column, an empty name, a value that is not a finite
        number, a frequency <= 0, an amplitude < 0, a drive amplitude <= 0, or an
        impacter with fewer than :data:`MIN_POINTS` distinct frequencies.
    """
    header_line, header, rows, fail = read_csv_rows(path, SWEEP_COLUMNS, SWEEP_OPTIONAL,
                                                    what="a sweep")
    records = []
    for line, row in rows:
        values = row_values(header, line, row, fail)
        if not values["impacter"]:
            raise fail(line, "impacter", "empty impacter name")
        rec = {"impacter": values["impacter"], "line": line}
        if "half" in values:
            half = values["half"].lower()
            if half and half not in HALVES:
                raise fail(line, "half", f"must be a or b (one cantilever of the pair) or "
                                         f"blank, {values['half']!r} was given")
            rec["half"] = half
        for column in header:
            if column in ("impacter", "half"):
                continue
            text = values[column]
            x = csv_number(text, line, column, fail)
            if column == "frequency_hz" and x <= 0:
                raise fail(line, column, f"frequency must be > 0 Hz, {text} was given")
            if column == "frequency_hz" and x < MIN_FREQUENCY:
                # a sweep in kHz fits a '4.44 Hz' resonance that no impacter has; the
                # model's own floor of a frequency in Hz (model.devices.MIN_FREQUENCY)
                raise fail(line, column, f"{text} Hz is below {MIN_FREQUENCY:g} Hz, no "
                                         "resonance of these devices: frequency_hz is in "
                                         "Hz (was the sweep written in kHz?)")
            if column == "amplitude_um" and x < 0:
                raise fail(line, column, f"amplitude must be >= 0 um, {text} was given")
            if column == "drive_amplitude_um" and x <= 0:
                raise fail(line, column, f"drive amplitude must be > 0 um, {text} was given")
            rec[column] = x
        records.append(rec)
    if not records:
        raise fail(header_line + 1, "impacter", "no measurements after the header")

    frame = pd.DataFrame.from_records(records)
    halves = "half" in frame.columns and bool(frame["half"].str.len().any())
    if halves:
        # a pair is measured half by half or as a whole, not both
        for name, group in frame.groupby("impacter", sort=False):
            if set(group["half"]) & {""} and set(group["half"]) - {""}:
                blank = group[group["half"] == ""]
                raise fail(int(blank["line"].iloc[0]), "half",
                           f"impacter {name!r} has rows with and without a half; give a "
                           f"or b on every row of a pair measured half by half")
    for key, group in frame.groupby(["impacter", "half"] if halves else ["impacter"],
                                    sort=False):
        name = key[0] if isinstance(key, tuple) else key
        what = f"{name!r} half {key[1]}" if halves else f"{name!r}"
        distinct = group["frequency_hz"].nunique()
        if distinct < MIN_POINTS:
            rows = ", ".join(str(n) for n in group["line"])
            raise fail(int(group["line"].iloc[0]), "impacter",
                       f"impacter {what} has {distinct} distinct frequencies (rows {rows}); "
                       f"fitting nu_n, Q and the scale needs at least {MIN_POINTS}")
    out = pd.DataFrame({"impacter": frame["impacter"].astype(str),
                        "frequency_hz": frame["frequency_hz"],
                        "amplitude_m": frame["amplitude_um"] * UM})
    if halves:
        out["half"] = frame["half"]
    if "drive_amplitude_um" in frame.columns:
        out["drive_amplitude_m"] = frame["drive_amplitude_um"] * UM
    out["line"] = frame["line"]
    return out


def write_measured(fits: pd.DataFrame, path) -> None:
    """Write the :data:`MEASURED_COLUMNS` of ``fits`` (from :func:`calibrate`) as CSV.

    Parameters
    ----------
    fits : pandas.DataFrame
        :func:`calibrate`'s result, or the rows of it to keep.
    path : str or os.PathLike
        The CSV file; frequencies to 10 significant digits.
    """
    columns = list(MEASURED_COLUMNS) + (["half"] if "half" in fits.columns else [])
    fits.loc[:, columns].to_csv(path, index=False, float_format="%.10g")
