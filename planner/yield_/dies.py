"""A yield study on wafers (``fabrication.wafer``): each chip's die, its outcome and
cause, the yield against the die's radius, and what a prober measures of each die.

A chip of the study is die ``chip % dies`` of wafer ``chip // dies``
(:func:`planner.fabrication.wafer.die_place`).  Its **outcome** is the first stage of the lab's
loop that makes it work -- the plan's drive as it is, the drive re-planned from its
measurement (``--replan``), the chip trimmed and re-planned (``--trim``) -- or
``fails``, with the causes of the last stage that was run (:func:`chip_outcome`: the
after-fabrication loop's rule, :func:`planner.afterfab.outcome.outcome_of`, which the
wafer batch gives its measured dies by too).
"""

from __future__ import annotations

import numpy as np

from planner.core.rng import chip_seed
from planner.afterfab.outcome import OUTCOMES, outcome_of
from planner.fabrication.tolerances import sample_chip
from planner.core.intervals import wilson_interval
from planner.fabrication.wafer import die_place, line_width_offsets, wafer_layout
from planner.yield_.chip import measured_frequencies
from planner.yield_.inputs import Payload
from planner.yield_.results import ChipResult

#: Rings of equal width, from the wafer's centre to its outermost die's centre, over
#: which the yield against the radius is counted.
RADIUS_RINGS = 5


def chip_outcome(result: ChipResult) -> tuple[str, list]:
    """``(outcome, causes)`` of one chip's result (:func:`planner.yield_.verify_chip`):
    the first of :data:`OUTCOMES` it reaches, and for ``fails`` the causes of the last
    stage run (the trim's, the re-plan's, or the failing checks of the plan's drive, in
    the order of :data:`planner.afterfab.checks.KINDS`): :func:`planner.afterfab.
    outcome.outcome_of`."""
    outcome, causes = outcome_of(result.passed, result.failures, result.replan,
                                 result.trim)
    return outcome, list(causes)


def outcome_counts(outcomes) -> dict:
    """Outcome -> how many of ``outcomes``, every outcome listed (in order)."""
    outcomes = list(outcomes)
    return {o: outcomes.count(o) for o in OUTCOMES}


def wafer_record(payload: Payload, results: list) -> dict:
    """yield.json's ``wafer`` block: the wafer's geometry, every die with its place,
    outcome and causes, the outcomes counted, and the yield against the radius.

    Parameters
    ----------
    payload : Payload
        The run's payload (its ``fabrication.wafer`` and the plan's array).
    results : list of ChipResult
        The headline scale's chips (:func:`planner.yield_.verify_chip`), any order.
    """
    spec, wafer = payload.design.spec, payload.fabrication.wafer
    layout = wafer_layout(spec.array, wafer)
    dies = []
    for r in sorted(results, key=lambda r: r.chip):
        outcome, causes = chip_outcome(r)
        dies.append({"chip": r.chip, **die_place(spec.array, wafer, r.chip),
                     "outcome": outcome, "causes": causes})
    radius = np.array([d["radius_mm"] for d in dies])
    top = float(layout.die_radius.max() / 1e-3)
    edges = np.linspace(0.0, top, RADIUS_RINGS + 1) if top > 0 else np.array([0.0, 1.0])
    rings = []
    for k in range(len(edges) - 1):
        lo, hi = float(edges[k]), float(edges[k + 1])
        inside = [d for d, r in zip(dies, radius)
                  if (r >= lo and r < hi) or (k == len(edges) - 2 and r == hi)]
        works = sum(1 for d in inside if d["outcome"] != OUTCOMES[-1])
        rings.append({"radius_from_mm": lo, "radius_to_mm": hi, "dies": len(inside),
                      "outcomes": outcome_counts(d["outcome"] for d in inside),
                      "works": works,
                      "yield": works / len(inside) if inside else None,
                      "ci95": wilson_interval(works, len(inside)) if inside else None})
    w, h = layout.die_size
    return {"diameter_mm": wafer.diameter_mm, "edge_exclusion_mm": wafer.edge_exclusion_mm,
            "die_size_mm": [w / 1e-3, h / 1e-3], "dies_per_wafer": layout.count,
            "wafers": len({d["wafer"] for d in dies}),
            "outcomes": outcome_counts(d["outcome"] for d in dies),
            "by_radius": rings, "dies": dies}


def die_measurements(payload: Payload, scale: float, chips) -> list:
    """What a prober measures of every die: for each chip index of ``chips``, its
    place (:func:`planner.fabrication.wafer.die_place`) and ``measured`` (impacter id -> its
    measured resonance [Hz], or (a, b) for the halves of a pair measured apart).

    The chip is the study's (the same draws as :func:`planner.yield_.verify_chip`), and
    so is its measurement (:func:`planner.yield_.measured_frequencies`: the normals of
    the chip's own seed) at the study's noise with ``--replan``, else at the spec's
    ``fabrication.measurement_noise_pct``: a batch re-plan of these files re-plans each
    die from exactly the resonances the study's re-plan used.
    """
    import dataclasses

    if not payload.replan:
        payload = dataclasses.replace(
            payload, measure_noise_pct=payload.fabrication.measurement_noise_pct)
    spec = payload.design.spec
    out = []
    for i in chips:
        rng = np.random.default_rng(chip_seed(payload.seed, scale, i))
        chip = sample_chip(payload.design, payload.fabrication, rng, scale,
                           line_width_offsets(spec, payload.fabrication, payload.seed,
                                              scale, i))
        if chip.unbuildable:
            # a die that cannot be built has nothing to measure: the prober skips it
            continue
        got = measured_frequencies(payload, scale, i, chip)
        out.append({"chip": int(i), **die_place(spec.array, payload.fabrication.wafer, i),
                    "measured": {n: m for n, (_, m) in got.items()}})
    return out


def write_wafer_files(payload: Payload, data: dict, folder) -> list:
    """Each wafer's measurement as a prober and a tester write it: ``wafer_<k>.csv``
    (:func:`planner.afterfab.wafer_file.write_wafer_csv`) and ``wafer_<k>.stdf``
    (:func:`planner.afterfab.wafer_file.write_wafer_stdf`), k from 1, of the headline
    scale's dies (:func:`die_measurements`); returns the names written."""
    from pathlib import Path

    from planner.afterfab.wafer_file import write_wafer_csv, write_wafer_stdf

    folder = Path(folder)
    dies = die_measurements(payload, data["sigma_scale"], range(data["chips"]))
    names = []
    for w in sorted({d["wafer"] for d in dies}):
        mine = [(d["die_x"], d["die_y"], d["measured"]) for d in dies if d["wafer"] == w]
        for ext, write in (("csv", write_wafer_csv), ("stdf", write_wafer_stdf)):
            name = f"wafer_{w + 1}.{ext}"
            if ext == "stdf":
                write(folder / name, mine, wafer_id=str(w + 1),
                      part_type=payload.design.spec.name)
            else:
                write(folder / name, mine)
            names.append(name)
    return names
