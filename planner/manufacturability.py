"""Manufacturability: will a fabricated chip's resonances still be told apart?

A plan verifies on the nominal chip.  A fabricated one has every natural frequency moved
by the process (:mod:`planner.fabrication`): a die-level part shared by every impacter
and a device-level part of each.  The drive can follow a die that moved every resonance
by one factor (a re-plan measures the chip and scales the tones), but not two impacters
whose resonances came too close to be told apart.  This module predicts, in seconds and
without simulating chips, the fraction of chips on which that never happens -- the
*collision-free yield* -- and sizes the channel grid for it:

- :func:`sensitivities` (per design, d ln nu_n / d parameter through the as-built
  equations of :mod:`planner.fabrication`);
- :func:`measure_separation` (per design, by simulation once): how far from its own
  resonance a tone must be for it to stay silent from every x0 at full power
  (``silent_beyond``), and how far its own tone may move and still drive it
  (``responds_within``);
- :func:`collision_free_yield`: a Monte Carlo of as-built resonances (10^4 chips in
  well under a second), first order in the errors, with its Wilson interval, the
  die-only and device-only yields, the closest-pair distribution and the pairs that
  limit it;
- :func:`tolerance_grid`: the channel grid of ``drive.channels.spacing: tolerance``.

The collision rule
------------------
Impacter k has its resonance nu_k and tone t_k (the plan's), a silent band: it answers
tones in (nu_k - a_k, nu_k + b_k) from some x0 and none outside, and a tone window: its
tone may sit anywhere in [t_k - lo_k, t_k + hi_k] and still drive it.  On a chip every
resonance and tone moves by the impacter's as-built factor g_k = nu_k' / nu_k (a re-plan
keeps each tone's place relative to its resonance).  Two impacters i, j that must be
told apart *collide* when i's whole tone window lies in j's silent band, or j's in i's:
no tone then drives one without the other answering.  Before any design exists (the
channel grid, ``--dry-run``) every band is ``drive.channels.separation_hz`` wide on
either side of the tone and the windows are points.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from planner.fabrication import ERRORS, NodeDesign, frequency_sensitivities

#: Chips of the Monte Carlo by default: the 95 % interval of a yield near 0.95 is then
#: +-0.004 wide.
CHIPS = 10_000
#: A tone drives an impacter while the least response over x0 stays above this fraction
#: of the least response at its planned tone [-]: the designs are retried until they are
#: predicted 2.5 x faster than the speed floor, so half the response keeps ~1.25 x.
RESPONDS_FRACTION = 0.5
#: Scan step of :func:`measure_separation`, relative to the frequency, and its floor [Hz].
SCAN_STEP_REL = 2e-3
SCAN_STEP_MIN_HZ = 5.0
#: Consecutive silent (or not driving) scan points that end a band [-].
SCAN_QUIET = 3
#: The largest scan, either side, relative to the frequency [-].
SCAN_SPAN_REL = 0.15
#: Edge tolerance of the bisection [Hz].
EDGE_TOL_HZ = 0.5
#: Every use of a silent band (the Monte Carlo's collision rule, the re-plan's tones, the
#: trim's targets) widens it by this fraction of its reach: measured on the nominal
#: design, its edge moves by a few per cent of its reach when the resonance moves by
#: ~2 % (the tone amplitude follows the power convention, ~f^-1.5): a tone 6 Hz below
#: a measured edge made a close pair answer on a chip 2 % off its design [-].
BAND_MARGIN = 0.1
#: Pairs listed as limiting the yield.
LIMITING_PAIRS = 10
#: Die-level common shifts (sigmas) the channel grid keeps from the band's ends [-].
DIE_SHIFT_SIGMAS = 3.0
#: Chips x pairs evaluated at once by the Monte Carlo (memory of its tables) [-].
MC_CELLS = 2_000_000
#: The reference beam of a matched array: its width [um] when the spec gives none, and
#: the beams' share of the mass assumed for the reference sensitivity (the default
#: plan's designs carry 1-31 % of their mass in the beams).
REFERENCE_WIDTH_UM = 5.0
REFERENCE_BEAM_MASS_FRACTION = 0.2


# ------------------------------------------------------------------------------ spec level
def sensitivity_target_per_um(design) -> float:
    """The array's common line-width sensitivity S* [1/um] of a ``design:`` section.

    ``design.sensitivity_per_um`` when given, else that of a beam of
    ``design.beam_width_um`` (or :data:`REFERENCE_WIDTH_UM`) carrying a plate of
    1 - :data:`REFERENCE_BEAM_MASS_FRACTION` of the mass
    (:func:`planner.designer.sensitivity.reference_sensitivity`).
    """
    from planner.designer.sensitivity import reference_sensitivity

    if design.sensitivity_per_um is not None:
        return float(design.sensitivity_per_um)
    width = design.beam_width_um if design.beam_width_um is not None else REFERENCE_WIDTH_UM
    return reference_sensitivity(width * 1e-6, REFERENCE_BEAM_MASS_FRACTION) * 1e-6


def predicted_sigmas(spec) -> tuple[np.ndarray, np.ndarray]:
    """Per-parameter sensitivities before any design: (s, spread), shape (5,) each.

    ``s`` [1/unit]: the line width's is the matched target S* (with
    ``design.match_sensitivity``), else that of the narrowest beam allowed (the worst
    case); the others, which do not depend on the geometry to first order (thickness
    and gap cancel in eqs. (2)-(4), E enters as sqrt), from a reference design.
    ``spread`` [1/unit]: how much two designs' sensitivities may differ (the matched
    band's full width, or the unmatched range), which turns a die-level error into a
    relative shift between them.
    """
    des = spec.design
    node = NodeDesign("reference", "A1", "forward", 3e-8, REFERENCE_WIDTH_UM * 1e-6, 4e-4,
                      4e-6, math.pi / 4, 0.5)
    s = frequency_sensitivities(spec, node)
    spread = np.zeros(len(ERRORS))
    if des.match_sensitivity:
        s[0] = sensitivity_target_per_um(des)
        spread[0] = 2.0 * des.sensitivity_tolerance * s[0]
    else:
        lo, hi = des.bounds.width_um or (2.0, 10.0)
        if des.beam_width_um is not None:
            lo = hi = des.beam_width_um
        # S lies between 1/w (beam mass) and 1.5/w (plate mass)
        s[0] = 1.5 / lo
        spread[0] = 1.5 / lo - 1.0 / hi
    return s, spread


def pair_sigma_rel(spec) -> float:
    """Relative standard deviation of the difference of two as-built resonances [-].

    sqrt(2 sum_i (s_i sigma_device_i)^2 + 2 sum_i (s_i sigma_pair_i)^2 + sum_i (spread_i
    sigma_die_i)^2 / 6): the device-level parts of two impacters are independent; the
    pair level moves each pair's mean and widens its band by about as much; a die-level
    error moves two designs apart by the difference of their sensitivities, uniform over
    the spread (variance spread^2 / 6 for the difference of two uniform draws on it).
    """
    fab = spec.fabrication
    s, spread = predicted_sigmas(spec)
    dev = np.array([getattr(fab, k).device for k in ERRORS])
    die = np.array([getattr(fab, k).die for k in ERRORS])
    # the pair level: each node's mean moves by sigma / sqrt(2) and its band widens by
    # about as much again (half the halves' difference); counted as one more device sigma
    pair = np.array([getattr(fab, k).pair for k in ERRORS])
    return float(math.sqrt(2.0 * np.sum((s * dev) ** 2) + 2.0 * np.sum((s * pair) ** 2)
                           + np.sum((spread * die) ** 2) / 6.0))


def z_for(target_yield: float, pairs: int) -> float:
    """The normal quantile z that makes ``pairs`` independent one-sided margins of z sigma
    all hold with probability ``target_yield``: 1 - p per pair, (1 - p)^pairs = target.

    >>> round(z_for(0.95, 49), 3)
    3.077
    """
    from scipy.stats import norm

    if not 0.0 < target_yield < 1.0:
        raise ValueError(f"target_yield must be in (0, 1), {target_yield!r} was given")
    pairs = max(int(pairs), 1)
    p = -math.expm1(math.log(target_yield) / pairs)
    return float(norm.isf(p))


def tolerance_grid(band_hz, separation_hz, sigma_rel, z, sub=1) -> np.ndarray:
    """Channel frequencies [Hz] spaced so that neighbours ``sub`` channels apart stay
    separable: f_{k+1} = f_k + (separation_hz + z sigma_rel f_k) / sub.

    Parameters
    ----------
    band_hz : (float, float)
        The band [Hz]; the grid starts at its bottom and ends at or below its top.
    separation_hz : float
        How close two resonances may be and still be told apart [Hz].
    sigma_rel : float
        Relative sigma of the difference of two as-built resonances [-]
        (:func:`pair_sigma_rel`).
    z : float
        Margin in sigmas (:func:`z_for`).
    sub : int
        Channels per separation (``drive.guard.separation_channels``): the colouring
        keeps tones that must be told apart ``sub`` channels apart.

    Returns
    -------
    ndarray, shape (n,)

    Examples
    --------
    >>> g = tolerance_grid((5000.0, 8000.0), 400.0, 0.008, 3.0)
    >>> [round(float(f)) for f in g[:3]], len(g)
    ([5000, 5520, 6052], 6)
    """
    lo, hi = (float(b) for b in band_hz)
    sub = max(int(sub), 1)
    if not (separation_hz > 0 and math.isfinite(separation_hz)):
        raise ValueError(f"separation_hz must be finite and > 0, {separation_hz!r} was given")
    factor = 1.0 + z * sigma_rel / sub
    step = separation_hz / sub
    # closed form of the recurrence: f_k + c = (f_0 + c) factor^k, c = step / (factor - 1)
    if factor > 1.0:
        c = step / (factor - 1.0)
        n = int(math.floor(math.log((hi + c) / (lo + c)) / math.log(factor) + 1e-12)) + 1
        return (lo + c) * factor ** np.arange(n) - c
    n = int(math.floor((hi - lo) / step + 1e-12)) + 1
    return lo + step * np.arange(n)


def told_apart_count(spec) -> int:
    """Impacters (channel groups) the spec's steps make distinct: the colouring's nodes."""
    from planner.assign import activity, plan_steps
    from planner.spec import LoadedSpec, resolve_steps

    loaded = LoadedSpec(spec, resolve_steps(spec), "<spec>")
    return max(len(set(activity(plan_steps(loaded, 0.01)).values())), 1)


def die_shift_rel(spec) -> float:
    """Relative sigma of the common shift a die-level error gives every resonance [-]:
    sqrt(sum_i (s_i sigma_die_i)^2), the predicted sensitivities."""
    s, _ = predicted_sigmas(spec)
    die = np.array([getattr(spec.fabrication, k).die for k in ERRORS])
    return float(math.sqrt(np.sum((s * die) ** 2)))


def spec_tolerance_grid(spec) -> np.ndarray:
    """The channel grid of a spec with ``drive.channels.spacing: tolerance`` [Hz].

    The channels keep :data:`DIE_SHIFT_SIGMAS` sigmas of the die-level common shift
    from either end of ``drive.band_hz``: a chip whose resonances all came out high
    (or low) is re-planned with every tone moved by that factor, which must still be
    in the band the piezo drives.
    """
    z = z_for(spec.fabrication.target_yield, told_apart_count(spec) - 1)
    lo, hi = spec.drive.band_hz
    m = 1.0 + DIE_SHIFT_SIGMAS * die_shift_rel(spec)
    return tolerance_grid((lo * m, hi / m), spec.drive.channels.resonance_separation_hz,
                          pair_sigma_rel(spec), z, spec.drive.guard.separation_channels)


# ------------------------------------------------------------------------------ per design
def sensitivities(spec, node: NodeDesign) -> dict:
    """Parameter name -> d ln nu_n / d parameter [1/unit] of one design (every
    :data:`planner.fabrication.ERRORS` entry)."""
    s = frequency_sensitivities(spec, node)
    return {name: float(v) for name, v in zip(ERRORS, s)}


@dataclass(frozen=True)
class Separation:
    """How far a design's silent band and tone window reach (by simulation).

    Attributes
    ----------
    natural_frequency_hz, tone_hz : float
        nu_n and the planned tone [Hz].
    silent_below_hz, silent_above_hz : float
        The design answers a tone (from some x0, at full power) only within
        (nu_n - silent_below, nu_n + silent_above) [Hz].
    responds_below_hz, responds_above_hz : float
        Its tone may move down or up this far and still drive it (least response over
        x0 at least :data:`RESPONDS_FRACTION` of the planned tone's) [Hz], at the
        amplitude its tone plays at alone.
    """

    natural_frequency_hz: float
    tone_hz: float
    silent_below_hz: float
    silent_above_hz: float
    responds_below_hz: float
    responds_above_hz: float

    @property
    def silent_beyond_hz(self) -> float:
        """The larger reach of the silent band from nu_n [Hz]."""
        return max(self.silent_below_hz, self.silent_above_hz)

    @property
    def responds_within_hz(self) -> float:
        """The smaller reach of the tone window [Hz]."""
        return min(self.responds_below_hz, self.responds_above_hz)

    def to_dict(self) -> dict:
        return {"silent_beyond": self.silent_beyond_hz,
                "responds_within": self.responds_within_hz,
                "silent_below": self.silent_below_hz, "silent_above": self.silent_above_hz,
                "responds_below": self.responds_below_hz,
                "responds_above": self.responds_above_hz}


def _edge(pred, inside, outside, tol):
    """Bisect between ``inside`` (pred true) and ``outside`` (false) to ``tol`` [Hz]."""
    while abs(outside - inside) > tol:
        mid = 0.5 * (inside + outside)
        if pred(mid):
            inside = mid
        else:
            outside = mid
    return inside


def _reach(pred, start, direction, step, limit, tol):
    """How far from ``start`` (pred true there) pred stays true walking in
    ``direction`` (+1, -1), a run of SCAN_QUIET false points ending it [Hz]."""
    last_true, quiet, k = start, 0, 0
    while True:
        k += 1
        f = start + direction * k * step
        if abs(f - start) > limit or f <= 0:
            return abs(last_true - start)
        if pred(f):
            last_true, quiet = f, 0
        else:
            quiet += 1
            if quiet >= SCAN_QUIET:
                break
    edge = _edge(pred, last_true, last_true + direction * step, tol)
    return abs(edge - start)


def measure_separation(impacter, tone_hz, *, power=50.0, amplitude=None, tone_amplitude=None,
                       x0s=None, window=3e-3, silent_window=None) -> Separation:
    """Silent band and tone window of one design (see :class:`Separation`).

    Parameters
    ----------
    impacter : model.Impacter
        The design.
    tone_hz : float
        Its planned tone [Hz].
    power : float
        Z0^2 w^3 of a tone [m^2/s^3]: the amplitude a neighbour's tone plays at.
    amplitude : float, optional
        A fixed tone amplitude [m] instead of the power convention.
    tone_amplitude : float, optional
        The amplitude its own tone plays at where it must be told apart from its
        neighbours [m]; default the power convention's at ``tone_hz``.
    x0s : array_like, optional
        Initial positions [m]; default the designer's grid over [-c, c].
    window : float
        Simulated time of the tone window's responses [s] (the designer's window).
    silent_window : float, optional
        Simulated time of the silent band's checks [s]: the longest an impacter sits
        idle under one tone (a single-impacter step, 10 ms in an array plan; a slow beat
        can bring an idle impacter to its wall late).  Default ``window``.

    Returns
    -------
    Separation
    """
    from model import Drive, SolverWarning, responses
    from model.drive import amplitude_from_power
    from planner.designer.runs import x0_grid

    x0s = x0_grid(impacter.gap) if x0s is None else np.asarray(x0s, dtype=float)
    nu = float(impacter.natural_frequency)
    tone_hz = float(tone_hz)

    silent_window = window if silent_window is None else float(silent_window)

    def r_of(f, z0, duration=window, stop=False):
        drive = Drive(np.array([f]), np.array([z0]), np.zeros(1))
        return responses(impacter, drive, x0s, duration=duration, stop_at_first=stop,
                         check_input=False)

    def z_at(f):
        return amplitude if amplitude is not None else float(amplitude_from_power(f, power))

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SolverWarning)

        def answers(f):
            return bool(np.any(r_of(f, z_at(f), silent_window, True) > 0))

        step = max(SCAN_STEP_REL * nu, SCAN_STEP_MIN_HZ)
        limit = SCAN_SPAN_REL * nu
        start = nu if answers(nu) else tone_hz
        below = nu - start + _reach(answers, start, -1, step, limit, EDGE_TOL_HZ)
        above = start - nu + _reach(answers, start, +1, step, limit, EDGE_TOL_HZ)

        z_tone = tone_amplitude if tone_amplitude is not None else z_at(tone_hz)
        r0 = float(np.min(r_of(tone_hz, z_tone)))
        if r0 > 0:
            def drives(f):
                return float(np.min(r_of(f, z_tone))) >= RESPONDS_FRACTION * r0

            step_t = max(SCAN_STEP_REL * 0.25 * tone_hz, SCAN_STEP_MIN_HZ)
            r_below = _reach(drives, tone_hz, -1, step_t, limit, EDGE_TOL_HZ)
            r_above = _reach(drives, tone_hz, +1, step_t, limit, EDGE_TOL_HZ)
        else:
            r_below = r_above = 0.0
    return Separation(nu, tone_hz, float(below), float(above), float(r_below), float(r_above))


# ------------------------------------------------------------------------------ Monte Carlo
@dataclass(frozen=True)
class YieldPrediction:
    """The collision-free yield of a set of designs under a tolerance model.

    Attributes
    ----------
    value : float
        Fraction of chips with no colliding pair [-].
    ci95 : (float, float)
        Its 95 % Wilson score interval.
    chips : int
        Chips sampled.
    die_only, device_only : float
        The yield with only the die-level or only the device-level errors (same draws).
    closest_pair_hz : dict
        Quantiles (``p5``, ``median``, ``p95``) over chips of the smallest distance
        between the as-built resonances of two impacters that must be told apart [Hz].
    limiting_pairs : list of dict
        The pairs that collide most often: ``pair`` (two ids), ``collision_fraction``
        (of chips), ``nominal_separation_hz`` (their resonances' distance as designed).
    nominal_collisions : list
        Pairs that collide on the nominal chip (the bands say they cannot be told apart
        even unbuilt; should be empty for a verified plan).
    """

    value: float
    ci95: tuple
    chips: int
    die_only: float
    device_only: float
    closest_pair_hz: dict
    limiting_pairs: list
    nominal_collisions: list

    def to_dict(self) -> dict:
        return {"value": self.value, "ci95": list(self.ci95), "chips": self.chips}

    @classmethod
    def from_block(cls, block: dict) -> "YieldPrediction | None":
        """The prediction recorded in plan.json's ``manufacturability`` block (None if the
        plan predicted none)."""
        y = block.get("collision_free_yield")
        if y is None:
            return None
        return cls(y["value"], tuple(y["ci95"]), y["chips"], block.get("die_only_yield"),
                   block.get("device_only_yield"), block.get("closest_pair_hz") or {},
                   block.get("limiting_pairs") or [], block.get("nominal_collisions") or [])


def _collisions(nu, tone, below, above, lo, hi, g, pairs, split=None):
    """(chips, pairs) bool: pair collides on the chip (see the module notes).

    ``split`` (chips, n): half the relative difference of a pair's two halves; the pair
    answers where either half does (its silent band widens by split nu on each side)
    and its tone must drive both (its window narrows by the same)."""
    i, j = pairs[:, 0], pairs[:, 1]
    nu_c, t_c = nu * g, tone * g
    if split is None:
        wide = np.zeros((1, nu.size))
    else:
        wide = np.abs(split) * nu_c
    b_lo, b_hi = below + wide, above + wide
    w_lo, w_hi = lo - wide, hi - wide

    def inside(a, b):       # a's whole tone window inside b's silent band
        return ((t_c[:, a] - w_lo[:, a] > nu_c[:, b] - b_lo[:, b])
                & (t_c[:, a] + w_hi[:, a] < nu_c[:, b] + b_hi[:, b]))

    return inside(i, j) | inside(j, i)


def collision_free_yield(ids, nu, tone, sens, sigma_die, sigma_device, pairs, *,
                         silent_below, silent_above, responds_below=None,
                         responds_above=None, chips=CHIPS, seed=0,
                         sigma_pair=None) -> YieldPrediction:
    """Monte Carlo of the collision-free yield (first order in the errors).

    Parameters
    ----------
    ids : sequence of str, shape (n,)
        Impacter ids.
    nu, tone : array_like, shape (n,)
        Natural frequencies and planned tones [Hz].
    sens : array_like, shape (n, p)
        d ln nu_n / d e of each impacter for each error [1/unit].
    sigma_die, sigma_device : array_like, shape (p,)
        Standard deviations of the die-level and device-level errors [unit].
    pairs : array_like of int, shape (m, 2)
        Indices of the impacters that must be told apart.
    silent_below, silent_above : array_like, shape (n,)
        Silent band reach below and above each nu_n [Hz].
    responds_below, responds_above : array_like, shape (n,), optional
        Tone window reach [Hz]; default 0 (the tone cannot move).
    chips : int
        Chips sampled.
    seed : int
        The draws come from ``numpy.random.SeedSequence([seed, 25])``.
    sigma_pair : array_like, shape (p,), optional
        Standard deviation of each half's own error (the ``pair`` level): the two
        halves of a pair then differ, the pair answers where either does and its tone
        must drive both (its silent band widens and its window narrows by half their
        difference).

    Returns
    -------
    YieldPrediction

    Notes
    -----
    As-built nu_k' = nu_k exp(sum_e s_ke (x_e + y_ke)), x_e ~ N(0, sigma_die_e) shared
    by the chip and y_ke ~ N(0, sigma_device_e) per impacter: first order in the
    errors (the line width's curvature is below 1e-4 relative at 0.05 um on 5 um
    beams; the tests hold it against chips sampled through the full equations).
    """
    from planner.yield_ import wilson_interval

    nu = np.asarray(nu, dtype=float)
    tone = np.asarray(tone, dtype=float)
    sens = np.asarray(sens, dtype=float)
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    n, p = sens.shape
    sd_die = np.asarray(sigma_die, dtype=float)
    sd_dev = np.asarray(sigma_device, dtype=float)
    zero = np.zeros(n)
    below, above = np.asarray(silent_below, float), np.asarray(silent_above, float)
    lo = zero if responds_below is None else np.asarray(responds_below, float)
    hi = zero if responds_above is None else np.asarray(responds_above, float)
    chips = int(chips)
    if chips < 1:
        raise ValueError(f"chips must be >= 1, {chips!r} was given")
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 25]))
    z_die = rng.standard_normal((chips, p))
    z_dev = rng.standard_normal((chips, n, p))
    sd_pair = None if sigma_pair is None else np.asarray(sigma_pair, dtype=float)
    if sd_pair is not None and not np.any(sd_pair > 0):
        sd_pair = None
    # drawn after the others: without a pair level the chips are the same
    z_half = rng.standard_normal((chips, n, 2, p)) if sd_pair is not None else None
    args = (nu, tone, below, above, lo, hi)
    ok_none = ~_collisions(*args, np.ones((1, n)), pairs)[0]
    nominal = [[ids[a], ids[b]] for (a, b), ok in zip(pairs, ok_none) if not ok]
    if pairs.size == 0:
        return YieldPrediction(1.0, tuple(wilson_interval(chips, chips)), chips, 1.0, 1.0,
                               {"p5": None, "median": None, "p95": None}, [], nominal)
    ok_both = np.zeros(chips, bool)
    ok_die = np.zeros(chips, bool)
    ok_dev = np.zeros(chips, bool)
    gaps = np.zeros(chips)
    hits = np.zeros(len(pairs))
    # chunks of chips, so that a large array's (chips, pairs) tables stay small
    step = max(1, MC_CELLS // len(pairs))
    for a in range(0, chips, step):
        b = min(chips, a + step)
        die_part = (z_die[a:b] * sd_die) @ sens.T                     # (chunk, n)
        dev_part = np.einsum("cnp,np->cn", z_dev[a:b] * sd_dev, sens)
        split = None
        if z_half is not None:
            h = np.einsum("cnkp,np->cnk", z_half[a:b] * sd_pair, sens)
            # the pair sits at the mean of its halves, half their difference either side
            dev_part = dev_part + 0.5 * (h[..., 0] + h[..., 1])
            split = 0.5 * (h[..., 0] - h[..., 1])
        both = _collisions(*args, np.exp(die_part + dev_part), pairs, split)
        ok_both[a:b] = ~both.any(axis=1)
        hits += both.sum(axis=0)
        ok_die[a:b] = ~_collisions(*args, np.exp(die_part), pairs).any(axis=1)
        ok_dev[a:b] = ~_collisions(*args, np.exp(dev_part), pairs, split).any(axis=1)
        nu_c = nu * np.exp(die_part + dev_part)
        gaps[a:b] = np.abs(nu_c[:, pairs[:, 0]] - nu_c[:, pairs[:, 1]]).min(axis=1)
    value = float(np.mean(ok_both))
    q = np.percentile(gaps, [5, 50, 95])
    closest = {"p5": float(q[0]), "median": float(q[1]), "p95": float(q[2])}
    frac = hits / chips
    order = np.argsort(-frac, kind="stable")[:LIMITING_PAIRS]
    limiting = [{"pair": [ids[pairs[k, 0]], ids[pairs[k, 1]]],
                 "collision_fraction": float(frac[k]),
                 "nominal_separation_hz": float(abs(nu[pairs[k, 0]] - nu[pairs[k, 1]]))}
                for k in order if frac[k] > 0]
    die_only, device_only = float(np.mean(ok_die)), float(np.mean(ok_dev))
    passed = int(round(value * chips))
    return YieldPrediction(value, tuple(wilson_interval(passed, chips)), chips, die_only,
                           device_only, closest, limiting, nominal)


def predict_from_channels(spec, assignment, *, chips=CHIPS, seed=0) -> YieldPrediction | None:
    """The collision-free yield of an assignment before any design (``--dry-run``).

    Every impacter's resonance is taken at its channel, its sensitivities the
    predicted ones (:func:`predicted_sigmas`: the matched target, or the worst case),
    plus a die-level spread of the line width's sensitivity across designs drawn
    uniformly over the matched band; two impacters collide when their as-built
    resonances come closer than ``drive.channels.separation_hz`` (400 Hz by default
    when the grid is not a tolerance grid).  None without tolerances.
    """
    from planner.assign import told_apart_pairs

    fab = spec.fabrication
    if fab.zero:
        return None
    nodes = sorted(assignment.frequencies)
    f = np.array([assignment.frequencies[n] for n in nodes])
    s, spread = predicted_sigmas(spec)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 26]))
    # each design's sensitivity somewhere in the matched band (or the unmatched range)
    sens = s[None, :] + (rng.random((len(nodes), len(ERRORS))) - 0.5) * spread[None, :]
    sep = spec.drive.channels.resonance_separation_hz
    edge = np.full(len(nodes), float(sep))
    return collision_free_yield([str(n) for n in nodes], f, f, sens,
                                [getattr(fab, k).die for k in ERRORS],
                                [getattr(fab, k).device for k in ERRORS],
                                told_apart_pairs(assignment, nodes), silent_below=edge,
                                silent_above=edge, chips=chips, seed=seed)


def prediction_lines(pred: YieldPrediction | None, target: float, *, before_designs: bool):
    """The predicted yield as the CLI prints it (a line or two)."""
    if pred is None:
        return ["collision-free yield: not predicted (no fabrication tolerances in the spec)"]
    when = ("from the channel grid, before any design" if before_designs
            else "from the designs' sensitivities and separations")
    lo, hi = pred.ci95
    verdict = ("above" if lo >= target else "BELOW" if hi < target else "at (within the "
               "interval)")
    lines = [f"predicted collision-free yield {pred.value:.3f} (95 % CI {lo:.3f}-{hi:.3f}, "
             f"{pred.chips} chips; die errors alone {pred.die_only:.3f}, device errors alone "
             f"{pred.device_only:.3f}) {when}: {verdict} the target {target:g}"]
    c = pred.closest_pair_hz
    if c.get("median") is not None:
        lines.append(f"  closest as-built pair: median {c['median']:.0f} Hz (5-95 %: "
                     f"{c['p5']:.0f}-{c['p95']:.0f} Hz)"
                     + ("; most often colliding: " + ", ".join(
                         f"{'/'.join(p['pair'])} {100 * p['collision_fraction']:.1f} %"
                         for p in pred.limiting_pairs[:3]) if pred.limiting_pairs else ""))
    return lines
