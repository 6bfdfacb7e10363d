"""report.md of a plan: what it is, whether it verifies, and why, in lab units.

:func:`plan_report` reads plan.json's content (``Plan.data``) and the verification
table and assembles the report from named sections (:class:`planner.core.markdown.Report`)
in the order of :data:`SECTIONS`; a later command's section (a re-plan's, a trim's)
is handed over as a :class:`~planner.core.markdown.Section` and takes its place there by its
title (:func:`write_report`'s ``sections``).  :func:`md_table` and :func:`fmt` (from
:mod:`planner.core.markdown`) also serve the re-plan's section
(:func:`planner.afterfab.replan.replan_section`).
"""

from __future__ import annotations

import math

from planner.core.markdown import Report, Section, fmt, md_table
from planner.core.nodes import device_key
from planner.planning.scenes import scene_overshoot
from planner.planning.settings import SETTLE_S
from planner.core.units import UM

#: The sections of a plan's report.md, in the order they are written.  A plan writes
#: those its content calls for; a re-plan adds "As-built re-plan" and a trim "Trim"
#: (:func:`write_report`'s ``sections``), each in its place here.
SECTIONS = (
    "Trim",
    "What the planner changed",
    "As-built re-plan",
    "Frequency assignment",
    "Designs",
    "Manufacturability",
    "Cross-coupling",
    "Steps",
    "Drive chain",
    "Every impacter alone",
    "Positions asked and got",
    "Scenes (state carried across steps)",
    "Failures",
    "Timings",
)


def drive_figure_name(step_key):
    return f"drive_{step_key.replace('/', '__')}.png"


def pattern_figure_name(scene):
    return f"pattern_{scene}.png"


def target_scenes(scene_rows):
    """Scene -> its rows, for every scene that asks for positions (``targets_um``)."""
    out = {}
    for r in scene_rows:
        out.setdefault(r["scene"], []).append(r)
    return {k: v for k, v in out.items() if any(r.get("targets_m") for r in v)}


def _step_summary(ver):
    """(scene, step) -> slowest mover [m/s], largest idle displacement [m], checks."""
    out = {}
    for (scene, step), g in ver.groupby(["scene", "step"], sort=False):
        movers = g[g["expected"] != "idle"]
        idle = g[g["expected"] == "idle"]
        out[(scene, step)] = {
            "slowest": float(movers["min_speed_m_s"].min()) if len(movers) else math.nan,
            "idle_disp": (float(idle["predicted_displacement_m"].abs().max()) if len(idle)
                          else math.nan),
            "passed": int(g["passed"].sum()), "checks": len(g)}
    return out


def _moves(rec):
    names = rec["forward"] + rec["backward"]
    if len(names) <= 6:
        return ", ".join([f"{n} fwd" for n in rec["forward"]] + [f"{n} bwd" for n in rec["backward"]])
    return f"{len(rec['forward'])} fwd, {len(rec['backward'])} bwd"


def _chain_section(d):
    """The drive chain's section (issue 46), for a plan with ``drive.chain`` only."""
    if "chain" not in d:
        return None
    from planner.planning.chain import chain_section

    return chain_section(d["chain"])


def write_report(result, out_dir, timings, sections=()):
    """Write ``out_dir/report.md`` of a :class:`~planner.planning.result.Plan`
    (:func:`plan_report`)."""
    plan_report(result, out_dir, timings, sections).write(out_dir / "report.md")


def plan_report(result, out_dir, timings, sections=()) -> Report:
    """The report of a :class:`~planner.planning.result.Plan`, section by section.

    Parameters
    ----------
    result : planner.planning.result.Plan
        The plan (or re-plan); its figures, where they were drawn, are linked from
        ``out_dir/figures``.
    out_dir : Path
        Where its files are.
    timings : dict or None
        Stage -> seconds, for the last table; None leaves the section out.
    sections : iterable of planner.core.markdown.Section
        A later command's sections (a re-plan's, a trim's), each placed by its title's
        place in :data:`SECTIONS`.

    Returns
    -------
    planner.core.markdown.Report
    """
    d, ver = result.data, result.verification
    summary = _step_summary(ver)
    parts = [_motion_notes(d), _assignment_section(d["assignment"]),
             _designs_section(d["impacters"]), _manufacturability_section(d),
             _coupling_section(), _steps_section(d["steps"], summary, out_dir),
             _chain_section(d), _alone_section(d["steps"], summary)]
    if d["scenes"]:
        parts += [_positions_section(d, ver), _scene_section(d["scenes"])]
    parts += [_failures_section(ver), None if timings is None else _timings_section(timings)]
    report = Report(_title(d), _head(result), [p for p in parts if p is not None])
    for section in sections:
        place(report, section)
    return report


