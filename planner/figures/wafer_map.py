"""Pictures of a wafer: each die coloured by its outcome and numbered by its cause, and
the yield against the die's radius (``vibroplan yield`` on wafers and the batch
``vibroplan replan`` of a wafer, issue 39).

The functions take plain records (die grid indices, outcome, causes) so that the yield
study, which knows every die's truth, and the batch re-plan, which knows what was
measured, draw the same map.
"""

from __future__ import annotations

from pathlib import Path

#: Colour of each outcome: green works as designed, blue after a re-plan, orange after
#: a trim, red fails (``scrapped`` in a batch re-plan), grey partly measured (a batch's
#: die with an impacter not measured: not known to work).
COLOURS = {"as designed": "#2ca02c", "after re-plan": "#1f77b4", "after trim": "#ff7f0e",
           "fails": "#d62728", "scrapped": "#d62728", "partly measured": "#7f7f7f"}
#: The outcomes of a die known to work.
WORKING = ("as designed", "after re-plan", "after trim")
#: Wafers drawn side by side at most (a study of more wafers maps its first ones).
MAX_MAP_WAFERS = 4
#: Dots per inch of the figures.
DPI = 110
#: Width of the wafer map's legend column [in].
LEGEND_IN = 3.0


def cause_codes(dies) -> dict:
    """Cause -> its number on the map (1, 2, ...), the causes of failing dies in sorted
    order: a die is labelled with its first cause's number."""
    causes = sorted({d["causes"][0] for d in dies if d.get("causes")})
    return {c: k + 1 for k, c in enumerate(causes)}


def plot_wafer_map(dies, die_size_mm, path, *, diameter_mm=None, edge_exclusion_mm=None,
                   title="") -> None:
    """Write the wafer map PNG.

    Parameters
    ----------
    dies : list of dict
        ``die_x``, ``die_y`` (grid indices), ``outcome`` (a key of :data:`COLOURS`),
        ``causes`` (list of str), optionally ``wafer`` (index; one panel per wafer).
    die_size_mm : (float, float)
        Die width and height [mm].
    path : path
        The PNG.
    diameter_mm, edge_exclusion_mm : float, optional
        The wafer's outline and its edge exclusion [mm] (not drawn when unknown).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Patch, Rectangle

    w, h = die_size_mm
    wafers = sorted({d.get("wafer", 0) for d in dies})[:MAX_MAP_WAFERS]
    codes = cause_codes(dies)
    # room on the right for the legend (outcomes and the causes' numbers)
    width = 5.0 * len(wafers) + LEGEND_IN
    fig, axes = plt.subplots(1, len(wafers), figsize=(width, 5.4), squeeze=False)
    for ax, wi in zip(axes[0], wafers):
        mine = [d for d in dies if d.get("wafer", 0) == wi]
        for d in mine:
            x, y = d["die_x"] * w, d["die_y"] * h
            ax.add_patch(Rectangle((x - w / 2, y - h / 2), w, h,
                                   facecolor=COLOURS.get(d["outcome"], "#999999"),
                                   edgecolor="white", linewidth=0.8))
            if d.get("causes"):
                ax.text(x, y, str(codes[d["causes"][0]]), ha="center", va="center",
                        fontsize=7, color="white", weight="bold")
        reach = max(max(abs(d["die_x"]) * w + w, abs(d["die_y"]) * h + h) for d in mine)
        if diameter_mm:
            ax.add_patch(Circle((0, 0), diameter_mm / 2, fill=False, color="black", lw=1))
            reach = max(reach, diameter_mm / 2)
            if edge_exclusion_mm:
                ax.add_patch(Circle((0, 0), diameter_mm / 2 - edge_exclusion_mm, fill=False,
                                    color="grey", lw=0.8, ls="--"))
        ax.set_xlim(-reach * 1.05, reach * 1.05)
        ax.set_ylim(-reach * 1.05, reach * 1.05)
        ax.set_aspect("equal")
        ax.set_xlabel("x [mm]")
        ax.set_ylabel("y [mm]")
        works = sum(1 for d in mine if d["outcome"] in WORKING)
        ax.set_title((f"wafer {wi + 1}: " if len(wafers) > 1 or "wafer" in mine[0] else "")
                     + f"{works} of {len(mine)} dies work")
    seen = [o for o in COLOURS if any(d["outcome"] == o for d in dies)]
    handles = [Patch(color=COLOURS[o], label=f"{o} ({sum(1 for d in dies if d['outcome'] == o)})")
               for o in seen]
    handles += [Patch(color="none", label=f"{k}: {c}") for c, k in codes.items()]
    axes[0][-1].legend(handles=handles, loc="upper left", bbox_to_anchor=(1.02, 1.0),
                       fontsize=8, frameon=False, title="outcome; cause of failure",
                       title_fontsize=8, alignment="left")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.subplots_adjust(left=0.9 / width, right=1 - LEGEND_IN / width, bottom=0.1, top=0.88,
                        wspace=0.25)
    fig.savefig(Path(path), dpi=DPI, bbox_inches="tight")
    plt.close(fig)


def plot_yield_by_radius(rings, path, *, title="") -> None:
    """Write the yield against the die's radius: each ring's yield (dies that work in
    the end) with its 95 % Wilson interval, and the outcomes stacked below it.

    ``rings``: yield.json's ``wafer.by_radius``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    rings = [r for r in rings if r["dies"]]
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(6.4, 6.0), sharex=True)
    mid = np.array([0.5 * (r["radius_from_mm"] + r["radius_to_mm"]) for r in rings])
    width = np.array([r["radius_to_mm"] - r["radius_from_mm"] for r in rings])
    y = np.array([r["yield"] for r in rings])
    lo = np.array([r["ci95"][0] for r in rings])
    hi = np.array([r["ci95"][1] for r in rings])
    top.errorbar(mid, y, yerr=[y - lo, hi - y], fmt="o-", capsize=3)
    top.set_ylim(-0.02, 1.02)
    top.set_ylabel("yield (works in the end)")
    top.grid(alpha=0.3)
    base = np.zeros(len(rings))
    for o in ("as designed", "after re-plan", "after trim", "fails"):
        frac = np.array([r["outcomes"].get(o, 0) / r["dies"] for r in rings])
        if frac.any():
            bottom.bar(mid, frac, width * 0.9, bottom=base, color=COLOURS[o], label=o)
            base += frac
    bottom.set_xlabel("die centre's distance from the wafer's centre [mm]")
    bottom.set_ylabel("fraction of the ring's dies")
    bottom.legend(fontsize=8)
    if title:
        top.set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(Path(path), dpi=DPI)
    plt.close(fig)
