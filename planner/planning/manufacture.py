"""Stage 7, manufacturability: sensitivities, separations and the collision-free yield.

After the designs are final, every design's sensitivity to each fabrication parameter
and its separation (silent band and tone window, by simulation once per design) are
measured, and a Monte Carlo of as-built resonances under the spec's ``fabrication:``
section predicts the fraction of chips whose impacters a re-planned drive can still tell
apart (:mod:`planner.manufacturability`).  The result is plan.json's
``manufacturability`` block.
"""

from __future__ import annotations

import numpy as np

from planner.assignment.assign import node_order, told_apart_pairs
from planner.fabrication.tolerances import ERRORS, NodeDesign
from planner.manufacturability import (
    BAND_MARGIN,
    CHIPS,
    collision_free_yield,
    measure_separation,
    sensitivities,
    z_for,
)
from planner.core.intervals import wilson_interval
from planner.core.nodes import Node


def _node_design(n: Node, design):
    g = design.geometry
    return NodeDesign(n.text, n.device, n.direction, g.area, g.width, g.length, g.gap,
                      design.impact_angle_rad, design.restitution)


def _tone_amplitudes(steps, assignment, waveforms):
    """Node -> the largest amplitude its tone plays at in any step [m]: its own
    single-tone step's, where it must be told apart from its neighbours (a multi-tone
    step lowered by the acceleration limit holds only tones far from its idle
    impacters: the ensemble separation)."""
    out = {}
    for st in steps:
        w = waveforms[st.key]
        req = np.asarray(w.requested_frequencies, dtype=float)
        for d, r in st.active_nodes():
            n = Node(d, r)
            f = assignment.frequencies.get(n)
            if f is None or req.size == 0:
                continue
            k = int(np.argmin(np.abs(req - f)))
            out[n] = max(out.get(n, 0.0), float(w.amplitudes[k]))
    return out


def _wafer_terms(settings, nodes) -> dict:
    """The wafer's part of the prediction (``fabrication.wafer``, issue 39): the
    across-wafer field's sigma (a die-level line width, shared by the die) and the
    within-die gradient's sigma with every impacter's place in its die; nothing without
    a wafer (the prediction is then the one before issue 39)."""
    wafer = settings.chip_spec.fabrication.wafer
    if wafer is None:
        return {}
    from planner.core.units import MM
    from planner.fabrication.wafer import device_positions

    pos = device_positions(settings.chip_spec.array)
    return {"sigma_field_line_width": wafer.line_width_field.sigma_um,
            "sigma_gradient": wafer.line_width_gradient_um_per_mm / MM,
            "positions": np.array([pos[n.device] for n in nodes])}


def assess(settings, steps, assignment, designs, waveforms, *, chips=CHIPS,
           store=None) -> dict:
    """plan.json's ``manufacturability`` block for the final designs.

    ``store`` (a :class:`~planner.planning.design_store.DesignStore`, optional): the
    block is read from the on-disk cache when every input it is computed from (the
    settings with their tolerances and seed, the steps, the designs, their tones and
    tone amplitudes, the pairs told apart, ``chips``) and the code are those of a
    stored one, and stored when computed.

    Returns
    -------
    dict
        Keyed by the impacters' text (plan.json): ``sensitivity`` (impacter id ->
        {parameter: d ln nu / d unit}),
        ``line_width_sensitivity_per_um`` ({min, max, spread}), ``separation_hz``
        (impacter id -> :meth:`planner.manufacturability.Separation.to_dict`),
        ``collision_free_yield`` ({value, ci95, chips}, None without tolerances),
        ``die_only_yield``, ``device_only_yield``, ``closest_pair_hz``,
        ``limiting_pairs``, ``nominal_collisions``, ``target_yield``, ``meets_target``,
        ``pair_sigma_rel`` (the grid's prediction of the scatter of a resonance
        difference), ``model``.
    """
    nodes = sorted(designs, key=node_order)
    amps = _tone_amplitudes(steps, assignment, waveforms)
    pairs = told_apart_pairs(assignment, nodes)
    if store is None:
        return _assess(settings, nodes, assignment, designs, amps, pairs, chips)
    from planner.planning.design_store import stage_digest

    key = stage_digest("manufacturability", settings, tuple(steps),
                       [(n, designs[n], assignment.frequencies[n], amps.get(n))
                        for n in nodes], pairs, chips)
    out = store.get_stage("manufacturability", key)
    if out is None:
        out = _assess(settings, nodes, assignment, designs, amps, pairs, chips)
        store.put_stage("manufacturability", key, out)
    return out