def place(report: Report, section: Section) -> None:
    """Insert ``section`` into a plan's ``report`` where :data:`SECTIONS` puts its title.

    Raises
    ------
    ValueError
        The title is none of :data:`SECTIONS`, or the report has that section already.
    """
    if section.title not in SECTIONS:
        raise ValueError(f"a plan's report has no place for a section {section.title!r} "
                         f"(its sections: {', '.join(SECTIONS)})")
    rank = SECTIONS.index(section.title)
    later = [t for t in report.titles if t in SECTIONS and SECTIONS.index(t) > rank]
    report.insert(section, before=later[0] if later else None)


def _title(d):
    """``vibroplan plan: NAME``, or ``vibroplan replan: NAME`` for a re-plan's."""
    return f"vibroplan {'replan' if d.get('replan') is not None else 'plan'}: {d['spec']['name']}"


def _head(result):
    """Under the title: the version and seed, whether the plan verifies, and its
    infeasible designs."""
    d = result.data
    ver = result.verification
    lines = [f"vibroplan {d['vibroplan_version']}, seed {d['seed']}.", "",
             f"**Verification: {'PASSED' if result.passed else 'FAILED'}** "
             f"({int(ver['passed'].sum())} of {len(ver)} step x device checks pass): every step "
             "re-simulated with its summed drive for its whole duration, from "
             f"{d['spec']['verification']['x0_points']} initial positions over [-c, c], then "
             "through its settle dwell with the drive off; every scene simulated with every "
             "impacter's and slider's state carried from step to step (a carried-state "
             "failure fails its step x device check too).  Contact law: "
             + ", ".join(sorted(set(result.settings.contacts.values())))
             + f"; no slider may travel more than {d['verification']['max_travel_m'] / UM:g} um "
             "in one step.", ""]
    problems = d["verification"].get("design_problems", [])
    if problems:
        lines += [f"**{len(problems)} impacter design(s) infeasible** (the plan fails on them "
                  "whatever the checks below say):", ""]
        lines += [f"- {p['impacter']} at {p['frequency_hz'] / 1e3:.2f} kHz: {p['why']}."
                  + (f" The planner tried: {'; '.join(p['tried'])}." if p.get("tried") else "")
                  + f" What to change: {p['what_to_change']}." for p in problems] + [""]
    confirmed = d["verification"].get("confirmed_designs", [])
    if confirmed:
        lines += [f"**{len(confirmed)} design(s) confirmed by simulation**: the designer found "
                  "no response under a summed drive from some x0 within its "
                  f"{d['spec']['design']['window_ms']:g} ms window, but each responds to "
                  "its own tone alone from every x0 of its fine grid, and every step it plays "
                  "in, simulated for its whole burst, moves its slider from every x0 of a "
                  "dense grid:", ""]
        lines += [f"- {c['impacter']} at {c['frequency_hz'] / 1e3:.2f} kHz ({c['shortfall']}): "
                  + "; ".join(f"{key} {_confirmed_worst(row)}"
                              for key, row in c["steps"].items())
                  + f", from {c['x0_points']} x0." for c in confirmed] + [""]
    return lines


def _confirmed_worst(row):
    """A confirmed design's step, as the report says it: its slowest speed or its
    largest position error from the dense grid."""
    if "min_speed_m_s" in row:
        return f"at least {row['min_speed_m_s'] * 1e3:.3g} mm/s"
    return f"within {abs(row['worst_position_error_m']) / UM:.3g} um of its move"


