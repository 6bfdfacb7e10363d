"""Stage 3, designs: forbidden sets, idle ensembles, the design cache and the worker pool.

Every driven impacter is designed for its tone with every tone that plays while it must
be idle as a forbidden frequency, and the summed drive of every multi-tone step it sits
out as a forbidden drive; designs sharing all their inputs are designed once.
"""

from __future__ import annotations

import math

import numpy as np

from planner.planning.drives import drive_of
from planner.planning.exposure import (driven_ensembles, forbidden_tones, idle_ensembles,
                                       played_tones)
from planner.planning.settings import Settings

#: Extra seeds tried for a design that is feasible but slower than the target speed.
#: The "fast" budget runs one annealing chain, so a try can settle in a light, slow
#: local optimum (measured on A4.backward of the default plan: seeds 0-5 gave
#: 0.006-0.34 mm/s); most designs stop at the first try, the slow ones are cheap to retry.
DESIGN_RETRIES = 7
#: Tries after which a design that never met its silence and response constraints is
#: given up: the first at the plan's budget, the second searching wider
#: (:func:`planner.designer.budget.widened`, level 1: about 6 first tries).  Another
#: seed rarely makes such a target feasible (seed 7 of the default: 0 of 9 tries, the
#: full budget's 80 s ones included, for the impacter above the positioning cluster),
#: while the plan's loop can change its inputs (a new phase draw of the summed drive it
#: sits out, a channel further from its offenders): bounded here, the search costs
#: about 10 s on an idle 2-core machine, where the four tries of issue 28 (two at level
#: 2) cost about 40 s and took a loaded machine's design stage to 10 minutes.
INFEASIBLE_TRIES = 2
#: A design is retried while its predicted speed is below this multiple of the spec's
#: minimum.  The prediction is the least over the verification's x0 grid and the
#: single-impacter step's length (``speed_x0_points``, ``speed_window``); the
#: verification, with the slider where the scene left it, measured 0.69-1.0 of it on the
#: default plan (median 0.92), so 1.75 leaves the measured speed >= 1.2 x the minimum.
#: A design that still verifies too slow is re-designed by the repair round
#: (:func:`planner.planning.repair.reseed_slow`), at the cost of one more verification.
#: (2.5 until the designer's first try became reliable: each try above the margin that
#: 2.5 asked for cost a full design, ~1/3 of the default plan's design time.)
SPEED_MARGIN = 1.75
#: ... and while the least of its window edges' predicted speeds (its tone moved by the
#: tone window, ``design.tone_window_pct``) is below this multiple: a re-planned tone
#: lands anywhere in the window (a measurement's noise), where the speed falls towards
#: the lower edge.  A design must respond there from every x0 (its feasibility); a speed
#: at the edges is what the retries aim for.
WINDOW_SPEED_MARGIN = 1.25


#: Members of the design family each design starts from: the reach probes' designs
#: nearest its tone in log frequency (:func:`family_for`).
FAMILY_SIZE = 3


def family_for(family, tone, size=FAMILY_SIZE):
    """The ``size`` members of ``family`` (((A, w, l, c), tone) each) nearest ``tone``
    [Hz] in log frequency, by tone: the starts a design at ``tone`` is given
    (:func:`planner.designer.design_impacter`'s ``family``)."""
    near = sorted(family, key=lambda d: (abs(math.log(d[1] / tone)), d[1]))[:size]
    return tuple(sorted(near, key=lambda d: d[1]))


#: A retry that brings a feasible design's speed score (:func:`_speed_score`) up by less
#: than this fraction gained nothing ...
RETRY_GAIN = 0.02
#: ... and after this many such tries in a row the design stops retrying: measured on the
#: default plan's top tones (49.7 and 51.1 kHz), 8 feasible tries at 0.15-0.23 mm/s,
#: none with its window edges at 1.25 x the floor: the tone allows no more, and the
#: retries cost 14 s each there.
RETRY_STALL = 2


