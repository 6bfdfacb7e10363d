"""Figures of the plan report: array map, response curves, coupling, drives, slider motion."""

from __future__ import annotations

import numpy as np

from planner.figures.device import plt, save

from planner.core.nodes import device_key  # noqa: E402
from planner.core.units import UM  # noqa: E402


def _cell(device):
    """(row, column) of a device on the array, from 0 (``"B3"`` -> (1, 2))."""
    row, col = device_key(device)
    return ord(row) - ord("A"), col - 1


def _row_letters(n_rows):
    return [chr(ord("A") + k) for k in range(n_rows)]


def array_map(settings, table, path):
    """The array with each device's forward/backward frequencies, coloured by channel.

    Parameters
    ----------
    settings : planner.planning.settings.Settings
        The array's shape, name and pitch, the band and its channel spacing.
    table : DataFrame
        One row per impacter: ``device``, ``direction``, ``channel``, ``frequency_hz``.
    path : path
        The PNG.
    """
    n_rows, n_cols = settings.array_shape
    fig, ax = plt.subplots(figsize=(1.7 * n_cols + 1.5, 1.2 * n_rows + 1))
    cmap = plt.get_cmap("viridis")
    lo, hi = settings.band_hz
    log = settings.channel_spacing == "log"
    norm = (plt.matplotlib.colors.LogNorm if log else plt.matplotlib.colors.Normalize)(lo, hi)
    by_node = {(r["device"], r["direction"]): r for r in table.to_dict(orient="records")}
    for i, letter in enumerate(_row_letters(n_rows)):
        for j in range(n_cols):
            dev = f"{letter}{j + 1}"
            y = n_rows - 1 - i
            ax.add_patch(plt.Rectangle((j, y), 0.96, 0.92, fill=False, lw=0.8, color="0.5"))
            ax.text(j + 0.04, y + 0.8, dev, fontsize=8, weight="bold", va="top")
            for k, direction in enumerate(("forward", "backward")):
                rec = by_node.get((dev, direction))
                if rec is None:
                    continue
                frac = float(norm(rec["frequency_hz"]))
                ax.add_patch(plt.Rectangle((j + 0.05, y + 0.42 - 0.34 * k), 0.86, 0.3,
                                           color=cmap(frac), alpha=0.85))
                ax.text(j + 0.48, y + 0.57 - 0.34 * k,
                        f"{'F' if k == 0 else 'B'} {rec['frequency_hz'] / 1e3:.2f}k ch{rec['channel']}",
                        fontsize=7, ha="center", va="center",
                        color="white" if frac < 0.6 else "black")
    ax.set_xlim(-0.1, n_cols + 0.1)
    ax.set_ylim(-0.1, n_rows + 0.1)
    ax.set_aspect("equal")
    ax.axis("off")
    sm = plt.cm.ScalarMappable(cmap=cmap, norm=norm)
    fig.colorbar(sm, ax=ax, fraction=0.04, label="drive frequency [Hz]")
    ax.set_title(f"{settings.name}: channels (F = forward, B = backward), pitch "
                 f"{settings.array_pitch_m / UM:g} um")
    save(fig, path)


def response_curves(curves, tones, path, title):
    """Every designed impacter's response band against frequency with all tones marked.

    Forward and backward impacters get a panel each, so neighbouring peaks stay apart.

    Parameters
    ----------
    curves : list of (Node, frequencies [Hz], worst r [N], own frequency [Hz])
        The own frequency should be one of the frequencies (its dot is read off exactly).
    tones : sequence of float
        Every tone of the plan [Hz].
    """
    groups = {}
    for c in curves:
        groups.setdefault(c[0].direction, []).append(c)
    fig, axes = plt.subplots(len(groups), 1, figsize=(10, 3.6 * len(groups) + 0.6),
                             squeeze=False, sharex=True)
    cmap = plt.get_cmap("tab10")
    for ax, (kind, group) in zip(axes[:, 0], groups.items()):
        for i, (_, f, r, own) in enumerate(group):
            color = cmap(i % 10)
            ax.semilogx(f, r * 1e9, color=color, lw=0.9)
            ax.plot([own], [np.interp(own, f, r) * 1e9], "o", color=color, ms=3.5)
        for t in tones:
            ax.axvline(t, color="0.75", lw=0.4, zorder=0)
        ax.set_ylabel("worst r over x0 [nN]")
        ax.set_title(f"{kind} impacters", fontsize=10, loc="left")
        ax.grid(alpha=0.3, which="both")
    axes[-1, 0].set_xlabel("drive frequency [Hz] (grey lines: every tone of the plan)")
    fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    save(fig, path)


