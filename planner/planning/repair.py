"""Repair: widen the separations that structured failures point at, for a re-colouring.

Acts on :class:`planner.planning.verify.Failure` records and on infeasible designs,
never on the readable failure text.
"""

from __future__ import annotations

import math

import numpy as np

from planner.core.nodes import Node
from planner.planning.designs import DESIGN_RETRIES
from planner.planning.verify import IDLE_RESPONSE, TOO_SLOW


def _widen(pair_sep, assignment, a, b, sep):
    # in positions (the channels where the design guard is narrower than the separation)
    where = assignment.positions or assignment.channels
    now = abs(where[a] - where[b]) // max(assignment.stride, 1)
    key = frozenset((a, b))
    pair_sep[key] = max(pair_sep.get(key, sep), now + max(1, sep // 2))


def widen_separations(failures, designs, steps, assignment, pair_sep, sep, skip=()):
    """Update ``pair_sep`` (frozenset of two nodes -> separation [channels]) in place for
    the verification's failures: each idle impacter that responds in a step moves away
    from the nearest tone of that step, unless it is in ``skip`` (re-designed in place
    instead, :func:`reseed_idle`).  Returns ``{node: offenders}`` of the impacters to
    move (infeasible designs are :func:`design_levers`' part)."""
    out = {}
    for fail in failures:
        if fail.kind != IDLE_RESPONSE or fail.impacter not in designs or fail.impacter in skip:
            continue
        active = sorted(Node(d, dr) for d, dr in steps[fail.step].active_nodes())
        f = assignment.frequencies[fail.impacter]
        near = min(active, key=lambda a: abs(math.log(assignment.frequencies[a] / f)))
        _widen(pair_sep, assignment, fail.impacter, near, sep)
        out.setdefault(fail.impacter, set()).add(near)
    return out


#: Phase draws of one multi-tone step the loop makes (the first included) before it
#: moves the impacters that cannot be made silent under its summed drive instead: the
#: phases decide how the step's tones add up in an idle impacter (seed 7 of the
#: default: the two backward impacters just above the 25-tone positioning cluster had
#: no feasible design in 9 tries under its first draw, and one in every try under
#: each of four other draws).
MAX_PHASE_DRAWS = 3
#: Candidate phase draws weighed each time the loop draws a multi-tone step's phases
#: anew (:func:`pick_draw`): the k-th new draw of a step chooses among draws
#: (k - 1) x PHASE_CANDIDATES + 1 .. k x PHASE_CANDIDATES, so no two choose among the
#: same.  A blind draw could trade one idle impacter's silence for seven others' (seed
#: 529687 of the default: the third draw of the positioning step left seven backward
#: impacters with no silent design).
PHASE_CANDIDATES = 4


def _nearest_tones(node, designs, assignment, count=1):
    """The impacters playing the forbidden tones nearest ``node``'s own, one each side."""
    f = assignment.frequencies[node]
    below = sorted((m for m in assignment.frequencies if m != node
                    and assignment.frequencies[m] < f and m in designs),
                   key=lambda m: f - assignment.frequencies[m])[:count]
    above = sorted((m for m in assignment.frequencies if m != node
                    and assignment.frequencies[m] > f and m in designs),
                   key=lambda m: assignment.frequencies[m] - f)[:count]
    return below + above


def design_levers(designs, steps, assignment, draws, pair_sep, sep, reseed, reseeded,
                  confirmed=(), previous=None):
    """What the loop changes for every infeasible design (their shortfalls say why).

    - it answers the summed drive of a multi-tone step it sits out: that step's phases
      are drawn anew (``draws``, step key -> draw, updated in place), up to
      :data:`MAX_PHASE_DRAWS` draws; after that it moves away from the step's tones;
    - it answers single tones (on the re-check grid or over the long window): it moves
      away from the impacters playing them (``pair_sep`` widened in place);
    - it does not respond from every x0 while silent: its nearest neighbours squeeze
      it, it moves away from them;
    - it misses only the speed floor, the mass cap, a bound or its sensitivity: it is
      re-designed from further seeds (``reseed``, in place) once (``reseeded``, a set
      updated in place), then moves away from its nearest neighbours.  If it sits out a
      multi-tone step, that step's phases are drawn anew instead (the one whose tones
      come nearest its own, while its draws last) when it misses again after further
      seeds, or at once when its design was feasible at the same tone in the last
      round (``previous``: node -> that round's design): silent under the step's summed
      drive, it may have room only for slow designs (seed 145902 of the default:
      A1.backward, 0.36 mm/s at 29.0 kHz until the positioning step's second draw, then
      0.066-0.070 mm/s from 16 seeds, 0.36 mm/s again under the third draw).

    ``confirmed``: the nodes whose design the steps' own simulation confirms
    (:func:`planner.planning.verify.confirm_responses`): no lever acts on them.

    Returns
    -------
    (actions, away)
        ``actions``: readable lines; ``away``: node -> set of nodes it should move away
        from (the movers).
    """
    from planner.planning.exposure import idle_ensembles, tone_players

    by_key = {st.key: st for st in steps}
    playing = tone_players(assignment.frequencies)
    sits_out = idle_ensembles(steps, assignment.frequencies)
    away, drawn, said = {}, set(), {}

    def say(text, n):
        # impacters sharing a channel get the same action: one line names them all
        said.setdefault(text, []).append(n)

    def tones_of(nodes):
        by_tone = {}
        for m in sorted(nodes):
            by_tone.setdefault(assignment.frequencies[m], []).append(m.text)
        return ", ".join(f"{f / 1e3:.5g} kHz ({_names(ms)})" for f, ms in sorted(by_tone.items()))

    for n in sorted(designs):
        d = designs[n]
        if d.feasible or n in confirmed:
            # a design the steps' own simulation confirms needs no lever
            continue
        kinds = {s["constraint"] for s in d.shortfalls}
        drives = [k for k in d.checks.get("violated_drives", ()) if k in by_key]
        loud = {float(hz) for hz, r in zip(d.forbidden_hz, d.r_max_forbidden_n) if r > 0}
        loud |= set(d.checks.get("violated_tones_hz", ()))
        singles = {m for hz in loud for m in playing(hz) if m != n}
        if "silence_long" in kinds and not singles and not drives:
            hz = next(s["value"] for s in d.shortfalls if s["constraint"] == "silence_long")
            if math.isfinite(hz):
                singles.update(m for m in playing(hz) if m != n)
        unanswered = [k for k in d.checks.get("unanswered_target_drives", ()) if k in by_key]
        if "response" in kinds and unanswered and not drives:
            # it does not respond under the summed drive of a step it plays in: that
            # step's phases decide how its tones add up in it
            drives = unanswered
        if (not drives and not singles and sits_out.get(n)
                and kinds & {"response", "silence", "silence_long"}):
            # silent under every summed drive it sits out but unable to respond from
            # every x0: the other side of the same trade-off; the step whose tones come
            # nearest its own squeezes it most
            drives = [_nearest_step(n, sits_out[n], by_key, assignment)]
        for k in drives:
            if k in drawn:
                continue
            if draws.get(k, 0) + 1 < MAX_PHASE_DRAWS:
                draws[k] = draws.get(k, 0) + 1
                drawn.add(k)
                say(f"{k}: phases drawn anew (draw {draws[k] + 1}): {{who}} "
                    + ("cannot move its slider under its summed drive from every x0"
                       if k in unanswered else "answer(s) its summed drive"), n)
            elif k in unanswered:
                # it plays in the step: no channel takes it away from its own tones;
                # another search may find a design the step's sum drives
                if n not in reseeded:
                    _next_seeds(reseed, n)
                    reseeded.add(n)
                    say(f"{{who}}: re-designed from further seeds (cannot move its slider "
                        f"under the summed drive of {k} after {MAX_PHASE_DRAWS} phase "
                        "draws)", n)
            else:
                players = sorted(Node(dv, dr) for dv, dr in by_key[k].active_nodes())
                f = assignment.frequencies[n]
                near = min(players, key=lambda a: abs(math.log(assignment.frequencies[a] / f)))
                _widen(pair_sep, assignment, n, near, sep)
                away.setdefault(n, set()).update(players)
                say(f"{{who}}: moved further from the tones of {k} (its summed drive still "
                    f"answered after {MAX_PHASE_DRAWS} phase draws)", n)
        for m in sorted(singles):
            _widen(pair_sep, assignment, n, m, sep)
            away.setdefault(n, set()).add(m)
        if singles:
            say(f"{{who}}: moved away from {tones_of(singles)} (it answers them)", n)
        if not drives and not singles:
            soft = kinds <= {"speed_floor", "mass_ratio", "bounds", "sensitivity"}
            squeezing = _squeezing_step(n, sits_out, by_key, assignment, draws)
            # feasible at this very tone in the last round: what changed around it (a
            # step's phases, its neighbours) squeezed it, not its seeds
            was = (previous or {}).get(n)
            squeezed = (was is not None and was.feasible
                        and was.frequency_hz == assignment.frequencies[n])
            if soft and squeezing is not None and (squeezed or n in reseeded):
                if squeezing not in drawn:
                    draws[squeezing] = draws.get(squeezing, 0) + 1
                    drawn.add(squeezing)
                say(f"{squeezing}: phases drawn anew (draw {draws[squeezing] + 1}): {{who}} "
                    + ("was feasible at its tone in the last round, now "
                       if squeezed else "after further seeds still ")
                    + "; ".join(s["text"] for s in d.shortfalls), n)
            elif soft and n not in reseeded:
                _next_seeds(reseed, n)
                reseeded.add(n)
                say("{who}: re-designed from further seeds ("
                    + "; ".join(s["text"] for s in d.shortfalls) + ")", n)
            else:
                for m in _nearest_tones(n, designs, assignment):
                    _widen(pair_sep, assignment, n, m, sep)
                    away.setdefault(n, set()).add(m)
                say("{who}: moved away from its nearest neighbours ("
                    + "; ".join(s["text"] for s in d.shortfalls) + ")", n)
    actions = [text.replace("{who}", _names([m.text for m in nodes]))
               for text, nodes in said.items()]
    return actions, away


def _nearest_step(node, keys, by_key, assignment):
    """Of the steps ``keys``, the one whose tones come nearest ``node``'s own (in log
    frequency; the first of them on a tie)."""
    f = assignment.frequencies[node]
    return min(keys, key=lambda k: min(abs(math.log(assignment.frequencies[Node(dv, dr)] / f))
                                       for dv, dr in by_key[k].active_nodes()))


def _squeezing_step(node, sits_out, by_key, assignment, draws):
    """The multi-tone step ``node`` sits out whose tones come nearest its own, if its
    phases may still be drawn anew (fewer than :data:`MAX_PHASE_DRAWS` draws), else
    None (a step further away squeezes it less: drawing that one would not help)."""
    keys = [k for k in sits_out.get(node, ()) if k in by_key]
    if not keys:
        return None
    near = _nearest_step(node, keys, by_key, assignment)
    return near if draws.get(near, 0) + 1 < MAX_PHASE_DRAWS else None


def _names(names, shown=3):
    """``A1.forward, A2.forward and 3 more``."""
    names = list(names)
    if len(names) <= shown + 1:
        return ", ".join(names)
    return ", ".join(names[:shown]) + f" and {len(names) - shown} more"


def _next_seeds(reseed, node):
    # the node's tries continue where its last ones could have ended
    reseed[node] = reseed.get(node, 0) + 1 + DESIGN_RETRIES


def reseed_slow(failures, designs, steps, reseed):
    """Update ``reseed`` (node -> design seed offset) in place for the driven impacters
    that were too slow in a step; returns the nodes re-seeded.

    The designer's fast budget runs one annealing chain, so a design can settle in a
    light, slow local optimum while the same target has fast designs; the separations
    are not at fault, so the repair re-designs that impacter alone from the next
    ``1 + DESIGN_RETRIES`` seeds (its tries then start where the last ones ended) and
    leaves the assignment and every other design as they are.
    """
    out = []
    for fail in failures:
        if fail.kind != TOO_SLOW:
            continue
        for d, dr in sorted(steps[fail.step].active_nodes()):
            node = Node(d, dr)
            if d == fail.device and node in designs and node not in out:
                _next_seeds(reseed, node)
                out.append(node)
    return out


def reseed_idle(failures, designs, reseed, tried):
    """Update ``reseed`` (node -> design seed offset) in place for the idle impacters
    that responded in a step although their designs were feasible; returns the nodes
    re-seeded.

    The designer checks each forbidden tone at a few points of its guard band, from a
    grid of x0 and over its own windows; the verification runs the step's drive from
    its own x0 grid for the whole step, so a design can pass the one and answer in the
    other.  The tone is not at fault then: the impacter is re-designed alone from the
    next ``1 + DESIGN_RETRIES`` seeds, which costs one design instead of a re-colouring
    and the re-design of every impacter whose tones move.  Each node is re-designed so
    once (``tried``, a set updated in place); if it answers again, the separations are
    widened (:func:`widen_separations`).
    """
    out = []
    for fail in failures:
        node = fail.impacter
        if (fail.kind != IDLE_RESPONSE or node not in designs or node in tried
                or not designs[node].feasible):
            continue
        _next_seeds(reseed, node)
        tried.add(node)
        out.append(node)
    return out


#: A travel-sized step whose fastest slider went over ``verification.max_travel_um`` is
#: re-sized from its verified travels when the burst that moves its slowest slider the
#: step's ``travel_um`` keeps the fastest within this fraction of the limit [-]
#: (:func:`repair_motion`; the step is verified again at the new burst).  Shortened,
#: the fastest travels less than in proportion (the impacters ring up first), so the
#: proportion is an upper bound.
TRAVEL_FIT = 0.95
#: ... and lengthened (a slowest slider short of its travel), more than in proportion:
#: the fastest, in proportion, within this fraction of the limit, and the lengthening
#: taken back if it goes over (:func:`repair_motion`) [-].
LENGTHEN_FIT = 0.9


def repair_motion(settings, steps, failures, dwells, longer_dwells, rows=(),
                  lengthened=None, may_lengthen=True):
    """Act on the motion failures of a verification and its scene simulation.

    - a slider travels over ``verification.max_travel_um`` in a step: that step's burst
      is shortened in proportion (to 0.8 of limit / travel, at least one burst quantum);
      not a ``targets_um`` step's, whose gates set where each slider stops.  A
      ``travel_um`` step, sized from predicted speeds, is first re-sized from its
      verified travels (``rows``, the checks' rows): to the burst that moves its slowest
      slider ``travel_um``, where that keeps the fastest within :data:`TRAVEL_FIT` of
      the limit (a 3 x 5 whose rows move at 0.86 and 1.2 mm/s: the predicted slowest
      speed, 0.78 mm/s, sized a 51.6 ms burst that took the fastest to 62.5 um, and the
      0.8 cut to 39.6 ms left the slowest at 33.9 um of the 40 um asked; re-sized, 46.8
      ms moves it 40 um and the fastest 56 um), never below the 0.8 cut; otherwise cut
      as above, and the action says how far the slowest then gets at most.  A travel
      step whose slowest slider fell short of ``travel_um`` by more than the position
      tolerance is lengthened in proportion, within its longest burst and with the
      fastest within :data:`LENGTHEN_FIT` of the limit, tentatively (below);
    - an idle slider moves in a scene step from the state the previous step left: the
      previous step's dwell is doubled (up to ``settings.max_settle_s``), so that its
      impacters ring down further before the next tones start;
    - a step still moving at the end of the longest dwell is not repaired (the cap is
      the limit; it stays a failure).

    ``longer_dwells`` (step key -> dwell [s]) is updated in place, and so is
    ``lengthened`` (step index -> the burst [s] a step had before this repair lengthened
    it, None once it went back to it), which the caller keeps from round to round: a
    lengthened step that then travels over the limit goes back to the burst that passed
    (seed 70590 of the default: its positioning step, lengthened from 6.5 to 9.4 ms in
    proportion to its slowest slider's travel, took its fastest to 100.07 um; travel
    grows faster than the burst once the impacters have rung up).  A step is lengthened
    only with ``may_lengthen``: when a repair round is left to take it back.

    Returns
    -------
    (steps, actions, redo) or None
        The steps with their new bursts, the readable actions taken and the indices of
        the steps to re-verify; None when nothing could be done.
    """
    import dataclasses

    from planner.arrayspec import DEFAULT_MAX_BURST_S
    from planner.planning.motion import BURST_QUANTUM_S, SETTLE_CHUNK_S, burst_for
    from planner.planning.verify import CARRIED_IDLE, TRAVEL_OVER

    by_index = {st.index: st for st in steps}
    actions, redo, new = [], set(), {}
    worst = {}
    for f in failures:
        if f.kind == TRAVEL_OVER:
            worst[f.step] = max(worst.get(f.step, 0.0), abs(f.value))
    movers = {}
    for r in rows:
        if r.get("expected") in ("forward", "backward"):
            movers.setdefault(r["index"], []).append(abs(float(r["travel_m"])))
    lengthened = {} if lengthened is None else lengthened
    for i, travel in sorted(worst.items()):
        st = by_index[i]
        if st.targets_m is not None:
            continue
        if lengthened.get(i) is not None:
            # this repair lengthened it and it went over: back to the burst that passed
            # (travel grows faster than the burst once the impacters have rung up)
            burst = lengthened.pop(i)
            lengthened[i] = None          # never lengthened again
            new[i] = dataclasses.replace(st, duration_s=float(burst))
            redo.add(i)
            actions.append(f"{st.key}: burst {st.duration_s * 1e3:g} -> {burst * 1e3:g} ms "
                           f"(lengthened, a slider travelled {travel * 1e6:.4g} um > "
                           f"{settings.max_travel_m * 1e6:g} um: back to the burst that "
                           "passed)")
            continue
        slowest = min(movers.get(i) or [0.0])
        why = (f"a slider travels {travel * 1e6:.4g} um > {settings.max_travel_m * 1e6:g} "
               "um")
        cut = max(BURST_QUANTUM_S, math.floor(st.duration_s * 0.8 * settings.max_travel_m
                                              / travel / BURST_QUANTUM_S) * BURST_QUANTUM_S)
        burst = cut
        if st.travel_m is not None and slowest > 0:
            # shorter, travel falls faster than the burst (the impacters ring up first):
            # the burst that takes the slowest slider as far as asked in proportion is a
            # floor, taken where it is longer than the cut and keeps the fastest, in
            # proportion too (an upper bound), within TRAVEL_FIT of the limit
            need = burst_for(st.travel_m, slowest / st.duration_s)
            fastest = travel * need / st.duration_s
            if cut < need < st.duration_s and fastest <= TRAVEL_FIT * settings.max_travel_m:
                burst = need
                why += (f"; {need * 1e3:g} ms moves the slowest slider about the step's "
                        f"{st.travel_m * 1e6:g} um, the fastest under "
                        f"{fastest * 1e6:.3g} um")
            elif slowest * cut / st.duration_s < st.travel_m:
                why += (f"; the slowest slider then travels under "
                        f"{slowest * cut / st.duration_s * 1e6:.3g} um of the step's "
                        f"{st.travel_m * 1e6:g} um: its sliders move at speeds too far apart "
                        "for both (a smaller travel_um, a larger verification.max_travel_um, "
                        "or the step split)")
        if burst >= st.duration_s:
            continue
        new[i] = dataclasses.replace(st, duration_s=float(burst))
        redo.add(i)
        actions.append(f"{st.key}: burst {st.duration_s * 1e3:g} -> {burst * 1e3:g} ms "
                       f"({why})")
    for st in steps:
        # a travel-sized step whose slowest slider fell short of its travel_um (the
        # predicted speed it was sized from was too high): lengthened from its verified
        # travels, within its longest burst and with the fastest, in proportion, within
        # LENGTHEN_FIT of the limit; tentatively (``lengthened``): one that then goes over
        # goes back to this burst, and is not lengthened again
        ms = movers.get(st.index)
        if (not may_lengthen or st.travel_m is None or st.targets_m is not None
                or st.index in worst or not ms or st.index in lengthened or min(ms) <= 0
                or min(ms) >= st.travel_m - settings.position_tolerance_m):
            continue
        slowest, fastest = min(ms), max(ms)
        cap = st.max_duration_s if st.max_duration_s is not None else DEFAULT_MAX_BURST_S
        need = burst_for(st.travel_m, slowest / st.duration_s)
        fits = math.floor(st.duration_s * LENGTHEN_FIT * settings.max_travel_m / fastest
                          / BURST_QUANTUM_S) * BURST_QUANTUM_S
        # only where the whole travel fits: a burst held short of it by the cap or the
        # fastest's limit gains the slowest little (the default's row C: 12.3 -> 12.9 ms
        # moved its slowest 10.77 -> 10.77 um and its fastest 90 -> 98 um of 100)
        if need <= st.duration_s or need > min(cap, fits):
            continue
        lengthened[st.index] = st.duration_s
        new[st.index] = dataclasses.replace(st, duration_s=float(need))
        redo.add(st.index)
        actions.append(
            f"{st.key}: burst {st.duration_s * 1e3:g} -> {need * 1e3:g} ms (its slowest "
            f"slider travelled {slowest * 1e6:.3g} um of the step's {st.travel_m * 1e6:g} um, "
            f"about {fastest * need / st.duration_s * 1e6:.3g} um the fastest now)")
    carried_steps = sorted({f.step for f in failures if f.kind == CARRIED_IDLE})
    for i in carried_steps:
        st = by_index[i]
        before = [s for s in steps if s.scene == st.scene and s.index < i]
        if not before:
            continue
        prev = before[-1]
        now = dwells.get(prev.key, 0.0)
        longer = min(settings.max_settle_s, max(2.0 * now, 2.0 * SETTLE_CHUNK_S))
        if longer <= now:
            continue
        longer_dwells[prev.key] = longer
        actions.append(f"{prev.key}: dwell {now * 1e3:g} -> {longer * 1e3:g} ms (idle "
                       f"sliders move in {st.key} from the state it leaves)")
    if not actions:
        return None
    return tuple(new.get(s.index, s) for s in steps), actions, redo


def settle_by_step(rows, start=()):
    """Step key -> the longest settle dwell [s] (``settle_s``) of verification or scene
    ``rows`` for that step, starting from the dict ``start``."""
    out = dict(start)
    for r in rows:
        if "settle_s" in r:
            key = f"{r['scene']}/{r['step']}"
            out[key] = max(out.get(key, 0.0), float(r["settle_s"]))
    return out


def merge_carried(ver_rows, carried, steps, scene_rows, dwells):
    """Fold the scene simulation's failures into the verification rows.

    Each :class:`~planner.planning.verify.Failure` of
    :func:`planner.planning.scenes.scene_failures` fails the row of its step and
    device (an unsettled step: every driven device's row) with a ``carried state:``
    cause, so that ``verification.passed`` and every count of the report include it.

    Returns
    -------
    (rows, settle)
        ``settle``: step key -> the step's settle dwell [s]: the scene's for scene
        steps (at least the verification's), else the verification's.
    """
    from planner.planning.verify import CARRIED_IDLE, OFF_TARGET, TRAVEL_OVER, UNSETTLED

    rows = [dict(r) for r in ver_rows]
    for f in carried:
        if f.kind == CARRIED_IDLE:
            text = (f"carried state: idle slider moves {f.value * 1e6:.3g} um over the step "
                    "and its dwell")
        elif f.kind == TRAVEL_OVER:
            text = f"carried state: travel {f.value * 1e6:.4g} um over the limit"
        elif f.kind == UNSETTLED:
            text = f"carried state: still moving {f.value * 1e3:g} ms after the drive stops"
        elif f.kind == OFF_TARGET:
            text = (f"carried state: ends {f.value * 1e6:+.3g} um from where the scene asks "
                    "(beyond verification.position_tolerance_um)")
        else:
            text = f"carried state: {f.kind}"
        for r in rows:
            if r["index"] != f.step:
                continue
            if f.device and r["device"] != f.device:
                continue
            if not f.device and r["expected"] == "idle":
                continue
            r["passed"] = False
            r["cause"] = "; ".join(c for c in (r["cause"], text) if c)
    settle = settle_by_step([r for r in scene_rows if r["driven"]],
                            {st.key: float(dwells.get(st.key, 0.0)) for st in steps})
    return rows, settle


def scenes_and_motion(settings, run_steps, waveforms, impacters, sliders, ver_rows, failures,
                      *, scheduler=None, dwell_floor=None, store=None):
    """The scenes with the state carried across steps, and the motion repair.

    Each scene is simulated in order, every step followed by its settle dwell; a step
    that travels too far or does not settle, in its own check or with the carried
    state, gets a shorter burst or a longer dwell (:func:`repair_motion`) and is checked
    again, up to ``settings.repair_rounds`` times.  The plan and the re-plan both end
    this way.

    Parameters
    ----------
    run_steps : sequence of Step
    waveforms : dict
        Step key -> Waveform.
    impacters, sliders : dict
        The models the drive is verified on.
    ver_rows, failures : list
        The per-step checks so far (:func:`planner.planning.verify.check_steps`).
    dwell_floor : dict, optional
        Step key -> a dwell [s] the step keeps at least (a re-plan keeps the plan's).
    store : planner.planning.design_store.DesignStore, optional
        The on-disk cache the repaired steps' checks are read from and written to
        (:func:`planner.planning.verify.check_steps`).

    Returns
    -------
    (run_steps, ver_rows, failures, scene_rows, motion_repairs, step_settle)
        The steps as repaired, the checks with the carried-state rows merged in, every
        failure (the carried-state ones included), the scene rows, the repairs made and
        the settle dwell of every step [s].
    """
    from planner.planning.scenes import scene_failures, simulate_scenes
    from planner.planning.verify import check_steps

    motion_repairs, longer_dwells, lengthened = [], dict(dwell_floor or {}), {}
    for mround in range(settings.repair_rounds + 1):
        dwells = settle_by_step(ver_rows, longer_dwells)
        scene_rows = simulate_scenes(settings, run_steps, waveforms, impacters, sliders, dwells)
        carried = scene_failures(settings, run_steps, scene_rows)
        if mround == settings.repair_rounds:
            break
        # a lengthened burst is tentative: only while a round is left to take it back
        fixed = repair_motion(settings, run_steps, failures + carried, dwells, longer_dwells,
                              ver_rows, lengthened,
                              may_lengthen=mround < settings.repair_rounds - 1)
        if fixed is None:
            break
        run_steps, actions, redo = fixed
        motion_repairs.append({"round": mround + 1, "actions": actions})
        again = [st for st in run_steps if st.index in redo]
        for st, (rows, fails) in zip(again, check_steps(settings, again, waveforms, impacters,
                                                         sliders, scheduler=scheduler,
                                                         store=store)):
            ver_rows = [r for r in ver_rows if r["index"] != st.index] + rows
            failures = [f for f in failures if f.step != st.index] + fails
        ver_rows.sort(key=lambda r: r["index"])
    ver_rows, step_settle = merge_carried(ver_rows, carried, run_steps, scene_rows, dwells)
    return run_steps, ver_rows, failures + carried, scene_rows, motion_repairs, step_settle


def pick_draw(settings, steps, assignment, designs, key, use):
    """The phase draw the ``use``-th new draw (1, 2 ...) of step ``key`` plays: of the
    candidates (:data:`PHASE_CANDIDATES` of them, see there), the one under whose summed
    drive fewest of this round's designs fail, the lower draw on a tie.  A design fails
    when it sits the step out and answers the summed drive from any x0 of the
    designer's grid over its window, or plays in it and does not respond from every
    x0 (as the designer checks them, on its nominal model; the next round re-checks
    every design under the draw chosen, and keeps those that pass).

    Each candidate is synthesised and held to the drive's limits as the round's own
    drives are (:func:`planner.planning.drives.synthesize_steps`,
    :func:`planner.planning.chain.limit_drives`).

    Returns
    -------
    (draw, table)
        ``draw``: the draw index chosen; ``table``: (draw, names of the designs that
        fail under it) per candidate, in draw order.
    """
    from model import responses
    from planner.designer.runs import _u_grid
    from planner.planning.chain import limit_drives
    from planner.planning.drives import drive_of, synthesize_steps
    from planner.planning.exposure import idle_ensembles

    step = next(st for st in steps if st.key == key)
    frequencies = assignment.frequencies
    players = sorted(Node(d, dr) for d, dr in step.active_nodes())
    idle = sorted(n for n, keys in idle_ensembles(steps, frequencies).items() if key in keys)
    u = _u_grid(settings.x0_points)
    table = []
    first = (use - 1) * PHASE_CANDIDATES + 1
    for draw in range(first, first + PHASE_CANDIDATES):
        loop = synthesize_steps(settings, [step], assignment, draws={key: draw})
        limited, _ = limit_drives(settings, loop, [step], frequencies)
        drive = drive_of(limited[key])
        failing = []
        for n in idle + players:
            d = designs.get(n)
            if d is None:
                continue
            imp = d.impacter
            r = responses(imp, drive, u * imp.gap, duration=settings.window_s,
                          stop_at_first=n not in players)
            if (np.any(r > 0) if n not in players else not np.all(r > 0)):
                failing.append(n.text)
        table.append((draw, failing))
    draw = min(table, key=lambda row: (len(row[1]), row[0]))[0]
    return draw, table