def _speeds(res):
    """(speed at its tone, least speed at its tone window's edges) [m/s] of a design."""
    at_tone = res.checks.get("speed_at_tone_m_s", res.predicted_slider_speed_m_s)
    return at_tone, min(res.checks.get("speed_at_window_edges_m_s") or [at_tone])


def _fast_enough(res, min_speed, margin):
    """Whether a feasible design needs no retry: its speed at its tone at least
    ``margin`` x the floor, and at its tone window's edges :data:`WINDOW_SPEED_MARGIN` x
    (or ``margin`` x when that is smaller: a probe's 1)."""
    at_tone, edges = _speeds(res)
    return (at_tone >= margin * min_speed
            and edges >= min(margin, WINDOW_SPEED_MARGIN) * min_speed)


def _hard(res) -> bool:
    """Whether a design misses more than its speed floor (silence, response, bounds)."""
    return any(sf["constraint"] != "speed_floor" for sf in res.shortfalls)


def _design_task(kwargs, min_speed, infeasible_tries=INFEASIBLE_TRIES, margin=SPEED_MARGIN,
                 max_tries=1 + DESIGN_RETRIES):
    """One impacter's design; retried with the next seeds while it is predicted slower
    than ``margin * min_speed`` [m/s] (the search is stochastic; the best of the
    tries is kept: feasible first, then the ones that miss only the speed floor, then
    the fastest), or its tone window's edges slower than :data:`WINDOW_SPEED_MARGIN` x
    the floor.  A design is infeasible when it misses any constraint by its own
    prediction, the floor ``min_speed`` included (the designer's ``min_speed``).  A try
    that misses more than the floor (silence, response) makes the next one search
    wider (:func:`planner.designer.budget.widened`, one level per such try), and after
    ``infeasible_tries`` of them without a feasible one the design is given up; tries
    that miss only the floor retry at the same budget, up to ``max_tries`` (1 +
    DESIGN_RETRIES) in all.  Try k of ``kwargs["seed"]`` is seeded by
    :func:`planner.core.rng.try_seed` with index ``_stream + k`` (``_stream``: the
    re-design offset of a repair round, popped from ``kwargs``), so no two plan seeds
    share a try.  A ``_keep`` entry (:func:`design_all`'s ``previous``) is tried first:
    the previous design, re-checked where its inputs changed."""
    from planner.core.rng import try_seed
    from planner.runtime.workers import single_thread_blas
    from planner.designer import design_impacter
    from planner.designer.budget import widened

    kwargs = dict(kwargs)
    stream = int(kwargs.pop("_stream", 0))
    keep = kwargs.pop("_keep", None)
    if keep is not None:
        kept = _recheck_kept(kwargs, keep, min_speed)
        if kept.feasible:
            return kept
    best, hard, stalled = None, 0, 0
    # BLAS on one thread wherever this runs (main process, pool or Dask worker): the SQP's
    # last digits depend on its thread count, the plan must not
    with single_thread_blas():
        for k in range(max_tries):
            kw = {**kwargs, "seed": try_seed(kwargs["seed"], stream + k), "min_speed": min_speed}
            if hard and not best[0][0]:
                # never feasible yet: search wider, not only elsewhere
                # (of the budget the first try used: design_impacter's default is "full")
                kw["budget"] = widened(kwargs.get("budget", "full"), hard)
            res = design_impacter(**kw)
            hard += _hard(res)
            rank = (bool(res.feasible), not _hard(res), _speed_score(res, min_speed, margin),
                    float(res.predicted_slider_speed_m_s))
            if best is None or rank[:3] > best[0][:3]:
                stalled = 0 if best is None or rank[:2] > best[0][:2] or (
                    rank[2] > (1.0 + RETRY_GAIN) * best[0][2]) else stalled + 1
                best = (rank, res)
            else:
                stalled += 1
            if res.feasible and _fast_enough(res, min_speed, margin):
                break
            if hard >= infeasible_tries and not best[0][0]:
                break
            if best[0][0] and stalled >= RETRY_STALL:
                # feasible, and the last tries gained nothing: the tone allows about this
                # much speed (the best is kept; a verification that finds it too slow
                # re-designs it from further seeds, planning.repair.reseed_slow)
                break
    return best[1]


