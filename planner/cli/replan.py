"""``vibroplan replan``: a new drive for a fabricated chip from its measured resonances."""

from __future__ import annotations

import inspect
import sys
from pathlib import Path

import click

from planner.cli._common import EXIT_CODES_HELP, chip_inputs, handle_errors


@click.command("replan")
@click.argument("plan_path", metavar="PLAN", type=click.Path(path_type=Path))
@click.option("--measured", "measured_path", required=True,
              type=click.Path(dir_okay=False, path_type=Path),
              help="measured.csv: impacter,natural_frequency_hz[,quality_factor][,gap_um] "
                   "(e.g. from `vibroplan calibrate`).")
@click.option("--windows", "windows_path", type=click.Path(dir_okay=False, path_type=Path),
              default=None,
              help="windows.csv of a tuning sweep on the chip (`vibroplan calibrate "
                   "--motion`): each tone goes to the middle of its impacter's working "
                   "window, where that stays clear of every silent band it must avoid.")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default="replan_out",
              show_default=True,
              help="Output folder: a new or empty folder, or one an earlier `vibroplan "
                   "replan` wrote and nothing else was added to (a folder with files it did "
                   "not write is refused, not emptied). Never the current directory, the "
                   "plan's folder or another command's output folder.")
@click.option("--force", is_flag=True,
              help="Replace --out even if vibroplan did not write it, another command "
                   "wrote it, or it holds files `vibroplan replan` did not write (they are "
                   "deleted).")
@click.option("--seed", type=click.IntRange(min=0), default=None, help="Drive phases' seed (default: the plan's).")
@click.option("--no-figures", is_flag=True, help="Skip the PNG figures (faster).")
@click.option("--quiet", is_flag=True, help="No progress output.")
@handle_errors
def command(plan_path, measured_path, windows_path, out_dir, force, seed, no_figures, quiet):
    """Re-plan the drive of a fabricated chip from its measured resonances.

    PLAN is a `vibroplan plan` (or `vibroplan replan`) output folder or its plan.json,
    checked as a whole first: a missing or mistyped key, a plan of another format, or
    numbers that contradict each other (an edited natural frequency) are refused
    naming the key (exit 2).  Each impacter's
    as-built model is rebuilt through eqs. (2)-(4) from the fabrication errors the
    measured resonances imply under the spec's tolerances (mass, stiffness, damping,
    gap and sliders), each resonance exactly as measured; a quality factor sets
    b = m 2 pi nu_n / Q.  The designs are fixed: each impacter's tone moves with its
    resonance (scaled by measured / designed nu_n).  Every pair the steps must tell
    apart is checked against the plan's measured silent bands and tone windows; a
    multi-tone step that drive.max_acceleration_g would weaken beyond the plan's
    verified drive is split into sub-steps of neighbouring tones; bursts asked as a
    travel are sized for the as-built speeds; the drive is verified on the as-built
    models and its motion repaired (shorter bursts, longer dwells) as a plan's.

    \b
    measured.csv: header, then one row per impacter (any column order):
      impacter              name, as in the plan (e.g. A1.forward)
      natural_frequency_hz  measured nu_n [Hz], > 0
      quality_factor        optional, Q [-], > 0
      gap_um                optional, measured gap [um], > 0
      half                  optional, a or b: one row per half of a pair whose two
                            cantilevers were measured apart (both rows then)
    Columns ending in _std (calibrate's uncertainties) are ignored; an impacter
    without a row keeps its design.  A malformed file is an error naming its row
    and column (exit 2, nothing written).

    Writes OUT/ as `vibroplan plan` does (plan.json with `as_built` and `replan`,
    report.md, waveforms/, CSVs, figures/).  The report says what moved and whether
    the ORIGINAL drive would have failed on this chip.  Impacters no drive can tell
    apart are named with their as-built resonances and the separation they would
    need, and the re-plan fails (exit 1): trim one of them (vibroplan trim).

    {EXIT}
    """
    from planner._io import output_folder
    from planner.afterfab.replan import replan, write_replan_outputs

    plan, measured, inputs, progress = chip_inputs(plan_path, measured_path, out_dir,
                                                   command="replan", force=force, quiet=quiet,
                                                   windows_path=windows_path)

    with output_folder(out_dir, command="replan", inputs=inputs, force=force) as tmp:
        result = replan(plan, measured, seed=seed, progress=progress)
        write_replan_outputs(result, tmp, figures=not no_figures)
    d = result.data
    rp = d["replan"]
    od = rp["original_drive"]
    missing = sorted(set(plan.impacter_ids) - set(measured))
    if missing:
        click.echo(f"warning: not measured, taken as designed: {', '.join(missing)}", err=True)
    big = max(rp["moved"], key=lambda m: abs(m["tone_shift"]))
    click.echo(f"{d['spec']['name']}: {len(d['impacters'])} impacters re-planned; largest tone "
               f"shift {big['id']} {100 * big['tone_shift']:+.2f} %")
    click.echo(f"original drive on this chip: {'PASSES' if od['passed'] else 'FAILS'} "
               f"({od['checks'] - od['failed_checks']}/{od['checks']} checks)")
    if rp.get("outside_band"):
        click.echo("warning: the as-built resonance moved the tone of "
                   f"{', '.join(rp['outside_band'])} outside the drive band "
                   f"{d['spec']['drive']['band_hz']} Hz: driven at the band edge", err=True)
    for key, subs in rp.get("split_steps", {}).items():
        click.echo(f"note: {key} plays as {len(subs)} sub-steps ({', '.join(subs)}): the "
                   "acceleration limit would have weakened its tones", err=True)
    for c in rp["inseparable"]:
        click.echo(f"error: {c['message']}", err=True)
    ver = result.verification
    click.echo(f"re-planned drive: {'PASSED' if result.passed else 'FAILED'} "
               f"({int(ver['passed'].sum())}/{len(ver)} checks); wrote {out_dir}/ "
               f"(see {out_dir}/report.md)")
    if not result.passed:
        sys.exit(1)


# cleandoc: click keeps the docstring's indentation when help is assigned like this
command.help = inspect.cleandoc(command.help).replace("{EXIT}", EXIT_CODES_HELP)
