"""Stage 1, reach: the tones a design can serve, and how far apart, measured for the spec
before any channel is assigned.

The spec's bounds, mass cap, process rules and sensitivity target decide which tones a
design can drive its slider at the speed floor: too low, no matched beam is soft enough
(the beam length at its bound); too high, no impacter with the smallest gap hits hard
enough under the drive's power.  And the environment decides how far a design answers
tones other than its own: in air a few hundred Hz, in vacuum (undamped) far.  Neither
follows from the spec alone, so the planner measures both with the designer itself, at
:data:`PROBE_COUNT` probe channels log-spaced over the channel grid (a spec that plays
fewer tones than that: at the channels an assignment on the packed grid takes), before
it assigns; the steps must first fit the band with every channel served at the packed
spacing, or the spec is refused before any probe (the probes can only take channels
away), and an undamped array is refused there too (its every probe was hopeless):

1. A design for the probe's tone with a neighbour on each side at the grid's packed
   spacing (the positions ``drive.guard.separation_channels`` away, as in a full band),
   by the planner's own tries (:func:`planner.planning.designs._design_task`, at most
   :data:`PROBE_TRIES`).  Feasible (silent at both, responding from every x0, at least
   the speed floor): the tone can be served and the spacing holds.
2. Otherwise the neighbours move out to :data:`RATIO_LIMIT` (a factor 4): infeasible
   there too, a design alone at the tone decides -- it can be served (but told apart
   from no other tone: the channels nearest the probe are not offered) or not (the tone
   is out of reach).  Feasible there, the neighbour ratio is narrowed to 1 + 2^k (r0 -
   1), k = 1, 2 ..., and bisected once in log ratio below the first feasible rung: the
   spacing the assigner must keep there (:func:`planner.core.separation.position_grid`'s
   ``min_ratio``).
3. Between a probe that can be served and one that cannot, the edge is bisected to the
   channel (each step one design with neighbours, and one alone if that fails).

A design alone is no measure of the speed a tone allows: unconstrained, the max-min
design of eq. (13) favours light impacters that hit often with small kicks, which
friction swallows (at 51 kHz in the default: m/M 0.03-0.05 and 0.04-0.07 mm/s alone,
0.14-0.40 and 0.10-0.37 mm/s with neighbours at the packed spacing), so it is asked
only when the designs with neighbours fail.

Channels out of reach are not offered to the assigner, and the positions it lays the
colouring on keep the measured spacing; a spec whose steps cannot fit what remains is
refused before any design, naming the reachable tones, the spacing and what would widen
them (:func:`planner.assignment.assign.assign`).  Every probe is a design task, run on the plan's
worker pool and kept in the design cache.
"""

from __future__ import annotations

import collections
import dataclasses
import math
import time
from dataclasses import dataclass, field

import numpy as np

