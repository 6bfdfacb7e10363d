"""Slider motion under a step's summed drive: phases with carried state, the settle
dwell after a burst and burst sizing for ``travel_um`` steps.

Every slider simulation of the plan goes through :func:`run_phase`, which kicks each
slider by its device's contact law (``device.contact``): impacts are collected as
:class:`model.Kicks` records, which either law can use ("paper" gives exactly the
velocity changes of :func:`model.kick`, bit for bit as before the option existed).

The settle dwell
----------------
After a burst the drive is switched off and the plan waits until nothing moves: every
slider at rest (friction holds it) and no impacter able to hit its slider again.  With
the drive off an impacter's mechanical energy never grows (film damping, and each hit
takes (1 - e^2) of it), so once its energy amplitude sqrt(x^2 + m v^2 / k) is at most
its gap c it can no longer reach the wall with a positive speed.  :func:`settle` runs
the undriven phase in chunks of :data:`SETTLE_CHUNK_S` until both hold, up to a cap;
the dwell is the simulated time, rounded up to whole chunks.

Burst sizing
------------
A step with ``travel_um`` gets the burst that moves its slowest driven slider that far:
every driven device is simulated under the step's summed drive from rest for
:data:`PROBE_S`; the slowest mean speed v_min gives duration = travel / v_min, rounded
up to :data:`BURST_QUANTUM_S` and bounded to [:data:`MIN_BURST_S`, the step's
``duration_ms`` or :data:`planner.arrayspec.DEFAULT_MAX_BURST_S`].  Faster sliders of the
same step travel further; ``verification.max_travel_um`` bounds them.
"""

from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np

import model
from model import Drive
from planner.core.nodes import Node
from planner.planning.drives import drive_of

#: Chunk [s] of the undriven settle simulation, and the dwell's granularity.
SETTLE_CHUNK_S = 5e-4
#: Probe window [s] of the burst sizing.
PROBE_S = 5e-3
#: Shortest burst [s] a ``travel_um`` step gets.
MIN_BURST_S = 1e-3
#: Bursts sized from a travel are rounded up to this [s].
BURST_QUANTUM_S = 1e-4
#: The drive switched off.
REST = Drive([1.0], [0.0])


def _empty_kicks():
    return np.empty(0), np.empty(0)


def by_node(models: dict) -> dict:
    """``models`` keyed by :class:`~planner.core.nodes.Node`, as every stage keys them.

    Two other keys are re-keyed here, once, at the entry of the verification and the
    scene simulation: a node's text (a chip sampled by
    :func:`planner.fabrication.tolerances.sample_chip` is keyed by plan.json's ids) and a plain
    ``(device, direction)`` tuple (what a Node key becomes when Dask scatters a dict to
    its worker processes: ``client.scatter`` sends a dict of plain types by msgpack).
    """
    if all(type(n) is Node for n in models):
        return models
    return {Node(*n) if isinstance(n, tuple) else Node.parse(n): m for n, m in models.items()}