def _assignment_section(a):
    """The conflict graph, the span and the guard-rule warnings (plan.json's
    ``assignment``)."""
    lines = [f"Conflict graph: {a['graph_nodes']} channel groups, {a['graph_edges']} edges; span "
             f"{a['span']} channels (lower bound {a['lower_bound']}, "
             f"{'proven optimal' if a['optimal'] else 'not proven optimal'}, {a['method']}).", "",
             "![array map](figures/array_map.png)", ""]
    if a["guard_violations"]:
        lines += [f"Guard-rule warnings ({len(a['guard_violations'])}): harmonic or intermodulation "
                  "products of tones that play together land near an idle impacter's frequency. "
                  "The verification simulates the ideal summed drive; these matter only if the "
                  "piezo or its amplifier distorts.", "",
                  "<details><summary>the first 15</summary>", ""]
        lines += [f"- {v}" for v in a["guard_violations"][:15]]
        lines += ["", f"All {len(a['guard_violations'])} are in plan.json.", "", "</details>", ""]
    return Section("Frequency assignment", lines)


def _times(value, factor):
    """``value * factor``, NaN for a value plan.json leaves out (None)."""
    return math.nan if value is None else value * factor

def _designs_section(impacters):
    """One row per designed impacter (plan.json's ``impacters``)."""
    lines = ["r_min (worst response over x0 at the impacter's own tone) and the slider speed are "
             "the designer's short-window predictions; the verification below is the check.", ""]
    rows = []
    for r in impacters:
        g = r["geometry"]
        rows.append([r["id"], r["channel"], fmt(r["frequency_hz"] / 1e3, ".2f"),
                     fmt(r["natural_frequency_hz"] / 1e3, ".3f"),
                     fmt(g["area_m2"] / UM**2, ".0f"), fmt(g["width_m"] / UM, ".2f"),
                     fmt(g["length_m"] / UM, ".0f"), fmt(r["gap_m"] / UM, ".2f"),
                     fmt(r["mass_kg"] * 1e12, ".3f"),
                     fmt(_times(r.get("r_min_n"), 1e9), ".1f"),
                     fmt(r.get("mass_ratio"), ".3f"),
                     # a plan.json without a prediction (None, or absent) reads as no value
                     fmt(_times(r.get("predicted_slider_speed_m_s"), 1e3), ".2f"),
                     "yes" if r.get("feasible", True) else "**no**"])
    lines += md_table(["impacter", "channel", "tone [kHz]", "nu_n [kHz]", "A [um^2]", "w [um]",
                       "l [um]", "gap [um]", "mass [ng]", "r_min [nN]", "m/M",
                       "speed [mm/s]", "feasible"], rows)
    lines += ["", "![response curves](figures/response_curves.png)", ""]
    return Section("Designs", lines)


def _coupling_section():
    """The cross-coupling figure (coupling.csv)."""
    return Section("Cross-coupling",
                   ["Worst response of every impacter to every tone alone, over the x0 grid "
                    "(coupling.csv).", "", "![coupling](figures/coupling.png)", ""])


def _steps_section(steps, summary, out_dir):
    """One row per step of the scenes (plan.json's ``steps``) and their drive figures."""
    lines = []
    rows = []
    for rec in steps:
        if rec["scene"] == "independent":
            continue
        sm = summary[(rec["scene"], rec["name"])]
        rows.append([f"{rec['scene']}/{rec['name']}", fmt(rec["duration_s"] * 1e3, "g"),
                     fmt(rec.get("settle_s", math.nan) * 1e3, "g"),
                     len(rec["tones"]), fmt(rec["crest_factor"], ".2f"), _moves(rec),
                     fmt(rec.get("peak_displacement_m", math.nan) / UM, ".2f"),
                     fmt(rec.get("peak_acceleration_g", math.nan), ".0f"),
                     fmt(sm["slowest"] * 1e3, ".2f"), _travel_range(rec),
                     fmt(sm["idle_disp"] / UM, ".3f"),
                     f"{sm['passed']}/{sm['checks']}"])
    if rows:
        lines += md_table(["step", "burst [ms]", "dwell [ms]", "tones", "crest factor",
                           "moves", "peak drive [um]", "peak acceleration [g]",
                           "slowest mover [mm/s]", "mover travel [um]",
                           "largest idle displacement [um]", "checks passed"], rows)
        lines += ["", "Burst: the drive on; dwell: the drive off afterwards until every slider "
                  "and impacter has stopped (simulated).  Travel: each moving slider's "
                  "predicted travel over burst and dwell from rest under the summed drive "
                  "(steps[].travel_m); peak acceleration: the true peak of the summed drive's "
                  "base acceleration over its loop.", ""]
    for rec in steps:         # in step order
        name = drive_figure_name(f"{rec['scene']}/{rec['name']}")
        if (out_dir / "figures" / name).exists():
            lines.append(f"![{rec['scene']}/{rec['name']}](figures/{name})")
    lines.append("")
    return Section("Steps", lines)