from planner.core.errors import PlanningError
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
#: The seed of every probe design, whatever the plan's: the reach is a property of the
#: spec (process, environment, bounds, band, floor), not of the seed, so every seed of a
#: spec reads the same probes from the design cache and pays for them once.
REACH_SEED = 0
#: The shape of a probe's result in the design cache (2: with its design, the family).
PROBE_FORMAT = 2
#: Most tries of one probe design (the plan's designs take up to 1 + DESIGN_RETRIES
#: while they are only too slow; a probe stops at its first feasible design whose
#: speed at its tone and at its tone window's edges reaches the floor: the design it
#: keeps is the family the plan's designs start from, so a faster one is worth a try.
#: Stopping at the first feasible design whatever its edges was measured: the reach
#: took 2-4 s less, the designs started from the slower family took as much more, and
#: every design of the specs downstream changed).
PROBE_TRIES = 4


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
        when the grid's spacing holds); None: none up to :data:`RATIO_LIMIT`.
    reachable : bool
        A design serves the tone at the speed floor (with its neighbours, or alone).
    speed_m_s : float
        The predicted slider speed of the best design found there [m/s].
    tried : tuple of (float, bool, str)
        Every rung: neighbour ratio (0: alone), feasible, why not.
    design : tuple or None
        ((A, w, l, c) [m], tone [Hz]) of the fastest feasible design found with
        neighbours, a member of the spec's design family (:attr:`Reach.family`); None
        when none was feasible.
    """

    channel: int
    tone_hz: float
    packed_ratio: float
    ratio: float | None
    reachable: bool
    speed_m_s: float
    tried: tuple = ()
    design: tuple | None = None

    @property
    def hopeless(self) -> bool:
        """Reachable (alone), but no design was silent even at neighbours
        :data:`RATIO_LIMIT` away: no tone here can be told apart from another."""
        return self.reachable and self.ratio is None

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
    #: numba's cache before the probes ran: (kernels that had to compile, all of them)
    #: (:func:`model.warmup.numba_cache_state`); the probes compile them
    kernels_cold: tuple = field(default=(0, 0), compare=False)
    #: the widened separations or the channels of a hopeless probe did not fit the band,
    #: and the assignment offers every reachable channel at the grid's packed spacing
    #: instead (:func:`measure_reach`); the plan's loop moves a design that then fails
    relaxed: bool = False
    #: the spec plays fewer tones than PROBE_COUNT: the probes sat at the tones an
    #: assignment on the packed grid takes, each first asked with the neighbours that
    #: assignment gives it (:func:`measure_reach`)
    assigned: bool = False
    #: the designs are made robust (``design.robust``): silent at their neighbours under
    #: every resonance shift the fabrication allows, which widens the spacing they need
    robust: bool = field(default=False, compare=False)

    @property
    def family(self) -> tuple:
        """((A, w, l, c), tone) of every probe's feasible design, by tone: the spec's
        design family, which the plan's designs start from
        (:func:`planner.planning.designs.family_for`)."""
        return _family(self.probes)

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
        """Probes whose spacing had to be widened beyond the packed grid's."""
        return [p for p in self.probes if _widened(p)]

    def speeds_by_tone(self):
        """(tone [Hz], speed [m/s]) per probe tone, by tone: with several kinds of
        impacter (``devices:``) each tone was probed once per kind, and the slowest
        kind's fastest design is the tone's (every kind must be served there)."""
        slowest = {}
        for p in self.probes:
            slowest[p.tone_hz] = min(slowest.get(p.tone_hz, math.inf), p.speed_m_s)
        return sorted(slowest.items())

    def summary(self) -> str:
        """One paragraph: the reachable tones and the separations, for messages."""
        grid = self.grid_hz
        rng = self.range_hz
        floor = self.floor_m_s * 1e3
        speeds = ", ".join(f"{tone / 1e3:.3g} kHz {speed * 1e3:.3g}"
                           for tone, speed in self.speeds_by_tone())
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
        lost = [p for p in self.probes if p.hopeless]
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
        if rng is None and self.probes:
            by_tone = self.speeds_by_tone()
            fastest = max(range(len(by_tone)), key=lambda i: by_tone[i][1])
            where = ("higher" if fastest == len(by_tone) - 1 else
                     "lower" if fastest == 0 else None)
            if where:
                out.append(f"or a {where} band (drive.band_hz): the fastest design was found "
                           f"at {by_tone[fastest][0]:.0f} Hz, the band's "
                           f"{'top' if where == 'higher' else 'bottom'}")
        if self.widened() or any(p.hopeless for p in self.probes):
            out.append("to bring separations down: more damping (environment."
                       "viscosity_mpa_s: an undamped impacter released from x0 = +-c "
                       "never stops ringing, and any tone it sits out adds to it until "
                       "it reaches its wall) or fewer impacters that must be told apart "
                       "(independent: false, scenes that move devices together)")
            if self.robust:
                out.append("or designs not made robust (design.robust: false: a robust "
                           "design must be silent at its neighbours under every resonance "
                           "shift the fabrication tolerances allow, which widens the "
                           "spacing it needs; smaller tolerances or a smaller "
                           "design.robust_k narrow it)")
        return "; ".join(out)

    def lines(self) -> list[str]:
        """Lines for the CLI before any design."""
        compiled = (f", numba's cache cold: {self.kernels_cold[0]} of {self.kernels_cold[1]} "
                    "kernels compiled first" if self.kernels_cold[0] and self.designs else "")
        head = (f"reach (measured in {self.seconds:.1f} s, {self.designs} probe "
                f"designs{compiled}): ")
        if not self.constrained and not self.relaxed and self.assigned:
            tones = ", ".join(f"{tone:.0f}" for tone, _ in self.speeds_by_tone())
            return [head + f"every tone the spec plays ({tones} Hz) can be served at "
                    f"{self.floor_m_s * 1e3:g} mm/s beside the tones it must be told "
                    "apart from"]
        if not self.constrained and not self.relaxed:
            return [head + f"every channel {self.grid_hz[0]:.0f}-{self.grid_hz[-1]:.0f} Hz "
                    f"can be served at {self.floor_m_s * 1e3:g} mm/s at the grid's packed "
                    "spacing"]
        out = [head + self.summary()]
        out.append(f"  channels offered to the assigner: {self.offered} of "
                   f"{len(self.grid_hz)}")
        if self.relaxed:
            out.append("  what the probes asked does not fit the band: every reachable "
                       "channel is offered at the grid's packed spacing, and the plan's "
                       "loop moves a design that fails there")
        return out

    def to_dict(self) -> dict:
        """plan.json's ``assignment.reach``: what was measured, not how long it took or
        what the cache answered (the same spec and seed give the same bytes)."""
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
                **({"relaxed_separations": True} if self.relaxed else {})}


# probe tasks (module level: workers import them by name) ------------------------------

def _why(res) -> str:
    return "; ".join(s["text"] for s in res.shortfalls)


