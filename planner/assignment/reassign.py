"""Moving a few impacters' channels, every other one kept: the plan loop's re-colouring.

When a design cannot be made feasible at its tone, the plan's loop tightens that
impacter's separations (from the tones it answered, or from the multi-tone step it
must sit out) and re-colours.  A colouring from scratch would move most channels, and
every moved channel is a new design; so the movers are first placed alone, on the
free positions that keep every separation of the tightened conflict graph to every
other impacter, which stay where they are (:func:`move_groups`).  Only when no free
position fits is the whole graph coloured again (:func:`planner.assignment.assign.assign`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from planner.assignment.assign import Assignment, _positions, conflict_graph, guard_violations
from planner.assignment.distortion import product_rule


def move_groups(settings, steps, assignment: Assignment, movers, pair_separation,
                separation=None, away=None):
    """``assignment`` with the channel groups of the nodes ``movers`` moved.

    Parameters
    ----------
    settings : planner.planning.settings.Settings
    steps : sequence of Step
    assignment : Assignment
        The current assignment (its reach and positions are kept).
    movers : iterable of Node
        Impacters to move (with every node of their channel group).
    pair_separation : dict
        ``frozenset({u, v}) -> separation`` [channels], the tightened constraints
        (:func:`planner.assignment.assign.conflict_graph`).
    separation : int, optional
        Default edge separation; ``settings.separation_channels``.
    away : dict, optional
        Node -> nodes it should move away from (its offenders): among the free
        positions that fit, the one furthest from them in log frequency wins, then the
        one nearest its old position.

    Returns
    -------
    (Assignment, moves) or None
        ``moves``: Node -> (old frequency, new frequency) [Hz] of every moved node;
        None when some mover has no free position that keeps every separation.
    """
    sep = settings.separation_channels if separation is None else int(separation)
    grid = np.asarray(settings.channel_grid_hz, dtype=float)
    positions = _positions(settings, grid, sep, assignment.reach)
    graph, groups = conflict_graph(steps, sep, pair_separation,
                                   settings.ensemble_separation_channels)
    if set(groups) != set(assignment.groups):
        return None
    q = max(int(assignment.stride), 1)
    where = {g: int(assignment.positions[members[0]]) for g, members in groups.items()}
    member_of = {n: g for g, members in groups.items() for n in members}
    moving = sorted({member_of[n] for n in movers if n in member_of})
    away = away or {}
    moved = {}
    for g in moving:
        others = {h: where[h] for h in groups if h != g}
        need = {h: graph[g][h]["sep"] * q for h in graph.neighbors(g)}
        fits = [p for p in range(len(positions))
                if all(abs(p - others[h]) >= need[h] for h in need)
                and p not in others.values()]
        if not fits:
            return None
        offenders = [member_of[m] for n in groups[g] for m in away.get(n, ()) if m in member_of]
        logf = np.log(grid[positions])

        def rank(p):
            far = min((abs(logf[p] - logf[where[h]]) for h in offenders), default=0.0)
            return (-round(far, 9), abs(p - where[g]), p)

        best = min(fits, key=rank)
        if best != where[g]:
            moved[g] = (where[g], best)
            where[g] = best
    if not moved:
        return None
    chans, freqs, pos = dict(assignment.channels), dict(assignment.frequencies), {}
    moves = {}
    for g, (_, new) in moved.items():
        for n in groups[g]:
            old_f = freqs[n]
            pos[n] = new
            chans[n] = int(positions[new])
            freqs[n] = float(grid[chans[n]])
            moves[n] = (old_f, freqs[n])
    coloring = dict(assignment.coloring)
    for g, (_, new) in moved.items():
        coloring[g] = (new - assignment.offset) / q
    new = dataclasses.replace(
        assignment, graph=graph, coloring=coloring, channels=chans, frequencies=freqs,
        positions={**assignment.positions, **pos},
        violations=guard_violations(steps, freqs, settings.tone_rules,
                                    product_rule(settings, assignment.reach)))
    return new, moves
