"""Which impacter takes which channel: frequency neighbours on neighbouring devices
(``drive.channels.placement: neighbours``, issue 39).

The colouring (:func:`planner.assignment.assign.assign`) says which channels the impacters take
and which of them must be how far apart; where the scenes allow it, *which* impacter
takes a given channel is free.  In an array whose impacters are independent (every pair
told apart by the same separation) any permutation of the impacters over the channels
is as valid as the colouring's own.  A line-width gradient across the die moves far
devices' resonances apart more than near ones' (McKenney et al. 2019: MKID arrays place
frequency neighbours next to each other for this reason), and the pairs whose
resonances are closest are the tone neighbours: placing tone neighbours on neighbouring
devices keeps the gradient's part of their difference to one pitch's worth.

:func:`neighbour_coloring` keeps the colouring's channels and, within each block of it
(runs of channels set apart by the wider separations of multi-tone steps, as
:func:`colour_blocks` finds them), gives the block's channels, lowest first,
to its impacters in the order of a serpentine walk of the devices (the block's first row
left to right, its next right to left, ...); a block whose new order would break a separation keeps the
colouring's.
"""

from __future__ import annotations

from planner.core.nodes import device_key


def serpentine_order(devices) -> list:
    """``devices`` along a serpentine walk of the rows they occupy: the first row left
    to right, the next right to left, and so on (a row no device of them is on is
    skipped, so the walk never jumps across the die at a missing row).

    >>> serpentine_order(["A1", "A2", "B1", "B2", "D1", "D2"])
    ['A1', 'A2', 'B2', 'B1', 'D1', 'D2']
    """
    keys = {d: device_key(d) for d in devices}
    rows = sorted({k[0] for k in keys.values()})
    turn = {r: i % 2 for i, r in enumerate(rows)}
    return sorted(devices, key=lambda d: (keys[d][0],
                                          keys[d][1] if not turn[keys[d][0]] else -keys[d][1]))


def _valid(graph, coloring, attr="sep") -> bool:
    return all(abs(coloring[a] - coloring[b]) >= d[attr] for a, b, d in graph.edges(data=True))


def colour_blocks(coloring, gap):
    """The colouring's groups in runs whose consecutive colours are < ``gap`` apart."""
    order = sorted(coloring, key=lambda g: (coloring[g], g))
    blocks = [[order[0]]]
    for a, b in zip(order, order[1:]):
        if coloring[b] - coloring[a] >= gap:
            blocks.append([])
        blocks[-1].append(b)
    return blocks


def neighbour_coloring(graph, groups: dict, coloring: dict, attr: str = "sep") -> dict:
    """The colouring with each block's channels given along the serpentine walk.

    Parameters
    ----------
    graph : networkx.Graph
        The conflict graph (:func:`planner.assignment.assign.conflict_graph`), edge attribute
        ``attr`` the separation [channels].
    groups : dict
        Channel group -> its impacter nodes (:class:`planner.core.nodes.Node`).
    coloring : dict
        Channel group -> colour, a valid colouring of ``graph``.

    Returns
    -------
    dict
        Channel group -> colour: the same colours, reassigned within blocks; every
        separation of ``graph`` kept (a block whose reordering would break one keeps its
        colours).
    """
    if graph.number_of_edges() == 0 or len(coloring) < 2:
        return dict(coloring)
    gap = min(d[attr] for _, _, d in graph.edges(data=True)) + 1
    out = dict(coloring)
    for block in colour_blocks(coloring, gap):
        slots = sorted(coloring[g] for g in block)
        # a channel group (impacters sharing a channel) walks with its first device
        first = {g: min((n.device for n in groups[g]), key=device_key) for g in block}
        rank = {d: i for i, d in enumerate(serpentine_order(sorted(set(first.values()))))}
        walk = sorted(block, key=lambda g: (rank[first[g]], str(g)))
        trial = dict(out)
        trial.update(zip(walk, slots))
        if _valid(graph, trial, attr):
            out = trial
    return out
