"""Figures: matplotlib with the Agg backend, written to PNG files."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from planner.core.units import UM  # noqa: E402


def save(fig, path):
    """Write ``fig`` to ``path`` (PNG, 120 dpi) and close it."""
    fig.savefig(path, dpi=120, bbox_inches="tight", metadata={"Software": None})
    plt.close(fig)


def time_response(runs, path, title=None):
    """Fig. 7: slider position (top) and impacter position (bottom) against time.

    Parameters
    ----------
    runs : list of (label, SliderResult, gap [m])
    """
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for label, res, gap in runs:
        t_ms = res.t * 1e3
        ax1.plot(t_ms, res.position / UM, label=label)
        ax2.plot(t_ms, res.impacts.x / UM, lw=0.8, label=label)
        ax2.plot(res.impacts.times * 1e3, np.full(res.impacts.n_impacts, gap / UM), "v",
                 ms=4, color=ax2.lines[-1].get_color())
    gaps = {gap for _, _, gap in runs}
    for gap in gaps:
        ax2.axhline(gap / UM, color="k", lw=0.8, ls="--")
    ax1.set_ylabel("slider position [um]")
    ax2.set_ylabel("impacter position [um]")
    ax2.set_xlabel("time [ms]")
    ax1.legend(loc="upper left")
    ax1.grid(alpha=0.3)
    ax2.grid(alpha=0.3)
    ax2.text(0.99, 0.02, "dashed: slider wall (gap); triangles: impacts",
             transform=ax2.transAxes, ha="right", va="bottom", fontsize=8)
    if title:
        ax1.set_title(title)
    save(fig, path)


def frequency_response(frequencies, r, x0s, path, title=None, natural_frequency=None,
                       markers=()):
    """Fig. 9: response r against frequency, one curve per initial position.

    Parameters
    ----------
    frequencies : ndarray, shape (n_freq,)
        [Hz].
    r : ndarray, shape (n_freq, n_x0)
        [N].
    x0s : ndarray, shape (n_x0,)
        [m].
    markers : iterable of (frequency [Hz], label)
        Vertical lines to mark.
    """
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for j, x0 in enumerate(x0s):
        ax.plot(np.asarray(frequencies) / 1e3, r[:, j] * 1e9, label=f"x(t0) = {x0 / UM:g} um")
    if natural_frequency is not None:
        ax.axvline(natural_frequency / 1e3, color="k", ls=":", lw=1, label="natural frequency")
    for f, label in markers:
        ax.axvline(f / 1e3, color="r", ls="--", lw=1)
        ax.annotate(label, (f / 1e3, ax.get_ylim()[1]), rotation=90, va="top", ha="right",
                    fontsize=8, color="r")
    ax.set_xlabel("drive frequency [kHz]")
    ax.set_ylabel("response r, eq. (12) [nN]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    if title:
        ax.set_title(title)
    save(fig, path)
