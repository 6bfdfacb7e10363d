"""Stage 4c, targets: a gated burst that puts every slider of a ``targets_um`` step where
its scene asks it to be.

One summed drive moves a step's sliders at speeds ten times apart, so a burst sized for
one slider leaves the others short or far beyond their targets.  A ``targets_um`` step
therefore plays a gated burst (:mod:`planner.synthesis.gating`): its tones one after the other,
each fading in, playing until its slider has gone far enough, and fading out.

Why one tone at a time
----------------------
Measured on the default 5 x 5 designs (docs/targets.md):

- under the summed drive of all 25 tones (~2,700 g peak: M zeta'' reaches the sliders'
  20 uN static friction) a slider that an impact has set sliding is carried by the
  substrate's vibration against only its 5 uN dynamic friction: it moves at 5-13 mm/s,
  up to 5-13 um in 0.1 ms, whenever the summed drive peaks, whichever tones still play.
  Gating each of the 25 tones at its own time left errors up to 16 um;
- a second tone playing beside a slider's own one, even below the dynamic friction
  (540 g), doubles its speed (B1: 0.32 mm/s alone, 0.61 with E5's tone), so the travel a
  tone gives depends on when its neighbours in time stop: gated in pairs and triples
  within that friction, the search oscillated and the pattern of configs/pattern_5x5.yaml
  missed by up to 17 um;
- one tone alone (140-480 g, below every slider's dynamic friction over its mass) moves
  its slider only while its impacter kicks it, 0.3-0.5 mm/s, in steps of 0.016 um per
  50 us of playing time, and nothing else: each slider's travel depends on its own
  tone's playing time alone.

So a targets step is a sequence of single-tone sub-steps, in device order, each tone
starting when the one before has faded out: a burst of about a second for 24 moves of
up to 24 um, where the summed drive would take tens of ms.  Idle sliders see one tone at a time, which the designs are
silent under.

The designs are not made against a targets step's summed drive, which never plays
(:func:`planner.planning.exposure.idle_ensembles`; nor does the assignment keep its
ensemble separation for it): every impacter idle in it is designed silent under each of
its tones, and each impacter of such a step silent under every other tone of it and able
to move its slider alone (:func:`planner.assignment.assign.plan_steps`).  The verification
re-simulates the burst exactly as it is exported, so none of this is taken on trust.

Finding the gates
-----------------
From the state the scene is in when the step starts (the carried state of
:func:`planner.planning.scenes.simulate_scenes`), each burst followed by its settle
dwell, since a slider moves on while its tone fades out:

1. **probe**: each tone alone, from the carried state, for the longest a tone may play
   (the step's ``duration_ms``, else :data:`planner.arrayspec.DEFAULT_MAX_BURST_S`), its
   slider's travel recorded every :data:`PROBE_CHUNK_S` (until it has gone its move).
   A slider that does not travel its move in that time cannot reach its target:
   :class:`~planner.core.errors.PlanningError` naming the device, the travel it made and the
   scale its tone had.  Its first playing time is where it had gone its move less half a
   ramp's travel.
2. **iterate**: the tones in sequence (:func:`sequence`), the burst simulated exactly
   (the same stretches the verification plays) through its settle dwell, and each
   tone's playing time moved by its slider's error over its speed (a secant through the
   last two tries, at most half its time a step) until every slider ends within
   :data:`AIM` of the position tolerance, or :data:`MAX_ITERATIONS` runs; the best try
   (least worst error) is kept.  Times sit on the sample grid (5 us at 200 kHz).
3. **limits**: a tone that alone is above ``drive.max_acceleration_g`` or the piezo's
   limit has every amplitude lowered by one factor before the probe; the burst's peak
   acceleration and displacement are measured over continuous time
   (:func:`planner.synthesis.gating.burst_peaks`, the ramps included), and above a limit every
   amplitude is lowered by one factor and the times found again.

A slider whose move is the other way of its impacter (the scene left it beyond a target
it was to approach) gets no tone.

The check is the verification's: the carried-state scene simulation must end every
slider within the tolerance of its target, and the per-step check must do so from every
initial position of its impacter (:func:`planner.planning.verify.check_step`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from model import Drive
from planner.core.errors import PlanningError
from planner.synthesis.gating import burst_peaks, gate
from planner.core.nodes import Node
from planner.planning.drives import scaled
from planner.planning.motion import run_phase, run_program, settle
from planner.planning.scenes import simulate_scenes
from planner.core.units import UM

#: Fade-in and fade-out of every tone of a gated burst [s]: many beat periods of an
#: impacter a few hundred Hz off the tone (a switched tone rings its neighbours at their
#: own resonance; a slow one excites nothing), and short beside a tone's playing time.
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


def sequence(durations, order, ramp):
    """Start of every tone [s]: one after the other in ``order``, each starting when the
    one before has faded out (its start + its playing time + ``ramp``).

    Parameters
    ----------
    durations : dict
        Tone index -> its playing time from start to gate [s].
    order : sequence
        The tone indices in the order they play.
    ramp : float
        [s].

    Returns
    -------
    dict
        Tone index -> start [s].

    Examples
    --------
    >>> sequence({0: 0.02, 3: 0.01}, [3, 0], 0.001)
    {3: 0.0, 0: 0.011}
    """
    out, t = {}, 0.0
    for i in order:
        out[i] = t
        t += durations[i] + ramp
    return out


def place_targets(settings, steps, waveforms, frequencies, impacters, sliders, progress=None):
    """Gate every ``targets_um`` step of ``steps`` from the carried state of its scene.

    Parameters
    ----------
    settings : Settings
    steps : sequence of Step
        With their bursts sized (:func:`planner.planning.motion.size_bursts`).
    waveforms : dict
        Step key -> the step's drive: a loop for every step, a ``targets_um`` step's as
        synthesised (its amplitudes not lowered for the peak of the whole sum, which
        never plays).
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
        its :class:`planner.synthesis.gating.Burst`; ``notes``: step key -> what the search did
        (:func:`search_gates`).

    Raises
    ------
    PlanningError
        A slider cannot reach its target within the longest its tone may play.
    """
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
    for the peak of the whole sum, which never plays).

    Returns
    -------
    (burst, moves, note)
        ``moves``: device -> the move [m] each targeted slider must make from where it
        is; ``note``: {"starts_s" and "gates_s": Node -> [s] (gate 0: not played),
        "ramp_s", "iterations", "errors_m": device -> the error of the try kept [m],
        "acceleration_scale": the factor the limits took, "peak_displacement_m",
        "peak_acceleration_m_s2"}.
    """
    from planner.arrayspec import DEFAULT_MAX_BURST_S

    start = {d: sl_states.get(d, (0.0, 0.0))[0] for d in sliders}
    moves = {d: (t - start[d] if step.relative_to == "scene_start" else t)
             for d, t in step.targets_m}
    requested = np.asarray(waveform.requested_frequencies)
    movers = {}
    for d, direction in sorted(step.active_nodes()):
        n = Node(d, direction)
        movers[d] = (n, int(np.argmin(np.abs(requested - frequencies[n]))), n.sign)
    fs = settings.sample_rate_hz
    ramp = round(RAMP_S * fs) / fs
    cap = step.max_duration_s if step.max_duration_s is not None else DEFAULT_MAX_BURST_S
    cap = max(ramp, math.floor(cap * fs) / fs)
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
    sim = _Simulation(settings, impacters, sliders, movers, states, sl_states)
    for _ in range(LIMIT_ROUNDS + 1):
        search = _Search(settings, step, w, movers, moves, ramp, cap, sim)
        burst = search.run()
        zp, ap = burst_peaks(burst)
        # the ramps add to a tone's own peak (the envelope's slope, up to pi / (R w) of
        # it): measured on the burst as played
        over = zp / settings.peak_limit_m
        if settings.max_acceleration_m_s2 is not None:
            over = max(over, ap / settings.max_acceleration_m_s2)
        if over <= 1.0:
            break
        factor = (1.0 - 1e-6) / over
        scale *= factor
        w = scaled(w, factor, f"every amplitude lowered by x{factor:.4g} so that the burst "
                              "meets drive.max_acceleration_g and peak_limit_um")
    else:
        raise PlanningError(f"{step.key}: the gated burst stays above drive.max_acceleration_g "
                            f"or peak_limit_um after lowering its amplitudes {LIMIT_ROUNDS} "
                            "times")
    note = {"starts_s": {movers[d][0]: float(burst.starts_s[movers[d][1]]) for d in movers},
            "gates_s": {movers[d][0]: float(burst.gates_s[movers[d][1]]) for d in movers},
            "ramp_s": ramp, "iterations": search.iterations, "errors_m": search.errors,
            "acceleration_scale": scale, "peak_displacement_m": zp,
            "peak_acceleration_m_s2": ap}
    return burst, moves, note


