"""What each impacter hears: the tones and summed drives it must stay silent under.

Every driven impacter is designed for its tone with every tone that plays while it is
idle as a forbidden frequency (:func:`forbidden_tones`, :func:`played_tones`) and the
summed drive of every multi-tone step it sits out as a forbidden drive
(:func:`idle_ensembles`); the multi-tone steps it plays in are its target drives
(:func:`driven_ensembles`).  :func:`design_offenders` names, for an infeasible design,
the impacters whose tones it could not be made silent under (the repair widens their
separations).  Every mapping is keyed by :class:`planner.core.nodes.Node`.
"""

from __future__ import annotations

import math

import numpy as np

from planner.core.nodes import Node


def _active(step) -> set[Node]:
    return {Node(d, dr) for d, dr in step.active_nodes()}


def forbidden_tones(steps, frequencies):
    """Node -> sorted frequencies of every tone that plays while the node is idle."""
    out = {n: set() for n in frequencies}
    for st in steps:
        active = _active(st)
        tones = {frequencies[n] for n in active if n in frequencies}
        for n in frequencies:
            if n not in active:
                out[n] |= tones
    return {n: tuple(sorted(v)) for n, v in out.items()}


def played_tones(steps, frequencies, waveforms):
    """Node -> :func:`forbidden_tones`, each tone of a single-tone step it sits out as
    that step's drive plays it.

    Synthesis snaps a tone to its loop's grid (up to 0.1 %; the default plan's 13.4 kHz
    channel plays at 13407.8 Hz), and the designer checks a forbidden tone at a few
    points of its guard band only: a design silent at 13400 Hz and 13453 Hz answered
    13407.8 Hz (seed 1 of the default plan).  So the designer is given the frequency that
    plays.  A tone that plays only in multi-tone steps keeps its channel frequency: those
    steps' summed drives, tones as played, are checked as forbidden drives.
    """
    played = {}
    for st in steps:
        w = waveforms[st.key]
        if len(w.frequencies) == 1:
            played[round(float(w.requested_frequencies[0]), 6)] = float(w.frequencies[0])
    return {n: tuple(sorted(played.get(round(f, 6), f) for f in tones))
            for n, tones in forbidden_tones(steps, frequencies).items()}


def _multi_tone_steps(steps, frequencies, playing):
    """Node -> keys of the multi-tone steps in which it plays (``playing``) or is idle.

    A ``targets_um`` step is none: its tones never play all together but take turns in
    its gated burst, a few at a time within the sliders' dynamic friction
    (:mod:`planner.planning.targets`), and the verification simulates that burst."""
    out = {n: [] for n in frequencies}
    for st in steps:
        active = _active(st)
        if (st.targets_m is not None
                or len({frequencies[n] for n in active if n in frequencies}) < 2):
            continue
        for n in frequencies:
            if (n in active) == playing:
                out[n].append(st.key)
    return {n: tuple(v) for n, v in out.items()}


def driven_ensembles(steps, frequencies):
    """Node -> keys of the multi-tone steps in which it plays (its target drives)."""
    return _multi_tone_steps(steps, frequencies, True)


def idle_ensembles(steps, frequencies):
    """Node -> keys of the multi-tone steps in which it is idle (their summed drives)."""
    return _multi_tone_steps(steps, frequencies, False)


def tone_players(frequencies):
    """A function: a forbidden tone [Hz] -> the nodes playing it (``frequencies``: node
    -> tone [Hz]).  A forbidden tone is a channel frequency or that tone as played
    (snapped by at most 0.1 %, less than half the channel grid): its nearest channel."""
    by_freq = {}
    for m, f in frequencies.items():
        by_freq.setdefault(round(f, 6), []).append(m)
    channels = np.array(sorted(by_freq))

    def playing(hz):
        return by_freq[float(channels[np.argmin(np.abs(np.log(channels / hz)))])]

    return playing


def design_offenders(designs, steps, assignment):
    """(node, (node, offender)) for every infeasible design: the node playing each
    forbidden frequency it responds at, and the nearest tone of each summed drive
    (step) it responds under."""
    playing = tone_players(assignment.frequencies)
    by_key = {st.key: st for st in steps}
    out = []
    for n in sorted(designs):
        d = designs[n]
        if d.feasible:
            continue
        f = assignment.frequencies[n]
        for hz, r in zip(d.forbidden_hz, d.r_max_forbidden_n):
            if r > 0:
                out += [(n, (n, m)) for m in playing(float(hz)) if m != n]
        for label in d.checks.get("violated_drives", ()):
            st = by_key.get(label)
            if st is None:
                continue
            tones = sorted(_active(st))
            near = min(tones, key=lambda a: abs(math.log(assignment.frequencies[a] / f)))
            out.append((n, (n, near)))
    return out

