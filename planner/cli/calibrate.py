"""``vibroplan calibrate``: as-built natural frequencies and Q from a lab's frequency sweep."""

from __future__ import annotations

from pathlib import Path

import click

from planner.cli._common import (FORCE_FILES_HELP, Finite, check_output_files,
                                 handle_errors, output_file, output_files)


@click.command("calibrate")
@click.argument("sweep_csv", metavar="SWEEP.csv",
                type=click.Path(dir_okay=False, path_type=Path))
@click.option("--motion", is_flag=True,
              help="SWEEP.csv is a speed-against-tone sweep (impacter,frequency_hz,"
                   "speed_mm_s): fit each impacter's working window and write windows.csv "
                   "(for `vibroplan replan --windows`).")
@click.option("--chain", is_flag=True,
              help="SWEEP.csv is a sweep of the drive chain (frequency_hz,input_v,"
                   "displacement_um,phase_deg[,harmonic2_um,harmonic3_um]): fit the "
                   "transfer from the amplifier input to the die, flag its resonances and "
                   "write the drive.chain block (chain.yaml) and its table (chain.csv).")
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), callback=output_file,
              default=None,
              help="The CSV to write: measured.csv (for `vibroplan replan --measured`; the "
                   "default) or, with --motion, windows.csv (for `vibroplan replan "
                   "--windows`; the default) or, with --chain, chain.yaml (the drive.chain "
                   "block; its table goes beside it, NAME.csv). Never the sweep; an existing file only if "
                   "`vibroplan calibrate` wrote it (see --force).")
@click.option("--fraction", type=click.FloatRange(0.0, 1.0, min_open=True, max_open=True),
              default=0.5, show_default=True,
              help="With --motion: a tone is in the working window while its slider moves "
                   "at least this fraction of the sweep's fastest speed.")
@click.option("--min-speed", "min_speed_mm_s", type=Finite(min=0.0), default=0.0,
              show_default=True,
              help="With --motion: ... and at least this speed [mm/s] (e.g. the spec's "
                   "verify.min_speed_mm_s).")
@click.option("--keep-flagged", is_flag=True,
              help="Write flagged impacters' fits too (by default only fits with status ok "
                   "are written, so a doubtful value never reaches a plan).")