def _alone_section(steps, summary):
    """The implicit single-impacter steps of an independently addressable array."""
    independent = [rec for rec in steps if rec["scene"] == "independent"]
    if not independent:
        return None
    lines = [f"One {independent[0]['duration_s'] * 1e3:g} ms step per impacter (the spec asks "
             "for every impacter to be independently addressable): its slider must move at "
             "the minimum speed from every initial position of its impacter, and every other "
             "slider stay within the idle tolerance.", ""]
    rows = []
    for rec in independent:
        sm = summary[(rec["scene"], rec["name"])]
        rows.append([rec["name"], fmt(rec["tones"][0]["frequency_hz"] / 1e3, ".2f"),
                     fmt(sm["slowest"] * 1e3, ".2f"), _travel_range(rec),
                     fmt(rec.get("settle_s", math.nan) * 1e3, "g"),
                     fmt(rec.get("peak_acceleration_g", math.nan), ".0f"),
                     fmt(sm["idle_disp"] / UM, ".3f"),
                     f"{sm['passed']}/{sm['checks']}"])
    lines += md_table(["impacter", "tone [kHz]", "slowest over x0 [mm/s]", "travel [um]",
                       "dwell [ms]", "peak acceleration [g]",
                       "largest idle displacement [um]", "checks passed"], rows)
    lines.append("")
    return Section("Every impacter alone", lines, level=3)


def _failures_section(ver):
    """Every failed step x device check, the first 60 in full."""
    fails = ver[~ver["passed"]]
    lines = []
    if fails.empty:
        lines.append("None: every step moves the sliders it should and no other.")
    else:
        for _, r in fails.head(60).iterrows():
            lines.append(f"- {r['scene']}/{r['step']} {r['device']} ({r['expected']}): {r['cause']}")
        if len(fails) > 60:
            lines.append(f"- ... and {len(fails) - 60} more (plan.json)")
    return Section("Failures", lines + [""])


def _timings_section(timings):
    """Seconds per stage (and the outputs')."""
    return Section("Timings", md_table(["stage", "seconds"],
                                       [[k, f"{v:.2f}"] for k, v in timings.items()]))


def _designed_windows(d) -> str:
    """' (designed for +-w % ...)': the window every design answers its tone over
    (``design.tone_window_pct``), where plan.json's impacters give one."""
    rel = [(w[1] - w[0]) / (w[1] + w[0]) for w in
           (r.get("tone_window_hz") for r in d.get("impacters", [])) if w]
    if not rel:
        return ""
    widths = [w[1] - w[0] for w in (r["tone_window_hz"] for r in d["impacters"]
                                    if r.get("tone_window_hz"))]
    return (f" (designed to answer over +-{100 * max(rel):.2f} % of the tone, "
            f"design.tone_window_pct: windows {min(widths):.0f}-{max(widths):.0f} Hz wide)")