def run_phase(impacters, sliders, contacts, drive, duration, states, sl_states, memo=None):
    """Advance impacters and sliders through one phase of ``duration`` [s].

    Parameters
    ----------
    impacters : dict
        :class:`~planner.core.nodes.Node` -> model.Impacter.
    sliders : dict
        Device id -> model.Slider (only these sliders move; each is kicked by its
        own impacters among ``impacters``).
    contacts : dict
        Device id -> contact law ("paper" or "two_body").
    drive : model.Drive
    duration : float
        [s].
    states : dict
        Node -> (x [m], v [m/s], stuck); updated in place (missing: rest at x = 0).  A
        pair of unequal halves (:class:`model.PairHalves`) has one such state per half.
    sl_states : dict
        Device -> (z [m], v [m/s]); updated in place (missing: rest at 0).
    memo : dict, optional
        Simulations already run in this phase's setting, reused when asked again (a
        check's runs from the x0 grid simulate every idle impacter of a device from
        rest once per start, and the start x0 = 0 is the run from rest again): an
        impacter half's simulation is keyed by its model, start, drive and duration
        (the drive and the models by identity: the caller keeps them alive while the
        memo is), a slider's by the kicks' simulations and its own start.  The same
        inputs give the same digits, so a memo changes no result, only the time.

    Returns
    -------
    dict
        Node -> number of impacts in the phase (chatter tails count once).
    """
    per_device = {d: [] for d in sliders}
    keys = {d: [] for d in sliders}
    hits = {}
    for node, imp in impacters.items():
        if node.device not in sliders:
            continue
        parts = model.halves(imp)
        # a pair of unequal halves carries one state per half
        prior = states.get(node)
        if len(parts) == 1:
            starts = (prior,)
        elif prior is None or not isinstance(prior[0], tuple):
            starts = (prior,) * len(parts)        # one start (an x0 of the grid) for both
        else:
            starts = prior
        after, count = [], 0
        for (half, share), start in zip(parts, starts):
            x0, v0, stuck = start or (0.0, 0.0, False)
            key = (id(half), share, node.sign, id(sliders[node.device]), _exact(x0),
                   _exact(v0), bool(stuck), id(drive), duration)
            got = None if memo is None else memo.get(key)
            if got is None:
                res = model.simulate(half, drive, x0, v0, duration, stuck=stuck or None,
                                     max_events=1_000_000)
                got = ((min(res.x_end, half.gap), res.v_end, res.stuck_end),
                       model.Kicks.from_impacts(half, sliders[node.device], res, node.sign,
                                                share),
                       int(res.times.size + res.chatter_times.size))
                if memo is not None:
                    # the models and the drive are keyed by identity: held here, so
                    # that no other object takes their id while the memo lives
                    memo[key] = got
                    memo.setdefault("_held", []).extend((half, drive, sliders[node.device]))
            after.append(got[0])
            per_device[node.device].append(got[1])
            keys[node.device].append(key)
            count += got[2]
        states[node] = after[0] if len(parts) == 1 else tuple(after)
        hits[node] = count
    for dev, slider in sliders.items():
        z0, v0 = sl_states.get(dev, (0.0, 0.0))
        key = ("slider", id(slider), contacts[dev], tuple(keys[dev]), _exact(z0),
               _exact(v0), id(drive), duration)
        if memo is not None and key in memo:
            sl_states[dev] = memo[key]
            continue
        if per_device[dev]:
            kicks = model.Kicks.concatenate(per_device[dev])
            _, _, z, v, _ = model.slider_motion(slider, drive, kicks, duration=duration,
                                                z0=z0, v0=v0, contact=contacts[dev])
        else:
            t, dv = _empty_kicks()
            _, _, z, v, _ = model.slider_motion(slider, drive, t, dv, duration, z0, v0)
        sl_states[dev] = (float(z), float(v))
        if memo is not None:
            memo[key] = sl_states[dev]
            memo.setdefault("_held", []).extend((slider, drive))
    return hits


def _exact(x):
    """A float as a memo key: its value and its sign (-0.0 is not 0.0 to a kernel)."""
    return float(x), math.copysign(1.0, x)


def can_hit(impacter, state):
    """Whether an undriven impacter in ``state`` (x, v, stuck) can still reach its wall
    with a positive speed: its energy amplitude sqrt(x^2 + m v^2 / k) exceeds c.  A
    pair of unequal halves (:class:`model.PairHalves`) has a state per half and can hit
    while either half can."""
    parts = model.halves(impacter)
    if len(parts) > 1:
        return any(can_hit(h, st or (0.0, 0.0, False)) for (h, _), st in zip(parts, state))
    x, v, _ = state
    amp2 = x * x + impacter.mass * v * v / impacter.stiffness
    return amp2 > impacter.gap * impacter.gap * (1.0 + 1e-9)


def settled(impacters, sliders, states, sl_states):
    """Every slider of ``sliders`` at rest and no impacter of theirs able to hit."""
    if any(sl_states.get(d, (0.0, 0.0))[1] != 0.0 for d in sliders):
        return False
    return not any(can_hit(imp, states.get(n, rest_state(imp)))
                   for n, imp in impacters.items() if n.device in sliders)


def rest_state(impacter):
    """The state of an impacter (pair) at rest, as :func:`run_phase` keeps it."""
    parts = model.halves(impacter)
    return (0.0, 0.0, False) if len(parts) == 1 else ((0.0, 0.0, False),) * len(parts)


