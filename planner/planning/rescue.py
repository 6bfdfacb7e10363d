"""A fabricated chip's drive in seconds: the re-plan that rescues what physics allows.

The plan designed every impacter for a tone just above its resonance and measured, once,
how far around its resonance it answers a tone (its silent band) and how far its own tone
may move and still drive it (its tone window): plan.json's ``manufacturability``.  On a
fabricated chip every resonance has moved; the measurement gives the new ones.  This
module re-plans the drive without searching by simulation:

1. **tones** (:func:`rescaled_tones`): each tone moves with its impacter's measured
   resonance, keeping its place relative to it (t' = t nu'/nu; for a pair of unequal
   halves, the mean of the halves).
2. **separability** (:func:`inseparable`): by the collision rule of
   :mod:`planner.manufacturability` (:class:`planner.trim.Separations`), every pair of
   impacters the plan's steps must tell apart is checked; a pair that cannot be is named
   with its as-built resonances and the separation it would need.  No drive can tell
   such a pair apart: a trim can (:mod:`planner.trim`).
3. **steps** (:func:`split_steps`): each multi-tone step is synthesised with the new tones
   and held to ``drive.max_acceleration_g`` as the plan's; when the limit lowers its tones
   further than the plan's verified drive did, the step is split into sub-steps of
   neighbouring tones (played one after the other), each strong enough again.
4. **bursts** (:func:`planner.planning.motion.size_bursts`): steps that ask for a travel
   get their burst from the as-built speeds.

The drive is then verified by simulation like a plan's; what fails is repaired like a
plan's motion (:func:`planner.planning.repair.repair_motion`: shorter bursts, longer
dwells).  Every step here is arithmetic or one synthesis; the verification is the cost.
"""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np

from model import halves
from planner.nodes import Node
from planner.trim import Separations

#: Sub-steps a multi-tone step may be split into at most (each a run of neighbouring
#: tones); further would make it a sequence of single-tone steps.
MAX_SPLIT = 8
#: A split stops when every sub-step keeps at least this fraction of the acceleration
#: scale the plan's own drive of the step was verified at [-].
SPLIT_SCALE_MARGIN = 0.999


def measured_frequency(value) -> float:
    """A measured resonance [Hz]: a number, or the mean of a pair's two halves."""
    if isinstance(value, (tuple, list)):
        return float(np.mean([float(v) for v in value]))
    return float(value)


def rescaled_tones(plan_data: dict, measured: dict) -> dict:
    """Impacter id -> its tone [Hz] moved with its measured resonance (t nu' / nu).

    Parameters
    ----------
    plan_data : dict
        The plan (plan.json).
    measured : dict
        Impacter id -> measured resonance [Hz] (or the two halves' (a, b)); an impacter
        not in it keeps its tone.
    """
    out = {}
    for rec in plan_data["impacters"]:
        n = rec["id"]
        ratio = (measured_frequency(measured[n]) / rec["natural_frequency_hz"]
                 if n in measured else 1.0)
        out[n] = rec["frequency_hz"] * ratio
    return out


def must_differ(steps) -> list:
    """Pairs of impacter ids some step drives one of and not the other (sorted)."""
    nodes = sorted({Node(d, r).text for st in steps for d, r in st.active_nodes()})
    active = [{Node(d, r).text for d, r in st.active_nodes()} for st in steps]
    out = []
    for a, b in itertools.combinations(nodes, 2):
        if any((a in act) != (b in act) for act in active):
            out.append((a, b))
    return out


def inseparable(seps: Separations, measured: dict, pairs) -> list:
    """The pairs no drive can tell apart on this chip, each as a dict: ``pair`` (ids,
    lower resonance first), ``as_built_hz`` (their measured resonances), ``apart_hz``
    (how far apart they are) and ``needs_hz`` (how far apart they would have to be)."""
    index = {n: k for k, n in enumerate(seps.ids)}
    out = []
    for a, b in pairs:
        fa, fb = measured_frequency(measured[a]), measured_frequency(measured[b])
        if fa > fb:
            a, b, fa, fb = b, a, fb, fa
        need = seps.needed(index[a], index[b], fa)
        if fb < need:
            out.append({"pair": [a, b], "as_built_hz": [fa, fb], "apart_hz": fb - fa,
                        "needs_hz": need - fa})
    return out