def coupling_heatmap(matrix, impacters, tones, path):
    """Cross-coupling: worst response of every impacter (rows) to every tone (columns)."""
    fig, ax = plt.subplots(figsize=(max(6, 0.16 * len(tones) + 3), max(5, 0.16 * len(impacters) + 2)))
    data = np.log10(np.maximum(matrix * 1e9, 1e-3))
    im = ax.imshow(data, aspect="auto", cmap="magma", vmin=-3,
                   vmax=max(float(np.max(data)), -2.0))
    ax.set_yticks(range(len(impacters)))
    ax.set_yticklabels(impacters, fontsize=5)
    ax.set_xticks(range(len(tones)))
    ax.set_xticklabels([f"{t / 1e3:.2f}" for t in tones], rotation=90, fontsize=5)
    ax.set_xlabel("tone [kHz]")
    fig.colorbar(im, ax=ax, label="log10 worst r [nN] (-3: no response)")
    ax.set_title("cross-coupling: impacter x tone\n(bright: each impacter's own tone; no other cell may light up)")
    save(fig, path)


#: Length of drive waveform the drive figure shows [s] (at most one loop).
PLOT_STRETCH = 2e-3


def waveform_and_spectrum(waveform, path, title="", *, peak_limit=None, stretch=PLOT_STRETCH):
    """Save a PNG: a stretch of the drive waveform and its spectrum with the tones marked.

    The one drive figure: the plan's report and ``vibroplan drive --plot`` both draw it.

    Parameters
    ----------
    waveform : Waveform
        The drive.
    path : str or os.PathLike
        PNG file.
    title : str, optional
        Figure title.
    peak_limit : float, optional
        The piezo's limit [m], drawn on the waveform.
    stretch : float, optional
        Length of waveform shown [s] (at most one loop).
    """
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.ticker import FuncFormatter

    fig = Figure(figsize=(9, 6.5), layout="constrained")
    FigureCanvasAgg(fig)
    ax_t, ax_f = fig.subplots(2, 1)

    from planner.synthesis.gating import Burst

    burst = isinstance(waveform, Burst)
    if burst:
        # a gated burst: all of it, its samples joined (the tones' envelopes show)
        n_show = len(waveform.samples)
        ax_t.plot(waveform.times * 1e3, waveform.samples / UM, lw=0.3, color="C0",
                  label=f"samples at {waveform.sample_rate / 1e3:g} kHz, played once")
    else:
        span = min(stretch, waveform.loop_length)
        n_show = int(round(span * waveform.sample_rate))
        t_fine = np.linspace(0, span, max(2000, 20 * n_show))
        ax_t.plot(t_fine * 1e3, waveform.evaluate(t_fine) / UM, lw=0.8, color="C0",
                  label="continuous (sum of cosines)")
        ax_t.plot(waveform.times[:n_show] * 1e3, waveform.samples[:n_show] / UM, ".", ms=2,
                  color="C1", label=f"samples at {waveform.sample_rate / 1e3:g} kHz")
    for sign in (1, -1):
        ax_t.axhline(sign * waveform.peak / UM, color="0.4", ls="--", lw=0.8,
                     label="peak" if sign > 0 else None)
        if peak_limit is not None:
            ax_t.axhline(sign * peak_limit / UM, color="C3", lw=1,
                         label="piezo limit" if sign > 0 else None)
    ax_t.set_xlabel("time [ms]")
    ax_t.set_ylabel("substrate displacement [um]")
    ax_t.set_title(f"{title}  crest factor {waveform.crest_factor:.2f}, scale {waveform.scale:.3f}"
                   + (f", gated burst {waveform.length_s * 1e3:.4g} ms, "
                      f"{int(np.sum(waveform.played))} tones taking turns" if burst else
                      f", loop {waveform.loop_length * 1e3:.4g} ms"))
    ax_t.legend(loc="upper right", fontsize=7, ncol=2)

    loop = waveform.samples[:waveform.loop_points]
    spectrum = 2 * np.abs(np.fft.rfft(loop)) / len(loop)
    bins = np.fft.rfftfreq(len(loop), 1 / waveform.sample_rate)
    floor = spectrum.max() * 1e-9   # rounding noise of the exact sum sits far below this
    ax_f.semilogy(bins[1:], np.maximum(spectrum[1:], floor) / UM, lw=0.6, color="C0",
                  label=("spectrum of the burst" if burst else
                         "spectrum of one loop (bins of 1 / loop)"))
    ax_f.plot(waveform.frequencies, waveform.amplitudes / UM, "x", color="C3", ms=7,
              label="tone table")
    for f in waveform.frequencies:
        ax_f.axvline(f, color="C3", lw=0.4, alpha=0.5)
    ax_f.set_xscale("log")
    lo, hi = waveform.frequencies.min(), waveform.frequencies.max()
    ax_f.set_xlim(lo / 1.5, min(hi * 1.5, waveform.sample_rate / 2))
    ax_f.set_ylim(floor / UM, max(spectrum.max(), waveform.amplitudes.max()) * 3 / UM)
    khz = FuncFormatter(lambda x, _: f"{x / 1e3:g}")
    ax_f.xaxis.set_major_formatter(khz)
    ax_f.xaxis.set_minor_formatter(khz)
    ax_f.tick_params(axis="x", which="minor", labelsize=7)
    ax_f.set_xlabel("frequency [kHz]")
    ax_f.set_ylabel("amplitude [um]")
    ax_f.legend(loc="upper right", fontsize=7)
    fig.savefig(path, dpi=120, format="png")