@click.option("--force", is_flag=True, help=FORCE_FILES_HELP)
@handle_errors
def command(sweep_csv, motion, chain, out, fraction, min_speed_mm_s, keep_flagged, force):
    """Fit each impacter's natural frequency and Q to a measured frequency sweep
    (or, with --motion, its working window to a speed-against-tone sweep).

    Measure each impacter's vibration amplitude relative to the die (vibrometer,
    fibre-optic sensor or camera, as in the paper's Section IV) over drive
    frequencies across its resonance, with a drive small enough that it never
    touches its slider (the linear regime).  The fit is to

    \b
      |X| = s u^2 / sqrt((1 - u^2)^2 + (u/Q)^2),  u = f / nu_n  (eqs. 1, 5)
    on log amplitude, with standard errors from the Jacobian.

    \b
    SWEEP.csv: header, then one row per measurement (any column order; blank
    lines and lines starting with # are skipped):
      impacter            name, as the plan's impacter table has it
      frequency_hz        drive frequency [Hz], > 0
      amplitude_um        impacter amplitude relative to the die, half the
                          peak-to-peak [um], >= 0 (zeros are left out)
      drive_amplitude_um  optional: the die's amplitude Z at that frequency
                          [um], > 0.  With it the fit is to |X|/Z and s
                          estimates cos(theta); without it the drive amplitude
                          is assumed the SAME at every frequency and s = Z
                          cos(theta) [um] is fitted.  A sweep at constant
                          power (Z^2 w^3 fixed) needs this column.
      half                optional: a or b, one cantilever of the pair, each
                          fitted on its own (blank: the pair as a whole; a
                          pair is measured one way or the other, not both)
    Other columns are errors (a misspelt unit would otherwise be ignored).
    Each impacter needs at least 5 distinct frequencies; in practice measure
    30-60, at least 3 of them inside the half-power band f_n (1 +- 1/(2Q)).

    \b
    measured.csv: impacter,natural_frequency_hz,quality_factor,
                  natural_frequency_std_hz,quality_factor_std[,half]
    (frequencies [Hz], Q [-], std = one standard error; half when the sweep
    has it, which vibroplan replan reads as the pair's two halves).

    A fit is flagged, and by default not written, when the peak is at or beyond
    the sweep's end, fewer than 3 points lie in the half-power band, Q is not
    determined by the data, or the scatter exceeds 10 %.  A malformed file is
    an error naming its row (line in the file) and column; nothing is written.

    \b
    With --motion, SWEEP.csv is a tuning sweep on the fabricated chip: a few
    tones around each re-planned tone (plan.json's impacters give each tone
    and the window its design answers over, tone_window_hz), played one
    impacter at a time, the slider watched (camera, as in the paper):
      impacter            name, as the plan's impacter table has it
      frequency_hz        the tone [Hz]
      speed_mm_s          the slider's mean speed in the direction the
                          impacter drives it [mm/s] (backward impacters:
                          moving backward reads positive; wrong way, negative)
    At least 3 distinct tones per impacter; 7 spanning the designed window
    2.5 times either side of the tone see both its edges.  The working window
    is the run of tones around the fastest one at which the slider moves at
    least --fraction of that speed (and --min-speed), its edges interpolated.
    A window is flagged, and by default not written, when no tone moves the
    slider or the window reaches the sweep's end (sweep wider).

    \b
    windows.csv: impacter,window_lo_hz,window_hi_hz,peak_hz,peak_speed_mm_s,
                 points,status

    \b
    With --chain, SWEEP.csv is a sweep of the drive chain (generator, amplifier,
    piezo) with a vibrometer on the substrate, one tone at a time:
      frequency_hz        the tone [Hz]
      input_v             its amplitude at the amplifier input [V]
      displacement_um     the substrate's displacement amplitude [um]
      phase_deg           its phase against the input [deg] (a lag < 0)
      harmonic2_um        optional: the displacement's 2nd harmonic [um]
      harmonic3_um        optional: its 3rd harmonic [um]
    The transfer (displacement / input) is written as a table, chain.csv
    (frequency_hz,gain_um_per_v,phase_deg; repeats averaged), and a flat gain
    with one resonance per peak of the gain (and a low-pass if it fits much
    better) is fitted to it: each resonance is printed with its frequency and
    Q.  chain.yaml is the drive.chain block a spec takes (transfer: chain.csv,
    relative to the spec: keep the two side by side), with the harmonics'
    levels at the sweep's largest displacement and the fitted model as a
    comment.  A spec's drive.band_hz must lie inside the swept range.

    \b
    Examples:
      vibroplan calibrate sweep.csv --out measured.csv
      vibroplan calibrate --motion motion.csv --out windows.csv
      vibroplan calibrate --chain chain_sweep.csv --out chain.yaml
      vibroplan replan plan_out --measured measured.csv --windows windows.csv
    """
    if motion and chain:
        raise click.UsageError("--motion and --chain are two kinds of sweep: give one")
    if chain:
        _chain(sweep_csv, out or Path("chain.yaml"), force)
        return
    if motion:
        _motion(sweep_csv, out or Path("windows.csv"), fraction, min_speed_mm_s,
                keep_flagged, force)
        return
    out = out or Path("measured.csv")
    from planner.lab.calibrate import calibrate, read_sweep, write_measured

    check_output_files("calibrate", [("--out", out)], inputs=[sweep_csv], force=force)
    sweep = read_sweep(sweep_csv)
    fits = calibrate(sweep)
    # the fitted scale is cos(theta) when |X|/Z was fitted, else Z cos(theta)
    if "drive_amplitude_m" in sweep.columns:
        scale_text = "cos(theta) = {:.4g}".format
    else:
        scale_text = lambda s: f"Z cos(theta) = {s * 1e6:.4g} um"  # noqa: E731
    halves = "half" in fits.columns
    labels = [f"{n} ({h})" if halves and h else str(n)
              for n, h in zip(fits["impacter"], fits["half"] if halves else fits["impacter"])]
    width = max(len(x) for x in labels)
    for label, fit in zip(labels, fits.itertuples(index=False)):
        name = f"{label}:".ljust(width + 1)
        if fit.status == "fit_failed":
            click.echo(f"{name} no fit [{fit.status}]")
        else:
            click.echo(f"{name} nu_n = {fit.natural_frequency_hz:.2f} +- "
                       f"{fit.natural_frequency_std_hz:.2g} Hz, Q = {fit.quality_factor:.4g} +- "
                       f"{fit.quality_factor_std:.2g}, {scale_text(fit.scale)} "
                       f"({fit.n_points} points, {fit.n_peak_points} in the "
                       f"half-power band, scatter {fit.residual_rms:.2%}) [{fit.status}]")
        if fit.status != "ok":
            click.echo(f"warning: {label}: {fit.message}", err=True)

    ok = fits["status"] == "ok"
    keep = fits if keep_flagged else fits[ok]
    keep = keep[keep["status"] != "fit_failed"]
    flagged = fits[~ok]
    summary = f"{int(ok.sum())} of {len(fits)} impacters fitted ok"
    if len(flagged):
        names = ", ".join(f"{n} ({s})" for n, s in zip(flagged["impacter"], flagged["status"]))
        summary += f"; flagged: {names}"
        summary += "" if keep_flagged else " (not written; --keep-flagged writes them)"
    click.echo(summary)
    if keep.empty:
        raise click.ClickException(f"no usable fit: {out} not written")
    with output_files([out], command="calibrate", inputs=[sweep_csv], force=force) as (tmp,):
        write_measured(keep, tmp)
    click.echo(f"wrote {out} ({len(keep)} impacter{'s' if len(keep) != 1 else ''})")