def _rung(shared, tone, neighbours, tries):
    """(feasible, speed [m/s], why, design) of a design at ``tone`` [Hz] silent at
    ``neighbours`` [Hz]: at most :data:`PROBE_TRIES` of the planner's tries (``tries``
    of them hard-infeasible), stopping at the first feasible one; ``design`` is its
    ((A, w, l, c), tone) when feasible, else None."""
    base, floor = shared
    res = _design_task({**base, "frequency": float(tone), "forbidden": tuple(neighbours)},
                       floor, infeasible_tries=tries, margin=1.0, max_tries=PROBE_TRIES)
    g = res.geometry
    design = (((float(g.area), float(g.width), float(g.length), float(g.gap)), float(tone))
              if res.feasible else None)
    return bool(res.feasible), float(res.predicted_slider_speed_m_s), _why(res), design


def _tone(shared, tone, packed, packed_neighbours, assigned=None):
    """One probe (see the module docstring): returns (ratio or None, reachable, speed
    [m/s], tried, design), ``tried`` every rung as (ratio, feasible, why), ratio 0
    alone; ``design`` the fastest feasible design with neighbours (or None).

    ``assigned`` ((ratio, neighbours [Hz]) the assignment on the packed grid gives the
    tone, wider than the packed ones): asked first, and when a design holds them the
    probe ends there with that ratio (the spacing the plan keeps)."""
    tried = []
    best = [0.0]
    family = [0.0, None]

    def at(ratio, neighbours, tries):
        ok, v, why, design = _rung(shared, tone, neighbours, tries)
        tried.append((ratio, ok, why))
        best[0] = max(best[0], v)
        if design is not None and ratio > 0 and v > family[0]:
            family[:] = [v, design]
        return ok

    if assigned is not None and at(assigned[0], assigned[1], 1):
        return assigned[0], True, best[0], tuple(tried), family[1]
    if at(packed, packed_neighbours, INFEASIBLE_TRIES):
        return packed, True, best[0], tuple(tried), family[1]
    if packed >= RATIO_LIMIT or not at(RATIO_LIMIT, (tone / RATIO_LIMIT, tone * RATIO_LIMIT),
                                       WIDE_RUNG_TRIES):
        alone = at(0.0, (), 1)
        return None, alone, best[0], tuple(tried), family[1]
    lo, hi, k = packed, RATIO_LIMIT, 1
    while True:
        rung = 1.0 + 2.0 ** k * (packed - 1.0)
        if rung >= RATIO_LIMIT:
            break
        if at(rung, (tone / rung, tone * rung), WIDE_RUNG_TRIES):
            hi = rung
            break
        lo, k = rung, k + 1
    for _ in range(RATIO_BISECTIONS):
        mid = math.sqrt(lo * hi)
        if at(mid, (tone / mid, tone * mid), WIDE_RUNG_TRIES):
            hi = mid
        else:
            lo = mid
    return hi, True, best[0], tuple(tried), family[1]


def _served(shared, tone, neighbours):
    """(reachable, speed): a design with ``neighbours``, or else alone, is feasible."""
    ok, v, _, _ = _rung(shared, tone, neighbours, 1)
    if ok:
        return True, v
    ok, w, _, _ = _rung(shared, tone, (), 1)
    return ok, max(v, w)


def _edge(shared, tones, neighbours, reachable_first):
    """Bisect the channels ``tones`` [Hz] (increasing; the first is reachable iff
    ``reachable_first``, the last is not) for the last channel on the first one's side
    (``neighbours[i]``: channel i's packed neighbours): returns (index into ``tones``,
    probes as (index, reachable, speed))."""
    a, b = 0, len(tones) - 1
    seen = []
    while b - a > 1:
        mid = (a + b) // 2
        ok, speed = _served(shared, tones[mid], neighbours[mid])
        seen.append((mid, ok, speed))
        if ok == reachable_first:
            a = mid
        else:
            b = mid
    return a, tuple(seen)


def _tone_from(shared, tone, packed, packed_neighbours, assigned, family):
    """A probe asked again (:func:`_tone`), its designs started from ``family`` (the
    designs its neighbour probes found, :func:`planner.planning.designs.family_for`)."""
    base, floor = shared
    return _tone(({**base, "family": tuple(family)}, floor), tone, packed, packed_neighbours,
                 assigned)


def _probe(shared, kind, *args):
    """One probe task of ``kind`` ("tone", "tone_from" or "edge") on a worker."""
    return {"tone": _tone, "tone_from": _tone_from, "edge": _edge}[kind](shared, *args)


def _family(probes) -> tuple:
    """((A, w, l, c), tone) of each of ``probes``' feasible designs, by tone."""
    return tuple(sorted((p.design for p in probes if p.design is not None),
                        key=lambda d: d[1]))


def _widened(p) -> bool:
    """Whether probe ``p`` needed a wider spacing than the packed grid's."""
    return p.ratio is not None and p.ratio > p.packed_ratio