def _speed_score(res, min_speed, margin):
    """How close a design comes to needing no retry: the lesser of its speed at its tone
    over ``margin`` x the floor and its window edges' over :data:`WINDOW_SPEED_MARGIN` x
    (1 or more: fast enough, :func:`_fast_enough`)."""
    if not min_speed:
        return 1.0
    at_tone, edges = _speeds(res)
    return min(at_tone / (margin * min_speed),
               edges / (min(margin, WINDOW_SPEED_MARGIN) * min_speed))


def _recheck_kept(kwargs, keep, min_speed):
    """The previous design re-checked against what changed
    (:func:`planner.designer.recheck_design`)."""
    from planner.runtime.workers import single_thread_blas
    from planner.designer import recheck_design

    rest = {k: v for k, v in kwargs.items()
            if k not in ("frequency", "forbidden", "forbidden_drives", "target_drives")}
    with single_thread_blas():
        return recheck_design(keep["previous"], kwargs["frequency"], kwargs["forbidden"],
                              new_forbidden=keep["new_forbidden"],
                              forbidden_drives=keep["forbidden_drives"],
                              target_drives=keep["target_drives"], min_speed=min_speed, **rest)


def _design_on_engine(min_speed, kwargs):
    """:func:`_design_task` as a :func:`dispatch` task (``shared`` first)."""
    return _design_task(kwargs, min_speed)


def dispatch(func, shared, args_list, *, jobs=1, scheduler=None, pool=None, on_done=None,
             on_tick=None):
    """``[func(shared, *args) for args in args_list]``: on the ``dask.distributed``
    cluster at ``scheduler``, on the plan's worker pool ``pool`` (or, with ``jobs`` > 1
    and two or more tasks, on a pool of ``jobs`` started for this call), or in this
    process.

    ``func`` is a module-level function (workers import it by name).
    ``on_done(i, result)`` is called for every task as it finishes (on Dask, in order
    once all have: the engine reports that a task finished, not which; ``on_tick()``
    is called as each finishes there).  Returns the
    results in the order of ``args_list``; they do not depend on where they ran.
    """
    results = [None] * len(args_list)
    if not args_list:
        return results

    def finish(i, res):
        results[i] = res
        if on_done is not None:
            on_done(i, res)

    if scheduler:
        from planner.runtime.engine import run_tasks

        for i, res in enumerate(run_tasks(func, shared, args_list, jobs=jobs,
                                          scheduler=scheduler, progress=on_tick)):
            finish(i, res)
    elif pool is not None or (jobs > 1 and len(args_list) > 1):
        import concurrent.futures as cf
        import contextlib

        from planner.runtime.workers import process_pool

        with (contextlib.nullcontext(pool) if pool is not None else process_pool(jobs)) as workers:
            warming = getattr(workers, "warming", lambda: False)
            todo = list(range(len(args_list)))
            futures = {}
            if warming():
                # the workers are still starting (importing the solver, seconds): this
                # process does the last tasks itself meanwhile, one at a time, and hands
                # the rest to the workers once they can take them (a spec of two probes
                # is done before they are); with more tasks than that, the first go to
                # the workers at once, so that none waits for this process's task
                if len(todo) > jobs + 1:
                    futures = {workers.submit(func, shared, *args_list[i]): i
                               for i in todo[:jobs]}
                    todo = todo[jobs:]
                while todo and warming():
                    i = todo.pop()
                    finish(i, func(shared, *args_list[i]))
            futures.update({workers.submit(func, shared, *args_list[i]): i for i in todo})
            for fut in cf.as_completed(futures):
                finish(futures[fut], fut.result())
    else:
        for i, args in enumerate(args_list):
            finish(i, func(shared, *args))
    return results


