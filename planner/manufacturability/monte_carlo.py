"""The collision-free yield: a first-order Monte Carlo of as-built resonances under the
tolerance model, from the designs (or, before any design, from the channel grid)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planner.assignment.assign import told_apart_pairs
from planner.fabrication.tolerances import ERRORS, Tolerances
from planner.core.intervals import wilson_interval
from planner.manufacturability.grid import predicted_sigmas

#: Chips of the Monte Carlo by default: the 95 % interval of a yield near 0.95 is then
#: +-0.004 wide.
CHIPS = 10_000
#: Pairs listed as limiting the yield.
LIMITING_PAIRS = 10
#: Chips x pairs evaluated at once by the Monte Carlo (memory of its tables) [-].
MC_CELLS = 2_000_000


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
    #: with ``sigma_measure``: the fraction of chips whose *measured* resonances have no
    #: colliding pair (what a re-plan from the measurement can tell apart) [-]
    told_apart: float | None = None

    def to_dict(self) -> dict:
        return {"value": self.value, "ci95": list(self.ci95), "chips": self.chips}

    @classmethod
    def from_block(cls, block: dict) -> "YieldPrediction | None":
        """The prediction recorded in plan.json's ``manufacturability`` block (None if the
        plan predicted none)."""
        y = block.get("collision_free_yield")
        if y is None:
            return None
        told = block.get("told_apart_yield")
        return cls(y["value"], tuple(y["ci95"]), y["chips"], block.get("die_only_yield"),
                   block.get("device_only_yield"), block.get("closest_pair_hz") or {},
                   block.get("limiting_pairs") or [], block.get("nominal_collisions") or [],
                   told_apart=None if told is None else told["value"])


def _collisions(nu, tone, below, above, lo, hi, g, pairs, split=None):
    """(chips, pairs) bool: pair collides on the chip (see the module notes;
    :func:`planner.manufacturability.kernels.collisions_kernel`).

    ``split`` (chips, n): half the relative difference of a pair's two halves; the pair
    answers where either half does (its silent band widens by split nu on each side)
    and its tone must drive both (its window narrows by the same)."""
    from planner.manufacturability.kernels import collisions_kernel

    g = np.ascontiguousarray(g, dtype=float)
    split = (np.zeros((0, 0)) if split is None
             else np.ascontiguousarray(np.broadcast_to(split, g.shape), dtype=float))
    return collisions_kernel(nu, tone, below, above, lo, hi, g,
                             np.ascontiguousarray(pairs, dtype=np.int64), split)


def collision_free_yield(ids, nu, tone, sens, sigma_die, sigma_device, pairs, *,
                         silent_below, silent_above, responds_below=None,
                         responds_above=None, chips=CHIPS, seed=0,
                         sigma_pair=None, sigma_field_line_width=0.0, sigma_gradient=0.0,
                         positions=None, sigma_measure=0.0) -> YieldPrediction:
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
    sigma_field_line_width : float
        The wafer's across-wafer line-width field at the die [um]
        (``fabrication.wafer.line_width_field.sigma_um``): a die-level line width on
        top of ``sigma_die``'s (the first error of :data:`planner.fabrication.tolerances.ERRORS`).
    sigma_gradient : float
        One sigma of each component of the within-die line-width gradient [um/m]; with
        ``positions``, impacter k's line width moves by g . positions[k], g drawn per
        chip.
    positions : array_like, shape (n, 2), optional
        Every impacter's place from its die's centre [m].
    sigma_measure : float
        One sigma of a measured resonance's relative error [-]
        (``fabrication.measurement_noise_pct`` / 100): with it, ``told_apart`` is the
        share of chips whose measured resonances (each as-built one times
        exp(sigma_measure z), z drawn per chip and impacter after every other draw) have
        no colliding pair: what a re-plan, which reads only the measurement, can tell
        apart (:func:`planner.afterfab.drive.inseparable` on the same rule).

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
    # the wafer's part (issue 39), drawn last: without it the chips are the same
    lw_wafer = None
    if (sigma_field_line_width or sigma_gradient) and positions is not None:
        z_wafer = rng.standard_normal((chips, 3))
        pos = np.asarray(positions, dtype=float).reshape(n, 2)
        # line width [um] per chip and impacter: the die's field value plus the gradient
        lw_wafer = (float(sigma_field_line_width) * z_wafer[:, :1]
                    + float(sigma_gradient) * (z_wafer[:, 1:] @ pos.T))
    # the measurement's error, drawn after everything else: without it the chips are
    # the same
    sigma_measure = float(sigma_measure)
    z_meas = rng.standard_normal((chips, n)) if sigma_measure > 0 else None
    args = (nu, tone, below, above, lo, hi)
    ok_none = ~_collisions(*args, np.ones((1, n)), pairs)[0]
    nominal = [[ids[a], ids[b]] for (a, b), ok in zip(pairs, ok_none) if not ok]
    if pairs.size == 0:
        return YieldPrediction(1.0, tuple(wilson_interval(chips, chips)), chips, 1.0, 1.0,
                               {"p5": None, "median": None, "p95": None}, [], nominal,
                               told_apart=1.0 if float(sigma_measure) > 0 else None)
    ok_both = np.zeros(chips, bool)
    ok_meas = np.zeros(chips, bool)
    ok_die = np.zeros(chips, bool)
    ok_dev = np.zeros(chips, bool)
    gaps = np.zeros(chips)
    hits = np.zeros(len(pairs))
    # chunks of chips, so that a large array's (chips, pairs) tables stay small
    step = max(1, MC_CELLS // len(pairs))
    for a in range(0, chips, step):
        b = min(chips, a + step)
        die_part = (z_die[a:b] * sd_die) @ sens.T                     # (chunk, n)
        if lw_wafer is not None:     # a die-level part too: where the die sat
            die_part = die_part + lw_wafer[a:b] * sens[:, 0]
        dev_part = np.einsum("cnp,np->cn", z_dev[a:b] * sd_dev, sens)
        split = None
        if z_half is not None:
            h = np.einsum("cnkp,np->cnk", z_half[a:b] * sd_pair, sens)
            # the pair sits at the mean of its halves, half their difference either side
            dev_part = dev_part + 0.5 * (h[..., 0] + h[..., 1])
            split = 0.5 * (h[..., 0] - h[..., 1])
        both = _collisions(*args, np.exp(die_part + dev_part), pairs, split)
        ok_both[a:b] = ~both.any(axis=1)
        if z_meas is not None:
            seen = die_part + dev_part + sigma_measure * z_meas[a:b]
            ok_meas[a:b] = ~_collisions(*args, np.exp(seen), pairs, split).any(axis=1)
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
                           device_only, closest, limiting, nominal,
                           told_apart=float(np.mean(ok_meas)) if z_meas is not None else None)


def predict_from_channels(spec, assignment, *, chips=CHIPS, seed=0) -> YieldPrediction | None:
    """The collision-free yield of an assignment before any design (``--dry-run``).

    Every impacter's resonance is taken at its channel, its sensitivities the
    predicted ones (:func:`predicted_sigmas`: the matched target, or the worst case),
    plus a die-level spread of the line width's sensitivity across designs drawn
    uniformly over the matched band; two impacters collide when their as-built
    resonances come closer than ``drive.channels.separation_hz`` (400 Hz by default
    when the grid is not a tolerance grid).  None without tolerances.
    """
    tol = Tolerances.from_spec(spec.fabrication)
    if tol.zero:
        return None
    nodes = sorted(assignment.frequencies)
    f = np.array([assignment.frequencies[n] for n in nodes])
    s, spread = predicted_sigmas(spec)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 26]))
    # each design's sensitivity somewhere in the matched band (or the unmatched range)
    sens = s[None, :] + (rng.random((len(nodes), len(ERRORS))) - 0.5) * spread[None, :]
    sep = spec.drive.channels.resonance_separation_hz
    edge = np.full(len(nodes), float(sep))
    return collision_free_yield([str(n) for n in nodes], f, f, sens, tol.die, tol.device,
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
    if pred.told_apart is not None:
        lines.append(f"  as a re-plan reads them (with the spec's measurement noise): "
                     f"{pred.told_apart:.3f} of the chips told apart")
    return lines
