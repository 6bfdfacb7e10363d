"""Stage 4c, targets: a gated burst that puts every slider of a ``targets_um`` step where
its scene asks it to be.

One summed drive moves a step's sliders at speeds ten times apart, so a burst sized for
one slider leaves the others short or far beyond their targets.  A ``targets_um`` step
therefore plays a gated burst (:mod:`planner.gating`): each tone fades in at its own
start and fades out at its own gate, when its slider has gone far enough.

Why the tones take turns
------------------------
Measured on the default 5 x 5 designs (docs/targets.md): under the summed drive of all
25 tones (~2,700 g peak, so M zeta'' reaches the sliders' 20 uN static friction) a
slider, once an impact has set it sliding, is carried by the substrate's vibration
against only its 5 uN dynamic friction: it moves 5-12 mm/s in jumps of 5-20 um, a jump
whenever the summed drive peaks, whichever tones still play.  No gate places it within
2 um then (gating all 25 tones at once left errors up to 16 um).  With the tones that
play together kept to a summed base acceleration below the sliders' dynamic friction
over their mass (:func:`slip_budget`; 2-3 tones here), a slider moves only while its
own impacter kicks it (0.3-0.8 mm/s, in steps of 0.02-0.4 um), stops when its tone
stops, and an idle slider never slips.  So the tones of a targets step take turns:
each starts as soon as the tones still playing leave room in that budget (in order of
their playing time, longest first), and a burst takes a few hundred ms where the summed
drive would take a few tens.

The designs need no change for this: the tones that play together are a subset of the
step's summed drive, which the idle impacters were designed silent under, and each
impacter of such a step is also designed silent under every other tone of it and able
to move its slider alone (:func:`planner.assign.plan_steps`); the verification
re-simulates the burst exactly as it is exported, so none of this is taken on trust.

Finding the gates
-----------------
From the state the scene is in when the step starts (the carried state of
:func:`planner.planning.scenes.simulate_scenes`), each burst followed by its settle
dwell, since a slider moves on while its tone fades out:

1. **probe**: the tones in groups within the budget, each group played to the
   longest a tone may play (the step's ``duration_ms``, else
   :data:`planner.spec.DEFAULT_MAX_BURST_S`); each slider's travel is recorded every
   :data:`PROBE_CHUNK_S`.  A slider that does not travel its move in that time cannot
   reach its target: :class:`~planner.errors.PlanningError` naming the device, the
   travel it made and the scale its tones had.  Its first playing time is where it had
   gone its move less half a ramp's travel.
2. **iterate**: the tones are scheduled (:func:`schedule`), the burst is simulated
   exactly (the same stretches the verification plays) through its settle dwell, and
   each tone's playing time is moved by its slider's error over its speed (secant
   steps, kept inside the bracket of times known short and long) until every slider
   ends within :data:`AIM` of the position tolerance, or :data:`MAX_ITERATIONS` runs.
   Times sit on the sample grid; one sample (5 us at 200 kHz) is a few nm of travel.
3. **limits**: a tone that alone is above ``drive.max_acceleration_g`` or the piezo's
   limit has every amplitude lowered by one factor before the probe; the budget keeps
   the tones playing together under them; and the burst's peak acceleration and
   displacement are measured over continuous time (:func:`planner.gating.burst_peaks`):
   above a limit, every amplitude is lowered by one factor and the times found again.

A slider whose move is the other way of its impacter (the scene left it beyond a target
it was to approach) gets no tone, nor does one whose shortest pulse (a fade-in straight
into a fade-out) would overshoot by more than staying put misses.

The check is the verification's: the carried-state scene simulation must end every
slider within the tolerance of its target, and the per-step check must do so from every
initial position of its impacter (:func:`planner.planning.verify.check_step`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from model import Drive
from planner.errors import PlanningError
from planner.gating import burst_peaks, gate
from planner.nodes import Node
from planner.planning.drives import scaled
from planner.planning.motion import run_phase, run_program, settle
from planner.units import UM

#: Fade-in and fade-out of every tone of a gated burst [s]: many beat periods of an
#: impacter a few hundred Hz off the tone (a switched tone rings its neighbours at their
#: own resonance; a slow one excites nothing), and still far below a tone's playing time.
RAMP_S = 0.5e-3
#: Trajectory resolution of the probe [s].
PROBE_CHUNK_S = 2e-4
#: The search stops when every slider ends within this fraction of
#: ``verification.position_tolerance_um`` of its target.
AIM = 0.1
#: Iterations of the search (each one simulation of the step's moving devices).
MAX_ITERATIONS = 12
#: Times the amplitudes are lowered to meet the limits before giving up.
LIMIT_ROUNDS = 3


def slip_budget(settings):
    """The largest summed base acceleration amplitude sum_i w_i^2 Z_i [m/s^2] the tones
    playing together in a gated burst may have.

    The least dynamic friction over mass of every slider of the array
    (``settings.sliders``: a sliding one is then never carried along by the vibration alone, and an idle one
    never slips, its static friction being larger), and at most
    ``drive.max_acceleration_g``.  The sum of amplitudes bounds the peak whatever the
    phases (over a burst of tens of ms the tones do line up).
    """
    budget = min(s.dynamic_friction / s.mass for s in settings.sliders.values())
    if settings.max_acceleration_m_s2 is not None:
        budget = min(budget, settings.max_acceleration_m_s2)
    return budget


def schedule(durations, accelerations, order, budget, ramp):
    """Start of every tone [s]: each in ``order`` starts at the earliest time, not before
    the one before it, at which it fits, with every tone still sounding then, within
    ``budget``.

    Parameters
    ----------
    durations : dict
        Tone index -> its playing time from start to gate [s] (it sounds until its gate
        plus ``ramp``).
    accelerations : dict
        Tone index -> its base acceleration amplitude w^2 Z [m/s^2].
    order : sequence
        The tone indices in the order they start.
    budget : float
        Largest summed acceleration amplitude of the tones sounding together [m/s^2]; a
        tone above it alone plays alone.
    ramp : float
        [s].

    Returns
    -------
    dict
        Tone index -> start [s].

    Examples
    --------
    >>> schedule({0: 1.0, 1: 0.5, 2: 0.5}, {0: 1.0, 1: 1.0, 2: 1.0}, [0, 1, 2], 2.0, 0.0)
    {0: 0.0, 1: 0.0, 2: 0.5}
    """
    placed, out, earliest = [], {}, 0.0
    for i in order:
        length = durations[i] + ramp
        candidates = sorted({earliest} | {e for _, e, _ in placed if e > earliest})
        for c in candidates:
            # the load is highest at c or where a tone starts inside [c, c + length)
            points = [c] + [s for s, _, _ in placed if c < s < c + length]
            load = max(sum(a for s, e, a in placed if s <= p < e) for p in points)
            if not placed or load + accelerations[i] <= budget * (1 + 1e-12) or load == 0.0:
                break
        out[i] = c
        earliest = c
        placed.append((c, c + length, accelerations[i]))
    return out


def place_targets(settings, steps, waveforms, frequencies, impacters, sliders, progress=None):
    """Gate every ``targets_um`` step of ``steps`` from the carried state of its scene.

    Parameters
    ----------
    settings : Settings
    steps : sequence of Step
        With their bursts sized (:func:`planner.planning.motion.size_bursts`).
    waveforms : dict
        Step key -> the step's summed drive (its loop, acceleration-limited).
    frequencies : dict
        Node -> its tone [Hz] (the assignment's), to find each node's tone.
    impacters, sliders : dict
        Node -> model.Impacter; device -> model.Slider.
    progress : callable, optional
        Called with a step's key after each gated step.

    Returns
    -------
    (steps, waveforms, notes)
        The steps, a ``targets_um`` step with its burst's length as ``duration_s`` and
        the moves it was gated for as ``moves_m``; the waveforms, a ``targets_um`` step's
        its :class:`planner.gating.Burst`; ``notes``: step key -> what the search did
        (:func:`search_gates`).

    Raises
    ------
    PlanningError
        A slider cannot reach its target within the step's longest burst.
    """
    from planner.planning.scenes import simulate_scenes

    bursts, moves, notes = {}, {}, {}

    def place(step, states, sl_states):
        burst, move, note = search_gates(settings, step, waveforms[step.key], frequencies,
                                         impacters, sliders, states, sl_states)
        bursts[step.key], moves[step.key], notes[step.key] = burst, move, note
        if progress is not None:
            progress(step.key)
        return burst

    scenes = {st.scene for st in steps if st.targets_m is not None}
    simulate_scenes(settings, [st for st in steps if st.scene in scenes], waveforms,
                    impacters, sliders, place=place)
    out = tuple(dataclasses.replace(st, duration_s=bursts[st.key].length_s,
                                    moves_m=tuple(moves[st.key].items()))
                if st.key in bursts else st for st in steps)
    return out, {**waveforms, **bursts}, notes


def search_gates(settings, step, waveform, frequencies, impacters, sliders, states,
                 sl_states):
    """The gated burst of one ``targets_um`` step from a carried state (see the module
    docstring); ``states`` and ``sl_states`` are read, not changed.

    ``waveform`` is the step's summed drive as synthesised (its amplitudes not lowered
    for the whole sum's peak: the tones that play together are kept within the limits
    here).

    Returns
    -------
    (burst, moves, note)
        ``moves``: device -> the move [m] each targeted slider must make from where it
        is; ``note``: {"starts_s" and "gates_s": node -> [s] (0, 0: not played),
        "ramp_s", "budget_m_s2", "iterations", "errors_m": device -> error of the last
        search simulation [m], "acceleration_scale": the factor the limits took,
        "peak_displacement_m", "peak_acceleration_m_s2"}.
    """
    from planner.spec import DEFAULT_MAX_BURST_S

    start = {d: sl_states.get(d, (0.0, 0.0))[0] for d in sliders}
    moves = {d: (t - start[d] if step.relative_to == "scene_start" else t)
             for d, t in step.targets_m}
    requested = np.asarray(waveform.requested_frequencies)
    movers = {}
    for d, direction in sorted(step.active_nodes()):
        n = Node(d, direction).text
        movers[d] = (n, int(np.argmin(np.abs(requested - frequencies[n]))), Node.parse(n).sign)
    fs = settings.sample_rate_hz
    ramp = round(RAMP_S * fs) / fs
    cap = step.max_duration_s if step.max_duration_s is not None else DEFAULT_MAX_BURST_S
    cap = max(2 * ramp, math.floor(cap * fs) / fs)
    budget = slip_budget(settings)
    sim = _Simulation(settings, impacters, sliders, movers, states, sl_states)
    w, scale = waveform, 1.0
    # a tone that alone is above a limit is lowered before anything plays (with the
    # others, by one factor: the designs saw the step's tones in these proportions)
    f = np.asarray(w.frequencies)[[m[1] for m in movers.values()]]
    z = np.asarray(w.amplitudes)[[m[1] for m in movers.values()]]
    over = float(np.max(z)) / settings.peak_limit_m
    if settings.max_acceleration_m_s2 is not None:
        over = max(over, float(np.max((2 * np.pi * f) ** 2 * z)) / settings.max_acceleration_m_s2)
    if over > 1.0:
        scale = (1.0 - 1e-6) / over
        w = scaled(w, scale, f"every amplitude lowered by x{scale:.4g}: a tone alone was above "
                             "drive.max_acceleration_g or peak_limit_um")
    for _ in range(LIMIT_ROUNDS + 1):
        search = _Search(settings, step, w, scale, movers, moves, ramp, cap, budget, sim)
        burst = search.run()
        zp, ap = burst_peaks(burst)
        over = zp / settings.peak_limit_m
        if settings.max_acceleration_m_s2 is not None:
            over = max(over, ap / settings.max_acceleration_m_s2)
        if over <= 1.0:
            break
        # a hair under the limit, as drives.limit_acceleration does
        factor = (1.0 - 1e-6) / over
        scale *= factor
        w = scaled(w, factor, f"every amplitude lowered by x{factor:.4g} so that the gated "
                              "burst meets drive.max_acceleration_g and peak_limit_um")
    else:
        raise PlanningError(f"{step.key}: the gated burst stays above drive.max_acceleration_g "
                            f"or peak_limit_um after lowering its amplitudes {LIMIT_ROUNDS} "
                            "times")
    note = {"starts_s": {movers[d][0]: float(burst.starts_s[movers[d][1]]) for d in movers},
            "gates_s": {movers[d][0]: float(burst.gates_s[movers[d][1]]) for d in movers},
            "ramp_s": ramp, "budget_m_s2": budget, "iterations": search.iterations,
            "errors_m": search.errors, "acceleration_scale": scale,
            "peak_displacement_m": zp, "peak_acceleration_m_s2": ap}
    return burst, moves, note


class _Simulation:
    """The moving devices of one step from a carried state, played through a program
    and their settle dwell, on copies of the states."""

    def __init__(self, settings, impacters, sliders, movers, states, sl_states):
        self.settings = settings
        self.devices = sorted(movers)
        self.own = {n: imp for n, imp in impacters.items()
                    if Node.parse(n).device in movers}
        self.sliders = {d: sliders[d] for d in self.devices}
        self.states = {n: states[n] for n in self.own if n in states}
        self.sl_states = {d: sl_states.get(d, (0.0, 0.0)) for d in self.devices}

    def travel(self, program, devices=None):
        """Device -> travel [m] over ``program`` and the settle dwell (of ``devices``,
        default every moving device)."""
        devices = self.devices if devices is None else devices
        own = {n: imp for n, imp in self.own.items() if Node.parse(n).device in devices}
        states = {n: s for n, s in self.states.items() if n in own}
        sl = {d: self.sl_states[d] for d in devices}
        sliders = {d: self.sliders[d] for d in devices}
        run_program(own, sliders, self.settings.contacts, program, states, sl)
        settle(own, sliders, self.settings.contacts, states, sl, self.settings.max_settle_s)
        return {d: sl[d][0] - self.sl_states[d][0] for d in devices}

    def trajectory(self, program, chunk, devices):
        """(times [s], device -> travel [m] at each time) of ``devices`` over
        ``program``, recorded every ``chunk`` [s] (each stretch cut into chunks, phases
        advanced to each)."""
        own = {n: imp for n, imp in self.own.items() if Node.parse(n).device in devices}
        states = {n: s for n, s in self.states.items() if n in own}
        sl = {d: self.sl_states[d] for d in devices}
        sliders = {d: self.sliders[d] for d in devices}
        times, travel, t = [0.0], {d: [0.0] for d in devices}, 0.0
        for duration, drive in program:
            k = max(1, math.ceil(duration / chunk - 1e-9))
            for j in range(k):
                t0, t1 = duration * j / k, duration * (j + 1) / k
                piece = Drive(drive.frequencies, drive.amplitudes,
                              drive.phases + drive.omegas * t0)
                run_phase(own, sliders, self.settings.contacts, piece, t1 - t0, states, sl)
                times.append(t + t1)
                for d in devices:
                    travel[d].append(sl[d][0] - self.sl_states[d][0])
            t += duration
        return np.array(times), {d: np.array(v) for d, v in travel.items()}


class _Search:
    """Steps 1 and 2 of the module docstring for one set of amplitudes."""

    def __init__(self, settings, step, waveform, scale, movers, moves, ramp, cap, budget,
                 sim):
        self.settings, self.step, self.waveform, self.scale = settings, step, waveform, scale
        self.movers, self.moves, self.ramp, self.cap, self.sim = movers, moves, ramp, cap, sim
        self.budget = budget
        self.fs = settings.sample_rate_hz
        w = 2.0 * np.pi * np.asarray(waveform.frequencies)
        self.accel = {i: float(w[i] ** 2 * waveform.amplitudes[i]) for _, i, _ in movers.values()}
        # a tone plays only if its slider is to move its impacter's way (the scene may
        # have left a slider beyond a target it was to approach)
        self.driven = {d: m for d, m in movers.items() if m[2] * moves[d] > 0.0}
        self.iterations, self.errors = 0, {}

    def burst(self, durations, order):
        """The burst of the tones of ``durations`` (tone index -> playing time [s]),
        started in ``order`` (:func:`schedule`)."""
        n = len(self.waveform.frequencies)
        starts, gates = np.zeros(n), np.zeros(n)
        for i, s0 in schedule(durations, self.accel, order, self.budget, self.ramp).items():
            starts[i], gates[i] = s0, s0 + durations[i]
        return gate(self.waveform, starts, gates, self.ramp)

    def run(self):
        if not self.driven:
            # a burst plays at least one tone: the shortest pulse of the slider asked to
            # move furthest (the verification judges whether that is near enough)
            d = max(self.movers, key=lambda dev: abs(self.moves[dev]))
            i = self.movers[d][1]
            return self.burst({i: self.ramp}, [i])
        durations, speed = self.probe()
        order = sorted(durations, key=lambda i: (-durations[i], i))
        last = {}
        aim = AIM * self.settings.position_tolerance_m
        burst = None
        for self.iterations in range(1, MAX_ITERATIONS + 1):
            burst = self.burst(durations, order)
            got = self.sim.travel(burst.program())
            self.errors = {d: got[d] - self.moves[d] for d in self.movers}
            todo = [d for d in self.driven if abs(self.errors[d]) > aim]
            if not todo:
                break
            for d in todo:
                _, i, sign = self.driven[d]
                g, err = durations[i], sign * self.errors[d]      # err > 0: too far
                # a secant through this try and the last (the tones a slider shares the
                # burst with move as the others' times change, so older tries are
                # stale), else its probed speed; at most half its time either way
                slope = speed[d]
                if d in last and last[d][0] != g and (err - last[d][1]) / (g - last[d][0]) > 0:
                    slope = (err - last[d][1]) / (g - last[d][0])
                last[d] = (g, err)
                change = max(-0.5 * g, min(0.5 * g, -err / slope))
                durations[i] = self._on_grid(min(max(g + change, self.ramp), self.cap))
        unreached = [d for d in self.driven
                     if durations[self.driven[d][1]] >= self.cap
                     and -self.driven[d][2] * self.errors[d] > self.settings.position_tolerance_m]
        for d in unreached:
            self._unreachable(d, self.moves[d] + self.errors[d])
        return burst

    def probe(self):
        """(tone index -> first playing time [s], device -> speed [m/s]) from the tones
        in groups within the budget, each group played to the cap."""
        groups, load = [[]], 0.0
        for d in sorted(self.driven, key=lambda dev: (-abs(self.moves[dev]), dev)):
            a = self.accel[self.driven[d][1]]
            if groups[-1] and load + a > self.budget:
                groups.append([])
                load = 0.0
            groups[-1].append(d)
            load += a
        n = len(self.waveform.frequencies)
        durations, speed = {}, {}
        for group in groups:
            starts, gates = np.zeros(n), np.zeros(n)
            for d in group:
                gates[self.driven[d][1]] = self.cap - self.ramp
            program = gate(self.waveform, starts, gates, self.ramp).program()
            times, travel = self.sim.trajectory(program, PROBE_CHUNK_S, group)
            for d in group:
                _, i, sign = self.driven[d]
                along, want = sign * travel[d], sign * self.moves[d]
                if along[-1] < want - self.settings.position_tolerance_m:
                    self._unreachable(d, travel[d][-1])
                k = int(np.argmax(along >= want)) if np.any(along >= want) else len(times) - 1
                speed[d] = max(float(along[-1] / times[-1]), 1e-9)
                # its travel while the tone fades out is about half a ramp at full speed
                durations[i] = self._on_grid(min(max(times[k] - 0.5 * self.ramp, self.ramp),
                                                 self.cap))
        return durations, speed

    def _unreachable(self, d, reached):
        total = self.scale * self.waveform.scale
        limit = ("" if total >= 1.0 else
                 f" with its tone lowered x{total:.3g} to meet drive.max_acceleration_g and "
                 "peak_limit_um")
        raise PlanningError(
            f"{self.step.key}: {d} cannot reach its target: it must move "
            f"{self.moves[d] / UM:+.4g} um but travels {reached / UM:+.4g} um in the longest "
            f"a tone may play, {self.cap * 1e3:g} ms{limit}; raise the step's duration_ms, "
            "move it less in this step, or raise drive.max_acceleration_g")

    def _on_grid(self, t):
        """``t`` [s] rounded to the sample grid."""
        return round(t * self.fs) / self.fs