def design_all(settings: Settings, steps, assignment, cache, progress=None, waveforms=None,
               jobs=1, scheduler=None, reseed=None, store=None, pool=None, previous=None):
    """Design every driven impacter; ``cache`` maps the design inputs -> result.

    With ``waveforms`` (step key -> Waveform), the summed drive of every multi-tone
    step in which an impacter is idle is a forbidden drive of its design too.  Designs
    sharing every input (tone, forbidden set, drives and the impacter's own settings:
    contact parameters, process, slider) are designed once; with ``jobs`` > 1 the
    distinct designs run in that many worker processes, with ``scheduler`` (an address)
    on that ``dask.distributed`` cluster (:func:`planner.runtime.engine.run_tasks`).  Each design
    is seeded by the spec alone and runs with BLAS on one thread
    (:func:`planner.runtime.workers.single_thread_blas`), so the results do not depend on where
    it ran: serial, the process pool and Dask give the same plan.json.
    
    ``reseed`` (node -> seed offset) re-designs the impacters a repair round found too
    slow from further seeds (:func:`planner.planning.repair.reseed_slow`); the offset
    is part of the design's key, so every other design comes from the cache.

    ``store`` (a :class:`planner.planning.design_store.DesignStore`, optional) is the
    on-disk cache: a design it holds is read instead of computed, and every design
    computed is written to it.

    ``pool`` (a :class:`planner.runtime.workers.WarmPool`, optional): the plan's worker pool,
    kept for its whole run (its first worker compiled the kernels while the plan
    assigned the channels); without it, ``jobs`` > 1 starts a pool for this call.

    ``previous`` (node -> (key, DesignResult), optional): the last round's designs
    (:func:`design_keys`).  A node whose tone, settings and seed offset did not change
    but whose forbidden tones or summed drives did keeps its feasible design if it
    passes the designer's re-checks against what changed
    (:func:`planner.designer.recheck_design`), and is designed anew only if it does
    not: a channel moved or a step's phases drawn anew re-designs the impacters they
    touch, not the array.  The kept design's key records what it was kept from.
    """
    from planner.designer import Ensemble

    # the spec's design family: the reach probes' designs (planning.reach), where the
    # assignment was made on a measured reach
    reach = getattr(assignment, "reach", None)
    family = reach.family if reach is not None else ()
    forbidden = (forbidden_tones(steps, assignment.frequencies) if waveforms is None else
                 played_tones(steps, assignment.frequencies, waveforms))
    none = {n: () for n in assignment.frequencies}
    ensembles = (idle_ensembles(steps, assignment.frequencies)
                 if waveforms is not None else none)
    targets = (driven_ensembles(steps, assignment.frequencies)
               if waveforms is not None else none)

    def ident(k):
        w = waveforms[k]
        return (k, tuple(np.round(w.frequencies, 6)), tuple(np.round(w.phases, 9)),
                tuple(np.round(w.amplitudes, 15)))

    keys, tasks = {}, {}
    for n in sorted(assignment.frequencies):
        drives = tuple(ident(k) for k in ensembles[n])
        offset = int((reseed or {}).get(n, 0))
        key = (round(assignment.frequencies[n], 6), forbidden[n], drives,
               tuple(ident(k) for k in targets[n]), settings.impacters[n], offset)
        was = (previous or {}).get(n)
        keep = None
        if (was is not None and was[1].feasible and was[0][0] == key[0]
                and was[0][4:6] == key[4:6] and was[0][:4] != key[:4]):
            keep = _keep_inputs(was, key, waveforms)
            key = key + (was[0],)
        keys[n] = key
        if key not in cache and key not in tasks:
            tasks[key] = dict(
                frequency=assignment.frequencies[n], forbidden=forbidden[n],
                forbidden_drives=[Ensemble(drive_of(waveforms[k]), k) for k in ensembles[n]],
                target_drives=[Ensemble(drive_of(waveforms[k]), k) for k in targets[n]],
                **settings.design_kwargs(n))
            if family:
                tasks[key]["family"] = family_for(family, assignment.frequencies[n])
            tasks[key]["_stream"] = offset
            if keep is not None:
                tasks[key]["_keep"] = keep
    min_speed = settings.min_speed_m_s
    digests = {}
    if store is not None and tasks:
        from planner.planning.design_store import task_digest

        for key in list(tasks):
            # a kept design is keyed by what it was kept from (the previous key), not by
            # the previous result object
            shown = dict(tasks[key])
            if "_keep" in shown:
                shown["_keep"] = {**shown["_keep"], "previous": key[-1]}
            digests[key] = task_digest(shown, min_speed, DESIGN_RETRIES,
                                       INFEASIBLE_TRIES, SPEED_MARGIN, WINDOW_SPEED_MARGIN,
                                       RETRY_GAIN, RETRY_STALL)
            res = store.get(digests[key])
            if res is not None:
                cache[key] = res
                del tasks[key]

    def keep(key, res):
        cache[key] = res
        if store is not None:
            store.put(digests[key], res)

    users = {}
    for n, key in keys.items():
        users.setdefault(key, []).append(n)
    for n, key in keys.items():
        if key in cache and progress is not None:
            progress(n)
    # longest first, so that no worker is left with a long design at the end: a
    # design's cost grows with the summed drives it checks and with the drive
    # cycles in its window (its frequency); a re-check costs a small part of one.
    # Results do not depend on the order.
    order = sorted(tasks, key=lambda k: ("_keep" in tasks[k],
                                         -len(tasks[k]["forbidden_drives"])
                                         - len(tasks[k]["target_drives"]),
                                         -tasks[k]["frequency"]))
    def bar(key):
        for n in users[key]:
            if progress is not None:
                progress(n)

    def done(i, res):
        keep(order[i], res)
        if not scheduler:
            bar(order[i])

    # on Dask the engine reports each finished task, not which: the bar counts designs
    # done (its total, and the end, are exact)
    ticks = iter(order)
    dispatch(_design_on_engine, min_speed, [(tasks[k],) for k in order], jobs=jobs,
             scheduler=scheduler, pool=pool, on_done=done,
             on_tick=lambda: bar(next(ticks)))
    return {n: cache[key] for n, key in keys.items()}


