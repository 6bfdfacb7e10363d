"""The outputs of ``vibroplan yield``: ``yield.json``, ``report.md`` (the yields with their
intervals, the failing checks, the re-plan's and the trim's causes and cost) and the
figures (yield against the sigma scale, failure rates over the array).

The numbers are :mod:`planner.yield_`'s (:func:`planner.yield_.run_yield`); this module
only writes them.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from planner.core.nodes import Node
from planner.arrayspec import ArraySpec
from planner.yield_ import scale_key


def _grid(spec: ArraySpec, rates: dict, direction: str):
    """The failure rates of the impacters of one direction on the array's (row, column)
    grid, NaN where there is none; ``rates`` is yield.json's ``impacters`` (node text ->
    rate)."""
    cols = spec.array.cols
    cell = {dev: divmod(i, cols) for i, dev in enumerate(spec.array.device_ids())}
    grid = np.full((spec.array.rows, cols), np.nan)
    for text, rate in rates.items():
        node = Node.parse(text)
        if node.direction == direction:
            grid[cell[node.device]] = rate
    return grid


def _figures(data: dict, spec: ArraySpec, folder: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder.mkdir(parents=True, exist_ok=True)
    names = []
    # yield with its CI, against the sigma scale when there are several
    by = data.get("by_sigma_scale") or {scale_key(data['sigma_scale']):
                                        {"yield": data["yield"], "ci95": data["ci95"]}}
    xs = [float(k) for k in by]
    ys = [v["yield"] for v in by.values()]
    lo = [v["yield"] - v["ci95"][0] for v in by.values()]
    hi = [v["ci95"][1] - v["yield"] for v in by.values()]
    fig, ax = plt.subplots(figsize=(5, 3.5))
    ax.errorbar(xs, ys, yerr=[lo, hi], fmt="o-", capsize=4,
                label="nominal drive" if "replan" in data else None)
    for block, fmt, label in (("replan", "s--", "re-planned per chip"),
                              ("tune", "D-.", "re-planned and tuned on the chip"),
                              ("trim", "^:", "trimmed where needed, re-planned")):
        if block not in data:
            continue
        rps = ([v[block] for v in data["by_sigma_scale"].values()]
               if "by_sigma_scale" in data else [data[block]])
        ax.errorbar(xs, [v["yield"] for v in rps],
                    yerr=[[v["yield"] - v["ci95"][0] for v in rps],
                          [v["ci95"][1] - v["yield"] for v in rps]],
                    fmt=fmt, capsize=4, label=label)
    if "replan" in data:
        ax.legend(loc="best", fontsize=8)
    ax.set_xlabel("sigma scale [-]")
    ax.set_ylabel("yield (95 % Wilson CI)")
    ax.set_ylim(-0.03, 1.03)
    ax.set_title(f"{data['chips']} chips per point, seed {data['seed']}")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(folder / "yield.png", dpi=110)
    plt.close(fig)
    names.append("yield.png")
    # the checks that fail most
    if data["failures"]:
        kinds = list(data["failures"])
        fig, ax = plt.subplots(figsize=(5.5, 0.5 + 0.45 * len(kinds)))
        ax.barh(kinds[::-1], [data["failures"][k] / data["chips"] for k in kinds[::-1]])
        ax.set_xlabel("fraction of chips failing the check")
        ax.set_xlim(0, 1)
        fig.tight_layout()
        fig.savefig(folder / "failures.png", dpi=110)
        plt.close(fig)
        names.append("failures.png")
    # each impacter's failure rate over the array grid
    fig, axes = plt.subplots(1, 2, figsize=(2 + 1.4 * spec.array.cols, 0.8 + 0.9 * spec.array.rows),
                             squeeze=False)
    for ax, direction in zip(axes[0], ("forward", "backward")):
        g = _grid(spec, data["impacters"], direction)
        im = ax.imshow(g, vmin=0, vmax=1, cmap="Reds")
        ax.set_title(direction)
        ax.set_xticks(range(spec.array.cols), [str(c + 1) for c in range(spec.array.cols)])
        ax.set_yticks(range(spec.array.rows), [chr(ord("A") + r) for r in range(spec.array.rows)])
        for (r, c), v in np.ndenumerate(g):
            ax.text(c, r, "-" if np.isnan(v) else f"{v:.2f}", ha="center", va="center",
                    fontsize=8)
    fig.colorbar(im, ax=axes[0].tolist(), label="failure rate")
    fig.savefig(folder / "impacters.png", dpi=110)
    plt.close(fig)
    names.append("impacters.png")
    return names


def _replan_lines(data: dict, timings: dict | None) -> list[str]:
    rp = data["replan"]
    lo, hi = rp["ci95"]
    nd = rp["nominal_drive"]
    lines = ["## Re-planned per chip (`--replan`)", "",
             "Every chip was measured (its true natural frequencies"
             + (f" with {rp['measure_noise_pct']:g} % Gaussian measurement noise"
                if rp["measure_noise_pct"] else ", no measurement noise")
             + "), its drive re-planned from the measurement (`replan_chip`: tones, "
             "amplitudes and timing; the geometry is fixed), and the re-planned drive "
             "verified with the same checks on the chip's TRUE models.", "",
             "| drive | yield | 95 % Wilson CI | chips passing |", "|---|---|---|---|",
             f"| nominal (plan.json's) | {nd['yield']:.3f} | [{nd['ci95'][0]:.3f}, "
             f"{nd['ci95'][1]:.3f}] | {nd['passed']} / {rp['chips']} |",
             f"| **re-planned per chip** | **{rp['yield']:.3f}** | [{lo:.3f}, {hi:.3f}] | "
             f"{rp['passed']} / {rp['chips']} |", "",
             f"Rescued by the re-plan: {rp['rescued']} chips; passing with the nominal drive "
             f"but not re-planned: {rp['lost']}.  The re-plan verified on its own "
             f"(measured) models on {rp['measured_passed']} chips.  The nominal chip "
             f"(no fabrication error, measured like the others) re-planned: {'passes' if rp['nominal']['replan_passed'] else 'FAILS'}"
             + (f" ({', '.join(rp['nominal']['causes'])})" if rp["nominal"]["causes"] else "")
             + ".", ""]
    if timings and timings.get("replan_s"):
        t = np.array(timings["replan_s"])
        tn = np.array(timings["nominal_s"])
        lines += [f"Cost (this run, wall time per chip): re-plan {t.mean():.1f} s mean "
                  f"({t.min():.1f}-{t.max():.1f} s), besides the nominal checks "
                  f"{tn.mean():.1f} s; {60 * len(tn) / timings['wall_s']:.2f} chips/min "
                  "overall.", ""]
    if rp["causes"]:
        lines += ["### Why re-plans fail", "", "| cause | chips |", "|---|---|"]
        lines += [f"| {k} | {v} |" for k, v in rp["causes"].items()]
        lines += ["", "Checks the re-planned drive fails on the true models: "
                  + ", ".join(f"{k} ({v} chips)" for k, v in rp["failures"].items()), ""]
    bad = [c for c in rp["per_chip"] if not c["replan_passed"]]
    if bad:
        lines += ["### Chips the re-plan does not rescue", "",
                  "| chip | nominal drive | causes | colliding resonances (as built) |",
                  "|---|---|---|---|"]
        for c in bad[:50]:
            pairs = "; ".join(" / ".join(f"{n} {hz:.0f} Hz" for n, hz in
                                         zip(x["pair"], x["as_built_hz"]))
                              + (f" (need {x['needs_hz']:.0f} Hz apart)"
                                 if x.get("needs_hz") is not None else "")
                              for x in c["collisions"][:4])
            if len(c["collisions"]) > 4:
                pairs += f"; ... {len(c['collisions']) - 4} more"
            lines.append(f"| {c['chip']} | {'passes' if c['nominal_passed'] else 'fails'} | "
                         f"{', '.join(c['causes']) or '-'} | {pairs or '-'} |")
        if len(bad) > 50:
            lines.append(f"| ... | | {len(bad) - 50} more in yield.json | |")
        lines.append("")
    if "tune" in data:
        tu = data["tune"]
        lines += ["## Tuned on the chip (`--tune`)", "",
                  f"Every re-planned chip was tuned as a lab with the piezo on would: "
                  f"{tu['tones_per_impacter']} tones around each re-planned tone, one impacter "
                  "at a time, each slider's speed read with "
                  f"{tu['speed_noise_pct']:g} % noise (simulated on the chip's true models); "
                  "each impacter's working window fitted (the tones moving its slider at half "
                  "the fastest speed or more, and at the speed floor), the tones off their "
                  "window's centre moved to its middle, the drive re-planned and verified "
                  "again on the true models.", "",
                  f"**Tuned yield {tu['yield']:.3f}** (95 % CI [{tu['ci95'][0]:.3f}, "
                  f"{tu['ci95'][1]:.3f}], {tu['passed']} / {tu['chips']} chips); rescued "
                  f"{tu['rescued']} the re-plan lost, lost {tu['lost']} it had.", ""]
        kept = tu.get("kept_replan", 0)
        chips_by = tu.get("repaired_chips") or {}
        raised = chips_by.get("amplitude_raised", 0)
        timed = chips_by.get("gates_timed_on_chip", 0)
        if kept or raised or timed:
            lines += [f"Played on the chip: on {kept} chip(s) the tuned drive failed where the "
                      "re-plan before the sweep worked, and the re-plan was kept; on "
                      f"{raised} chip(s) a slider too slow on the chip had its tone raised "
                      f"({(tu.get('repairs') or {}).get('amplitude_raised', 0)} step(s)); on "
                      f"{timed} chip(s) a slider off its target had its step's gates timed "
                      "on the chip.", ""]
        if tu["causes"]:
            lines += ["| why a tuned chip still fails | chips |", "|---|---|"]
            lines += [f"| {k} | {v} |" for k, v in tu["causes"].items()] + [""]
    if "trim" in data:
        tr = data["trim"]
        lines += ["## Trimmed where needed (`--trim`)", "",
                  "A chip the re-plan could not rescue because two of its impacters cannot "
                  "be told apart was trimmed (one-way moves within the spec's "
                  "trim.range_pct, chosen from its measurement), each trim off its target by "
                  "the trim precision, measured again, re-planned and verified on its "
                  "trimmed true models.", "",
                  f"**Yield with trims {tr['yield']:.3f}** (95 % CI [{tr['ci95'][0]:.3f}, "
                  f"{tr['ci95'][1]:.3f}], {tr['passed']} / {tr['chips']} chips); "
                  f"{tr['trimmed']} chips trimmed, {tr['rescued']} rescued by the trim.", ""]
        if tr["causes"]:
            lines += ["| why a chip still fails | chips |", "|---|---|"]
            lines += [f"| {k} | {v} |" for k, v in tr["causes"].items()] + [""]
    return lines


def _report(data: dict, spec: ArraySpec, plan_path: str, figures: list[str],
            timings: dict | None = None) -> str:
    lo, hi = data["ci95"]
    lines = [f"# Yield of {spec.name}", "",
             f"Plan: `{plan_path}`; {data['chips']} chips, seed {data['seed']}, "
             f"sigma scale {scale_key(data['sigma_scale'])}.", "",
             f"**Yield {data['yield']:.3f}** ({data['passed']} of {data['chips']} chips pass "
             f"every check, the carried-state check included, with the plan's drive); "
             f"95 % Wilson interval [{lo:.3f}, {hi:.3f}]."
             + (f"  Re-planned per chip: **{data['replan']['yield']:.3f}** "
                f"[{data['replan']['ci95'][0]:.3f}, {data['replan']['ci95'][1]:.3f}] "
                "(below)." if "replan" in data else ""), "",
             "The nominal chip (no fabrication error) "
             + ("passes every check." if data["nominal"]["passed"] else
                "FAILS: " + ", ".join(f"{k} ({v})" for k, v in data["nominal"]["failures"].items())
                + "; the plan itself does not verify."), "",
             "## Tolerance model", "",
             "| error | per die (sigma) | per device (sigma) |", "|---|---|---|"]
    for k, v in data["tolerance"].items():
        if isinstance(v, dict) and "die" in v:   # the tolerances (not the wafer)
            lines.append(f"| {k} | {v['die']:g} | {v['device']:g} |")
    lines += ["", "![yield](figures/yield.png)", ""]
    if "replan" in data:
        lines += _replan_lines(data, timings)
    if "by_sigma_scale" in data:
        rp = "replan" in data
        lines += ["## Yield against the tolerance scale", "",
                  "| sigma scale | yield | 95 % CI | chips passed |"
                  + (" re-planned yield | 95 % CI |" if rp else ""),
                  "|---|---|---|---|" + ("---|---|" if rp else "")]
        for s, v in data["by_sigma_scale"].items():
            row = (f"| {s} | {v['yield']:.3f} | [{v['ci95'][0]:.3f}, {v['ci95'][1]:.3f}] "
                   f"| {v['passed']} / {data['chips']} |")
            if rp:
                r = v["replan"]
                row += f" {r['yield']:.3f} | [{r['ci95'][0]:.3f}, {r['ci95'][1]:.3f}] |"
            lines.append(row)
        lines.append("")
    lines += ["## Checks that fail", ""]
    if data["failures"]:
        lines += ["| check | chips failing it | fraction |", "|---|---|---|"]
        for k, v in data["failures"].items():
            lines.append(f"| {k} | {v} | {v / data['chips']:.3f} |")
        lines += ["", "![failures](figures/failures.png)", ""]
    else:
        lines += ["None: every chip passes every check.", ""]
    worst = sorted(data["impacters"].items(), key=lambda kv: -kv[1])[:10]
    lines += ["## Impacters", "",
              "Failure rate: the fraction of chips on which the impacter pair was implicated "
              "in a failed check (it responded while idle, its slider was too slow, or its "
              "idle slider moved)." + (
                  "  With --replan the plan's own drive is only the reference: its checks "
                  "on each chip stop at its first failing step, so these rates (and the "
                  "failing checks above) say which impacters fail first under the plan's "
                  "drive, not how often each would fail; the re-planned drive's failures "
                  "are in the re-plan section." if "replan" in data else ""),
              "", "![impacters](figures/impacters.png)", "",
              "| impacter | failure rate |", "|---|---|"]
    lines += [f"| {n} | {r:.3f} |" for n, r in worst]
    lines.append("")
    return "\n".join(lines)


def write_yield_outputs(data: dict, spec: ArraySpec, folder: Path, plan_path: str,
                  figures: bool = True, timings: dict | None = None) -> None:
    """``yield.json``, ``report.md`` and ``figures/`` into ``folder`` (a temporary one
    from :func:`planner.files.output_folder`); ``timings`` (:func:`run_yield`'s) adds the
    re-plan's cost to the report only, never to yield.json."""
    folder = Path(folder)
    (folder / "yield.json").write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")
    names = _figures(data, spec, folder / "figures") if figures else []
    text = _report(data, spec, plan_path, names, timings)
    if "wafer" in data:
        if figures:
            names += _wafer_figures(data, spec, folder / "figures")
        text += "\n".join(_wafer_lines(data, figures)) + "\n"
    (folder / "report.md").write_text(text, encoding="utf-8")


def _wafer_figures(data: dict, spec: ArraySpec, folder: Path) -> list[str]:
    """The wafer map and the yield against the radius (yield.json's ``wafer``)."""
    from planner.figures.wafer_map import plot_wafer_map, plot_yield_by_radius

    w = data["wafer"]
    plot_wafer_map(w["dies"], w["die_size_mm"], folder / "wafer_map.png",
                   diameter_mm=w["diameter_mm"], edge_exclusion_mm=w["edge_exclusion_mm"],
                   title=f"{spec.name}: {data['chips']} dies, seed {data['seed']}"
                   + (f", sigma scale {w['sigma_scale']:g}"
                      if len(data.get("by_sigma_scale", {})) > 1 else ""))
    plot_yield_by_radius(w["by_radius"], folder / "yield_radius.png",
                         title=f"{spec.name}: yield against the die's radius")
    return ["wafer_map.png", "yield_radius.png"]


def _wafer_lines(data: dict, figures: bool) -> list[str]:
    """report.md's section on the wafer: outcomes, the map, the yield by ring."""
    from planner.yield_.dies import OUTCOMES

    w = data["wafer"]
    lines = ["## The wafer", "",
             f"{w['dies_per_wafer']} dies of {w['die_size_mm'][0]:g} x "
             f"{w['die_size_mm'][1]:g} mm on a wafer of {w['diameter_mm']:g} mm "
             f"({w['edge_exclusion_mm']:g} mm edge exclusion); {data['chips']} dies sampled "
             f"on {w['wafers']} wafer{'s' if w['wafers'] != 1 else ''} "
             "(fabrication.wafer: the across-wafer field and the within-die gradient on "
             "top of the die and device levels).  Each die's outcome is the first of: the "
             "plan's drive works on it (as designed), a drive re-planned from its "
             "measurement does (after re-plan, with --replan), trimmed and re-planned it "
             "does (after trim, with --trim); else it fails, numbered on the map by its "
             "first cause.  The dies as a prober measures them: wafer_<k>.csv and "
             "wafer_<k>.stdf (`vibroplan replan PLAN --measured wafer_1.csv`).", ""]
    by_scale = data.get("by_sigma_scale", {})
    if len(by_scale) > 1:
        # the map and the tables below are one scale's dies: say which, and count all
        lines += [f"The map, the table below and the yield against the radius are the "
                  f"dies of sigma scale {w['sigma_scale']:g} (the headline's); every "
                  "scale's outcomes:", "",
                  "| sigma scale | " + " | ".join(OUTCOMES) + " |",
                  "|---|" + "---|" * len(OUTCOMES)]
        lines += [f"| {k} | " + " | ".join(str(v["wafer_outcomes"][o]) for o in OUTCOMES)
                  + " |" for k, v in by_scale.items()]
        lines.append("")
    lines += ["| outcome | dies | fraction |", "|---|---|---|"]
    lines += [f"| {o} | {w['outcomes'][o]} | {w['outcomes'][o] / data['chips']:.3f} |"
              for o in OUTCOMES]
    lines.append("")
    if figures:
        lines += ["![wafer map](figures/wafer_map.png)", ""]
    lines += ["### Yield against the radius", "",
              "| ring [mm] | dies | " + " | ".join(OUTCOMES) + " | yield | 95 % CI |",
              "|---|---|" + "---|" * len(OUTCOMES) + "---|---|"]
    for r in w["by_radius"]:
        if not r["dies"]:
            lines.append(f"| {r['radius_from_mm']:.1f}-{r['radius_to_mm']:.1f} | 0 |"
                         + " |" * len(OUTCOMES) + " - | - |")
            continue
        lines.append(f"| {r['radius_from_mm']:.1f}-{r['radius_to_mm']:.1f} | {r['dies']} | "
                     + " | ".join(str(r["outcomes"][o]) for o in OUTCOMES)
                     + f" | {r['yield']:.3f} | [{r['ci95'][0]:.3f}, {r['ci95'][1]:.3f}] |")
    lines.append("")
    if figures:
        lines += ["![yield against the radius](figures/yield_radius.png)", ""]
    return lines