def _assess(settings, nodes, assignment, designs, amps, pairs, chips) -> dict:
    """:func:`assess`'s block, computed (``amps``: node -> tone amplitude [m];
    ``pairs``: the pairs the steps must tell apart)."""
    import numba

    from planner.runtime.cores import thread_map

    tol = settings.tolerances
    sens, seps, keys = {}, {}, {}
    for n in nodes:
        d = designs[n]
        sens[n] = sensitivities(settings.chip_spec, _node_design(n, d))
        # once per distinct design, tone and amplitude (a row sharing one design and
        # one tone: row_assembly's 40 impacters have 4)
        keys[n] = (d.impacter, assignment.frequencies[n], amps.get(n))
    distinct = list(dict.fromkeys(keys.values()))
    kwargs = settings.separation_kwargs()
    # each design's scan on its own thread (the stage's threads: its time is in the
    # nogil response kernel), the same separations as one after the other
    measured = dict(zip(distinct, thread_map(
        lambda k: measure_separation(k[0], k[1], tone_amplitude=k[2], **kwargs),
        distinct, numba.get_num_threads())))
    for n in nodes:
        seps[n] = measured[keys[n]]
    lw = np.array([sens[n]["line_width_um"] for n in nodes])
    out = {
        "model": ("first-order Monte Carlo of as-built natural frequencies (planner."
                  "manufacturability); a pair collides when one impacter's tone window "
                  "lies inside the other's silent band on the chip"),
        "sensitivity": {n.text: sens[n] for n in nodes},
        "line_width_sensitivity_per_um": {
            "min": float(lw.min()), "max": float(lw.max()),
            "spread": float(lw.max() / lw.min() - 1.0) if lw.min() > 0 else None},
        "separation_hz": {n.text: seps[n].to_dict() for n in nodes},
        "target_yield": settings.target_yield,
        "sensitivity_band_per_um": (None if settings.sensitivity_band is None else
                                    [b * 1e-6 for b in settings.sensitivity_band]),
    }
    if tol.zero:
        out.update(collision_free_yield=None, meets_target=None,
                   note="no fabrication tolerances in the spec (fabrication: all sigmas 0): "
                        "nothing to predict")
        return out
    nu = np.array([designs[n].natural_frequency_hz for n in nodes])
    tone = np.array([assignment.frequencies[n] for n in nodes])
    s_mat = np.array([[sens[n][e] for e in ERRORS] for n in nodes])
    pred = collision_free_yield(
        [n.text for n in nodes], nu, tone, s_mat, tol.die, tol.device, pairs,
        silent_below=[(1 + BAND_MARGIN) * seps[n].silent_below_hz for n in nodes],
        silent_above=[(1 + BAND_MARGIN) * seps[n].silent_above_hz for n in nodes],
        responds_below=[seps[n].responds_below_hz for n in nodes],
        responds_above=[seps[n].responds_above_hz for n in nodes],
        chips=chips, seed=settings.seed,
        sigma_pair=tol.pair, **_wafer_terms(settings, nodes),
        sigma_measure=settings.measurement_noise)
    told = {}
    if pred.told_apart is not None:
        passed = int(round(pred.told_apart * pred.chips))
        told = {"told_apart_yield": {
            "value": pred.told_apart, "ci95": list(wilson_interval(passed, pred.chips)),
            "chips": pred.chips,
            "measurement_noise_pct": 100.0 * settings.measurement_noise}}
    out.update(
        collision_free_yield=pred.to_dict(), **told, die_only_yield=pred.die_only,
        device_only_yield=pred.device_only, closest_pair_hz=pred.closest_pair_hz,
        limiting_pairs=pred.limiting_pairs, nominal_collisions=pred.nominal_collisions,
        meets_target=bool(pred.value >= settings.target_yield),
        pair_sigma_rel=settings.pair_sigma_rel,
        z_for_target=z_for(settings.target_yield, max(len(nodes) - 1, 1)))
    return out