class _Simulation:
    """The moving devices of one step from a carried state, played through a program
    and their settle dwell, on copies of the states."""

    def __init__(self, settings, impacters, sliders, movers, states, sl_states):
        self.settings = settings
        self.devices = sorted(movers)
        self.own = {n: imp for n, imp in impacters.items() if n.device in movers}
        self.sliders = {d: sliders[d] for d in self.devices}
        self.states = {n: states[n] for n in self.own if n in states}
        self.sl_states = {d: sl_states.get(d, (0.0, 0.0)) for d in self.devices}

    def _copies(self, devices):
        """(impacters, sliders, impacter states, slider states) of ``devices``, the
        states copied."""
        own = {n: imp for n, imp in self.own.items() if n.device in devices}
        return (own, {d: self.sliders[d] for d in devices},
                {n: s for n, s in self.states.items() if n in own},
                {d: self.sl_states[d] for d in devices})

    def travel(self, program, devices=None):
        """Device -> travel [m] over ``program`` and the settle dwell (of ``devices``,
        default every moving device)."""
        devices = self.devices if devices is None else devices
        own, sliders, states, sl = self._copies(devices)
        run_program(own, sliders, self.settings.contacts, program, states, sl)
        settle(own, sliders, self.settings.contacts, states, sl, self.settings.max_settle_s)
        return {d: sl[d][0] - self.sl_states[d][0] for d in devices}

    def trajectory(self, program, chunk, devices, until=None):
        """(times [s], device -> travel [m] at each time) of ``devices`` over
        ``program``, recorded every ``chunk`` [s] (each stretch cut into chunks, phases
        advanced to each); stopped early once ``until(travel)`` (device -> travel [m]
        now) is true."""
        own, sliders, states, sl = self._copies(devices)
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
                if until is not None and until({d: v[-1] for d, v in travel.items()}):
                    return np.array(times), {d: np.array(v) for d, v in travel.items()}
            t += duration
        return np.array(times), {d: np.array(v) for d, v in travel.items()}


