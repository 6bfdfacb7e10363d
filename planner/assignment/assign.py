"""Frequency assignment: conflict graph -> bandwidth colouring -> channels -> frequencies.

Stage 2 and 3 of the plan pipeline.  Each impacter pair that some step drives is a
node (:class:`planner.core.nodes.Node`, ``Node("C3", "forward")``; every mapping here is keyed
by it).  Two nodes must be told apart -- an edge, weighted by the
separation they need in channels -- when some step drives one and not the other;
nodes in the same state in every step may share a channel (they are merged into one
colouring node).  A device's forward and backward pairs are never driven together,
so they always conflict when both are used.

The colouring (``planner.coloring.solve_bandwidth``) gives offsets in *positions*:
the channels of :func:`planner.core.separation.position_grid`, on which any two positions
``separation`` apart are also outside each other's design guard band (``design.guard``),
so that no tone the assigner picks is one the designer must refuse.  Where the guard
is narrower than the separation the positions are the channels.  The offsets are
spread over the positions with an integer stride (so every separation is kept,
multiplied by the stride: that is the spare room turned into guard band), and the
offset and stride are chosen to avoid harmonic and low-order intermodulation
products of tones that play together landing in an idle impacter's band.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import networkx as nx
import numpy as np
import pandas as pd

from planner.core.errors import PlanningError
from planner.core.intervals import z_for
from planner.core.nodes import DIRECTIONS, Node, device_key
from planner.assignment.distortion import SECOND_ORDER, product_rule
from planner.assignment.placement import colour_blocks, neighbour_coloring
from planner.core.separation import guard_onset_hz, position_grid
from planner.arrayspec import LoadedSpec, Step


def node_order(node: Node):
    """Sort key of a node: its device's row and column (``A2`` before ``A10``), then its
    direction (the order of :func:`planner.core.nodes.node_key` on the node's text)."""
    return (*device_key(node.device), node.direction)


def plan_steps(loaded: LoadedSpec, single_step_s: float) -> tuple[Step, ...]:
    """The spec's steps plus implicit single-impacter steps (scene ``independent``).

    When every impacter must be independent, one per impacter.  Otherwise one for each
    impacter of a ``targets_um`` step that moves two or more devices: its tones are
    switched off one by one (:mod:`planner.synthesis.gating`), so each must be told apart from
    the others, silent under the others' tones and able to move its slider alone (the
    last one to stop plays alone).
    """
    steps = list(loaded.steps)
    if loaded.spec.all_independent:
        alone = [(dev, direction) for dev in loaded.device_ids for direction in DIRECTIONS]
    else:
        gated = set()
        for st in loaded.steps:
            if st.targets_m is not None and len(st.active_nodes()) > 1:
                gated |= st.active_nodes()
        alone = [(dev, direction) for dev in loaded.device_ids for direction in DIRECTIONS
                 if (dev, direction) in gated]
    for dev, direction in alone:
        fwd = (dev,) if direction == "forward" else ()
        bwd = (dev,) if direction == "backward" else ()
        steps.append(Step("independent", Node(dev, direction).text, len(steps),
                          single_step_s, fwd, bwd))
    return tuple(steps)


def activity(steps) -> dict[Node, tuple[bool, ...]]:
    """Node -> tuple of "driven in step i" for every node driven in some step."""
    nodes = sorted({Node(d, dr) for st in steps for d, dr in st.active_nodes()})
    active = [st.active_nodes() for st in steps]
    # a Node equals its (device, direction) tuple
    return {n: tuple(n in act for act in active) for n in nodes}


def conflict_graph(steps, separation=1, pair_separation=None,
                   ensemble_separation=None) -> tuple[nx.Graph, dict]:
    """Build the conflict graph.

    Parameters
    ----------
    steps : sequence of Step
    separation : int
        Default separation [channels] of an edge.
    pair_separation : dict, optional
        ``frozenset({node_u, node_v}) -> separation`` overriding the default (the
        repair loop widens offending pairs this way).
    ensemble_separation : int, optional
        Separation between a node idle in a step that plays two or more tones and
        every node that plays in it (off-resonant responses to a step's tones add up);
        not in a ``targets_um`` step, whose tones take turns a few at a time
        (:mod:`planner.planning.targets`).

    Returns
    -------
    graph : networkx.Graph
        One node per channel group (nodes with identical activity share one),
        named by its first member; edge attribute ``sep`` [channels].
    groups : dict
        Group name -> list of impacter nodes in it.
    """
    act = activity(steps)
    by_pattern: dict[tuple, list[str]] = {}
    for n, pattern in act.items():
        by_pattern.setdefault(pattern, []).append(n)
    groups = {members[0]: members for members in by_pattern.values()}
    pair_separation = pair_separation or {}
    graph = nx.Graph()
    for g in groups:
        graph.add_node(g, members=groups[g])
    names = sorted(groups)
    member_of = {n: g for g, members in groups.items() for n in members}
    ensemble = set()
    if ensemble_separation:
        for st in steps:
            playing = {member_of[Node(d, dr)] for d, dr in st.active_nodes()}
            if len(playing) < 2 or st.targets_m is not None:
                continue
            for idle in set(groups) - playing:
                ensemble.update(frozenset((idle, p)) for p in playing)
    for a, b in itertools.combinations(names, 2):
        # different activity patterns: some step drives one and not the other
        sep = separation
        if frozenset((a, b)) in ensemble:
            sep = max(sep, ensemble_separation)
        for u in groups[a]:
            for v in groups[b]:
                sep = max(sep, pair_separation.get(frozenset((u, v)), 0))
        graph.add_edge(a, b, sep=int(sep))
    return graph, groups


@dataclass(frozen=True)
class Violation:
    """A guard-rule violation: a product of playing tones in an idle impacter's band."""

    step: str
    node: Node      # the idle impacter
    kind: str       # "harmonic" or "intermodulation"
    product_hz: float
    node_hz: float
    sources: tuple
    #: with a drive chain that distorts (issue 46): the product's amplitude at the die
    #: [m] and whether it can move the idle impacter
    #: (:class:`planner.assignment.distortion.ProductRule`); None without one
    amplitude_m: float | None = None
    moves: bool | None = None

    def __str__(self):
        src = ", ".join(f"{s:.1f}" for s in self.sources)
        text = (f"{self.step}: {self.kind} product {self.product_hz:.1f} Hz of tones ({src}) "
                f"lands in {self.node}'s band at {self.node_hz:.1f} Hz")
        if self.amplitude_m is None:
            return text
        return text + (f" ({self.amplitude_m * 1e9:.3g} nm at the die at drive.chain's "
                       + ("distortion: can move it)" if self.moves else
                          "distortion: too weak to move it)"))


def _triples(n):
    """Indices (i, j, k) of the products f_i + f_j - f_k, i < j, k not i or j, in the
    order of ``itertools.combinations`` then k (int64 arrays)."""
    i, j = np.triu_indices(n, 1)
    k = np.arange(n)
    keep = (k[None, :] != i[:, None]) & (k[None, :] != j[:, None])
    rows = np.broadcast_to(np.arange(i.size)[:, None], keep.shape)[keep]
    return i[rows].astype(np.int64), j[rows].astype(np.int64), np.broadcast_to(
        k, keep.shape)[keep].astype(np.int64)


def guard_violations(steps, frequencies: dict, rules, products=None) -> list[Violation]:
    """Harmonic and intermodulation products that land in an idle impacter's band.

    For every step, products of the step's tones -- n f_i and f_i / n (n = 2, 3),
    2 f_i - f_j, f_i + f_j - f_k -- are compared with the frequency of every impacter
    idle in that step; within ``rules.relative_bandwidth`` of it is a violation.

    ``products`` (a drive chain's :class:`~planner.assignment.distortion.ProductRule`,
    optional): every violation then carries its amplitude at the die and whether it can
    move its impacter, and the 2nd-order products f_i + f_j and |f_i - f_j| of a chain
    with a 2nd-order term are looked for too.
    """
    out = []
    bw = rules.relative_bandwidth
    for st in steps:
        active = {Node(d, dr) for d, dr in st.active_nodes()}
        tones = np.array(sorted({frequencies[n] for n in active if n in frequencies}))
        idle = {n: f for n, f in frequencies.items() if n not in active}
        if tones.size == 0 or not idle:
            continue
        idle_names = list(idle)
        idle_f = np.array([idle[n] for n in idle_names])
        # every product as (kind, frequencies, the indices of their source tones), in
        # the order the rules list them; only the products near an idle impacter are
        # made into violations (a 25-tone step has ~7000 third-order products)
        segs = []
        if rules.harmonics:
            idx = np.arange(tones.size)
            for nh in (2, 3):
                segs.append(("harmonic", nh * tones, (idx,)))
                segs.append(("harmonic", tones / nh, (idx,)))
        if rules.intermodulation and tones.size >= 2:
            i, j = (np.array(a, dtype=np.int64).reshape(-1) for a in
                    zip(*itertools.permutations(range(tones.size), 2)))
            segs.append(("intermodulation", 2 * tones[i] - tones[j], (i, j)))
            if tones.size >= 3 and tones.size <= 40:
                i, j, k = _triples(tones.size)
                segs.append(("intermodulation", tones[i] + tones[j] - tones[k], (i, j, k)))
        if (products is not None and products.nonlinearity.a2 and rules.intermodulation
                and tones.size >= 2):
            i, j = (np.array(a, dtype=np.int64).reshape(-1) for a in
                    zip(*itertools.combinations(range(tones.size), 2)))
            both = np.stack([tones[i] + tones[j], np.abs(tones[j] - tones[i])], axis=1)
            segs.append((SECOND_ORDER, both.reshape(-1),
                         (np.repeat(i, 2), np.repeat(j, 2))))
        if not segs:
            continue
        for kind, pf, src in segs:
            # relative distance of each product to each idle impacter's frequency
            near = np.abs(pf[:, None] - idle_f[None, :]) <= bw * idle_f[None, :]
            for pi, ni in zip(*np.nonzero(near)):
                out.append(Violation(st.key, idle_names[ni], kind, float(pf[pi]),
                                     float(idle_f[ni]), tuple(tones[a[pi]] for a in src)))
    if products is not None:
        out = [products.judge(v) for v in out]
    return out


def conflict_count(violations, products=None):
    """How bad an assignment's violations are, least first: their number, or with a
    drive chain's :class:`~planner.assignment.distortion.ProductRule` (the products too
    weak to move their impacter are no conflict) the number that can, then all."""
    if products is None:
        return (len(violations),)
    return (sum(1 for v in violations if v.moves), len(violations))


@dataclass(frozen=True)
class Assignment:
    """Channels and frequencies of every driven impacter, and how they were found."""

    graph: nx.Graph           # one vertex per channel group, named by its first Node
    groups: dict              # group -> its Nodes
    coloring: dict            # group -> colour
    span: int
    lower_bound: int
    optimal: bool
    method: str
    seconds: float
    stride: int               # [positions]
    offset: int               # [positions]
    channels: dict            # impacter node -> channel index on the grid
    frequencies: dict         # impacter node -> frequency [Hz]
    violations: list = field(default_factory=list)
    #: impacter node -> index on the position grid (``offset + stride * colour``);
    #: equal to ``channels`` where the guard band is narrower than the separation
    positions: dict = field(default_factory=dict)
    #: the spec's measured reach the positions were laid on
    #: (:class:`planner.planning.reach.Reach`), or None
    reach: object = None

    def table(self) -> pd.DataFrame:
        """One row per impacter: device, direction, channel, frequency_hz."""
        rows = []
        for n in sorted(self.channels, key=node_order):
            rows.append({"id": n.text, "device": n.device, "direction": n.direction,
                         "channel": self.channels[n], "frequency_hz": self.frequencies[n]})
        return pd.DataFrame(rows)


def _mapping_candidates(span: int, count: int, max_candidates=64):
    """(stride, offset) pairs that fit a span onto a grid, widest stride first."""
    if span > count:
        return []
    q_max = (count - 1) // max(span - 1, 1) if span > 1 else 1
    out = []
    for q in range(q_max, 0, -1):
        room = count - 1 - q * (span - 1)
        centre = room // 2
        offsets = sorted(range(room + 1), key=lambda o: abs(o - centre))
        for o in offsets[: max(1, max_candidates // q_max)]:
            out.append((q, o))
        if len(out) >= max_candidates:
            break
    return out


def _guard_note(settings, grid, sep, positions):
    """Why the band holds fewer positions than channels (empty if it does not)."""
    if positions >= grid.size:
        return ""
    g = settings.guard
    onset = guard_onset_hz(grid, sep, g)
    if onset is None:
        # thinned by the measured reach, not by the guard (see the reach's note)
        return f" (the channels the spec's reach offers hold only {positions} positions)"
    return (f" (above {onset:g} Hz, {sep} channels are inside the designer's guard band: "
            f"tones there must be more than {100 * g:g} % apart (design.guard {g:g}), so "
            f"the {grid.size} channels hold only {positions} positions {sep} apart)")


def _tolerance_note(settings, n, fit, grid, sep):
    """Why a tolerance grid cannot hold ``n`` independent impacters, and what would."""
    lo, hi = settings.band_hz
    target = settings.target_yield
    sigma = settings.pair_sigma_rel
    spacing = settings.resonance_separation_hz
    z = z_for(target, n - 1)
    top = grid[-1] if len(grid) else lo
    return (f"{n} impacters must each be independently addressable (independent: true), "
            f"but the band {lo:g}-{hi:g} Hz, spaced for the fabrication scatter "
            f"(drive.channels.spacing: tolerance: {spacing:g} Hz "
            f"plus {z:.2f} sigma between neighbours, sigma {100 * sigma:.2f} % of the "
            f"frequency for the difference of two as-built resonances, for a "
            f"collision-free yield of {target:g}), holds only {fit}: neighbours "
            f"({sep} channels) are {grid[min(sep, len(grid) - 1)] - grid[0]:.0f} Hz apart at "
            f"{lo:g} Hz and "
            f"{(spacing + z * sigma * top):.0f} Hz at {top:.0f} Hz. "
            f"Fixes: a wider band (drive.band_hz), a lower fabrication.target_yield, "
            f"smaller tolerances (fabrication), a smaller line-width sensitivity (wider "
            f"beams: design.sensitivity_per_um or design.beam_width_um), a narrower "
            f"drive.channels.separation_hz, fewer devices, or independent: false with "
            f"scenes in which devices move together and share channels.")


def _reach_note(reach):
    """The measured reach's part of a refusal (empty without a constrained reach)."""
    if reach is None or not reach.constrained:
        return ""
    return (f" Measured for this spec before any design: {reach.summary()}. To widen it: "
            f"{reach.advice()}.")


def _positions(settings, grid, sep, reach):
    """The position grid, on the channels the reach offers with its separations."""
    if reach is None or not reach.constrained:
        return position_grid(grid, sep, settings.guard)
    if not reach.offered:
        lo, hi = settings.band_hz
        advice = reach.advice()
        raise PlanningError(f"no channel of the band {lo:g}-{hi:g} Hz can be used: "
                            f"{reach.summary()}. {advice[:1].upper()}{advice[1:]}.")
    return position_grid(grid, sep, settings.guard, allowed=reach.allowed,
                         min_ratio=reach.min_ratio)


def _check_capacity(settings, steps, sep, grid, positions, reach=None):
    """Refuse, in well under a second, a spec whose independently addressable impacters
    cannot fit the band whatever the colouring.

    When every impacter must be drivable on its own, every impacter is idle while every
    other one plays, so all of them must be told apart: the conflict graph is complete
    and no colouring spans fewer than (n - 1) sep + 1 positions (the channels, thinned
    where the designer's guard band is wider than ``sep`` channels: see
    :func:`planner.core.separation.position_grid`).  Building that graph for a large array
    (a 26 x 99 array: 5148 impacters, 13 million edges) takes minutes and gigabytes
    before the same answer; this bound gives it at once.
    """
    if not settings.all_independent:
        return
    nodes = {n for st in steps for n in st.active_nodes()}
    need = (len(nodes) - 1) * sep + 1
    count = len(positions)
    if need > count:
        lo, hi = settings.band_hz
        fit = (count - 1) // sep + 1
        if settings.channel_spacing == "tolerance":
            raise PlanningError(_tolerance_note(settings, len(nodes), fit, grid, sep)
                                + _reach_note(reach))
        what = (f"{count} channels" if count == grid.size else
                f"{count} positions{_guard_note(settings, grid, sep, count)}")
        raise PlanningError(
            f"{len(nodes)} impacters must each be independently addressable (independent: "
            f"true), so every pair must be {sep} channels apart and outside each other's "
            f"design guard band: that needs at least {need} positions (channels where "
            f"the guard band is narrower than {sep} channels), but the band {lo:g}-{hi:g} Hz "
            f"holds {what}; at most "
            f"{fit} independent impacters fit. Fixes: fewer devices (array), independent: "
            f"false with scenes in which devices move together and share channels, more "
            f"channels with a narrower separation (drive.channels.count, "
            f"drive.guard.separation_channels), a narrower design guard (design.guard), or "
            f"a wider band (drive.band_hz)." + _reach_note(reach))


def _span_error(settings, graph, result, grid, sep, count, reach=None):
    """The refusal of a colouring whose span the band's positions cannot hold."""
    lo, hi = settings.band_hz
    what = (f"{grid.size} channels" if count == grid.size else
            f"{count} positions{_guard_note(settings, grid, sep, count)}")
    fixes = ("a wider band (drive.band_hz), a lower fabrication.target_yield, smaller "
             "tolerances (fabrication), wider beams (design.sensitivity_per_um), a "
             "narrower drive.channels.separation_hz or ensemble separation "
             "(drive.guard.ensemble_separation_channels)"
             if settings.channel_spacing == "tolerance" else
             "a wider band (drive.band_hz), more channels (drive.channels.count) with a "
             "narrower response band (drive.guard.separation_channels), a narrower "
             "design guard (design.guard)")
    return PlanningError(
        f"the band {lo:g}-{hi:g} Hz holds {what}, but the conflict graph "
        f"({graph.number_of_nodes()} channel groups that must be told apart, separation "
        f"{sep} channels) needs a span of {result.span} (lower bound {result.lower_bound}). "
        f"Fixes: {fixes}, fewer independently addressable devices (independent: false), "
        f"or scenes in which devices move together and share a channel." + _reach_note(reach))


def assign(settings, steps, *, separation=None, pair_separation=None, method="auto",
           time_limit=None, reach=None) -> Assignment:
    """Give every driven impacter a channel and a frequency.

    Parameters
    ----------
    settings : planner.planning.settings.Settings
        The channel grid, the band, the guard rules, the ensemble separation, the
        design guard and the seed of the colouring.
    steps : sequence of Step
        From :func:`plan_steps`.
    separation : int, optional
        Default edge separation [channels]; ``settings.separation_channels``.
    pair_separation : dict, optional
        Per-pair overrides, see :func:`conflict_graph`.
    method, time_limit :
        The colouring's strategy and time limit [s]
        (:func:`planner.coloring.solve_bandwidth`).
    reach : planner.planning.reach.Reach, optional
        The spec's measured reach: only the channels it offers are used, and positions
        keep its separations (:func:`planner.core.separation.position_grid`).

    Raises
    ------
    PlanningError
        When the band cannot hold the graph, saying which constraint fails and
        what would fix it.
    """
    from planner.coloring import solve_bandwidth

    sep = settings.separation_channels if separation is None else int(separation)
    grid = np.asarray(settings.channel_grid_hz, dtype=float)
    # every edge is >= sep positions: on these positions that keeps the designer's guard
    positions = _positions(settings, grid, sep, reach)
    _check_capacity(settings, steps, sep, grid, positions, reach)
    graph, groups = conflict_graph(steps, sep, pair_separation,
                                   settings.ensemble_separation_channels)
    if graph.number_of_nodes() == 0:
        raise PlanningError("no step drives any impacter: nothing to assign")
    result = solve_bandwidth(graph, "sep", method=method, time_limit=time_limit,
                             seed=settings.seed)
    count = len(positions)
    if result.span > count:
        raise _span_error(settings, graph, result, grid, sep, count, reach)
    # layout: a colouring read upward or downward is equally valid, and so is any order
    # of its blocks (runs of channels set apart by wide gaps) that keeps every
    # separation within the span; choose the one whose multi-tone steps stir their
    # idle impacters least (see _ensemble_severity)
    mapping = _mapping_candidates(result.span, count)
    q0, o0 = mapping[0]
    freq_of = lambda col: {g: float(grid[positions[o0 + q0 * c]])  # noqa: E731
                           for g, c in col.items()}
    candidates = _block_layouts(graph, result.coloring, result.span)
    coloring = min(candidates,
                   key=lambda col: (_ensemble_severity(steps, groups, freq_of(col)),
                                    _ensemble_exposure(steps, groups, col)))
    if _placement(settings) == "neighbours":
        # tone neighbours on neighbouring devices (issue 39): a die's line-width
        # gradient then moves the closest pairs alike
        coloring = neighbour_coloring(graph, groups, coloring)
    # with a distorting drive chain, only the products that can move an idle impacter
    # are conflicts (issue 46): the layout keeps those apart first
    rule = product_rule(settings, reach)
    best = None
    for q, o in mapping:
        freqs, chans, where = {}, {}, {}
        for g, colour in coloring.items():
            for n in groups[g]:
                where[n] = o + q * colour
                chans[n] = int(positions[where[n]])
                freqs[n] = float(grid[chans[n]])
        viol = guard_violations(steps, freqs, settings.tone_rules, rule)
        score = conflict_count(viol, rule)
        if best is None or score < best[6]:
            best = (q, o, chans, freqs, viol, where, score)
        if not score[0]:
            break
    q, o, chans, freqs, viol, where, _ = best
    return Assignment(graph, groups, dict(coloring), result.span, result.lower_bound,
                      result.optimal, result.method, result.seconds, q, o, chans, freqs, viol,
                      where, reach)


def _placement(settings) -> str:
    """``drive.channels.placement`` (:attr:`Settings.channel_placement`); ``coloring`` for
    a settings-like object without one."""
    return settings.channel_placement if hasattr(settings, "channel_placement") else "coloring"


#: At most this many blocks are permuted (their orders times per-block mirrors).
MAX_LAYOUT_BLOCKS = 5


def _block_layouts(graph, coloring, span, attr="sep"):
    """Valid colourings of no greater span made by reordering and mirroring blocks.

    The blocks are the runs of the colouring split where two consecutive colours are
    further apart than the graph's smallest separation (the wide gaps the ensemble
    separations open).  Each order of the blocks, each block read up or down, is
    packed bottom-up as tightly as every edge's separation allows; the packings that
    fit in ``span`` channels are returned, the given colouring and its mirror first.
    """
    top = max(coloring.values())
    out = [dict(coloring), {g: top - c for g, c in coloring.items()}]
    if graph.number_of_edges() == 0:
        return out
    seps = [d[attr] for _, _, d in graph.edges(data=True)]
    blocks = colour_blocks(coloring, min(seps) + 1)
    if not 2 <= len(blocks) <= MAX_LAYOUT_BLOCKS:
        return out
    names = sorted(coloring)
    index = {g: i for i, g in enumerate(names)}
    sep = np.zeros((len(names), len(names)), dtype=np.int64)
    for a, b, d in graph.edges(data=True):
        sep[index[a], index[b]] = sep[index[b], index[a]] = d[attr]
    seen = {tuple(sorted(c.items())) for c in out}
    for perm in itertools.permutations(range(len(blocks))):
        for flips in itertools.product((False, True), repeat=len(blocks)):
            placed_idx, placed_col, col = [], [], {}
            for bi, flip in zip(perm, flips):
                blk = blocks[bi]
                rel = np.array([coloring[g] - coloring[blk[0]] for g in blk])
                if flip:
                    rel = rel.max() - rel
                idx = np.array([index[g] for g in blk])
                base = 0
                if placed_idx:
                    pi, pc = np.array(placed_idx), np.array(placed_col)
                    # every new colour at least sep above each placed one
                    need = pc[None, :] + sep[np.ix_(idx, pi)] - rel[:, None]
                    base = max(0, int(need.max()))
                for g, r in zip(blk, rel):
                    col[g] = base + int(r)
                placed_idx += list(idx)
                placed_col += [col[g] for g in blk]
            if max(col.values()) + 1 > span:
                continue
            key = tuple(sorted(col.items()))
            if key not in seen:
                seen.add(key)
                out.append(col)
    return out


def _ensemble_severity(steps, groups, freqs):
    """How hard the multi-tone steps shake the impacters idle in them.

    For an idle impacter at f and a tone at f_p > f of the same step, ``(f_p / f)^0.5
    / ((f_p / f)^2 - 1)`` is the tone's forced relative amplitude near f at the
    drive's constant power (amplitude ~ f_p^-1.5, base-excitation gain rho^2 /
    |1 - rho^2|), summed in squares over the step's tones above and over the idle
    impacters.  Tones below an idle impacter are left out: the designer and the
    verification find those far easier to stay silent under (the mass line, and a
    lower drive force m w^2 Z ~ f^0.5).
    """
    member_of = {n: g for g, members in groups.items() for n in members}
    total = 0.0
    for st in steps:
        playing = {member_of[Node(d, dr)] for d, dr in st.active_nodes()
                   if (d, dr) in member_of}
        if len(playing) < 2:
            continue
        fp = np.array(sorted(freqs[p] for p in playing))
        for g in set(groups) - playing:
            rho = fp[fp > freqs[g]] / freqs[g]
            total += float(np.sum(rho / (rho ** 2 - 1.0) ** 2))
    return round(total, 9)


def _ensemble_exposure(steps, groups, coloring):
    """Pairs (idle impacter, tone above it) over the steps that play several tones.

    Above its resonance an impacter follows a tone with about the tone's amplitude
    (the mass line), below it with (f / nu_n)^2 of it; so the sum of a step's tones
    stirs an idle impacter below them more than one above them.
    """
    member_of = {n: g for g, members in groups.items() for n in members}
    count = 0
    for st in steps:
        playing = {member_of[Node(d, dr)] for d, dr in st.active_nodes()
                   if (d, dr) in member_of}
        if len(playing) < 2:
            continue
        for g in set(groups) - playing:
            count += sum(coloring[p] > coloring[g] for p in playing)
    return count


def told_apart_pairs(assignment: Assignment, nodes) -> np.ndarray:
    """Index pairs (into ``nodes``) of the impacters the conflict graph keeps apart,
    ndarray shape (n_pairs, 2), each pair ascending, the pairs in order."""
    index = {n: k for k, n in enumerate(nodes)}
    out = set()
    for a, b in assignment.graph.edges():
        for u in assignment.groups[a]:
            for v in assignment.groups[b]:
                if u in index and v in index:
                    out.add(tuple(sorted((index[u], index[v]))))
    return np.array(sorted(out), dtype=np.int64).reshape(-1, 2)


def verify_assignment(assignment: Assignment) -> list[str]:
    """Independent check: every edge's separation holds on the channels actually used."""
    problems = []
    for a, b, data in assignment.graph.edges(data=True):
        for u in assignment.groups[a]:
            for v in assignment.groups[b]:
                d = abs(assignment.channels[u] - assignment.channels[v])
                if d < data["sep"]:
                    problems.append(f"{u} and {v}: {d} channels apart, need {data['sep']}")
    return problems
