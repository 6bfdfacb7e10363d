"""Outputs: plan.json, CSVs, waveform files, figures and report.md of a :class:`Plan`
(report.md's text: :mod:`planner.planning.report`)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

import model
from planner.planning.report import (drive_figure_name, pattern_figure_name, target_scenes,
                                     write_report)
from planner.planning.result import Plan
from planner.core.units import MS

#: Response-curve figure: points over the band, half-width of the fine grid across each
#: design's own peak (relative), and initial positions over [-c, c].
RESPONSE_GRID_POINTS = 160
RESPONSE_PEAK_SPAN = 0.04
RESPONSE_X0_POINTS = 5


def write_outputs(result: Plan, out_dir: Path, *, figures=True, sections=(), timings=True,
                  cache_dir=None) -> float:
    """Write plan.json, CSVs, waveforms, figures and report.md into ``out_dir``.

    ``sections``: :class:`planner.core.markdown.Section` s a later command adds to report.md
    (a re-plan's, a trim's), each where :data:`planner.planning.report.SECTIONS` puts its
    title.  ``timings=False`` leaves report.md's timings out (outputs that must depend on
    their inputs only).  ``cache_dir``: the design cache
    (:class:`planner.planning.design_store.DesignStore`), where the figures of a plan
    drawn before with the same inputs and code are read rather than drawn again (their
    bytes are the same either way: :func:`_cached_figures`).

    Returns
    -------
    float
        Seconds the files took (report.md's timings list them as ``outputs``).
    """
    import warnings

    from planner.lab.exporters import export

    settings = result.settings
    t0 = time.perf_counter()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "plan.json").write_text(json.dumps(result.data, indent=2, sort_keys=False) + "\n")
    result.coupling.to_csv(out_dir / "coupling.csv", float_format="%.6g")
    table = result.impacters.assign(
        area_m2=[g["area_m2"] for g in result.impacters["geometry"]],
        width_m=[g["width_m"] for g in result.impacters["geometry"]],
        length_m=[g["length_m"] for g in result.impacters["geometry"]],
    ).drop(columns=["geometry"])
    if "shortfalls" in table:
        # what an infeasible design misses, as the report says it (empty when feasible)
        table["shortfalls"] = ["; ".join(sf["text"] for sf in (v or ()))
                               for v in table["shortfalls"]]
    table.to_csv(out_dir / "designs.csv", index=False, float_format="%.8g")
    (out_dir / "waveforms").mkdir(exist_ok=True)
    for rec in result.data["steps"]:
        w = result.waveforms[f"{rec['scene']}/{rec['name']}"]
        if settings.chain is not None:
            # the amplifier input [V] that gives the die this drive (issue 46)
            from planner.planning.chain import input_waveform

            die, w = w, input_waveform(settings, w)
        for fmt, rel in rec["files"].items():
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                if settings.chain is not None:
                    export(w, out_dir / rel, fmt, die=die,
                           amplifier_gain=settings.amplifier_gain)
                else:
                    export(w, out_dir / rel, fmt, um_per_v=settings.um_per_v,
                           amplifier_gain=settings.amplifier_gain)
    if figures:
        _cached_figures(result, out_dir, cache_dir)
    seconds = time.perf_counter() - t0
    write_report(result, out_dir, {**result.timings, "outputs": seconds} if timings else None,
                 sections)
    return seconds


def _cached_figures(result, out_dir, cache_dir):
    """:func:`_figures`, read from the design cache's ``figures/`` stage when it holds
    them for the same plan: keyed by the plan's record, settings and drives (all a
    figure is drawn from, the response curves' simulations included), the source of
    the code and matplotlib's version (:func:`planner.planning.design_store.stage_digest`).
    A figure's PNG bytes depend on these only, so a re-run writes the same files
    without importing matplotlib."""
    figs = Path(out_dir) / "figures"
    store = digest = None
    if cache_dir is not None:
        from importlib.metadata import version

        from planner.planning.design_store import DesignStore, stage_digest

        store = DesignStore(cache_dir)
        digest = stage_digest("figures", result.data, result.settings, result.waveforms,
                              version("matplotlib"))
        held = store.get_stage("figures", digest)
        if isinstance(held, dict) and held:
            figs.mkdir(exist_ok=True)
            for name, data in sorted(held.items()):
                (figs / name).write_bytes(data)
            return
    _figures(result, out_dir)
    if store is not None and digest is not None:
        store.put_stage("figures", digest, {f.name: f.read_bytes()
                                            for f in sorted(figs.iterdir()) if f.is_file()})


def _figures(result, out_dir):
    from planner.figures import plan as rp

    figs = out_dir / "figures"
    figs.mkdir(exist_ok=True)
    settings = result.settings
    rp.array_map(settings, result.impacters, figs / "array_map.png")
    tones = [float(c) for c in result.coupling.columns]
    rp.coupling_heatmap(result.coupling.to_numpy(), list(result.coupling.index), tones,
                        figs / "coupling.png")
    # response curves: worst r over x0 against frequency, on the band grid plus every
    # tone of the plan exactly plus a fine grid across the design's own peak (in air a
    # peak is a few hundred Hz wide: a coarse grid alone misses its top)
    curves = []
    lo, hi = settings.band_hz
    band = np.geomspace(lo, hi, RESPONSE_GRID_POINTS)
    for n, d in sorted(result.designs.items()):
        imp = d.impacter
        own = result.assignment.frequencies[n]
        peak = own * (1.0 + np.linspace(-RESPONSE_PEAK_SPAN, RESPONSE_PEAK_SPAN, 41))
        grid = np.unique(np.concatenate([band, tones, peak[(peak >= lo) & (peak <= hi)]]))
        r = model.sweep(imp, grid, np.linspace(-imp.gap, imp.gap, RESPONSE_X0_POINTS),
                        settings.power_m2_s3, settings.window_s).max(axis=1)
        curves.append((n, grid, r, own))
    rp.response_curves(curves, tones, figs / "response_curves.png",
                       f"worst-case response over {RESPONSE_X0_POINTS} x0 in "
                       f"{settings.window_s / MS:g} ms (dots: own tone)")
    shown = [k for k in result.waveforms if not k.startswith("independent/")]
    shown = shown or list(result.waveforms)[:1]
    for k in shown:
        rp.waveform_and_spectrum(result.waveforms[k], figs / drive_figure_name(k), k)
    if settings.chain is not None:
        from planner.planning.chain import chain_figure

        chain_figure(settings, result.waveforms, figs / "drive_chain.png",
                     f"{settings.name}: drive chain and the plan's tones",
                     near=(result.data.get("chain") or {}).get("products_near_idle"))
    if result.data["scenes"]:
        rp.slider_positions(result.data["scenes"], figs / "slider_positions.png")
    for scene, rows in target_scenes(result.data["scenes"]).items():
        rp.target_map(settings, scene, rows, figs / pattern_figure_name(scene))
    # a re-plan carries its designs' separations only: the figure is the plan's
    if result.data.get("manufacturability") and result.data.get("as_built") is None:
        rp.manufacturability(result.data["impacters"], result.data["manufacturability"],
                             figs / "manufacturability.png")