def _may_relax(probes, total, served):
    """Whether the relaxation of :func:`assign_on_reach` applies, by ``probes``'
    verdicts: fewer than half of ``total`` probes hopeless, and fewer than half of the
    ``served`` ones (those a design can serve) widened or hopeless."""
    hopeless = sum(p.hopeless for p in probes)
    wide = sum(_widened(p) for p in probes)
    return not (2 * hopeless >= total or 2 * (wide + hopeless) >= served)


def _relaxed(reach):
    """``reach`` relaxed: every reachable channel offered at the packed spacing."""
    return dataclasses.replace(reach, min_ratio=tuple(1.0 for _ in reach.min_ratio),
                               allowed=reach.reachable, relaxed=True)


def _packed_ok(p) -> bool:
    """Whether probe ``p`` was served at its packed spacing."""
    return p.reachable and p.ratio is not None and p.ratio <= p.packed_ratio


def _worth_asking_again(prev, p, nxt) -> bool:
    """Whether probe ``p``'s verdict is worse than both its neighbours' (``prev``,
    ``nxt``): out of reach between two probes a design serves, or needing a wider
    spacing (or none) between two served at the packed one.  A probe is a few seeded
    design searches; such a verdict is likelier the search's than the tone's (a 3 x 3
    in 20-80 kHz: 67.2 kHz found nothing faster than 0.038 mm/s between 56.5 and 80 kHz
    probes at 0.20 and 0.18 mm/s; started from their designs, 0.179 mm/s in 0.4 s), so
    it is asked again from their designs (:func:`measure_reach`)."""
    if _packed_ok(p):
        return False
    if not p.reachable:
        return prev.reachable and nxt.reachable
    return _packed_ok(prev) and _packed_ok(nxt)


def _better(old, new):
    """The better verdict of a probe asked twice (each is a witness: a design found
    feasible serves the tone at its spacing, whichever search found it), with both
    searches' rungs and the fastest design's speed."""
    def rank(p):
        return (p.reachable, p.ratio is not None, -(p.ratio or 0.0))

    best = new if rank(new) > rank(old) else old
    return dataclasses.replace(best, tried=old.tried + new.tried,
                               speed_m_s=max(old.speed_m_s, new.speed_m_s))


# the stage ---------------------------------------------------------------------------

def probe_channels(grid, count=PROBE_COUNT):
    """Indices of ``count`` channels log-spaced over ``grid`` (ends included)."""
    grid = np.asarray(grid, dtype=float)
    if grid.size <= count:
        return list(range(grid.size))
    want = np.geomspace(grid[0], grid[-1], count)
    return sorted({int(np.argmin(np.abs(np.log(grid / f)))) for f in want})


def _kinds(settings: Settings):
    """One representative node per distinct impacter setting among the driven nodes."""
    from planner.core.nodes import Node

    driven = sorted({Node(d, dr) for st in settings.steps for d, dr in st.active_nodes()})
    out = {}
    for n in driven:
        out.setdefault(settings.impacters[n], n)
    return list(out.values())


def packed_neighbours(grid, positions, separation, channel):
    """(ratio, neighbours [Hz]) of ``channel`` on the packed positions: the tones
    ``separation`` positions above and below it that lie in the grid, and the smaller of
    their ratios to its tone (:data:`RATIO_LIMIT` with none)."""
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


def probe_line(probe: Probe, floor_m_s) -> str:
    """One probe's verdict as a line (what :func:`measure_reach` reports as it goes)."""
    head = f"probe {probe.tone_hz / 1e3:.4g} kHz: "
    fastest = f"fastest design {probe.speed_m_s * 1e3:.3g} mm/s"
    if not probe.reachable:
        return head + (f"no design reaches the floor {floor_m_s * 1e3:g} mm/s ({fastest})")
    if probe.ratio is None:
        return head + (f"served alone ({fastest}), but no design is silent at neighbours "
                       f"x{RATIO_LIMIT:g} away")
    if probe.ratio > probe.packed_ratio:
        return head + (f"neighbours must be x{probe.ratio:.3g} away (the grid packs them "
                       f"x{probe.packed_ratio:.3g}); {fastest}")
    return head + f"served with neighbours x{probe.packed_ratio:.3g} away; {fastest}"


def _probe_of(channel, tone_hz, packed_ratio, given, result) -> Probe:
    """The :class:`Probe` of a tone probe's ``result`` (:func:`_tone`'s); a probe that
    held the neighbours its assignment gives it (``given``) counts them as its packed
    ones."""
    ratio, ok, speed, tried, design = result
    packed = packed_ratio if given is None or ratio != given[0] else given[0]
    return Probe(channel, tone_hz, packed, ratio, ok, speed, tried, design)