def _manufacturability_section(d):
    """Design for yield: what a fabricated chip does to these designs."""
    m = d.get("manufacturability")
    if not m or d.get("as_built") is not None:
        # a re-plan carries only its designs' separations: the prediction is the plan's
        return None
    lw = m["line_width_sensitivity_per_um"]
    seps = m["separation_hz"].values()
    out = [f"Line-width sensitivity d ln nu_n / dw of the {len(m['sensitivity'])} designs: "
           f"{lw['min']:.4f}-{lw['max']:.4f} per um"
           + (f" (spread {100 * lw['spread']:.1f} %)" if lw.get("spread") is not None else "")
           + (f", matched band {m['sensitivity_band_per_um'][0]:.4f}-"
              f"{m['sensitivity_band_per_um'][1]:.4f} per um" if m.get("sensitivity_band_per_um")
              else ", not matched (design.match_sensitivity: false)")
           + ": a die-level line-width error moves every resonance by nearly one factor, "
           "which a re-plan absorbs.  Silent bands (how far from its resonance a tone must "
           f"be for an impacter to stay silent from every x0 at full power): "
           f"{min(s['silent_beyond'] for s in seps):.0f}-"
           f"{max(s['silent_beyond'] for s in seps):.0f} Hz; tone windows (how far its own "
           f"tone may move and still drive it): {min(s['responds_within'] for s in seps):.0f}-"
           f"{max(s['responds_within'] for s in seps):.0f} Hz"
           + _designed_windows(d) + ".", ""]
    y = m.get("collision_free_yield")
    if y is None:
        out += [f"Collision-free yield: not predicted ({m.get('note', 'no tolerances')}).", ""]
    else:
        c = m["closest_pair_hz"]
        out += [f"**Predicted collision-free yield {y['value']:.3f}** (95 % CI "
                f"{y['ci95'][0]:.3f}-{y['ci95'][1]:.3f}, {y['chips']} chips; target "
                f"{m['target_yield']:g}): the fraction of fabricated chips on which a drive "
                "re-planned from the measured resonances can still tell every pair apart "
                f"that must be told apart.  Die-level errors alone: {m['die_only_yield']:.3f}; "
                f"device-level alone: {m['device_only_yield']:.3f}.  Closest as-built pair: "
                f"median {c['median']:.0f} Hz (5-95 %: {c['p5']:.0f}-{c['p95']:.0f} Hz).", ""]
        t = m.get("told_apart_yield")
        if t is not None:
            out += [f"With the measurement's own error on each resonance "
                    f"(fabrication.measurement_noise_pct {t['measurement_noise_pct']:g} %), "
                    f"as a re-plan reads them: **{t['value']:.3f}** of the chips told apart "
                    f"(95 % CI {t['ci95'][0]:.3f}-{t['ci95'][1]:.3f}); the rest need a trim "
                    "or a measurement again (benchmarks/results/collision_calibration.md "
                    "holds this against sampled chips).", ""]
        if m["limiting_pairs"]:
            out += md_table(["pair", "collides on", "designed distance [Hz]"],
                            [[" / ".join(p["pair"]), f"{100 * p['collision_fraction']:.2f} %",
                              f"{p['nominal_separation_hz']:.0f}"]
                             for p in m["limiting_pairs"]]) + [""]
    return Section("Manufacturability",
                   out + ["![manufacturability](figures/manufacturability.png)", ""])


def _travel_range(rec):
    """The moving sliders' travel of a step [um], as 'a' or 'a to b'."""
    movers = set(rec["forward"]) | set(rec["backward"])
    vals = [abs(z) / UM for dev, z in rec.get("travel_m", {}).items() if dev in movers]
    if not vals:
        return "-"
    lo, hi = min(vals), max(vals)
    return f"{lo:.3g}" if math.isclose(lo, hi, rel_tol=1e-3) else f"{lo:.3g} to {hi:.3g}"


