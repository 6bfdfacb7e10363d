"""``vibroplan sweep``: response against frequency and initial position (Fig. 9)."""

from __future__ import annotations

import click

from planner.cli._common import atomic_path, handle_errors

UM = 1e-6
#: Frequencies per parallel batch; the progress bar advances once per batch.
CHUNK = 64


def _floats(text):
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise click.BadParameter(f"expected comma-separated numbers, got {text!r}") from None


@click.command("sweep", short_help="Sweep the response r (eq. 12) over frequency and initial position.")
@click.argument("config", type=click.Path(dir_okay=False))
@click.option("--from", "f_from", type=float, required=True, help="First frequency [Hz].")
@click.option("--to", "f_to", type=float, required=True, help="Last frequency [Hz] (included).")
@click.option("--step", "f_step", type=float, required=True, help="Frequency step [Hz].")
@click.option("--x0", "x0_text", default="0", show_default=True,
              help="Initial positions [um], comma-separated, e.g. 0,1,2,3 (v0 = 0).")
@click.option("--duration", "duration_ms", type=float, default=None,
              help="Window [ms] (default: the config's, 3 ms).")
@click.option("--pair", type=click.Choice(["forward", "backward"]), default="forward",
              show_default=True)
@click.option("--out", type=click.Path(dir_okay=False), required=True,
              help="CSV to write: frequency_hz and one r column [N] per x0.")
@click.option("--plot", type=click.Path(dir_okay=False), default=None,
              help="Write a Fig. 9-style PNG of r against frequency.")
@click.option("--quiet", is_flag=True, help="No progress bar.")
@handle_errors
def command(config, f_from, f_to, f_step, x0_text, duration_ms, pair, out, plot, quiet):
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
    from planner.config import load_device

    if f_step <= 0:
        raise ValueError(f"--step must be > 0, {f_step!r} was given")
    if f_to < f_from:
        raise ValueError(f"--to ({f_to}) must be >= --from ({f_from})")
    if f_from <= 0:
        raise ValueError(f"--from must be > 0, {f_from!r} was given")
    x0_um = _floats(x0_text)
    device = load_device(config)
    impacter = device.impacter(pair)
    if max(x0_um) * UM > impacter.gap:
        raise ValueError(f"--x0 values must be <= the gap, {impacter.gap / UM:g} um")
    duration = (device.config.simulation.duration_ms if duration_ms is None else duration_ms) * 1e-3
    n = int(np.floor((f_to - f_from) / f_step + 1e-9)) + 1
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
    with atomic_path(out) as tmp:
        frame.to_csv(tmp, index=False, float_format="%.10g")
    if plot:
        from planner.plots import frequency_response

        with atomic_path(plot) as tmp:
            frequency_response(freqs, r, x0s, tmp, natural_frequency=impacter.natural_frequency,
                               title=f"{device.config.name or config}: {pair} pair")
    click.echo(f"{n} frequencies x {x0s.size} initial positions -> {out}")
    for j, x in enumerate(x0_um):
        col = r[:, j]
        if np.any(col > 0):
            peak = int(np.argmax(col))
            click.echo(f"  x0 = {x:g} um: peak r = {col[peak] * 1e9:.4g} nN at "
                       f"{freqs[peak]:.1f} Hz; responds over {freqs[col > 0].min():.1f}-"
                       f"{freqs[col > 0].max():.1f} Hz")
        else:
            click.echo(f"  x0 = {x:g} um: no response in the range")
    if plot:
        click.echo(f"wrote {plot}")