def measure_reach(settings: Settings, *, jobs=1, scheduler=None, pool=None, store=None,
                  progress=None):
    """Probe the spec's reach and spacing (see the module docstring) and assign the
    channels it offers.

    Parameters
    ----------
    settings : Settings
    jobs, scheduler, pool :
        Where the probe designs run (:func:`planner.planning.designs.dispatch`).
    store : planner.planning.design_store.DesignStore, optional
        The design cache: a probe it holds is read, not run.
    progress : callable(stage, item=None, total=None), optional
        The plan's progress callback (stages "reach" and "edges"), and, as each probe
        tone is answered, ``progress("probe", line)``: a line saying what it found
        (:func:`probe_line`), for a reader who would stop a long reach early.

    Returns
    -------
    (Reach, Assignment)
        The reach (channels offered and spacing per channel: with several kinds of
        impacter, set apart by ``devices:``, the channels every kind can serve and the
        widest spacing any needs) and the assignment on it
        (:func:`planner.assignment.assign.assign`; its ``reach`` is this one).

    Raises
    ------
    planner.core.errors.PlanningError
        The steps cannot fit the channels a design can serve with the spacing it needs
        (the message names the reachable tones, the spacing and what would widen them).
    """
    from model.warmup import numba_cache_state
    from planner.core.separation import position_grid

    from planner.assignment.assign import assign

    cold = numba_cache_state()
    t0 = time.perf_counter()
    # Know early: the probes can only take channels away or widen the spacing, so steps
    # that do not fit the band with every channel served at the grid's packed spacing
    # are refused here, before any probe design (PlanningError, in seconds)
    unconstrained = assign(settings, settings.steps)
    _refuse_undamped(settings, unconstrained)
    tick = progress or (lambda stage, item=None, total=None: None)
    grid = np.asarray(settings.channel_grid_hz, dtype=float)
    sep = settings.separation_channels
    positions = position_grid(grid, sep, settings.guard)
    floor = settings.min_speed_m_s
    # a spec that plays fewer tones than PROBE_COUNT is probed at the tones it would
    # play on the packed grid (a 1 x 2 array: 2 probe designs, not 9): the probes answer
    # for the channels the assignment takes, the channels between and beyond them are
    # judged as between and beyond any two probes
    used = sorted({int(c) for c in unconstrained.channels.values()})
    few = len(used) < PROBE_COUNT
    probes_at = used if few else probe_channels(grid)
    packed = [packed_neighbours(grid, positions, sep, c) for c in probes_at]
    # ... and each of those probes is first asked with the neighbours the assignment
    # gives it (the tones next to its own), where they are wider than the packed ones
    given = [None] * len(probes_at)
    if few:
        for i, c in enumerate(probes_at):
            nb = [float(grid[used[j]]) for j in (i - 1, i + 1) if 0 <= j < len(used)]
            ratio = (min(max(f, grid[c]) / min(f, grid[c]) for f in nb) if nb
                     else RATIO_LIMIT)
            if ratio > packed[i][0]:
                given[i] = (float(ratio), tuple(nb))
    env = "vacuum" if settings.environment.viscosity_mpa_s == 0 else ""
    kinds = _kinds(settings)
    ran = [0]
    reachable = np.ones(grid.size, dtype=bool)
    allowed = np.ones(grid.size, dtype=bool)
    need = np.ones(grid.size)
    probes, all_edges = [], []
    total = len(probes_at) * len(kinds)
    for node in kinds:
        shared = ({**settings.design_kwargs(node), "seed": REACH_SEED}, floor)
        tick("reach", total=len(probes_at))
        so_far = [None] * len(probes_at)

        def answered(i, res):
            tick("reach", i)
            c = probes_at[i]
            probe = _probe_of(c, float(grid[c]), packed[i][0], given[i], res)
            tick("probe", probe_line(probe, floor))
            so_far[i] = probe
            if not probe.reachable or probe.ratio != probe.packed_ratio:
                # a probe that takes channels away or widens the spacing: refuse now if
                # the steps cannot fit whatever the probes still to come find
                _refuse_early(settings, grid, probes_at, so_far, (reachable, allowed, need),
                              probes, total, env, assigned=few)

        found = _cached_run(shared, [("tone", float(grid[c]), r, nb, g)
                                     for c, (r, nb), g in zip(probes_at, packed, given)],
                            store, ran, jobs, scheduler, pool, on_done=answered)
        mine = [_probe_of(c, float(grid[c]), r, g, res)
                for c, (r, _), g, res in zip(probes_at, packed, given, found)]
        mine = _ask_again(shared, mine, packed, given, store, ran, jobs, scheduler, pool, tick,
                          floor)
        pairs = [(i, i + 1) for i in range(len(mine) - 1)
                 if mine[i].reachable != mine[i + 1].reachable
                 and probes_at[i + 1] - probes_at[i] > 1]
        if pairs:
            tick("edges", total=len(pairs))
        edges = _cached_run(
            shared, [("edge", tuple(float(f) for f in grid[probes_at[i]:probes_at[j] + 1]),
                      tuple(packed_neighbours(grid, positions, sep, c)[1]
                            for c in range(probes_at[i], probes_at[j] + 1)),
                      mine[i].reachable) for i, j in pairs],
            store, ran, jobs, scheduler, pool, on_done=lambda i, res: tick("edges", i))
        ok = _reachable_mask(grid.size, probes_at, [p.reachable for p in mine], pairs, edges)
        reachable &= ok
        allowed &= ok
        need = np.maximum(need, _needed_ratio(grid, mine, allowed))
        for (i, _), (_, seen) in zip(pairs, edges):
            all_edges += [(probes_at[i] + k, bool(r), float(v)) for k, r, v in seen]
        probes += mine
    reach = Reach(floor, tuple(float(f) for f in grid), tuple(bool(a) for a in reachable),
                  tuple(bool(a) for a in allowed), tuple(float(r) for r in need),
                  tuple(probes), tuple(all_edges), ran[0], time.perf_counter() - t0, env,
                  cold, assigned=few, robust=settings.robust_k is not None)
    if not reach.constrained and not _distorting(settings):
        # the reach takes nothing from the grid: the assignment made before the probes
        return reach, dataclasses.replace(unconstrained, reach=reach)
    # (with a distorting drive chain the layout weighs each product against the
    # reach's design family, which the assignment before the probes did not have)
    return assign_on_reach(settings, reach)


