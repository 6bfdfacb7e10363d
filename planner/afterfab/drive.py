"""A fabricated chip's drive in seconds: the re-plan that rescues what physics allows.

The plan designed every impacter for a tone just above its resonance and measured, once,
how far around its resonance it answers a tone (its silent band) and how far its own tone
may move and still drive it (its tone window): plan.json's ``manufacturability``.  On a
fabricated chip every resonance has moved; the measurement gives the new ones.  This
module re-plans the drive without searching by simulation:

1. **tones** (:func:`rescaled_tones`): each tone moves with its impacter's measured
   resonance, keeping its place relative to it (t' = t nu'/nu; for a pair of unequal
   halves, the mean of the halves).
2. **separability** (:func:`inseparable`): by the collision rule of
   :mod:`planner.manufacturability` (:class:`planner.afterfab.separations.Separations`), every pair of
   impacters the plan's steps must tell apart is checked; a pair that cannot be is named
   with its as-built resonances and the separation it would need.  No drive can tell
   such a pair apart: a trim can (:mod:`planner.afterfab.trim`).
3. **steps** (:func:`split_weak`): each multi-tone step is synthesised with the new tones
   and held to ``drive.max_acceleration_g`` as the plan's; when the limit lowers its tones
   further than the plan's verified drive did and the step then fails by a slow slider,
   it is split into sub-steps of neighbouring tones (played one after the other), each
   strong enough again, and kept split where that passes more checks.
4. **bursts** (:func:`planner.planning.motion.size_bursts`): steps that ask for a travel
   get their burst from the as-built speeds.

The drive is then verified by simulation like a plan's; what fails is repaired like a
plan's motion (:func:`planner.planning.repair.repair_motion`: shorter bursts, longer
dwells).  Every step here is arithmetic or one synthesis; the verification is the cost.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable

import numpy as np

from planner.core.nodes import Node
from planner.afterfab.separations import Separations, remeasured, separations_of

#: A tone chosen beside a neighbour's silent band keeps this far from its edge: the
#: edge's bisection tolerance (planner.manufacturability.EDGE_TOL_HZ) and twice the
#: snapping of a single tone (planner.planning.drives.SINGLE_TONE_TOLERANCE_REL) [Hz, -].
EDGE_MARGIN_HZ = 1.0
EDGE_MARGIN_REL = 2e-4
#: Sub-steps a multi-tone step may be split into at most (each a run of neighbouring
#: tones); further would make it a sequence of single-tone steps.
MAX_SPLIT = 8
#: A step is split when the acceleration limit lowers its tones below this fraction of
#: the scale the plan's own drive of the step was verified at, and its sub-steps until
#: each keeps at least that [-].  Small changes (the tones' new crest factor) are left:
#: every impacter of another run is idle beside a run's edge, a new exposure the
#: designs were not made for, so a split is the last resort (the verification decides).
SPLIT_SCALE_MARGIN = 0.95
#: The re-plan holds every slider's travel on the *measured* models to this fraction of
#: ``verification.max_travel_um`` (the motion repair shortens a burst that goes further):
#: a tone sits near the edge of its window, where a few Hz of error in the measured
#: resonance change the speed by tens of per cent, and the chip's true speeds are not
#: known.  On 200 sampled chips of the default plan at 0.05 % measurement noise, 4 re-planned
#: drives that held the full limit on the measured models sent a slider past it on the
#: true ones [-].
REPLAN_TRAVEL_MARGIN = 0.85
#: A travel step's burst is sized so that its fastest slider, at the burst sizing's probe
#: speed, goes at most this fraction of the travel limit the re-plan checks against
#: (:func:`size_within`; the motion repair's own factor,
#: :func:`planner.planning.repair.repair_motion`) [-].
PRESIZE_FACTOR = 0.8


def size_within(settings, steps, waveforms, models, sliders, limit_m):
    """:func:`planner.planning.motion.size_bursts`, each burst then held to what keeps
    its fastest slider within ``limit_m`` [m].

    The sizing gives a travel step the burst its *slowest* slider needs (up to the
    step's ``duration_ms``); on a chip the fastest then often goes twice the limit, and
    the motion repair shortened the burst only after the whole step had been
    simulated at its full length (the costliest check of a re-plan, 60 ms of a 25-tone
    step) and then simulated it again.  The probe's speeds already say how far each
    slider goes: the burst is at most :data:`PRESIZE_FACTOR` x ``limit_m`` / the fastest
    probe speed, floored to the burst quantum as the repair floors it (at least one
    quantum).  The repair still acts on what the verification finds.

    Returns
    -------
    (steps, notes)
        As ``size_bursts``; a held step's note has ``travel_limited_s`` [s].
    """
    from planner.planning.motion import BURST_QUANTUM_S, size_bursts

    steps, notes = size_bursts(settings, steps, waveforms, models, sliders)
    out = []
    for st in steps:
        note = notes.get(st.key)
        fastest = (0.0 if note is None or st.targets_m is not None else
                   max((abs(v) for v in note["probe_speeds_m_s"].values()), default=0.0))
        if fastest > 0.0:
            most = max(BURST_QUANTUM_S, math.floor(PRESIZE_FACTOR * limit_m / fastest
                                                   / BURST_QUANTUM_S) * BURST_QUANTUM_S)
            if most < st.duration_s:
                st = dataclasses.replace(st, duration_s=float(most))
                notes[st.key] = {**note, "travel_limited_s": float(most)}
        out.append(st)
    return tuple(out), notes


def measured_frequency(value) -> float:
    """A measured resonance [Hz]: a number, or the mean of a pair's two halves."""
    if isinstance(value, (tuple, list)):
        return float(np.mean([float(v) for v in value]))
    return float(value)


def rescaled_tones(plan, measured: dict, seps: Separations | None = None,
                   window: float = 0.0) -> dict:
    """Impacter id -> its tone [Hz] moved with its measured resonance (t nu' / nu).

    Parameters
    ----------
    plan : PlanRecord
        The plan (:func:`planner.planfile.reader.read_plan`).
    measured : dict
        Impacter id -> measured resonance [Hz] (or the two halves' (a, b)); an impacter
        not in it keeps its tone.
    seps : Separations, optional
        With the plan's tone windows, each tone moves to the middle of its window
        first: the designer leaves a tone just below the frequency where the response
        collapses (the max-min optimum), with 10 Hz of room above it and 100 below;
        the middle keeps the most room for what the model does not know (measurement
        noise, the amplitude's change with the frequency).
    window : float
        The designs' relative tone window [-] (``settings.tone_window``): the move to
        the middle stays within it, where the design is known to drive its slider at
        speed (the measured window is where it responds at all: a targets plan's
        100 Hz below a 7 kHz tone is 0.7 %, where its slider is below the floor).  0:
        no limit.  On 40 chips of the default plan (seed 5, 0.05 % noise) the move
        re-plans 39 (0.975); keeping the scaled tones, 36 (three more pairs collide).
    """
    centre = {}
    if seps is not None:
        centre = {n: 0.5 * (seps.hi[k] - seps.lo[k]) for k, n in enumerate(seps.ids)}
        if window > 0.0:
            tone0 = {r.id: r.frequency_hz for r in plan.impacters}
            centre = {n: float(np.clip(c, -window * tone0[n], window * tone0[n]))
                      for n, c in centre.items()}
    # from the design's tone and resonance (a re-planned plan's are as built: its tones
    # moved already, and would move again)
    tone = plan.design_frequency_hz or {r.id: r.frequency_hz for r in plan.impacters}
    nu = plan.design_natural_frequency_hz
    out = {}
    for rec in plan.impacters:
        n = rec.id
        if n not in measured:
            out[n] = rec.frequency_hz + centre.get(n, 0.0)
            continue
        out[n] = (tone[n] + centre.get(n, 0.0)) * measured_frequency(measured[n]) / nu[n]
    return out


def _rows(plan, tones: dict) -> list:
    """The impacters of ``tones`` (node -> tone) that share one tone in ``plan``, two or
    more: one list of nodes per shared tone."""
    by_tone = {}
    for rec in plan.impacters:
        if rec.node in tones:
            by_tone.setdefault(round(rec.frequency_hz, 6), []).append(rec.node)
    return [members for members in by_tone.values() if len(members) > 1]


def shared_tones(plan, tones: dict, window: float) -> dict:
    """``tones`` (node -> re-planned tone [Hz]) with the impacters that share one tone in
    ``plan`` (one channel: driven together, one design) on one tone again, the mean of
    their re-planned tones, where it lies within each one's tone window (``window``,
    relative, ``settings.tone_window``: where its design drives its slider at speed).

    Each follows its own measured resonance otherwise, and a step then plays a tone per
    impacter where the plan played one: a row of four 7-20 Hz apart (0.05 % of
    measurement noise at 25 kHz) beats to four times the plan's amplitude, and the idle
    impacters near it answer (a 2 x 4 of our own: the nominal chip's re-plan failed,
    B1.forward at 41.5 kHz answering the four tones at 25.43 kHz; 0 of 20 chips
    re-planned).  Tones closer than :data:`planner.planning.drives.MERGE_HZ` are played
    as one anyway; this keeps the rest of a shared tone shared."""
    out = dict(tones)
    for members in _rows(plan, tones):
        fs = [tones[n] for n in members]
        mean = sum(fs) / len(fs)
        if all(abs(f - mean) <= window * f for f in fs):
            for n in members:
                out[n] = mean
    return out


def must_differ(steps) -> list:
    """Pairs of impacter ids some step drives one of and not the other (sorted)."""
    nodes = sorted({Node(d, r).text for st in steps for d, r in st.active_nodes()})
    active = [{Node(d, r).text for d, r in st.active_nodes()} for st in steps]
    out = []
    for a, b in itertools.combinations(nodes, 2):
        if any((a in act) != (b in act) for act in active):
            out.append((a, b))
    return out


def inseparable(seps: Separations, measured: dict, pairs) -> list:
    """The pairs no drive can tell apart on this chip, each as a dict: ``pair`` (ids,
    lower resonance first), ``as_built_hz`` (their measured resonances), ``apart_hz``
    (how far apart they are) and ``needs_hz`` (how far apart they would have to be)."""
    index = {n: k for k, n in enumerate(seps.ids)}
    out = []
    for a, b in pairs:
        fa, fb = measured_frequency(measured[a]), measured_frequency(measured[b])
        if fa > fb:
            a, b, fa, fb = b, a, fb, fa
        need = seps.needed(index[a], index[b], fa)
        if fb < need:
            out.append({"pair": [a, b], "as_built_hz": [fa, fb], "apart_hz": fb - fa,
                        "needs_hz": need - fa})
    return out


def choose_tones(seps: Separations, tones: dict, measured: dict, pairs, windows=None,
                 band=None, free_out: dict | None = None) -> tuple:
    """Each impacter's tone inside its window, inside the drive band and outside the
    silent band of every impacter it must be told apart from, nearest the window's
    middle.

    Parameters
    ----------
    seps : Separations
    tones : dict
        Impacter id -> the window's middle [Hz] (:func:`rescaled_tones`).
    measured : dict
        Impacter id -> measured resonance [Hz] (or the halves').
    pairs : iterable of (str, str)
        Impacters that must be told apart.
    windows : dict, optional
        Impacter id -> its working window (lo, hi) [Hz] measured on the chip (a tuning
        sweep: :mod:`planner.afterfab.tune`), instead of the design's scaled to its
        measured resonance.
    band : (float, float), optional
        The drive band (lo, hi) [Hz] (``drive.band_hz``): no tone is chosen outside it.
    free_out : dict, optional
        Filled with impacter id -> the free intervals [(lo, hi), ...] [Hz] its tone was
        chosen in (its window, clear of the bands it must avoid, within the drive band):
        where :func:`move_tones` may move it.

    Returns
    -------
    (tones, blocked, outside)
        ``blocked``: impacter id -> the impacters whose silent bands cover its whole
        window (no tone drives it without one of them answering).  ``outside``:
        impacter id -> the tone it would need [Hz], for an impacter whose free window
        lies wholly outside ``band``: its tone is the band edge nearest that window (it
        plays, and nothing says it drives the impacter: the re-plan fails).
    """
    index = {n: k for k, n in enumerate(seps.ids)}
    partners = {n: set() for n in seps.ids}
    for a, b in pairs:
        partners[a].add(b)
        partners[b].add(a)
    nu = {n: measured_frequency(measured[n]) for n in seps.ids}
    # the loop below names a neighbour's silent band ``band``: the drive band is this
    drive_band = None if band is None else (float(band[0]), float(band[1]))
    out, blocked, outside = dict(tones), {}, {}
    for n in seps.ids:
        k = index[n]
        if windows and n in windows:
            free = [tuple(float(x) for x in windows[n])]
        else:
            scale = nu[n] / (tones[n] / seps.rho[k]) if tones[n] else 1.0
            half = 0.5 * (seps.lo[k] + seps.hi[k]) * scale
            free = [(tones[n] - half, tones[n] + half)]
        covers = []
        for m in sorted(partners[n]):
            j = index[m]
            band = (nu[m] - seps.below[j], nu[m] + seps.above[j])
            cut = []
            for lo, hi in free:
                if band[1] <= lo or band[0] >= hi:
                    cut.append((lo, hi))
                    continue
                covers.append(m)
                if lo < band[0]:
                    cut.append((lo, band[0]))
                if band[1] < hi:
                    cut.append((band[1], hi))
            free = cut
        if not free:
            blocked[n] = sorted(set(covers))
            continue
        if drive_band is not None:
            b_lo, b_hi = drive_band
            in_band = [(max(lo, b_lo), min(hi, b_hi)) for lo, hi in free
                       if max(lo, b_lo) < min(hi, b_hi)]
            if not in_band:
                # no tone of the band lies in its window: the band edge nearest it plays
                outside[n] = min(max(tones[n], free[0][0]), free[-1][1])
                out[n] = min(max(outside[n], b_lo), b_hi)
                continue
            free = in_band
        if free_out is not None:
            free_out[n] = list(free)
        # the free point nearest the middle, kept off a band's edge by what the edge's
        # measurement and the synthesis' snapping may be off (or the middle of a
        # narrower free interval)
        best = min(free, key=lambda iv: 0.0 if iv[0] <= tones[n] <= iv[1] else
                   min(abs(iv[0] - tones[n]), abs(iv[1] - tones[n])))
        edge = min(0.5 * (best[1] - best[0]), EDGE_MARGIN_HZ + EDGE_MARGIN_REL * tones[n])
        out[n] = min(max(tones[n], best[0] + edge), best[1] - edge)
    return out, blocked, outside


def _sub_steps(step, groups):
    """``step`` split into one sub-step per group of its active nodes."""
    out = []
    for k, group in enumerate(groups):
        fwd = tuple(d for d in step.forward if Node(d, "forward") in group)
        bwd = tuple(d for d in step.backward if Node(d, "backward") in group)
        out.append(dataclasses.replace(step, name=f"{step.name}.{k + 1}", forward=fwd,
                                       backward=bwd))
    return out


def split_step(step, tones, need, synthesize_and_limit):
    """``step`` as 2, 3, ... :data:`MAX_SPLIT` sub-steps of neighbouring tones, the
    fewest whose every sub-step keeps an acceleration scale of at least ``need``.

    Returns
    -------
    (sub-steps, waveforms, notes)
        Their indices are the step's (renumber them when placing them).
    """
    nodes = sorted((Node(d, r) for d, r in step.active_nodes()), key=lambda n: tones[n])
    chosen = None
    for k in range(2, min(MAX_SPLIT, len(nodes)) + 1):
        # k runs of neighbouring tones: an impacter of another run is idle next to a
        # run's edge only, never between its tones (the verification decides)
        groups = [{nodes[i] for i in run} for run in np.array_split(np.arange(len(nodes)), k)]
        subs = _sub_steps(step, groups)
        w, nt = synthesize_and_limit(subs, tones)
        chosen = (subs, w, nt)
        if all(nt[s.key]["acceleration_scale"] >= need for s in subs):
            break
    return chosen


def weakened(steps, notes, plan_scales):
    """The multi-tone steps whose tones the acceleration limit lowers below
    :data:`SPLIT_SCALE_MARGIN` of the scale the plan verified them at: step key ->
    the scale a split must keep."""
    out = {}
    for st in steps:
        need = plan_scales.get(st.key, 1.0) * SPLIT_SCALE_MARGIN
        if len(st.active_nodes()) > 1 and notes[st.key]["acceleration_scale"] < need:
            out[st.key] = need
    return out


def plan_phases(plan) -> dict:
    """Step key -> {Node -> the phase [rad] its tone played at in the plan}.

    The designs were made silent under each multi-tone step's drive as it was played,
    phases included; a re-plan that moves the tones by a fraction of a per cent and
    optimises their phases afresh plays another waveform.  Measured on the default
    (seed 0, chips 3, 8 and 16 of ``vibroplan yield --replan``): with new phases idle
    backward impacters (28-33 kHz) touched their sliders under the 25-tone positioning
    step from the edge of their gaps, at any amplitude that still moved every slider;
    with the plan's phases none did.  A gated burst's tones (``start_s`` given) and a
    step whose tones cannot be matched to its impacters keep optimised phases.
    """
    tone_of = {r.node: r.frequency_hz for r in plan.impacters}
    out = {}
    for st in plan.steps:
        if not st.tones or any(t.start_s is not None for t in st.tones):
            continue
        freqs = np.array([t.frequency_hz for t in st.tones])
        got = {}
        for d, r in st.step.active_nodes():
            n = Node(d, r)
            k = int(np.argmin(np.abs(freqs - tone_of[n])))
            # the played tone is the planned one snapped by at most 0.1 %
            if abs(freqs[k] - tone_of[n]) <= 2e-3 * tone_of[n]:
                got[n] = float(st.tones[k].phase_rad)
        if got and len(got) == len(st.step.active_nodes()):
            out[st.key] = got
    return out


@dataclasses.dataclass(frozen=True)
class RescuedDrive:
    """A chip's re-planned drive before its verification.

    Attributes
    ----------
    steps : tuple of Step
        The steps to play (multi-tone steps split where needed), bursts sized.
    waveforms, notes : dict
        Step key -> Waveform, and -> the acceleration limit's notes.
    dwells : dict
        Step key -> settle dwell after it [s] (the plan's; a sub-step takes its step's).
    tones : dict
        Node -> tone [Hz].
    inseparable : list of dict
        :func:`inseparable`'s pairs (no drive tells them apart).
    splits : dict
        Original step key -> its sub-step keys (:func:`split_weak`).
    sizing : dict
        :func:`planner.planning.motion.size_bursts`'s notes.
    weak : dict
        Step key -> the acceleration scale a split must keep (:func:`weakened`).
    synthesize_and_limit : callable
        ``(steps, tones) -> (waveforms, notes)`` under the plan's settings.
    gating : dict
        Step key -> the gate search's notes of each ``targets_um`` step, gated again
        for the chip (:func:`planner.afterfab.replan.regate`).
    """

    steps: tuple
    waveforms: dict
    notes: dict
    dwells: dict
    tones: dict
    inseparable: list
    splits: dict
    sizing: dict
    weak: dict = dataclasses.field(default_factory=dict)
    synthesize_and_limit: Callable | None = None
    gating: dict = dataclasses.field(default_factory=dict)
    #: impacter id -> the tone it would need [Hz], beyond the drive band (it plays at
    #: the band edge, ``tones``; :func:`choose_tones`)
    outside_band: dict = dataclasses.field(default_factory=dict)
    #: impacter id -> the free intervals [(lo, hi), ...] [Hz] of its window its tone
    #: may move in (:func:`choose_tones`' ``free_out``)
    free: dict = dataclasses.field(default_factory=dict)
    #: the tones :func:`move_tones` moved within their window, each a dict: ``id``,
    #: ``from_hz``, ``to_hz``, ``window_hz`` (the free interval it moved in), ``tries``,
    #: ``failures_before`` and ``failures_after`` (the checks of the steps it plays in
    #: that fail by more than the motion)
    tone_moves: tuple = ()


def rescue(plan, measured: dict, settings, models: dict, sliders: dict,
           remeasure=(), windows=None) -> RescuedDrive:
    """Re-plan a chip's drive from its measured resonances (steps 1-4 of the module
    notes); no simulation but the burst sizing's short probes.

    Parameters
    ----------
    plan : PlanRecord
    measured : dict
        Impacter id -> measured resonance [Hz] (or the halves' (a, b)).
    settings : Settings
        The plan's.
    models, sliders : dict
        The chip's models as measured (:func:`~planner.afterfab.as_built.as_built`) and its sliders: the
        bursts are sized for their speeds.
    remeasure : iterable of str
        Impacter ids whose separations are measured again on their models
        (:func:`remeasured`; a trim's moved impacters) instead of taken from the plan.
    windows : dict, optional
        Impacter id -> its working window (lo, hi) [Hz] measured on the chip by a tuning
        sweep: its tone goes to the window's middle (:func:`choose_tones`).
    """
    from planner.planning.drives import limit_acceleration, synthesize_steps

    measured = {n: measured.get(n, plan.design_natural_frequency_hz[n])
                for n in (r.id for r in plan.impacters)}
    seps = separations_of(plan, settings)
    pairs = must_differ(settings.steps)
    middle = rescaled_tones(plan, measured, seps, settings.tone_window)
    for n, (lo, hi) in (windows or {}).items():
        middle[n] = 0.5 * (lo + hi)
    remeasure = sorted(set(remeasure))
    if remeasure:
        by_id = {rec.id: models[rec.node] for rec in plan.impacters}
        seps = remeasured(seps, remeasure, by_id, middle, settings)
    free = {}
    chosen, blocked, outside = choose_tones(seps, middle, measured, pairs, windows,
                                            band=tuple(settings.band_hz), free_out=free)
    tones = shared_tones(plan, {rec.node: chosen[rec.id] for rec in plan.impacters},
                         settings.tone_window)
    # what blocks a tone is named pair by pair, with the separation each would need
    bad = inseparable(seps, measured, pairs)
    named = {n for c in bad for n in c["pair"]}
    for n, by in blocked.items():
        if n not in named:
            fa = measured_frequency(measured[n])
            bad.append({"pair": [n] + by, "as_built_hz": [fa] + [measured_frequency(
                measured[m]) for m in by], "apart_hz": None, "needs_hz": None})
    # the plan's steps as it played them: its sized and repaired bursts and dwells
    recorded = {st.key: st for st in plan.steps}
    base = []
    for st in settings.steps:
        rec = recorded.get(st.key)
        base.append(st if rec is None else dataclasses.replace(st, duration_s=rec.duration_s))
    scales = {st.key: (st.acceleration_scale or 1.0) for st in plan.steps}

    phases = plan_phases(plan)

    def synthesize_and_limit(steps, freqs):
        return limit_acceleration(settings, synthesize_steps(settings, steps, freqs,
                                                             phases=phases))

    waveforms, notes = synthesize_and_limit(tuple(base), tones)
    steps, sizing = size_within(settings, tuple(base), waveforms, models, sliders,
                                settings.max_travel_m * REPLAN_TRAVEL_MARGIN)
    dwells = {st.key: plan.dwells.get(st.key, 0.0) for st in steps}
    return RescuedDrive(steps, waveforms, notes, dwells, tones, bad, {}, sizing,
                        weakened(steps, notes, scales), synthesize_and_limit,
                        outside_band=outside, free=free)


def split_weak(settings, drive: RescuedDrive, rows, failures, models, sliders, check):
    """Split the weakened steps that fail by a slow slider, where that passes more checks.

    Parameters
    ----------
    drive : RescuedDrive
        Its steps verified: ``rows`` and ``failures`` of ``check(steps)``.
    check : callable
        ``(steps, waveforms) -> (rows, failures)`` on the models the drive is verified on.

    Returns
    -------
    (drive, rows, failures)
        The drive with its kept splits (steps renumbered in play order), and the checks
        of every step as it now stands.
    """
    from planner.planning.verify import TOO_SLOW

    slow = {f.step for f in failures if f.kind == TOO_SLOW}
    tries = [st for st in drive.steps if st.key in drive.weak and st.index in slow]
    if not tries:
        return drive, rows, failures
    keep = {}
    for st in tries:
        subs, w, nt = split_step(st, drive.tones, drive.weak[st.key],
                                 drive.synthesize_and_limit)
        subs, _ = size_within(settings, tuple(subs), w, models, sliders,
                              settings.max_travel_m)
        checked = [check([sub], w) for sub in subs]          # per sub-step
        before = sum(1 for r in rows if r["index"] == st.index and not r["passed"])
        after = sum(1 for sub_rows, _ in checked for r in sub_rows if not r["passed"])
        if after < before:
            keep[st.key] = (subs, w, nt, checked)
    if not keep:
        return drive, rows, failures
    # renumber the steps in play order; the checks follow their steps
    steps, new_rows, new_failures, index = [], [], [], {}
    for st in drive.steps:
        if st.key not in keep:
            index[st.index] = len(steps)
            steps.append(dataclasses.replace(st, index=len(steps)))
            continue
        subs, _, _, checked = keep[st.key]
        for sub, (sub_rows, sub_fails) in zip(subs, checked):
            k = len(steps)
            steps.append(dataclasses.replace(sub, index=k))
            new_rows += [{**r, "index": k} for r in sub_rows]
            new_failures += [dataclasses.replace(f, step=k) for f in sub_fails]
    waveforms, notes = dict(drive.waveforms), dict(drive.notes)
    for _, w, nt, _ in keep.values():
        waveforms.update(w)
        notes.update(nt)
    rows = sorted([{**r, "index": index[r["index"]]} for r in rows if r["index"] in index]
                  + new_rows, key=lambda r: r["index"])
    failures = ([dataclasses.replace(f, step=index[f.step]) for f in failures
                 if f.step in index] + new_failures)
    splits = {key: [s.key for s in subs] for key, (subs, _, _, _) in keep.items()}
    parent = {sub: key for key, subs in splits.items() for sub in subs}
    dwells = {st.key: drive.dwells.get(parent.get(st.key, st.key), 0.0) for st in steps}
    return (dataclasses.replace(drive, steps=tuple(steps), waveforms=waveforms, notes=notes,
                                dwells=dwells, splits=splits),
            rows, failures)


#: Phase draws :func:`redraw_slow` tries on a multi-tone step whose slider is too slow on
#: the chip (each optimised afresh; the plan's phases are draw 0) [-].
SLOW_REDRAWS = 3


def redraw_slow(settings, drive: RescuedDrive, rows, failures, models, sliders, check):
    """Draw the phases of every multi-tone step a slider is too slow in anew, where a
    draw passes more checks.

    The plan's phases are kept first (its designs were made silent under the summed
    drives as they played), but on a chip a 25-tone step's sum can hold a mover off its
    wall from some initial state, or the acceleration limit lowers it further (a
    slider at 0 mm/s from some x0 of the default's positioning step on 2 of 40 sampled
    chips).  As the plan's own loop does, :data:`SLOW_REDRAWS` new draws are tried
    (:func:`planner.planning.drives.synthesize_steps`'s ``draws``), each under the
    acceleration limit and a drive chain's input limit (new phases, a new peak at the
    amplifier input: :func:`planner.planning.chain.limit_drives`) and with its burst
    sized again; the first draw whose step passes every check but the motion's is kept,
    else the one with the fewest such failures if fewer than before.  Every check, the
    idle impacters' silence included, is on the chip's models.

    Parameters and returns as :func:`quieten`.
    """
    from planner.planning.chain import limit_drives
    from planner.planning.drives import synthesize_steps
    from planner.planning.verify import TOO_SLOW

    slow = {f.step for f in failures if f.kind == TOO_SLOW}
    steps = list(drive.steps)
    waveforms, notes = dict(drive.waveforms), dict(drive.notes)
    rows, failures = list(rows), list(failures)
    for pos, st in enumerate(drive.steps):
        if (st.index not in slow or st.targets_m is not None
                or len(np.atleast_1d(waveforms[st.key].frequencies)) < 2):
            continue
        before = _serious(f for f in failures if f.step == st.index)
        def draw(k):
            # every draw held to the limits the plan's phases were: the acceleration's,
            # and a drive chain's input volts (new phases, a new peak at the input)
            w, nt = limit_drives(settings, synthesize_steps(
                settings, (st,), drive.tones, draws={st.key: k}), (st,), drive.tones)
            (sub,), _ = size_within(settings, (st,), w, models, sliders,
                                    settings.max_travel_m)
            got_rows, got_fails = check([sub], w)
            return _serious(got_fails), (sub, w, nt, got_rows, got_fails)

        best = _least_serious(range(1, SLOW_REDRAWS + 1), draw)
        if best is None or best[0] >= before:
            continue
        _, k, (sub, w, nt, got_rows, got_fails), _ = best
        steps[pos] = sub
        waveforms.update(w)
        notes[st.key] = {**nt[st.key], "phases_drawn": k}
        rows = [r for r in rows if r["index"] != st.index] + got_rows
        failures = [f for f in failures if f.step != st.index] + list(got_fails)
    rows.sort(key=lambda r: r["index"])
    return (dataclasses.replace(drive, steps=tuple(steps), waveforms=waveforms, notes=notes),
            rows, failures)


#: Amplitude factors :func:`quieten` tries, in turn, on a step an idle impacter answers
#: (relative to the step's drive as re-planned) [-].
QUIET_FACTORS = (0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3)


def _serious(fails) -> int:
    """The failures a re-plan's repair counts: every kind but the motion's (a travel over
    the limit, a step that does not settle), which the motion repair acts on after it."""
    from planner.planning.verify import TRAVEL_OVER, UNSETTLED

    return sum(1 for f in fails if f.kind not in (TRAVEL_OVER, UNSETTLED))


def _least_serious(candidates, attempt):
    """The repairs' loop: ``attempt(c)`` -> (serious failures, result) for each of
    ``candidates`` in order, stopping at the first with none.  Returns (failures,
    candidate, result, tries) of the one with the fewest (the first of equals), or None
    when there is no candidate."""
    best, tries = None, 0
    for c in candidates:
        tries += 1
        bad, result = attempt(c)
        if best is None or bad < best[0]:
            best = (bad, c, result)
        if bad == 0:
            break
    return None if best is None else (*best, tries)


def reunite(plan, settings, drive: RescuedDrive, rows, failures, models, sliders, check):
    """Play each row that shared one tone in ``plan`` on one tone again where its members
    now play several and the drive fails: the members' mean, beyond their designed
    windows too, kept where fewer checks fail.

    :func:`shared_tones` keeps a row on one tone only within each member's designed
    tone window; spread wider by fabrication, every member plays its own tone, and the
    step sums a tone per member where the plan played one: their beats reach N times the
    plan's amplitude at the idle impacters, which were designed silent under one tone.
    One tone at the row's mean may still drive every member (each responds over a band
    wider than its designed window, at a lower speed): the verification decides.  Every
    step a row plays in is synthesised again with the row on its mean, its burst sized
    again, and the variant kept where it has fewer failures than the drive as it stands
    (the motion's aside, as :func:`quieten` counts them).

    Returns
    -------
    (drive, rows, failures)
    """
    if not _serious(failures):
        return drive, rows, failures
    split = [ms for ms in _rows(plan, drive.tones) if len({drive.tones[n] for n in ms}) > 1]
    if not split:
        return drive, rows, failures
    tones = dict(drive.tones)
    for members in split:
        mean = sum(tones[n] for n in members) / len(members)
        for n in members:
            tones[n] = mean
    moved = {n for ms in split for n in ms}
    touched = [st for st in drive.steps
               if any(Node(d, r) in moved for d, r in st.active_nodes())
               and st.targets_m is None]
    if not touched:
        return drive, rows, failures
    waveforms, notes = drive.synthesize_and_limit(tuple(touched), tones)
    sized, _ = size_within(settings, tuple(touched), waveforms, models, sliders,
                           settings.max_travel_m)
    got_rows, got_fails = check(list(sized), waveforms)
    keys = {st.index for st in touched}
    before = _serious(f for f in failures if f.step in keys)
    if _serious(got_fails) >= before:
        return drive, rows, failures
    by_key = {st.key: st for st in sized}
    steps = tuple(by_key.get(st.key, st) for st in drive.steps)
    rows = sorted([r for r in rows if r["index"] not in keys] + list(got_rows),
                  key=lambda r: r["index"])
    failures = [f for f in failures if f.step not in keys] + list(got_fails)
    notes_all = {**drive.notes, **{k: {**v, "rows_reunited": True} for k, v in notes.items()}}
    return (dataclasses.replace(drive, steps=steps, tones=tones,
                                waveforms={**drive.waveforms, **waveforms}, notes=notes_all),
            rows, failures)


def quieten(settings, drive: RescuedDrive, rows, failures, models, sliders, check):
    """Lower the drive of each step an idle impacter answers until it no longer does.

    On a chip an idle impacter can answer a step its design was silent under: its
    resonance has moved towards the step's tones, or (most often, measured) it starts at
    the edge of its gap and the transient of its release plus the step's forced response
    reaches the wall (an impacter with Q ~ 70 swings back to 98 % of its gap in half a
    cycle).  A new phase draw does not change a multi-tone step's optimised phases; a
    weaker drive does.  Each such step is tried at :data:`QUIET_FACTORS` of its amplitude,
    its burst sized again for the slower sliders, and the first factor whose step passes
    every check but the motion's is kept (else the one with the fewest such failures, if
    fewer than before); the movers' speed floor is one of the checks, so a step is never
    weakened below what moves its sliders; a step gated for targets is not tried (its
    gates are its amplitudes').  A slider that then travels too far, or
    settles too late, is the motion repair's (shorter bursts, longer dwells:
    :func:`planner.planning.repair.repair_motion`), which runs after this.

    Parameters
    ----------
    drive : RescuedDrive
        Its steps verified: ``rows`` and ``failures`` of ``check(steps)``.
    check : callable
        ``(steps, waveforms) -> (rows, failures)`` on the models the drive is verified on.

    Returns
    -------
    (drive, rows, failures)
        The drive with the weakened steps (their notes say by how much), and the checks
        of every step as it now stands.
    """
    from planner.planning.drives import drive_peaks, scaled
    from planner.planning.verify import IDLE_RESPONSE

    answered = {f.step for f in failures if f.kind == IDLE_RESPONSE}
    if not answered:
        return drive, rows, failures
    steps = list(drive.steps)
    waveforms, notes = dict(drive.waveforms), dict(drive.notes)
    rows, failures = list(rows), list(failures)
    for pos, st in enumerate(drive.steps):
        if st.index not in answered or st.targets_m is not None:
            # a step gated for targets plays its tones one at a time for the times that
            # put each slider on its target: weaker, every slider falls short (and each
            # try simulates a burst of up to a second from every x0: on configs/
            # pattern_5x5.yaml's 24 moves, minutes a chip)
            continue
        before = _serious(f for f in failures if f.step == st.index)
        def lowered(factor):
            w = scaled(waveforms[st.key], factor, f"every amplitude lowered by x{factor:g} "
                       "more: an idle impacter answered the step on this chip")
            (sub,), _ = size_within(settings, (st,), {st.key: w}, models, sliders,
                                    settings.max_travel_m)
            got_rows, got_fails = check([sub], {st.key: w})
            return _serious(got_fails), (sub, w, got_rows, got_fails)

        best = _least_serious(QUIET_FACTORS, lowered)
        if best is None or best[0] >= before:
            continue
        _, factor, (sub, w, got_rows, got_fails), _ = best
        steps[pos] = sub
        waveforms[st.key] = w
        zp, ap = drive_peaks(w)
        note = dict(notes.get(st.key, {}))
        note.update(peak_displacement_m=zp, peak_acceleration_m_s2=ap,
                    acceleration_scale=note.get("acceleration_scale", 1.0) * factor,
                    quietened_by=factor)
        notes[st.key] = note
        rows = [r for r in rows if r["index"] != st.index] + got_rows
        failures = [f for f in failures if f.step != st.index] + list(got_fails)
    rows.sort(key=lambda r: r["index"])
    return (dataclasses.replace(drive, steps=tuple(steps), waveforms=waveforms, notes=notes),
            rows, failures)


#: Positions :func:`move_tones` tries for a failing impacter's tone, as fractions of the
#: free interval of its window it lies in (kept off the interval's edges as
#: :func:`choose_tones` keeps a tone), nearest the tone first; the one within
#: :data:`MOVE_MIN_FRACTION` of the interval's width of the tone is not tried [-].
MOVE_FRACTIONS = (0.1, 0.3, 0.5, 0.7, 0.9)
MOVE_MIN_FRACTION = 0.1
#: Positions tried per failing impacter at most (0: the repair is off) [-].
MOVE_TRIES = 5
#: Failing impacters whose tone is moved at most per chip [-]: each try re-checks every
#: step the impacter plays in (the costliest part of a re-plan).
MOVE_IMPACTERS = 4


def _suspects(drive: RescuedDrive, failures) -> list:
    """The impacters whose tone a step fails by, in order of first failure: a slow
    slider's moving impacter (its tone drives it too weakly), and for an idle impacter
    that answers a step the step's tone nearest its own (the neighbour's tone it
    answers).  Steps gated for targets are left (their gates are the tone's)."""
    from planner.planning.verify import IDLE_RESPONSE, TOO_SLOW

    by_index = {st.index: st for st in drive.steps}
    out = []
    for f in sorted(failures, key=lambda f: (f.step, f.device, f.kind)):
        st = by_index.get(f.step)
        if st is None or st.targets_m is not None:
            continue
        active = sorted((Node(d, r) for d, r in st.active_nodes()), key=lambda n: n.text)
        if f.kind == TOO_SLOW:
            got = [n for n in active if n.device == f.device]
        elif f.kind == IDLE_RESPONSE and f.impacter is not None and active:
            own = drive.tones[Node(*f.impacter)]
            got = [min(active, key=lambda n: abs(drive.tones[n] - own))]
        else:
            continue
        out += [n for n in got if n not in out]
    return out


def _positions(free, tone: float) -> list:
    """The tones [Hz] :func:`move_tones` tries within ``free`` (intervals [Hz]) for a
    tone now at ``tone`` [Hz], nearest first."""
    out = []
    for lo, hi in free:
        edge = min(0.5 * (hi - lo), EDGE_MARGIN_HZ + EDGE_MARGIN_REL * tone)
        lo, hi = lo + edge, hi - edge
        if hi <= lo:
            continue
        for frac in MOVE_FRACTIONS:
            t = lo + frac * (hi - lo)
            if abs(t - tone) > MOVE_MIN_FRACTION * (hi - lo):
                out.append(float(t))
    return sorted(out, key=lambda t: (abs(t - tone), t))[:MOVE_TRIES]


def move_tones(settings, drive: RescuedDrive, rows, failures, models, sliders, check):
    """Move the tone of each impacter a step fails by to another place in its window,
    where the steps it plays in then pass more checks.

    The re-plan puts each tone in the middle of its window (the designs' measured tone
    window scaled to the measured resonance, within the designed window; or a tuning
    sweep's working window), clear of the silent bands it must avoid
    (:func:`choose_tones`).  On the measured models a tone may still drive its slider too
    slowly there, or an idle neighbour may answer it.  For each such impacter
    (:func:`_suspects`, at most :data:`MOVE_IMPACTERS`), up to :data:`MOVE_TRIES`
    positions of its free window (:data:`MOVE_FRACTIONS`, nearest first) are tried: the
    steps it plays in are synthesised again with the moved tone (the plan's phases, the
    acceleration and input limits), their bursts sized again, and checked; the first
    position whose steps pass every check but the motion's is kept, else the one with the
    fewest such failures if fewer than before.  A moved tone drops what the other
    repairs did to its steps (a phase draw, a quietening): they run again after this.
    Steps gated for targets are not moved (their gates are the tone's).

    Parameters and returns as :func:`quieten`; the returned drive's ``tone_moves`` says
    what moved.
    """
    from planner.planning.verify import TRAVEL_OVER, UNSETTLED

    if MOVE_TRIES <= 0 or drive.synthesize_and_limit is None:
        return drive, rows, failures
    suspects = _suspects(drive, [f for f in failures
                                 if f.kind not in (TRAVEL_OVER, UNSETTLED)])
    steps = list(drive.steps)
    tones, waveforms, notes = dict(drive.tones), dict(drive.waveforms), dict(drive.notes)
    rows, failures = list(rows), list(failures)
    moves = list(drive.tone_moves)
    for n in suspects[:MOVE_IMPACTERS]:
        where = [pos for pos, st in enumerate(steps) if n in
                 {Node(d, r) for d, r in st.active_nodes()}]
        played = [steps[pos] for pos in where]
        if not played or any(st.targets_m is not None for st in played):
            continue
        indices = {st.index for st in played}
        before = _serious(f for f in failures if f.step in indices)
        if before == 0:
            continue
        free = drive.free.get(n.text, [])
        def moved(t):
            w, nt = drive.synthesize_and_limit(tuple(played), {**tones, n: t})
            subs, _ = size_within(settings, tuple(played), w, models, sliders,
                                  settings.max_travel_m)
            got_rows, got_fails = check(list(subs), w)
            return _serious(got_fails), (subs, w, nt, got_rows, got_fails)

        # the nearest position that passes: the tone was placed for the most room
        # (the window's middle), and the speeds rise toward the window's cliff, where
        # the measured models' error matters most (keeping the fastest of the passing
        # positions lost 2 chips more of 200 on their true models)
        best = _least_serious(_positions(free, tones[n]), moved)
        if best is None or best[0] >= before:
            continue
        bad, t, (subs, w, nt, got_rows, got_fails), tries = best
        window = next(([float(lo), float(hi)] for lo, hi in free if lo <= t <= hi), None)
        moves.append({"id": n.text, "from_hz": float(tones[n]), "to_hz": float(t),
                      "window_hz": window, "tries": tries, "failures_before": before,
                      "failures_after": bad})
        tones[n] = t
        for pos, sub in zip(where, subs):
            steps[pos] = sub
        waveforms.update(w)
        for key, note in nt.items():
            notes[key] = note
        rows = [r for r in rows if r["index"] not in indices] + list(got_rows)
        failures = [f for f in failures if f.step not in indices] + list(got_fails)
    if len(moves) == len(drive.tone_moves):
        return drive, rows, failures
    rows.sort(key=lambda r: r["index"])
    return (dataclasses.replace(drive, steps=tuple(steps), tones=tones, waveforms=waveforms,
                                notes=notes, tone_moves=tuple(moves)),
            rows, failures)


#: Factors :func:`raise_slow` raises a slow slider's tones by, in turn (the step's other
#: tones as they were; the step then held to the peak and acceleration limits, which may
#: lower every tone of it) [-].
RAISE_FACTORS = (1.03, 1.06, 1.1, 1.15)


def raise_slow(settings, steps, waveforms, tones, failures, models, sliders, check_models,
               check_chip, why="its slider moved too slowly"):
    """Raise the tone of each impacter whose slider a lab sees too slow on the chip, in
    the steps it is too slow in: the drive of that impacter's steps changed before the
    chip is scrapped (issue 45, item 2).

    The re-plan placed every tone for the chip's *measured* models; on the chip itself a
    slider may still move below the speed floor (its impacter's true resonance a little
    further from the tone than measured, so that the tone drives it from fewer starting
    states).  A stronger tone widens the band in which an impacter answers it: for each
    step a slider is too slow in (``failures``: the chip's, as the lab sees them playing
    the drive), the tones of its moving impacters are raised by :data:`RAISE_FACTORS` in
    turn, the step held to ``drive.peak_limit_um`` and ``drive.max_acceleration_g`` (the
    other tones lowered with it where a limit binds) and its burst sized again within the
    travel limit; the first factor whose step passes every check but the motion's on the
    measured models (the idle impacters' silence among them) and then on the chip is
    kept.  Steps gated for targets, and a plan with a drive chain (whose input limit the
    re-synthesis would have to hold), are left as they are.

    Parameters
    ----------
    steps : sequence of Step
    waveforms : dict
        Step key -> its loop (:class:`planner.synthesis.Waveform`).
    tones : dict
        Node -> the impacter's tone [Hz] in this drive.
    failures : sequence of Failure
        The drive's failed checks on the chip.
    models, sliders :
        The measured models the bursts are sized on.
    check_models, check_chip : callable
        ``(steps, waveforms) -> (rows, failures)``: the per-step checks on the measured
        models and on the chip.
    why : str
        The reason the raised waveform's warning gives.

    Returns
    -------
    (steps, waveforms, raised)
        The drive with the raised steps, and one record per raised step (``step``,
        ``ids``, ``factor``).
    """
    from planner.planning.drives import limit_acceleration, reweighted, scaled
    from planner.planning.motion import by_node
    from planner.planning.verify import TOO_SLOW
    from planner.synthesis import Waveform

    models = by_node(models)        # a chip's models may be keyed by impacter id
    if settings.chain is not None:
        return tuple(steps), dict(waveforms), ()
    slow = {}
    for f in failures:
        if f.kind == TOO_SLOW:
            slow.setdefault(f.step, set()).add(f.device)
    steps, waveforms, raised = list(steps), dict(waveforms), []
    for pos, st in enumerate(steps):
        w = waveforms.get(st.key)
        if st.index not in slow or st.targets_m is not None or not isinstance(w, Waveform):
            continue
        movers = sorted(Node(d, r) for d, r in st.active_nodes() if d in slow[st.index])
        freqs = np.atleast_1d(w.frequencies)
        idx = sorted({int(np.argmin(np.abs(freqs - tones[n]))) for n in movers if n in tones})
        if not idx:
            continue

        def attempt(factor, st=st, w=w, idx=idx):
            a = np.array(w.amplitudes, dtype=float)
            a[idx] *= factor
            got = reweighted(w, a, f"tone(s) {', '.join(f'{freqs[i]:.1f}' for i in idx)} Hz "
                                   f"raised x{factor:g}: {why}")
            limit = settings.peak_limit_m
            if limit is not None and got.peak > limit:
                got = scaled(got, limit / got.peak * (1.0 - 1e-6),
                             "every amplitude lowered to meet drive.peak_limit_um")
            held, _ = limit_acceleration(settings, {st.key: got})
            (sub,), _ = size_within(settings, (st,), held, models, sliders,
                                    settings.max_travel_m)
            _, on_models = check_models([sub], held)
            if _serious(on_models):
                return 1 + _serious(on_models), None
            _, on_chip = check_chip([sub], held)
            return _serious(on_chip), (sub, held)

        best = _least_serious(RAISE_FACTORS, attempt)
        if best is None or best[0] > 0 or best[2] is None:
            continue
        _, factor, (sub, held), _ = best
        steps[pos] = sub
        waveforms.update(held)
        raised.append({"step": st.key, "ids": [n.text for n in movers], "factor": factor})
    return tuple(steps), waveforms, tuple(raised)