def design_keys(settings: Settings, steps, assignment, waveforms, designs, reseed=None):
    """Node -> (key, design) of a round's designs, as :func:`design_all` keys them: the
    ``previous`` of the next round's :func:`design_all`."""
    forbidden = played_tones(steps, assignment.frequencies, waveforms)
    ensembles = idle_ensembles(steps, assignment.frequencies)
    targets = driven_ensembles(steps, assignment.frequencies)

    def ident(k):
        w = waveforms[k]
        return (k, tuple(np.round(w.frequencies, 6)), tuple(np.round(w.phases, 9)),
                tuple(np.round(w.amplitudes, 15)))

    out = {}
    for n, d in designs.items():
        key = (round(assignment.frequencies[n], 6), forbidden[n],
               tuple(ident(k) for k in ensembles[n]), tuple(ident(k) for k in targets[n]),
               settings.impacters[n], int((reseed or {}).get(n, 0)))
        out[n] = (key, d)
    return out


def _keep_inputs(was, key, waveforms):
    """What a kept design must be re-checked against: the forbidden tones and summed
    drives of ``key`` that the previous key ``was[0]`` did not have, and every target
    drive when any changed."""
    from planner.designer import Ensemble

    old, new = was[0], key
    new_forbidden = tuple(f for f in new[1] if f not in set(old[1]))
    old_drives = set(old[2])
    drives = [Ensemble(drive_of(waveforms[d[0]]), d[0]) for d in new[2] if d not in old_drives]
    targets = ([Ensemble(drive_of(waveforms[d[0]]), d[0]) for d in new[3]]
               if tuple(new[3]) != tuple(old[3]) else [])
    return {"previous": was[1], "new_forbidden": new_forbidden, "forbidden_drives": drives,
            "target_drives": targets}