def _motion(sweep_csv, out, fraction, min_speed_mm_s, keep_flagged, force):
    """``calibrate --motion``: working windows fitted to a speed-against-tone sweep."""
    from planner.afterfab.tune import MM, fit_windows, read_motion, write_windows

    check_output_files("calibrate", [("--out", out)], inputs=[sweep_csv], force=force)
    rows = read_motion(sweep_csv)
    fitted = fit_windows(rows, fraction=fraction, min_speed=min_speed_mm_s * MM)
    width = max(len(n) for n in fitted)
    for name, w in fitted.items():
        label = f"{name}:".ljust(width + 1)
        if w.peak_speed_m_s > 0 and w.status != "no tone moves its slider":
            click.echo(f"{label} window {w.lo_hz:.1f}-{w.hi_hz:.1f} Hz ({w.hi_hz - w.lo_hz:.1f}"
                       f" Hz wide, middle {w.middle_hz:.1f} Hz), fastest "
                       f"{w.peak_speed_m_s / MM:.3g} mm/s at {w.peak_hz:.1f} Hz "
                       f"({w.points} tones) [{w.status}]")
        else:
            click.echo(f"{label} no window ({w.points} tones) [{w.status}]")
        if not w.ok:
            click.echo(f"warning: {name}: {w.status}", err=True)
    ok = {n: w for n, w in fitted.items() if w.ok}
    flagged = {n: w for n, w in fitted.items() if not w.ok}
    keep = {n: w for n, w in fitted.items()
            if w.ok or (keep_flagged and w.status != "no tone moves its slider")}
    summary = f"{len(ok)} of {len(fitted)} windows fitted ok"
    if flagged:
        summary += "; flagged: " + ", ".join(f"{n} ({w.status})" for n, w in flagged.items())
        summary += "" if keep_flagged else " (not written; --keep-flagged writes them)"
    click.echo(summary)
    if not keep:
        raise click.ClickException(f"no usable window: {out} not written")
    with output_files([out], command="calibrate", inputs=[sweep_csv], force=force) as (tmp,):
        write_windows(keep, tmp)
    click.echo(f"wrote {out} ({len(keep)} window{'s' if len(keep) != 1 else ''})")


def _chain(sweep_csv, out, force):
    """``calibrate --chain``: the drive chain fitted to a sweep; chain.yaml and its
    table beside it."""
    from planner.lab.chain_sweep import chain_yaml, fit_sweep, read_chain_sweep, write_table

    table = out.with_suffix(".csv")
    check_output_files("calibrate", [("--out", out), ("the table", table)],
                       inputs=[sweep_csv], force=force)
    cal = fit_sweep(read_chain_sweep(sweep_csv))
    fit = cal.fit
    click.echo(f"{len(fit.frequency_hz)} frequencies, {fit.frequency_hz[0]:g}-"
               f"{fit.frequency_hz[-1]:g} Hz; gain at the lowest "
               f"{abs(fit.response[0]) * 1e6:.4g} um/V")
    for r in fit.resonances:
        click.echo(f"resonance: {r['frequency_hz']:.1f} +- {r['frequency_std_hz']:.2g} Hz, "
                   f"Q = {r['q']:.4g} +- {r['q_std']:.2g} (gain peak at {r['peak_hz']:.1f} Hz)")
    if not fit.resonances:
        click.echo("no resonance found in the sweep")
    if fit.model.low_pass_hz is not None:
        click.echo(f"low-pass: {fit.model.low_pass_hz:.4g} Hz")
    click.echo(f"model fit: rms {fit.gain_rms:.2%} in gain, "
               f"{fit.phase_rms * 57.29577951308232:.2g} deg in phase")
    for order, level in cal.harmonics_db.items():
        click.echo(f"harmonic {order}: {level:.1f} dB at {cal.stroke_m * 1e6:.4g} um")
    with output_files([out, table], command="calibrate", inputs=[sweep_csv],
                      force=force) as (tmp_yaml, tmp_table):
        write_table(fit, tmp_table)
        Path(tmp_yaml).write_text(chain_yaml(cal, table.name))
    click.echo(f"wrote {out} and {table} (the drive.chain block and its table)")
