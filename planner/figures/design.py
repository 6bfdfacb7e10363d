"""Figures of the designer: the paper's Fig. 10 (both response curves of a pair)."""

from __future__ import annotations

import numpy as np

from planner.figures.device import plt, save

#: Frequencies of the response curves of :func:`pair_response`.
CURVE_POINTS = 400
#: x0 grid of the curves (odd: -c, 0 and +c are nodes).
CURVE_X0_POINTS = 33


def pair_response(pair, path, *, power=50.0, amplitude=None, window=3e-3, frequencies=None,
                  x0_points=CURVE_X0_POINTS, title=None):
    """Fig. 10: the responses of a forward and a backward design against frequency.

    For each design the worst response over x0 in D (min over x0, solid: what (13)
    maximises) and the best (max over x0, shaded up to it: what (14) must keep at 0)
    are drawn against the drive frequency, with both drive frequencies (dashed) and
    both natural frequencies (dotted) marked.

    Parameters
    ----------
    pair : planner.designer.PairDesign
    path : str or Path
        PNG to write.
    power : float
        Z0^2 w^3 of each tone [m^2/s^3]; ignored with ``amplitude`` [m].
    window : float
        Window of eq. (12) [s].
    frequencies : array_like, optional
        [Hz]; default CURVE_POINTS from 0.5x the lowest to 1.4x the highest of the
        drive and natural frequencies.
    x0_points : int
        Uniform x0 grid over [-c, c] (plus points just inside the wall).
    """
    from planner.designer import response_curves, x0_grid

    designs = [("forward", pair.forward, "tab:blue"), ("backward", pair.backward, "tab:orange")]
    marks = [v for _, d, _ in designs for v in (d.frequency_hz, d.natural_frequency_hz)]
    if frequencies is None:
        frequencies = np.linspace(0.5 * min(marks), 1.4 * max(marks), CURVE_POINTS)
    f = np.asarray(frequencies, dtype=float)
    fig, ax = plt.subplots(figsize=(9, 4.8))
    for name, d, colour in designs:
        imp = d.impacter
        r_min, r_max = response_curves(imp, f, x0_grid(imp.gap, x0_points), power, window,
                                       amplitude=amplitude)
        ax.fill_between(f / 1e3, 0.0, r_max * 1e9, color=colour, alpha=0.18, lw=0,
                        label=f"{name}: max over x0")
        # outline too: where the two shadings overlap, a tail of one design under the
        # other's (a response at the forbidden frequency) would otherwise be invisible
        ax.plot(f / 1e3, r_max * 1e9, color=colour, lw=0.7, alpha=0.7)
        ax.plot(f / 1e3, r_min * 1e9, color=colour, lw=1.8, label=f"{name}: min over x0")
        ax.axvline(d.natural_frequency_hz / 1e3, color=colour, ls=":", lw=1.2)
        ax.axvline(d.frequency_hz / 1e3, color=colour, ls="--", lw=1.2)
    top = ax.get_ylim()[1]
    for name, d, colour in designs:
        ax.annotate(rf" $\nu_{name[0]}$ = {d.frequency_hz / 1e3:g} kHz", (d.frequency_hz / 1e3, top),
                    rotation=90, va="top", ha="right", fontsize=8, color=colour)
        ax.annotate(rf" $\nu_{{n,{name[0]}}}$ = {d.natural_frequency_hz / 1e3:.3g} kHz",
                    (d.natural_frequency_hz / 1e3, top), rotation=90, va="top", ha="right",
                    fontsize=8, color=colour, alpha=0.8)
    ax.set_xlim(f[0] / 1e3, f[-1] / 1e3)
    ax.set_ylim(0.0, top)
    ax.set_xlabel("drive frequency [kHz]")
    ax.set_ylabel("response r, eq. (12) [nN]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.text(1.01, 0.02, "dashed: drive frequencies\ndotted: natural frequencies",
            transform=ax.transAxes, fontsize=8, va="bottom")
    ax.set_title(title or "Designed impacters (Fig. 10): response against drive frequency")
    save(fig, path)
