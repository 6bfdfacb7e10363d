"""Pictures of a layout (matplotlib, Agg): the whole chip and one device.

Drawn from the GDSII library as written (:func:`planner.layout.gds.read_gds`), so the
pictures show the file, not the intentions.  Coordinates in um, as in the file.
"""

from __future__ import annotations

from pathlib import Path

#: Fill colour, opacity and drawing order of every mask (POLY0 at the bottom).
STYLE = {
    "POLY0": ("#d9d9d9", 1.0),
    "POLY1": ("#d62728", 0.55),
    "POLY2": ("#1f77b4", 0.45),
    "POLY1_POLY2_VIA": ("#9467bd", 0.5),
    "ANCHOR1": ("#000000", 0.9),
    "ANCHOR2": ("#000000", 0.9),
    "DIMPLE": ("#8c564b", 0.9),
    "TRIM": ("#ff7f0e", 0.0),
}
#: Picture resolution [dots per inch].
DPI = 150


def _polygons(cell, layers, name):
    layer, datatype = layers[name]
    return [p.points for p in cell.get_polygons(layer=layer, datatype=datatype)]


def _draw(ax, cell, layers, *, edges=False):
    from matplotlib.collections import PolyCollection
    from matplotlib.patches import Patch

    handles = []
    for name, (colour, alpha) in STYLE.items():
        if name not in layers:
            continue
        polys = _polygons(cell, layers, name)
        if not polys:
            continue
        outline = name == "TRIM"
        ax.add_collection(PolyCollection(
            polys, facecolors="none" if outline else colour, alpha=None if outline else alpha,
            edgecolors=colour if (outline or edges) else "none", linewidths=0.6))
        handles.append(Patch(facecolor="none" if outline else colour, edgecolor=colour,
                             alpha=1.0 if outline else alpha, label=name))
    ax.autoscale_view()
    ax.set_aspect("equal")
    ax.set_xlabel("x [um]")
    ax.set_ylabel("y [um]")
    return handles


def _save(fig, path):
    # no date or software version in the file: the same layout gives the same bytes
    fig.savefig(path, dpi=DPI, bbox_inches="tight", metadata={"Software": None})


def chip_figure(lib, layers: dict, path: str | Path, title: str) -> None:
    """The whole chip (the library's top cell), one label per device.

    Parameters
    ----------
    lib : gdstk.Library
    layers : dict
        Mask name -> (layer, datatype).
    path : str or Path
        The PNG to write.
    title : str
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    top = lib.top_level()[0]
    fig, ax = plt.subplots(figsize=(8, 8))
    try:
        handles = _draw(ax, top, layers)
        for ref in top.references:
            ax.annotate(ref.cell.name, ref.origin, ha="center", va="center", fontsize=9,
                        fontweight="bold")
        ax.set_title(title)
        ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
        _save(fig, path)
    finally:
        plt.close(fig)


def device_figure(lib, layers: dict, device: str, path: str | Path, title: str) -> None:
    """One device (its cell, in its own frame), its impacter pairs labelled.

    Raises
    ------
    ValueError
        The library has no cell ``device``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cells = {c.name: c for c in lib.cells}
    if device not in cells:
        raise ValueError(f"the layout has no device {device!r}")
    cell = cells[device]
    fig, ax = plt.subplots(figsize=(8, 8))
    try:
        handles = _draw(ax, cell, layers, edges=True)
        label = layers["LABEL"]
        for text in cell.get_labels(layer=label[0], texttype=label[1]):
            if text.text != device:
                # beside the plate, outwards: the two pairs' labels never overlap
                x, y = text.origin
                ax.annotate(text.text.replace(" (", "\n("), (x, y),
                            xytext=(-40 if x < 0 else 40, 0), textcoords="offset points",
                            ha="right" if x < 0 else "left", va="center", fontsize=7,
                            bbox={"boxstyle": "round", "fc": "white", "alpha": 0.8})
        ax.set_title(title)
        ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
        _save(fig, path)
    finally:
        plt.close(fig)