def _ask_again(shared, mine, packed, given, store, ran, jobs, scheduler, pool, tick, floor):
    """``mine`` with every probe whose verdict is worse than both its neighbours'
    (:func:`_worth_asking_again`) asked again from the designs of the probes a design
    served (the nearest :data:`planner.planning.designs.FAMILY_SIZE` in tone), keeping
    the better verdict (:func:`_better`)."""
    from planner.planning.designs import family_for

    again = [i for i in range(1, len(mine) - 1)
             if _worth_asking_again(mine[i - 1], mine[i], mine[i + 1])]
    family = _family(mine)
    if not again or not family:
        return mine

    def answered(j, res):
        i = again[j]
        p = _probe_of(mine[i].channel, mine[i].tone_hz, packed[i][0], given[i], res)
        tick("probe", probe_line(p, floor) + " (asked again from its neighbours' designs)")

    found = _cached_run(shared, [("tone_from", mine[i].tone_hz, packed[i][0], packed[i][1],
                                  given[i], family_for(family, mine[i].tone_hz))
                                 for i in again],
                        store, ran, jobs, scheduler, pool, on_done=answered)
    out = list(mine)
    for i, res in zip(again, found):
        out[i] = _better(mine[i], _probe_of(mine[i].channel, mine[i].tone_hz, packed[i][0],
                                            given[i], res))
    return out


def _refuse_early(settings, grid, probes_at, so_far, before, earlier, total, env, assigned):
    """Raise the reach's refusal now when the steps cannot fit whatever the probes not
    yet answered find (know early: a spec in a robust process was refused after 3 min
    of probes, most of whose verdict its first few probes had already decided).

    The probes can only take channels away or widen the spacing, so the most any
    completion offers is this one: every probe not yet answered served at the packed
    spacing (an edge between an answered probe that cannot be served and one that can,
    or has not answered yet, at its most generous: only the channels of probes found
    out of reach lost); the kinds probed ``before`` (reachable, allowed, need) as they
    were found, later kinds unconstrained.  The assignment fails on that reach, and
    :func:`assign_on_reach` would not relax it (most of the probes answered so far
    need the wider spacing or are hopeless, counted against every probe that could
    still be served, or its relaxed assignment fails too), so it fails on every reach
    the remaining probes can give.  A probe that will be asked again
    (:func:`_ask_again`: its neighbours are both answered and better) counts as not yet
    answered.  ``earlier``: the probes of the kinds before."""
    from planner.assignment.assign import assign

    reach_before, allowed_before, need_before = before
    answered = [p for p in so_far if p is not None]
    n = len(so_far)

    def final(i):
        # answered, and not to be asked again (_ask_again): at an end, or with a
        # neighbour answered no better than it
        p = so_far[i]
        if p is None:
            return False
        if i == 0 or i == n - 1 or _packed_ok(p):
            return True
        prev, nxt = so_far[i - 1], so_far[i + 1]
        return prev is not None and nxt is not None and not _worth_asking_again(prev, p, nxt)

    optimistic = [so_far[i] if final(i) else Probe(c, float(grid[c]), 1.0, 1.0, True, 0.0)
                  for i, c in enumerate(probes_at)]
    ok = [p.reachable for p in optimistic]
    pairs = [(i, i + 1) for i in range(len(ok) - 1)
             if ok[i] != ok[i + 1] and probes_at[i + 1] - probes_at[i] > 1]
    # the most generous edge: every channel between the two probes on the served side
    edges = [((probes_at[j] - probes_at[i] - 1) if ok[i] else 0, ()) for i, j in pairs]
    mask = _reachable_mask(len(grid), probes_at, ok, pairs, edges)
    reachable = reach_before & mask
    allowed = allowed_before & mask
    need = np.maximum(need_before, _needed_ratio(grid, optimistic, allowed))
    reach = Reach(settings.min_speed_m_s, tuple(float(f) for f in grid),
                  tuple(bool(a) for a in reachable), tuple(bool(a) for a in allowed),
                  tuple(float(r) for r in need), tuple(earlier) + tuple(answered),
                  environment=env, assigned=assigned,
                  robust=settings.robust_k is not None)
    try:
        assign(settings, settings.steps, reach=reach)
        return
    except PlanningError as exc:
        refusal = exc
    # the verdicts that stand (a probe to be asked again may still be served packed)
    seen = list(earlier) + [so_far[i] for i in range(n) if final(i)]
    could_serve = sum(p.reachable for p in seen) + (total - len(seen))
    if _may_relax(seen, total, could_serve):
        try:
            assign(settings, settings.steps, reach=_relaxed(reach))
            return
        except PlanningError:
            pass
    done = len(earlier) + len(answered)
    raise PlanningError(
        f"{refusal} (Refused after {done} of {total} probes: the {total - done} not yet "
        "answered could only take channels away or widen the spacing.)") from None