#: Markers for the rows of an array (A, B, ...) in the slider-position figure.
ROW_MARKERS = "osD^v<>pP*Xh"


def _device_styles(devices):
    """Device id -> (colour, marker): one colour per column, one marker per row, so that
    every device of a grid is told apart (tab10 alone repeats after 10 lines)."""
    cells = {d: _cell(d) for d in devices}
    cols = sorted({c for _, c in cells.values()})
    rows = sorted({r for r, _ in cells.values()})
    cmap = plt.get_cmap("tab10") if len(cols) <= 10 else plt.get_cmap("viridis")
    colour = {c: cmap(i if len(cols) <= 10 else i / max(len(cols) - 1, 1))
              for i, c in enumerate(cols)}
    return {d: (colour[c], ROW_MARKERS[rows.index(r) % len(ROW_MARKERS)])
            for d, (r, c) in cells.items()}


def slider_positions(scene_rows, path):
    """Predicted slider positions after each step of each scene (scene simulation)."""
    scenes = sorted({r["scene"] for r in scene_rows})
    fig, axes = plt.subplots(len(scenes), 1, figsize=(9, 3.2 * len(scenes)), squeeze=False)
    for ax, scene in zip(axes[:, 0], scenes):
        rows = [r for r in scene_rows if r["scene"] == scene]
        steps = [r["step"] for r in rows]
        devices = sorted(rows[0]["positions_m"], key=device_key)
        style = _device_styles(devices)
        for dev in devices:
            y = [0.0] + [r["positions_m"][dev] / UM for r in rows]
            color, marker = style[dev]
            ax.plot(range(len(y)), y, marker=marker, ms=4, lw=0.8, color=color, label=dev)
        ax.set_xticks(range(len(steps) + 1))
        ax.set_xticklabels(["start"] + steps, fontsize=8)
        ax.set_ylabel("slider position [um]")
        ax.set_title(f"scene {scene}: predicted slider positions after each step")
        ax.grid(alpha=0.3)
        if len(devices) <= 100:
            ncol = len({_cell(d)[1] for d in devices})
            # beside the axes: inside, 25 entries hide the lines they name
            ax.legend(fontsize=6, ncol=min(ncol, 10), title="colour: column, marker: row",
                      title_fontsize=6, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    save(fig, path)


def manufacturability(impacters, block, path):
    """Design for yield: each design's line-width sensitivity against its tone (the
    matched band shaded), and the distance from each resonance to the next one up
    against what a collision-free chip needs.

    Parameters
    ----------
    impacters : list of dict
        plan.json's impacter records (``id``, ``frequency_hz``, ``natural_frequency_hz``).
    block : dict
        plan.json's ``manufacturability`` block.
    path : path
        The PNG.
    """
    recs = sorted(impacters, key=lambda r: r["natural_frequency_hz"])
    f = np.array([r["frequency_hz"] for r in recs]) / 1e3
    nu = np.array([r["natural_frequency_hz"] for r in recs])
    s = np.array([block["sensitivity"][r["id"]]["line_width_um"] for r in recs])
    sep = block["separation_hz"]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 3.8))
    band = block.get("sensitivity_band_per_um")
    if band:
        a1.axhspan(band[0], band[1], color="C2", alpha=0.15, label="matched band")
    a1.plot(f, s, "o", ms=4, label="design")
    a1.set_xlabel("tone [kHz]")
    a1.set_ylabel("d ln nu_n / d line width [1/um]")
    a1.set_title("line-width sensitivity")
    a1.legend(fontsize=8)
    gap = np.diff(nu)
    need = np.array([max(sep[recs[k + 1]["id"]]["silent_below"], sep[recs[k]["id"]]["silent_above"])
                     for k in range(len(recs) - 1)])
    mid = 0.5 * (nu[1:] + nu[:-1]) / 1e3
    a2.plot(mid, gap, "o", ms=4, label="designed distance to the next resonance")
    a2.plot(mid, need, "s", ms=3, color="C3", label="wider silent band of the two")
    sig = block.get("pair_sigma_rel")
    if sig:
        a2.errorbar(mid, gap, yerr=3 * sig * nu[1:], fmt="none", ecolor="C0", alpha=0.4,
                    label="+-3 sigma of its scatter")
    a2.set_yscale("log")
    a2.set_xlabel("frequency [kHz]")
    a2.set_ylabel("[Hz]")
    y = block.get("collision_free_yield")
    a2.set_title("neighbours" + (f": predicted collision-free yield {y['value']:.3f}" if y else ""))
    a2.legend(fontsize=7)
    fig.tight_layout()
    save(fig, path)


