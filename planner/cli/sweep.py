"""``vibroplan sweep``: response against frequency and initial position (Fig. 9)."""

from __future__ import annotations

import math

import click

from planner.cli._common import (FORCE_FILES_HELP, Finite, check_output_files, handle_errors,
                                 output_file, output_files)

from planner.core.units import UM  # noqa: E402
#: Frequencies per parallel batch; the progress bar advances once per batch.
CHUNK = 64
#: Memory per cell of the response table [bytes]: the float64 table, the DataFrame's copy
#: and its CSV text (an upper estimate).
SWEEP_BYTES_PER_CELL = 64


def _floats(text):
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        values = []
    if not values or not all(math.isfinite(v) for v in values):
        raise click.BadParameter(f"expected comma-separated finite numbers, got {text!r}",
                                 param_hint="'--x0'")
    return values


#: The response has collapsed (Fig. 9's bifurcation) where r falls below this fraction
#: of its peak; what responds beyond is a weaker residual orbit, reported apart.
COLLAPSE_FRACTION = 0.5


def response_band(freqs, r):
    """Where an impacter responds, as Fig. 9 shows it: a band that collapses.

    Returns ``(lo, collapse, residual)``: the lowest frequency [Hz] of the responding
    run that leads up to the peak, the first swept frequency above the peak where r
    falls below :data:`COLLAPSE_FRACTION` of the peak (None if it never does in the
    sweep), and the frequencies outside ``[lo, collapse)`` that still respond (weaker
    residual orbits, e.g. chattering or subharmonic ones).  None if nothing responds.
    """
    import numpy as np

    freqs = np.asarray(freqs)
    r = np.asarray(r)
    on = r > 0
    if not on.any():
        return None
    peak = int(np.argmax(r))
    lo = peak
    while lo > 0 and on[lo - 1]:
        lo -= 1
    above = np.nonzero(r[peak:] < COLLAPSE_FRACTION * r[peak])[0]
    hi = peak + int(above[0]) if above.size else r.size
    outside = on.copy()
    outside[lo:hi] = False
    return float(freqs[lo]), (float(freqs[hi]) if hi < r.size else None), freqs[outside]


def _describe(freqs, col):
    import numpy as np

    band = response_band(freqs, col)
    if band is None:
        return "no response in the range"
    lo, collapse, residual = band
    peak = int(col.argmax())
    text = f"peak r = {col[peak] * 1e9:.4g} nN at {freqs[peak]:.1f} Hz; responds from {lo:.1f} Hz"
    text += (f", collapses at {collapse:.1f} Hz" if collapse is not None else
             " to the end of the sweep")
    if residual.size:
        mask = np.isin(freqs, residual)
        text += (f"; residual response outside that band at {residual.size} frequencies in "
                 f"{residual.min():.1f}-{residual.max():.1f} Hz, up to "
                 f"{col[mask].max() * 1e9:.3g} nN")
    return text


@click.command("sweep", short_help="Sweep the response r (eq. 12) over frequency and initial position.")
@click.argument("config", type=click.Path(dir_okay=False))
@click.option("--from", "f_from", type=Finite(min=0, min_open=True), required=True,
              help="First frequency [Hz].")
@click.option("--to", "f_to", type=Finite(min=0, min_open=True), required=True,
              help="Last frequency [Hz] (included).")
@click.option("--step", "f_step", type=Finite(min=0, min_open=True), required=True,
              help="Frequency step [Hz]. A sweep whose response table would not fit in "
                   "memory is refused before any work, with the figure.")
@click.option("--x0", "x0_text", default="0", show_default=True,
              help="Initial positions [um], comma-separated, e.g. 0,1,2,3 (v0 = 0).")
@click.option("--duration", "duration_ms", type=Finite(min=0, min_open=True), default=None,
              help="Window [ms] (default: the config's, 3 ms).")
@click.option("--pair", type=click.Choice(["forward", "backward"]), default="forward",
              show_default=True)
@click.option("--out", type=click.Path(dir_okay=False), callback=output_file, required=True,
              help="CSV to write: frequency_hz and one r column [N] per x0. Never the "
                   "config; an existing file only if `vibroplan sweep` wrote it (see "
                   "--force).")
@click.option("--plot", type=click.Path(dir_okay=False), callback=output_file, default=None,
              help="Write a Fig. 9-style PNG of r against frequency.")
@click.option("--quiet", is_flag=True, help="No progress bar.")
@click.option("--force", is_flag=True, help=FORCE_FILES_HELP)
@handle_errors
def command(config, f_from, f_to, f_step, x0_text, duration_ms, pair, out, plot, quiet, force):
    """Sweep the response r of eq. (12) over frequency and initial position.

    \b
    Example (the paper's Fig. 9):
      vibroplan sweep configs/paper_fig7.yaml --from 4000 --to 9000 --step 10 \\
          --x0 0,1,2,3 --out fig9.csv --plot fig9.png
    """
    import numpy as np
    import pandas as pd
    from tqdm import tqdm

    from model import sweep
    from planner.runtime.limits import check_memory
    from planner.config import load_device

    if f_to < f_from:
        raise ValueError(f"--to ({f_to}) must be >= --from ({f_from})")
    check_output_files("sweep", [("--out", out), ("--plot", plot)], inputs=[config],
                       force=force)
    n = int(np.floor((f_to - f_from) / f_step + 1e-9)) + 1
    x0_um = _floats(x0_text)
    # the response table, its CSV and the frame behind it: a few copies of n x (x0 + 1)
    check_memory(SWEEP_BYTES_PER_CELL * n * (len(x0_um) + 1),
                 f"--from {f_from:g} --to {f_to:g} --step {f_step:g}: {n:.4g} frequencies x "
                 f"{len(x0_um)} initial positions")
    device = load_device(config)
    impacter = device.impacter(pair)
    if max(x0_um) * UM > impacter.gap:
        raise ValueError(f"--x0 values must be <= the gap, {impacter.gap / UM:g} um")
    duration = (device.config.simulation.duration_ms if duration_ms is None else duration_ms) * 1e-3
    freqs = f_from + f_step * np.arange(n)
    x0s = np.array(x0_um) * UM
    power = device.config.drive.power_m2_s3
    if device.config.drive.amplitude_um is not None:
        raise ValueError("sweep uses the power convention: drive.amplitude_um is not supported "
                         "(set drive.power_m2_s3)")
    r = np.empty((n, x0s.size))
    with tqdm(total=n, unit="freq", disable=quiet, desc="sweep") as bar:
        for start in range(0, n, CHUNK):
            stop = min(start + CHUNK, n)
            r[start:stop] = sweep(impacter, freqs[start:stop], x0s, power, duration)
            bar.update(stop - start)
    frame = pd.DataFrame({"frequency_hz": freqs})
    for j, x in enumerate(x0_um):
        frame[f"r_n_x0_{x:g}um"] = r[:, j]
    with output_files([out], command="sweep", inputs=[config], force=force) as (tmp,):
        frame.to_csv(tmp, index=False, float_format="%.10g")
    if plot:
        from planner.figures.device import frequency_response

        with output_files([plot], command="sweep", inputs=[config], force=force) as (tmp,):
            frequency_response(freqs, r, x0s, tmp, natural_frequency=impacter.natural_frequency,
                               title=f"{device.config.name or config}: {pair} pair")
    click.echo(f"{n} frequencies x {x0s.size} initial positions -> {out}")
    for j, x in enumerate(x0_um):
        click.echo(f"  x0 = {x:g} um: " + _describe(freqs, r[:, j]))
    if plot:
        click.echo(f"wrote {plot}")