def settle(impacters, sliders, contacts, states, sl_states, cap, at_least=0.0):
    """Drive off until :func:`settled` (at least ``at_least`` [s], at most ``cap`` [s]).

    Returns
    -------
    (dwell [s], settled, hits)
        ``hits``: node -> impacts during the dwell.
    """
    t, hits = 0.0, {}
    n_min = math.ceil(at_least / SETTLE_CHUNK_S - 1e-9)
    n_max = max(1, math.ceil(cap / SETTLE_CHUNK_S - 1e-9))
    k = 0
    while True:
        if k >= n_min and settled(impacters, sliders, states, sl_states):
            return k * SETTLE_CHUNK_S, True, hits
        if k >= n_max:
            return k * SETTLE_CHUNK_S, False, hits
        for n, h in run_phase(impacters, sliders, contacts, REST, SETTLE_CHUNK_S, states,
                              sl_states).items():
            if h:
                hits[n] = hits.get(n, 0) + h
        k += 1
        t += SETTLE_CHUNK_S


def run_program(impacters, sliders, contacts, program, states, sl_states, memo=None):
    """:func:`run_phase` through every (duration [s], model.Drive) stretch of
    ``program`` in turn, the states carried across (a step's drive as
    :func:`planner.planning.drives.program_of` gives it: one stretch for a loop, one
    per stretch between ramp edges for a gated burst).

    ``memo``: as :func:`run_phase`'s.

    Returns
    -------
    dict
        Node -> impacts over the whole program.
    """
    hits = {}
    for duration, drive in program:
        for n, h in run_phase(impacters, sliders, contacts, drive, duration, states,
                              sl_states, memo).items():
            hits[n] = hits.get(n, 0) + h
    return hits


def device_travel(own, dev, slider, contact, program, cap, starts=None, memo=None):
    """One device from rest (or ``starts``: node -> (x0, v0, stuck)) through a step's
    ``program`` (:func:`run_program`, with ``memo``) and its settle dwell.

    Returns
    -------
    (burst displacement [m], travel incl. the dwell [m], dwell [s], settled)
    """
    states = dict(starts or {})
    sl = {dev: (0.0, 0.0)}
    run_program(own, {dev: slider}, {dev: contact}, program, states, sl, memo)
    burst = sl[dev][0]
    dwell, ok, _ = settle(own, {dev: slider}, {dev: contact}, states, sl, cap)
    return burst, sl[dev][0], dwell, ok


def probe_speeds(settings, step, drive, impacters, sliders, window=PROBE_S):
    """Device -> mean speed [m/s] along its commanded direction over ``window`` [s]
    from rest, under the step's summed drive (every driven device)."""
    out = {}
    for d, direction in sorted(step.active_nodes()):
        own = {n: imp for n, imp in impacters.items() if n.device == d}
        states, sl = {}, {d: (0.0, 0.0)}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", model.SolverWarning)
            run_phase(own, {d: sliders[d]}, {d: settings.contacts[d]}, drive, window,
                      states, sl)
        sign = 1.0 if direction == "forward" else -1.0
        out[d] = sign * sl[d][0] / window
    return out


def burst_for(travel_m, speed_m_s):
    """The burst [s] that moves a slider ``travel_m`` [m] at ``speed_m_s`` [m/s], rounded
    up to :data:`BURST_QUANTUM_S`."""
    return math.ceil(travel_m / speed_m_s / BURST_QUANTUM_S - 1e-9) * BURST_QUANTUM_S


def size_bursts(settings, steps, waveforms, impacters, sliders):
    """Steps with their bursts sized from ``travel_m`` (see the module docstring).

    Returns
    -------
    (steps, notes)
        ``notes``: step key -> {"probe_speeds_m_s": ..., "sized_s": ...} of each sized
        step.
    """
    from planner.arrayspec import DEFAULT_MAX_BURST_S

    out, notes = [], {}
    for st in steps:
        if st.travel_m is None:
            out.append(st)
            continue
        speeds = probe_speeds(settings, st, drive_of(waveforms[st.key]), impacters, sliders)
        slowest = min(speeds.values()) if speeds else 0.0
        cap = st.max_duration_s if st.max_duration_s is not None else DEFAULT_MAX_BURST_S
        if slowest > 0:
            want = burst_for(st.travel_m, slowest)
            duration = min(max(want, MIN_BURST_S), cap)
        else:
            duration = cap
        notes[st.key] = {"probe_speeds_m_s": speeds, "slowest_m_s": slowest,
                         "sized_s": duration}
        out.append(dataclasses.replace(st, duration_s=float(duration)))
    return tuple(out), notes