class _Search:
    """Steps 1 and 2 of the module docstring for one set of amplitudes."""

    def __init__(self, settings, step, waveform, movers, moves, ramp, cap, sim):
        self.settings, self.step, self.waveform = settings, step, waveform
        self.movers, self.moves, self.ramp, self.cap, self.sim = movers, moves, ramp, cap, sim
        self.fs = settings.sample_rate_hz
        # a tone plays only if its slider is to move its impacter's way (the scene may
        # have left a slider beyond a target it was to approach)
        self.driven = {d: m for d, m in movers.items() if m[2] * moves[d] > 0.0}
        # one after the other in device order: a burst a lab can read off the table
        self.order = [self.driven[d][1] for d in sorted(self.driven)]
        self.iterations, self.errors = 0, {}

    def burst(self, durations):
        """The burst of the tones of ``durations`` (tone index -> playing time [s]) in
        sequence (:func:`sequence`)."""
        n = len(self.waveform.frequencies)
        starts, gates = np.zeros(n), np.zeros(n)
        for i, s0 in sequence(durations, [i for i in self.order if i in durations],
                              self.ramp).items():
            starts[i], gates[i] = s0, s0 + durations[i]
        return gate(self.waveform, starts, gates, self.ramp)

    def run(self):
        if not self.driven:
            # a burst plays at least one tone: the shortest pulse of the slider asked to
            # move furthest (the verification judges whether that is near enough)
            d = max(self.movers, key=lambda dev: abs(self.moves[dev]))
            return self.burst({self.movers[d][1]: self.ramp})
        durations, speed = self.probe()
        last, best = {}, None
        aim = AIM * self.settings.position_tolerance_m
        for self.iterations in range(1, MAX_ITERATIONS + 1):
            burst = self.burst(durations)
            got = self.sim.travel(burst.program())
            errors = {d: got[d] - self.moves[d] for d in self.movers}
            worst = max(abs(errors[d]) for d in self.driven)
            if best is None or worst < best[0]:
                best = (worst, burst, errors)
            if worst <= aim:
                break
            for d in self.driven:
                _, i, sign = self.driven[d]
                g, err = durations[i], sign * errors[d]      # err > 0: too far
                if abs(errors[d]) <= aim:
                    continue
                # a secant through this try and the last, else its probed speed; at
                # most half its time a step
                slope = speed[d]
                if d in last and last[d][0] != g and (err - last[d][1]) / (g - last[d][0]) > 0:
                    slope = (err - last[d][1]) / (g - last[d][0])
                last[d] = (g, err)
                change = max(-0.5 * g, min(0.5 * g, -err / slope))
                durations[i] = self._on_grid(min(max(g + change, self.ramp), self.cap))
        _, burst, self.errors = best
        for d, (_, i, sign) in self.driven.items():
            played = burst.gates_s[i] - burst.starts_s[i]
            if (played >= self.cap - 0.5 / self.fs
                    and -sign * self.errors[d] > self.settings.position_tolerance_m):
                self._unreachable(d, self.moves[d] + self.errors[d])
        return burst

    def probe(self):
        """(tone index -> first playing time [s], device -> speed [m/s]): each tone
        alone from the carried state, played to the cap or until its slider has gone
        its move."""
        n = len(self.waveform.frequencies)
        durations, speed = {}, {}
        for d in sorted(self.driven):
            _, i, sign = self.driven[d]
            want = sign * self.moves[d]
            starts, gates = np.zeros(n), np.zeros(n)
            gates[i] = self.cap
            program = gate(self.waveform, starts, gates, self.ramp).program()
            times, travel = self.sim.trajectory(
                program, PROBE_CHUNK_S, [d], until=lambda tr, d=d: sign * tr[d] >= want)
            along = sign * travel[d]
            if along[-1] < want - self.settings.position_tolerance_m:
                self._unreachable(d, travel[d][-1])
            k = int(np.argmax(along >= want)) if np.any(along >= want) else len(times) - 1
            speed[d] = max(float(along[k] / times[k]) if times[k] > 0 else 0.0, 1e-9)
            # its travel while the tone fades out is about half a ramp at full speed
            durations[i] = self._on_grid(min(max(times[k] - 0.5 * self.ramp, self.ramp),
                                             self.cap))
        return durations, speed

    def _unreachable(self, d, reached):
        # the waveform's scale holds every lowering (synthesis, limits)
        total = self.waveform.scale
        limit = ("" if total >= 1.0 else
                 f" with its tone lowered x{total:.3g} to meet drive.max_acceleration_g and "
                 "peak_limit_um")
        raise PlanningError(
            f"{self.step.key}: {d} cannot reach its target: it must move "
            f"{self.moves[d] / UM:+.4g} um but travels {reached / UM:+.4g} um in the longest "
            f"its tone may play, {self.cap * 1e3:g} ms{limit}; raise the step's duration_ms, "
            "move it less in this step, or raise drive.max_acceleration_g")

    def _on_grid(self, t):
        """``t`` [s] rounded to the sample grid."""
        return round(t * self.fs) / self.fs