def _distorting(settings) -> bool:
    """Whether the spec's drive chain distorts (issue 46)."""
    chain = settings.chain
    return chain is not None and bool(chain.nonlinearity.a2 or chain.nonlinearity.a3)


def _refuse_undamped(settings: Settings, assignment):
    """Refuse, before any probe design, an undamped array in which some impacter sits out
    a tone: every probe of such a spec was hopeless (none silent even at neighbours
    x4 away), since an undamped impacter released from x0 = +-c never stops ringing and
    any tone it sits out, however far, adds to that swing until it reaches its wall."""
    if settings.environment.viscosity_mpa_s > 0:
        return
    from planner.planning.exposure import forbidden_tones

    idle = sorted(n.text for n, tones in forbidden_tones(settings.steps,
                                                         assignment.frequencies).items()
                  if tones)
    if not idle:
        return
    raise PlanningError(
        f"no design could be told apart from another tone: in vacuum an impacter is "
        f"undamped (environment.viscosity_mpa_s: 0), and released from x0 = +-c, the "
        f"initial states every design is checked from, its free oscillation never "
        f"decays, so any tone it sits out adds to it until it reaches its wall, however "
        f"far that tone is; {len(idle)} impacters sit out another's tone "
        f"({', '.join(idle[:4])}{' ...' if len(idle) > 4 else ''}). Refused before any "
        f"design. To plan: some damping (environment.viscosity_mpa_s: 0.0179 is air at "
        f"room temperature), or fewer impacters that must be told apart (independent: "
        f"false, scenes that move devices together and share one tone).")


def assign_on_reach(settings: Settings, reach: Reach):
    """(reach, assignment): the assignment on the channels and spacing ``reach`` offers,
    or, where those cannot hold the steps but most of the band holds the packed
    spacing, on every reachable channel at the packed spacing (the reach returned then
    says ``relaxed``).

    Raises
    ------
    planner.core.errors.PlanningError
        Neither fits the steps, or most probes are hopeless (an undamped array).
    """
    from planner.assignment.assign import assign

    probes = reach.probes
    try:
        return reach, assign(settings, settings.steps, reach=reach)
    except PlanningError:
        if not reach.widened() and not any(p.hopeless for p in probes):
            raise
        # most probes hopeless (an undamped array in vacuum), or most of those a design
        # can serve needing the wider spacing or hopeless: refused here, naming the
        # spacing.  Of the served ones, because a probe below the floor offers no
        # channel, and counted as "packed" it would outvote the band that is left (a
        # 1 x 4 in 2-8 kHz: 5 of its 8 probes below the floor, the 3 others needing
        # neighbours x1.28-1.38 apart, relaxed, and 8 of 8 designs infeasible); at the
        # packed spacing the loop would fail by trying (a 3 x 3 in a 5 um process, 5-40
        # kHz: every probe needed neighbours x1.4-2.7 apart, and 18 of 18 designs then
        # answered several other tones, exit 1 after minutes)
        if not _may_relax(probes, len(probes), sum(p.reachable for p in probes)):
            raise
        # A widened spacing, or a probe found hopeless, at a few probes is what a few
        # seeded probe designs found (when the probes still took the plan's seed, seed 13
        # of the default: one probe at 20.5 kHz needed x1.06 where the grid packs x1.04;
        # seed 16: the 51.1 kHz probe's one try at x4 answered its neighbours; either way
        # the 50 channels no longer fit).  Where most of the band holds the packed
        # spacing, plan at it on every reachable channel and let the loop move what fails
        # there, rather than refuse a spec other seeds plan; refuse when that cannot hold
        # the steps either, when most probes are hopeless (an undamped array in vacuum),
        # or when most need the wider spacing (above).
        relaxed = _relaxed(reach)
        try:
            return relaxed, assign(settings, settings.steps, reach=relaxed)
        except PlanningError:
            pass
        raise