def _sub_steps(step, groups):
    """``step`` split into one sub-step per group of its active nodes."""
    out = []
    for k, group in enumerate(groups):
        fwd = tuple(d for d in step.forward if Node(d, "forward").text in group)
        bwd = tuple(d for d in step.backward if Node(d, "backward").text in group)
        out.append(dataclasses.replace(step, name=f"{step.name}.{k + 1}", forward=fwd,
                                       backward=bwd))
    return out


def split_steps(settings, steps, tones, plan_scales, synthesize_and_limit):
    """Steps whose tones the acceleration limit would weaken beyond the plan's, split.

    Parameters
    ----------
    settings : Settings
    steps : sequence of Step
    tones : dict
        Impacter id -> tone [Hz].
    plan_scales : dict
        Step key -> the acceleration scale the plan verified the step at (plan.json's
        ``acceleration_scale``; 1 when none).
    synthesize_and_limit : callable
        ``(steps, tones) -> (waveforms, notes)``: synthesis of the steps and the
        acceleration limit (:func:`planner.planning.drives.limit_acceleration`).

    Returns
    -------
    (steps, waveforms, notes, splits)
        ``splits``: original step key -> the sub-step keys it became.
    """
    waveforms, notes = synthesize_and_limit(steps, tones)
    out, splits = [], {}
    for st in steps:
        need = plan_scales.get(st.key, 1.0) * SPLIT_SCALE_MARGIN
        if notes[st.key]["acceleration_scale"] >= need:
            out.append(st)
            continue
        nodes = sorted((Node(d, r).text for d, r in st.active_nodes()),
                       key=lambda n: tones[n])
        chosen = None
        for k in range(2, min(MAX_SPLIT, len(nodes)) + 1):
            # k runs of neighbouring tones: an impacter of another run is idle next to a
            # run's edge only, never between its tones (the verification decides)
            groups = [set(g) for g in np.array_split(np.array(nodes, dtype=object), k)]
            subs = _sub_steps(st, groups)
            w, nt = synthesize_and_limit(subs, tones)
            chosen = (subs, w, nt)
            if all(nt[s.key]["acceleration_scale"] >= need for s in subs):
                break
        subs, w, nt = chosen
        out += subs
        waveforms.update(w)
        notes.update(nt)
        splits[st.key] = [s.key for s in subs]
    # the sub-steps are numbered in play order
    out = [dataclasses.replace(st, index=i) for i, st in enumerate(out)]
    return tuple(out), waveforms, notes, splits


def as_built_models(plan_data: dict, measured: dict, *, quality=None):
    """Node id -> the as-built model of a measured chip: the design's mass, damping and
    gap, its stiffness from the measured resonance (k = m (2 pi nu)^2); a pair measured
    half by half is a :class:`model.PairHalves` of two such models.

    ``quality`` (node -> Q or (Q_a, Q_b)), optional: the damping from a measured
    quality factor instead of the design's (b = m 2 pi nu / Q).
    """
    import model

    out = {}
    for rec in plan_data["impacters"]:
        n = rec["id"]
        m = float(rec["mass_kg"])
        value = measured.get(n, rec["natural_frequency_hz"])
        freqs = value if isinstance(value, (tuple, list)) else (value,)
        qs = (quality or {}).get(n)
        qs = qs if isinstance(qs, (tuple, list)) else (qs,) * len(freqs)
        parts = []
        for nu, q in zip(freqs, qs):
            w = 2.0 * math.pi * float(nu)
            b = m * w / float(q) if q else float(rec["damping_ns_per_m"])
            parts.append(model.Impacter(m, m * w * w, b, float(rec["gap_m"]),
                                        float(rec["impact_angle_rad"]),
                                        float(rec["restitution"])))
        out[n] = parts[0] if len(parts) == 1 else model.pair_of(*parts)
    return out


def natural_frequencies(impacters: dict) -> dict:
    """Node id -> natural frequency [Hz] of each model (each half's, (a, b), for a pair of
    unequal halves): what a lab measures of a chip."""
    out = {}
    for n, imp in impacters.items():
        parts = halves(imp)
        out[n] = (float(parts[0][0].natural_frequency) if len(parts) == 1 else
                  tuple(float(h.natural_frequency) for h, _ in parts))
    return out