def _motion_notes(d):
    """What the planner changed to the steps: acceleration limit, sized bursts, repairs."""
    lines = []
    for rec in d["steps"]:
        key = f"{rec['scene']}/{rec['name']}"
        scale = rec.get("acceleration_scale", 1.0)
        if scale is not None and scale < 1.0:
            lines.append(f"- {key}: every tone amplitude lowered by x{scale:.3g} to meet "
                         f"drive.max_acceleration_g (peak now {rec['peak_acceleration_g']:.0f} g)")
        gating = rec.get("gating")
        if gating is not None:
            played = [n for n, g in gating["gates_s"].items() if g > 0]
            lines.append(
                f"- {key}: a gated burst of {rec['duration_s'] * 1e3:.4g} ms, played once: "
                f"its {len(played)} tones one after the other, each fading in and out over "
                f"{gating['ramp_s'] * 1e3:g} ms and playing until its slider has gone its "
                f"move ({gating['search_iterations']} simulation(s) of the step to find "
                "them)")
        if rec.get("requested_travel_m") is not None:
            v = (rec.get("sizing") or {}).get("slowest_probe_speed_m_s")
            sized = (rec.get("sizing") or {}).get("sized_s") or rec["duration_s"]
            lines.append(f"- {key}: burst {sized * 1e3:g} ms sized for "
                         f"{rec['requested_travel_m'] / UM:g} um at the slowest predicted "
                         f"speed {fmt(v * 1e3 if v is not None else None, '.3g')} mm/s")
    reach = (d.get("assignment") or {}).get("reach")
    if reach and reach.get("constrained"):
        rng = reach.get("range_hz")
        text = (f"- reach: {reach['channels_offered']} of the grid's "
                f"{reach['channels_in_grid']} channels offered to the assigner")
        if rng:
            text += f" (a design serves {rng[0]:.0f}-{rng[1]:.0f} Hz at the speed floor)"
        wide = [f"x{p['ratio']:.3g} at {p['tone_hz'] / 1e3:.3g} kHz" for p in reach["probes"]
                if p["ratio"] is not None and p["ratio"] > p["packed_ratio"]]
        if wide and not reach.get("relaxed_separations"):
            text += ("; neighbours kept further apart than the grid packs them: "
                     + ", ".join(wide))
        lines.append(text)
    if reach and reach.get("relaxed_separations"):
        lines.append("- reach: what a probe design asked (a wider spacing, or no tone told "
                     "apart near it) did not fit the band: every reachable channel was "
                     "offered at the grid's packed spacing, and the loop below moves a "
                     "design that fails there")
    for rnd in d["verification"].get("repair_rounds", []):
        # a design round that failed checks and what the next round changed
        r = rnd["round"]
        if rnd.get("infeasible"):
            lines.append(f"- design round {r}: {len(rnd['infeasible'])} infeasible "
                         f"design(s): {', '.join(rnd['infeasible'])}")
        for action in rnd.get("actions", ()):
            lines.append(f"- design round {r}: {action}")
        moved = {}
        for mv in rnd.get("moved", ()):
            moved.setdefault((mv["from_hz"], mv["to_hz"]), []).append(mv["impacter"])
        for (a, b), who in moved.items():
            lines.append(f"- design round {r}: {', '.join(who)} moved {a:.0f} -> {b:.0f} Hz, "
                         "every other channel kept")
        if rnd.get("recoloured"):
            lines.append(f"- design round {r}: no free channel kept the widened separations; "
                         f"coloured again ({rnd['recoloured']} channels moved)")
        if rnd.get("no_channel"):
            lines.append(f"- design round {r}: no channel keeps the widened separations of "
                         f"{', '.join(rnd['no_channel']['impacters'])}; they stay")
        for field, why in (("redesigned_slow", "too slow in a step"),
                           ("redesigned_idle", "answered a step it sits out")):
            if rnd.get(field):
                lines.append(f"- design round {r}: re-designed from further seeds "
                             f"({why}): {', '.join(rnd[field])}")
        st = rnd.get("designs")
        if st and r and (st.get("kept") or st.get("designed")):
            lines.append(f"- design round {r}: {st['designed']} designed, {st['kept']} kept "
                         f"after a re-check, {st['reused']} unchanged")
        if rnd.get("kept_round") is not None:
            lines.append(f"- design round {rnd['kept_round']} kept: {rnd['why']}")
    for rnd in d["verification"].get("motion_repairs", []):
        lines += [f"- repair round {rnd['round']}: {a}" for a in rnd["actions"]]
    return Section("What the planner changed", lines + [""]) if lines else None


