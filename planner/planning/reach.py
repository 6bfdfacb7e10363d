"""Stage 1, reach: the tones a design can serve, and how far apart, measured for the spec
before any channel is assigned.

The spec's bounds, mass cap, process rules and sensitivity target decide which tones a
design can drive its slider at the speed floor: too low, no matched beam is soft enough
(the beam length at its bound); too high, no impacter with the smallest gap hits hard
enough under the drive's power.  And the environment decides how far a design answers
tones other than its own: in air a few hundred Hz, in vacuum (undamped) far.  Neither
follows from the spec alone, so the planner measures both with the designer itself, at a
few probe channels (:data:`PROBE_COUNT`, log-spaced over the channel grid):

- **separation**: a design for the probe's tone with a neighbour on each side at the
  grid's packed separation (``drive.guard.separation_channels`` positions away), by the
  planner's own retry policy (:func:`planner.planning.designs._design_task`).  Feasible
  (silent at both, responding from every x0, at least the speed floor): the spec's
  separation holds there.  Otherwise the neighbours move out: first to
  :data:`RATIO_LIMIT` (infeasible there too: no tone there can be told apart from
  another), then from the packed ratio r0 to 1 + 2^k (r0 - 1), k = 1, 2 ..., and one
  bisection in log ratio below the first feasible rung: the separation the assigner
  must keep there.
- **reach**: a design alone at the tone (no forbidden tone), the best of the planner's
  tries: infeasible means no design serves that tone at the floor.  Between a reachable
  and an unreachable probe the edge is bisected to the channel.

Channels outside the reach are not offered to the assigner, and the positions it lays
the colouring on keep the measured separations (:func:`planner.separation.position_grid`);
a spec whose steps cannot fit what remains is refused before any design, naming the
reachable tones and the separations (:func:`planner.assign.assign`).  Every probe is a
design task, run on the plan's worker pool and kept in the design cache.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from planner.planning.designs import (DESIGN_RETRIES, INFEASIBLE_TRIES, SPEED_MARGIN,
                                      _design_task, dispatch)
from planner.planning.settings import Settings

#: Probe channels, log-spaced over the grid, its ends included [-].
PROBE_COUNT = 9
#: The widest neighbour ratio a separation probe tries [-]: a design still answering a
#: tone a factor 4 away (vacuum) cannot be told apart from any other tone.
RATIO_LIMIT = 4.0
#: Bisection steps in log ratio below the first feasible rung of the ladder [-].
RATIO_BISECTIONS = 1
#: Hard-infeasible tries of a separation probe beyond the packed ratio (one: those
#: rungs measure where a design stops answering, not whether a hard target is met).
WIDE_RUNG_TRIES = 1


@dataclass(frozen=True)
class Probe:
    """What the designer found at one probe channel.

    Attributes
    ----------
    channel : int
        Index on the channel grid.
    tone_hz : float
        Its tone [Hz].
    packed_ratio : float
        The ratio of its neighbours on the packed position grid [-].
    ratio : float or None
        The least neighbour ratio at which a design was feasible [-] (``packed_ratio``
        when the spec's separation holds); None: none up to :data:`RATIO_LIMIT`.
    reachable : bool
        A design serves the tone at the speed floor (with its neighbours, or alone).
    speed_m_s : float
        The predicted slider speed of the best design found there [m/s].
    tried : tuple of (float, bool, str)
        Every rung: neighbour ratio (0: alone), feasible, why not.
    """

    channel: int
    tone_hz: float
    packed_ratio: float
    ratio: float | None
    reachable: bool
    speed_m_s: float
    tried: tuple = ()

    def to_dict(self) -> dict:
        return {"channel": self.channel, "tone_hz": self.tone_hz,
                "packed_ratio": self.packed_ratio, "ratio": self.ratio,
                "reachable": self.reachable, "speed_m_s": self.speed_m_s,
                "tried": [{"ratio": r, "feasible": ok, "why": why}
                          for r, ok, why in self.tried]}


@dataclass(frozen=True)
class Reach:
    """The tones a design can serve and the separations it needs, per channel.

    Attributes
    ----------
    floor_m_s : float
        The speed floor the reach is measured at [m/s].
    grid_hz : tuple of float
        The channel grid [Hz].
    reachable : tuple of bool
        Channels a design alone can serve at the speed floor.
    allowed : tuple of bool
        Channels offered to the assigner: reachable, and not nearest a probe at which
        no neighbour ratio up to :data:`RATIO_LIMIT` could be told apart.
    min_ratio : tuple of float
        Per channel, the least ratio to the next tone it must be told apart from [-]
        (1 where the spec's own separation holds).
    probes : tuple of Probe
    edges : tuple of (int, bool, float)
        The edge bisections' probes: channel, reachable, speed [m/s].
    designs : int
        Probe designs run (not read from the cache).
    seconds : float
    """

    floor_m_s: float
    grid_hz: tuple
    reachable: tuple
    allowed: tuple
    min_ratio: tuple
    probes: tuple
    edges: tuple = ()
    designs: int = 0
    seconds: float = 0.0
    environment: str = field(default="", compare=False)

    @property
    def constrained(self) -> bool:
        """Whether the reach takes anything from the grid (channels or separations)."""
        return not all(self.allowed) or any(r > 1.0 for r in self.min_ratio)

    @property
    def offered(self) -> int:
        """Channels offered to the assigner."""
        return int(sum(self.allowed))

    @property
    def range_hz(self):
        """(lowest, highest) reachable tone [Hz], or None when no channel is."""
        idx = np.flatnonzero(self.reachable)
        if idx.size == 0:
            return None
        return (self.grid_hz[int(idx[0])], self.grid_hz[int(idx[-1])])

    def widened(self):
        """Probes whose separation had to be widened beyond the packed grid's."""
        return [p for p in self.probes if p.ratio is not None and p.ratio > p.packed_ratio]

    def summary(self) -> str:
        """One paragraph: the reachable tones and the separations, for messages."""
        grid = self.grid_hz
        rng = self.range_hz
        floor = self.floor_m_s * 1e3
        speeds = ", ".join(f"{p.tone_hz / 1e3:.3g} kHz {p.speed_m_s * 1e3:.3g}"
                           for p in self.probes)
        if rng is None:
            text = (f"no tone of the channel grid ({grid[0]:.0f}-{grid[-1]:.0f} Hz) can be "
                    f"served at the speed floor {floor:g} mm/s: the fastest design the "
                    f"planner found at each probe tone [mm/s]: {speeds}")
        else:
            n = int(sum(self.reachable))
            text = (f"the tones a design can serve at the speed floor {floor:g} mm/s are "
                    f"{rng[0]:.0f}-{rng[1]:.0f} Hz ({n} of the grid's {len(grid)} channels; "
                    f"the fastest design found at each probe tone [mm/s]: {speeds})")
        wide = self.widened()
        if wide:
            text += ("; designs answer tones further from their own than the grid's "
                     "separation: " + ", ".join(
                         f"at {p.tone_hz / 1e3:.3g} kHz neighbours must be x{p.ratio:.3g} "
                         f"away (the grid packs them x{p.packed_ratio:.3g})" for p in wide))
        lost = [p for p in self.probes if p.reachable and p.ratio is None]
        if lost:
            text += ("; but no design could be told apart from another tone: none was "
                     f"silent even at neighbours x{RATIO_LIMIT:g} away, at " + ", ".join(
                         f"{p.tone_hz / 1e3:.3g} kHz" for p in lost))
            if self.environment == "vacuum":
                text += (" (in vacuum an impacter is undamped: released from x0 = +-c, "
                         "the initial states every design is checked from, its free "
                         "oscillation never decays, and any tone it sits out adds to it "
                         "until it reaches its wall, however far that tone is)")
        return text

    def advice(self) -> str:
        """What would widen the reach or narrow the separations (field names)."""
        out = []
        rng = self.range_hz
        lo, hi = self.grid_hz[0], self.grid_hz[-1]
        if rng is None or rng[0] > lo:
            out.append("to serve lower tones: longer or narrower beams (design.bounds."
                       "length_um, a smaller design.sensitivity_per_um or "
                       "design.beam_width_um), a larger plate (design.bounds.area_um2) "
                       "or mass cap (design.max_mass_ratio)")
        if rng is None or rng[1] < hi:
            out.append("to serve higher tones: a smaller gap (design.bounds.gap_um, "
                       "process.min_space_um) or more drive (drive.power_m2_s3)")
        if rng is None or rng[0] > lo or rng[1] < hi:
            out.append("or a lower floor (verification.min_speed_mm_s), a heavier "
                       "impacter for its slider (design.max_mass_ratio) or a lighter "
                       "slider (device.slider.area_um2)")
        if self.widened() or any(p.ratio is None for p in self.probes if p.reachable):
            out.append("to bring separations down: more damping (environment."
                       "viscosity_mpa_s: an undamped impacter released from x0 = +-c "
                       "never stops ringing, and any tone it sits out adds to it until "
                       "it reaches its wall) or fewer impacters that must be told apart "
                       "(independent: false, scenes that move devices together)")
        return "; ".join(out)

    def lines(self) -> list[str]:
        """Lines for the CLI before any design."""
        rng = self.range_hz
        head = (f"reach (measured in {self.seconds:.1f} s, {self.designs} probe designs): ")
        if not self.constrained:
            return [head + f"every channel {self.grid_hz[0]:.0f}-{self.grid_hz[-1]:.0f} Hz "
                    f"can be served at {self.floor_m_s * 1e3:g} mm/s at the grid's "
                    "separation"]
        out = [head + self.summary()]
        out.append(f"  channels offered to the assigner: {self.offered} of "
                   f"{len(self.grid_hz)}")
        return out

    def to_dict(self) -> dict:
        rng = self.range_hz
        return {"floor_m_s": self.floor_m_s,
                "range_hz": None if rng is None else [float(rng[0]), float(rng[1])],
                "channels_reachable": int(sum(self.reachable)),
                "channels_offered": self.offered,
                "channels_in_grid": len(self.grid_hz),
                "constrained": self.constrained,
                "probes": [p.to_dict() for p in self.probes],
                "edges": [{"channel": c, "reachable": ok, "speed_m_s": v}
                          for c, ok, v in self.edges],
                "designs": self.designs, "seconds": self.seconds}


# probe tasks (module level: workers import them by name) ------------------------------

def _why(res) -> str:
    return "; ".join(s["text"] for s in res.shortfalls)


def _alone(shared, tone):
    """(feasible, speed [m/s], why) of a design alone at ``tone`` [Hz]."""
    return _rung(shared, tone, (), INFEASIBLE_TRIES)


def _rung(shared, tone, neighbours, tries):
    """(feasible, speed [m/s], why) of a design at ``tone`` [Hz] silent at
    ``neighbours`` [Hz]: the planner's tries, stopping at the first feasible one (a
    probe asks whether a design exists, not for the fastest)."""
    base, floor = shared
    res = _design_task({**base, "frequency": float(tone), "forbidden": tuple(neighbours)},
                       floor, infeasible_tries=tries, margin=1.0)
    return bool(res.feasible), float(res.predicted_slider_speed_m_s), _why(res)


def _ladder(shared, tone, packed, packed_neighbours):
    """One separation probe (see the module docstring): returns (ratio or None,
    reachable, speed, tried)."""
    tried = []
    ok, speed, why = _rung(shared, tone, packed_neighbours, INFEASIBLE_TRIES)
    tried.append((packed, ok, why))
    if ok:
        return packed, True, speed, tuple(tried)
    alone_ok, alone_speed, alone_why = _alone(shared, tone)
    tried.append((0.0, alone_ok, alone_why))
    if not alone_ok:
        return None, False, max(speed, alone_speed), tuple(tried)

    def at(ratio):
        ok, v, why = _rung(shared, tone, (tone / ratio, tone * ratio), WIDE_RUNG_TRIES)
        tried.append((ratio, ok, why))
        return ok, v

    ok, best = at(RATIO_LIMIT)
    if not ok:
        return None, True, alone_speed, tuple(tried)
    lo, hi, k = packed, RATIO_LIMIT, 1
    while True:
        rung = 1.0 + 2.0 ** k * (packed - 1.0)
        if rung >= RATIO_LIMIT:
            break
        ok, v = at(rung)
        if ok:
            hi, best = rung, v
            break
        lo, k = rung, k + 1
    for _ in range(RATIO_BISECTIONS):
        mid = math.sqrt(lo * hi)
        ok, v = at(mid)
        if ok:
            hi, best = mid, v
        else:
            lo = mid
    return hi, True, best, tuple(tried)


def _edge(shared, tones, reachable_first):
    """Bisect the channels ``tones`` [Hz] (increasing; the first is reachable iff
    ``reachable_first``, the last is not) for the last channel on the first one's side:
    returns (index into ``tones``, probes as (index, reachable, speed))."""
    a, b = 0, len(tones) - 1
    seen = []
    while b - a > 1:
        mid = (a + b) // 2
        ok, speed, _ = _alone(shared, tones[mid])
        seen.append((mid, ok, speed))
        if ok == reachable_first:
            a = mid
        else:
            b = mid
    return a, tuple(seen)


# the stage ---------------------------------------------------------------------------

def probe_channels(grid, count=PROBE_COUNT):
    """Indices of ``count`` channels log-spaced over ``grid`` (ends included)."""
    grid = np.asarray(grid, dtype=float)
    if grid.size <= count:
        return list(range(grid.size))
    want = np.geomspace(grid[0], grid[-1], count)
    return sorted({int(np.argmin(np.abs(np.log(grid / f)))) for f in want})


def packed_neighbours(grid, positions, separation, channel):
    """(ratio, neighbours [Hz]) of ``channel`` on the packed positions: the tones
    ``separation`` positions above and below it that lie in the grid, and the smaller of
    their ratios to its tone."""
    grid = np.asarray(grid, dtype=float)
    i = int(np.argmin(np.abs(np.asarray(positions) - channel)))
    f = grid[channel]
    nb, ratios = [], []
    if i - separation >= 0:
        nb.append(float(grid[positions[i - separation]]))
        ratios.append(f / nb[-1])
    if i + separation < len(positions):
        nb.append(float(grid[positions[i + separation]]))
        ratios.append(nb[-1] / f)
    return (min(ratios) if ratios else RATIO_LIMIT), tuple(nb)


def _kinds(settings: Settings):
    """One representative node per distinct impacter setting among the driven nodes."""
    from planner.nodes import Node

    driven = sorted({Node(d, dr) for st in settings.steps for d, dr in st.active_nodes()})
    out = {}
    for n in driven:
        out.setdefault(settings.impacters[n], n)
    return list(out.values())


def measure_reach(settings: Settings, *, jobs=1, scheduler=None, pool=None, store=None,
                  progress=None) -> Reach:
    """Probe the spec's reach and separations (see the module docstring).

    Parameters
    ----------
    settings : Settings
    jobs, scheduler, pool :
        Where the probe designs run (:func:`planner.planning.designs.dispatch`).
    store : planner.planning.design_store.DesignStore, optional
        The design cache: a probe it holds is read, not run.
    progress : callable(stage, item=None, total=None), optional
        The plan's progress callback (stage "reach").

    Returns
    -------
    Reach
        Channels allowed and separations per channel: with several kinds of impacter
        (devices set apart by ``devices:``), the channels every kind can serve and the
        widest separation any needs.
    """
    from planner.separation import position_grid

    t0 = time.perf_counter()
    tick = progress or (lambda stage, item=None, total=None: None)
    grid = np.asarray(settings.channel_grid_hz, dtype=float)
    sep = settings.separation_channels
    positions = position_grid(grid, sep, settings.guard)
    floor = settings.min_speed_m_s
    probes_at = probe_channels(grid)
    reachable = np.ones(grid.size, dtype=bool)
    allowed = np.ones(grid.size, dtype=bool)
    need = np.ones(grid.size)
    all_probes, all_edges, ran = [], [], [0]
    kinds = _kinds(settings)
    tick("reach", total=len(kinds) * len(probes_at))
    for node in kinds:
        base = settings.design_kwargs(node)
        shared = (base, floor)
        packed = [packed_neighbours(grid, positions, sep, c) for c in probes_at]
        args = [(float(grid[c]), r, nb) for c, (r, nb) in zip(probes_at, packed)]
        found = _cached_run(_ladder, shared, args, "ladder", store, ran, jobs, scheduler, pool,
                            on_done=lambda i, res: tick("reach", i))
        probes = [Probe(c, float(grid[c]), r, ratio, reach, speed, tried)
                  for c, (r, _), (ratio, reach, speed, tried) in zip(probes_at, packed, found)]
        # edges between probes that disagree on reach
        pairs = [(a, b) for a, b in zip(probes, probes[1:]) if a.reachable != b.reachable
                 and b.channel - a.channel > 1]
        edge_args = [(tuple(float(f) for f in grid[a.channel:b.channel + 1]), a.reachable)
                     for a, b in pairs]
        edges = _cached_run(_edge, shared, edge_args, "edge", store, ran, jobs, scheduler,
                            pool)
        ok = _reachable_mask(grid.size, probes, pairs, edges)
        reachable &= ok
        allowed &= ok
        need = np.maximum(need, _needed_ratio(grid, probes, allowed))
        for (a, _), (_, seen) in zip(pairs, edges):
            all_edges += [(a.channel + i, bool(r), float(v)) for i, r, v in seen]
        all_probes += probes
    env = "vacuum" if settings.environment.viscosity_mpa_s == 0 else ""
    return Reach(floor, tuple(float(f) for f in grid), tuple(bool(a) for a in reachable),
                 tuple(bool(a) for a in allowed),
                 tuple(float(r) for r in need), tuple(all_probes), tuple(all_edges),
                 ran[0], time.perf_counter() - t0, env)


def _cached_run(func, shared, args_list, kind, store, ran, jobs, scheduler, pool,
                on_done=None):
    """:func:`dispatch` of probe tasks, each read from / written to the design cache."""
    out = [None] * len(args_list)
    digests = []
    if store is not None:
        from planner.planning.design_store import task_digest

        base, floor = shared
        for args in args_list:
            digests.append(task_digest({"reach_probe": kind, "args": args, **base}, floor,
                                       DESIGN_RETRIES, INFEASIBLE_TRIES, SPEED_MARGIN,
                                       RATIO_LIMIT, RATIO_BISECTIONS, WIDE_RUNG_TRIES))
    todo = []
    for i, args in enumerate(args_list):
        hit = store.get(digests[i]) if store is not None else None
        if hit is not None:
            out[i] = hit
            if on_done is not None:
                on_done(i, hit)
        else:
            todo.append(i)

    def done(j, res):
        i = todo[j]
        out[i] = res
        ran[0] += 1
        if store is not None:
            store.put(digests[i], res)
        if on_done is not None:
            on_done(i, res)

    dispatch(func, shared, [args_list[i] for i in todo], jobs=jobs, scheduler=scheduler,
             pool=pool, on_done=done)
    return out


def _reachable_mask(n, probes, pairs, edges):
    """Channels reachable by the probes and the edges bisected between them."""
    ok = np.zeros(n, dtype=bool)
    if not probes:
        return ok
    edge_of = {a.channel: a.channel + last for (a, _), (last, _) in zip(pairs, edges)}
    first, last = probes[0], probes[-1]
    if first.reachable:
        ok[:first.channel + 1] = True
    if last.reachable:
        ok[last.channel:] = True
    for a, b in zip(probes, probes[1:]):
        if a.reachable and b.reachable:
            ok[a.channel:b.channel + 1] = True
        elif a.reachable != b.reachable:
            cut = edge_of.get(a.channel, a.channel)     # the last channel on a's side
            if a.reachable:
                ok[a.channel:cut + 1] = True
            else:
                ok[cut + 1:b.channel + 1] = True
    return ok


def _needed_ratio(grid, probes, allowed):
    """Per channel, the least neighbour ratio [-] the probes measured: 1 where the packed
    grid's holds, interpolated in log ratio and log frequency between probes that needed
    more, constant beyond the first and last; a channel nearest a probe at which no
    ratio up to :data:`RATIO_LIMIT` worked is left out (``allowed`` is updated)."""
    grid = np.asarray(grid, dtype=float)
    need = np.ones(grid.size)
    usable = [p for p in probes if p.reachable]
    if not usable:
        return need
    # a probe that held at the packed ratio needs nothing more
    excess = {p.channel: (0.0 if p.ratio is None or p.ratio <= p.packed_ratio
                          else math.log(p.ratio)) for p in usable if p.ratio is not None}
    chans = np.array(sorted(excess))
    if chans.size:
        logf = np.log(grid)
        vals = np.array([excess[c] for c in chans])
        need = np.exp(np.interp(logf, logf[chans], vals))
    hopeless = [p.channel for p in usable if p.ratio is None]
    if hopeless:
        centres = np.array([p.channel for p in probes])
        nearest = centres[np.argmin(np.abs(np.arange(grid.size)[:, None] - centres[None, :]),
                                    axis=1)]
        allowed &= ~np.isin(nearest, hopeless)
    return need