#: Probe results of this process by task digest (at most :data:`MEMO_SIZE`, oldest
#: dropped): a process that plans one spec several times (the tests, a notebook) probes
#: it once even without a design cache; the results are deterministic.
_MEMO: collections.OrderedDict = collections.OrderedDict()
MEMO_SIZE = 4096


def _cached_run(shared, args_list, store, ran, jobs, scheduler, pool, on_done=None):
    """:func:`dispatch` of probe tasks (:func:`_probe`; ``args_list``: (kind, *args)
    each), each read from this process's memo or the design cache, and written to both."""
    from planner.planning.design_store import task_digest

    out = [None] * len(args_list)
    base, floor = shared
    digests = [task_digest({"reach_probe": args, "probe_format": PROBE_FORMAT, **base},
                           floor, DESIGN_RETRIES,
                           INFEASIBLE_TRIES, SPEED_MARGIN, RATIO_LIMIT, RATIO_BISECTIONS,
                           WIDE_RUNG_TRIES, PROBE_TRIES) for args in args_list]
    todo = []
    for i, digest in enumerate(digests):
        hit = _MEMO.get(digest)
        if hit is not None and store is not None and not store.holds(digest):
            # probed earlier in this process for another cache (or none): this cache
            # holds it too, so that the next process reads it rather than probing
            store.put(digest, hit, probe=True)
        if hit is None and store is not None:
            hit = store.get(digest, probe=True)
        if hit is not None:
            out[i] = hit
            _remember(digest, hit)
            if on_done is not None:
                on_done(i, hit)
        else:
            todo.append(i)

    # longest first, so that no worker is left alone with the top tone's probe at the
    # end: a probe's designs cost about as many drive cycles as their window holds (its
    # frequency; an edge bisects between its tones).  Results do not depend on the order.
    todo.sort(key=lambda i: -max(np.atleast_1d(args_list[i][1])))

    def done(j, res):
        i = todo[j]
        out[i] = res
        ran[0] += 1
        _remember(digests[i], res)
        if store is not None:
            store.put(digests[i], res, probe=True)
        if on_done is not None:
            on_done(i, res)

    dispatch(_probe, shared, [args_list[i] for i in todo], jobs=jobs, scheduler=scheduler,
             pool=pool, on_done=done)
    return out


def _remember(digest, result):
    _MEMO[digest] = result
    _MEMO.move_to_end(digest)
    while len(_MEMO) > MEMO_SIZE:
        _MEMO.popitem(last=False)


def _reachable_mask(n, probes_at, ok, pairs, edges):
    """Channels reachable by the probes at ``probes_at`` (reachable where ``ok``) and the
    edges bisected between the probe index pairs ``pairs``."""
    mask = np.zeros(n, dtype=bool)
    if not len(probes_at):
        return mask
    edge_of = {i: probes_at[i] + last for (i, _), (last, _) in zip(pairs, edges)}
    if ok[0]:
        mask[:probes_at[0] + 1] = True
    if ok[-1]:
        mask[probes_at[-1]:] = True
    for i in range(len(probes_at) - 1):
        a, b = probes_at[i], probes_at[i + 1]
        if ok[i] and ok[i + 1]:
            mask[a:b + 1] = True
        elif ok[i] != ok[i + 1]:
            cut = edge_of.get(i, a)          # the last channel on probe i's side
            if ok[i]:
                mask[a:cut + 1] = True
            else:
                mask[cut + 1:b + 1] = True
    return mask


def _needed_ratio(grid, probes, allowed):
    """Per channel, the least neighbour ratio [-] the probes measured: 1 where the
    packed grid's holds, interpolated in log ratio and log frequency between probes that needed
    more, constant beyond the first and last; a channel nearest a probe at which no
    ratio up to :data:`RATIO_LIMIT` worked is left out (``allowed`` is updated)."""
    grid = np.asarray(grid, dtype=float)
    need = np.ones(grid.size)
    usable = [p for p in probes if p.reachable]
    if not usable:
        return need
    # a probe that held at the packed ratio needs nothing more
    excess = {p.channel: (0.0 if p.ratio <= p.packed_ratio else math.log(p.ratio))
              for p in usable if p.ratio is not None}
    chans = np.array(sorted(excess))
    if chans.size:
        logf = np.log(grid)
        vals = np.array([excess[c] for c in chans])
        need = np.exp(np.interp(logf, logf[chans], vals))
    hopeless = [p.channel for p in usable if p.hopeless]
    if hopeless:
        centres = np.array([p.channel for p in probes])
        nearest = centres[np.argmin(np.abs(np.arange(grid.size)[:, None] - centres[None, :]),
                                    axis=1)]
        allowed &= ~np.isin(nearest, hopeless)
    return need