def target_map(settings, scene, rows, path):
    """A scene's pattern on the array: for each ``targets_um`` step (and the scene's end)
    the position each slider was asked for (left) and how far from it it ended (right,
    red or blue up to the tolerance and beyond).

    Parameters
    ----------
    settings : planner.planning.settings.Settings
        The array's shape and ``position_tolerance_m`` [m].
    scene : str
        The scene's name (the title).
    rows : list of dict
        The scene's rows of :func:`planner.planning.scenes.simulate_scenes`: a driven row
        with ``targets_m`` and ``position_errors_m``, the tail with
        ``expected_positions_m`` and ``final_positions_m``.
    path : path
        The PNG.
    """
    import matplotlib.colors as mcolors

    panels = []
    for r in rows:
        if r.get("targets_m"):
            panels.append((f"after {r['step']}", r["targets_m"], r["positions_m"]))
        elif not r["driven"] and r.get("expected_positions_m"):
            end = ("at the end, drive off", r["expected_positions_m"], r["final_positions_m"])
            # the end only if it says more than the last targets step did
            if not panels or (panels[-1][1], panels[-1][2]) != end[1:]:
                panels.append(end)
    n_rows, n_cols = settings.array_shape
    tolerance = settings.position_tolerance_m
    letters = _row_letters(n_rows)
    asked = [z / UM for _, t, _ in panels for z in t.values()] or [1.0]
    reach = max(1e-9, max(abs(z) for z in asked))
    fig, axes = plt.subplots(len(panels), 2, squeeze=False,
                             figsize=(2 * (0.9 * n_cols + 1.6), 0.8 * n_rows * len(panels) + 1.2))
    pos_norm = mcolors.TwoSlopeNorm(vcenter=0.0, vmin=-reach, vmax=reach)
    err_norm = mcolors.TwoSlopeNorm(vcenter=0.0, vmin=-tolerance / UM, vmax=tolerance / UM)
    for (title, want, got), (ax_t, ax_e) in zip(panels, axes):
        t_grid = np.full((n_rows, n_cols), np.nan)
        e_grid = np.full((n_rows, n_cols), np.nan)
        for dev, z in want.items():
            i, j = _cell(dev)
            t_grid[i, j] = z / UM
            e_grid[i, j] = (got[dev] - z) / UM
        im_t = ax_t.imshow(t_grid, cmap="coolwarm", norm=pos_norm)
        im_e = ax_e.imshow(np.clip(e_grid, -tolerance / UM, tolerance / UM), cmap="PuOr",
                           norm=err_norm)
        for i in range(n_rows):
            for j in range(n_cols):
                if np.isnan(t_grid[i, j]):
                    continue
                ax_t.text(j, i, f"{t_grid[i, j]:+.3g}", ha="center", va="center", fontsize=7)
                off = abs(e_grid[i, j]) > tolerance / UM
                ax_e.text(j, i, f"{e_grid[i, j]:+.2f}", ha="center", va="center", fontsize=7,
                          weight="bold" if off else "normal", color="red" if off else "black")
        for ax, what in ((ax_t, "asked [um]"), (ax_e, "got - asked [um]")):
            ax.set_xticks(range(n_cols))
            ax.set_xticklabels(range(1, n_cols + 1), fontsize=7)
            ax.set_yticks(range(n_rows))
            ax.set_yticklabels(letters, fontsize=7)
            ax.set_title(f"{title}: {what}", fontsize=8)
        fig.colorbar(im_t, ax=ax_t, fraction=0.046, pad=0.04)
        fig.colorbar(im_e, ax=ax_e, fraction=0.046, pad=0.04)
    worst = max((abs(g[d] - z) for _, t, g in panels for d, z in t.items()), default=0.0)
    fig.suptitle(f"scene {scene}: positions asked and got (carried-state simulation); "
                 f"worst error {worst / UM:.2f} um, tolerance {tolerance / UM:g} um",
                 fontsize=9)
    fig.tight_layout()
    save(fig, path)