def _positions_section(d, ver):
    """Asked against got for every scene with targets: each targets step's slider
    positions (carried-state simulation) and the worst error from the per-step check's
    initial positions, and where every slider rests at the end."""
    scenes = target_scenes(d["scenes"])
    if not scenes:
        return None
    tol = d["verification"]["position_tolerance_m"]
    lines = ["Each targets step is a gated burst (What the planner changed); positions "
             "from the scene simulated with every state carried from step to step, "
             f"relative to where the scene started.  Tolerance {tol / UM:g} um "
             "(verification.position_tolerance_um); 'worst from x0': the largest error of "
             "the step's own check, which starts the slider's impacter from each of the "
             "x0 grid instead of the carried state (the move it was gated for).", ""]
    worst_x0 = {}
    if "worst_position_error_m" in ver:
        for _, r in ver.dropna(subset=["worst_position_error_m"]).iterrows():
            worst_x0[(r["scene"], r["step"], r["device"])] = r["worst_position_error_m"]
    for scene, rows in scenes.items():
        targeted = [r for r in rows if r.get("targets_m")]
        tail = [r for r in rows if not r["driven"]]
        devices = sorted(tail[0]["final_positions_m"] if tail else rows[0]["positions_m"],
                         key=device_key)
        header = ["device"]
        for r in targeted:
            header += [f"{r['step']}: asked [um]", "got [um]", "error [um]", "worst from x0 [um]"]
        header += ["end: asked [um]", "rests at [um]", "error [um]"]
        table, worst = [], 0.0
        for dev in devices:
            row = [dev]
            for r in targeted:
                if dev in r["targets_m"]:
                    err = r["position_errors_m"][dev]
                    worst = max(worst, abs(err))
                    x0 = worst_x0.get((scene, r["step"], dev))
                    row += [fmt(r["targets_m"][dev] / UM, ".2f"),
                            fmt(r["positions_m"][dev] / UM, ".2f"), _err(err, tol),
                            "-" if x0 is None or x0 != x0 else _err(x0, tol)]
                else:
                    row += ["stays", fmt(r["positions_m"][dev] / UM, ".2f"), "-", "-"]
            if tail and dev in tail[0].get("expected_positions_m", {}):
                want = tail[0]["expected_positions_m"][dev]
                err = tail[0]["final_positions_m"][dev] - want
                worst = max(worst, abs(err))
                row += [fmt(want / UM, ".2f"), fmt(tail[0]["final_positions_m"][dev] / UM, ".2f"),
                        _err(err, tol)]
            else:
                row += ["-", fmt(tail[0]["final_positions_m"][dev] / UM, ".2f") if tail else "-",
                        "-"]
            table.append(row)
        lines += [f"**{scene}**: worst error {worst / UM:.2f} um.", ""]
        lines += md_table(header, table)
        lines += ["", f"![pattern {scene}](figures/{pattern_figure_name(scene)})", ""]
    return Section("Positions asked and got", lines)


def _err(err, tol):
    """An error [m] for the positions table, bold beyond the tolerance."""
    text = f"{err / UM:+.2f}"
    return f"**{text}**" if abs(err) > tol else text


def _scene_section(scene_rows):
    """Slider positions after each step of each scene, the overshoot once the drive
    stops, and the impacters that hit while their step did not drive them."""
    lines = ["Each scene from rest, every step from the state the previous one left, each "
             "followed by its settle dwell (positions below are at the end of the dwell); after "
             f"the last dwell the drive stays off for {SETTLE_S * 1e3:g} ms more, and the "
             "overshoot is how far each slider moves then.", "",
             "![slider positions](figures/slider_positions.png)", ""]
    overshoot = scene_overshoot(scene_rows)
    for scene in dict.fromkeys(r["scene"] for r in scene_rows):
        rows = [r for r in scene_rows if r["scene"] == scene]
        steps = [r for r in rows if r["driven"]]
        devices = sorted(rows[0]["positions_m"], key=device_key)
        header = ["device"] + [f"after {r['step']} [um]" for r in steps]
        if scene in overshoot:
            header.append("overshoot [um]")
        table = []
        for dev in devices:
            row = [dev] + [fmt(r["positions_m"][dev] / UM, ".1f") for r in steps]
            if scene in overshoot:
                row.append(fmt(overshoot[scene][dev] / UM, ".3f"))
            table.append(row)
        lines += [f"**{scene}**", ""] + md_table(header, table) + [""]
        for r in rows:
            hits, moved = r["idle_hits"], r["idle_moved_m"]
            what = ("after the drive stopped" if not r["driven"] else
                    f"in {r['step']}, which does not drive them")
            if hits:
                shown = sorted(hits.items())
                lines.append(f"- impacters that hit their slider {what}: "
                             + ", ".join(f"{n} ({k} impact{'s' if k > 1 else ''})"
                                         for n, k in shown[:10])
                             + (f" and {len(hits) - 10} more" if len(hits) > 10 else ""))
            if moved:
                shown = sorted(moved.items(), key=lambda kv: -abs(kv[1]))
                lines.append(f"- **idle sliders moved more than the idle tolerance {what}** "
                             "(state carried from the previous step; a verification "
                             "failure): "
                             + ", ".join(f"{dv} {z / UM:+.2f} um" for dv, z in shown[:10])
                             + (f" and {len(moved) - 10} more" if len(moved) > 10 else ""))
        lines.append("")
    return Section("Scenes (state carried across steps)", lines)
