"""``vibroplan replan``: a new drive for a fabricated chip from its measured resonances."""

from __future__ import annotations

import inspect
import sys
from pathlib import Path

import click

from planner.cli._common import EXIT_CODES_HELP, chip_inputs, handle_errors


@click.command("replan")
@click.argument("plan_path", metavar="PLAN", type=click.Path(path_type=Path))
@click.option("--measured", "measured_path", default=None,
              type=click.Path(dir_okay=False, path_type=Path),
              help="measured.csv: impacter,natural_frequency_hz[,quality_factor][,gap_um] "
                   "(e.g. from `vibroplan calibrate`); or a whole wafer's file: a CSV "
                   "with die_x,die_y in front of those columns, or a tester's STDF V4 "
                   "file (every die re-planned in batch).")
@click.option("--measured-dir", "measured_dir", default=None,
              type=click.Path(file_okay=False, path_type=Path),
              help="A wafer as a folder of one measured.csv per die, named "
                   "die_<x>_<y>.csv (its grid indices): every die re-planned in batch.")
@click.option("--trim", is_flag=True,
              help="A wafer: trim the dies whose impacters no drive tells apart "
                   "(vibroplan trim) and re-plan them.")
@click.option("--jobs", type=int, default=None,
              help="A wafer: local Dask worker processes, at most the cores [default: "
                   "every core; 1 runs in this process].")
@click.option("--scheduler", default=None, metavar="ADDRESS",
              help="A wafer: run the dies on an existing dask.distributed scheduler "
                   "(overrides --jobs); checked before any work.")
@click.option("--test-map", "test_map", default=None,
              type=click.Path(dir_okay=False, path_type=Path),
              help="An STDF wafer: test_name,impacter[,half] CSV naming the tests that "
                   "measure each resonance [default: the test named by the impacter's "
                   "id, e.g. A1.forward, or A1.forward:a for a half].")
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
def command(plan_path, measured_path, windows_path, measured_dir, trim, jobs, scheduler, test_map,
            out_dir, force, seed, no_figures, quiet):
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

    A wafer (--measured WAFER.csv with die_x,die_y columns, a tester's STDF V4 file,
    or --measured-dir) is re-planned die by die on Dask (--jobs, --scheduler), with
    --trim trimming the dies no drive can tell apart; OUT/ then holds dies/die_<x>_<y>/
    (each die's drive files, trim.csv), summary.csv (one line per die: as designed,
    after re-plan, after trim, scrapped, or partly measured when its file leaves an
    impacter out, with the causes), report.md and
    wafer_map.png; exit 1 when a die is scrapped.  Each die is kept as it finishes in
    .OUT.dies/ beside OUT: run the same command again after an interruption and the
    finished dies are read back, not redone.

    {EXIT}
    """
    from planner.files import output_folder
    from planner.afterfab.replan import outside_band_message, replan, write_replan_outputs

    if (measured_path is None) == (measured_dir is None):
        raise click.UsageError("give the measurement: --measured FILE (a chip's "
                               "measured.csv or a wafer's file) or --measured-dir DIR")
    if test_map is not None and (measured_path is None or not _is_stdf(measured_path)):
        raise click.UsageError("--test-map needs --measured with a tester's STDF file (it "
                               "names that file's tests); "
                               + (f"--measured {measured_path} is not one" if measured_path
                                  else "--measured-dir holds CSV files"))
    if measured_dir is not None or _is_wafer(measured_path):
        from planner.cli._batch import replan_wafer_command

        if windows_path is not None:
            raise click.UsageError("--windows is one chip's tuning sweep (vibroplan "
                                   "calibrate --motion); a wafer is re-planned from its "
                                   "resonances only")

        return replan_wafer_command(plan_path, measured_path or measured_dir, out_dir,
                                    trim=trim, jobs=jobs, scheduler=scheduler,
                                    test_map=test_map, seed=seed, force=force,
                                    quiet=quiet)
    for flag, given in (("--trim", trim), ("--jobs", jobs is not None),
                        ("--scheduler", scheduler), ("--test-map", test_map)):
        if given:
            raise click.UsageError(f"{flag} applies to a wafer (--measured with die_x,die_y "
                                   "columns or an STDF file, or --measured-dir); one chip is "
                                   "trimmed by `vibroplan trim`")
    plan, measured, inputs, progress = chip_inputs(plan_path, measured_path, out_dir,
                                                   command="replan", force=force, quiet=quiet,
                                                   windows_path=windows_path)

    with output_folder(out_dir, command="replan", inputs=inputs, force=force) as tmp:
        result = replan(plan, measured, seed=seed, progress=progress)
        write_replan_outputs(result, tmp, figures=not no_figures)
    rp = result.replan
    od = rp.original_drive
    missing = sorted(set(plan.impacter_ids) - set(measured))
    if missing:
        click.echo(f"warning: not measured, taken as designed: {', '.join(missing)}", err=True)
    big = max(rp.moved, key=lambda m: abs(m.tone_shift))
    click.echo(f"{plan.spec.name}: {len(result.plan_file.impacters)} impacters re-planned; "
               f"largest tone shift {big.id} {100 * big.tone_shift:+.2f} %")
    click.echo(f"original drive on this chip: {'PASSES' if od.passed else 'FAILS'} "
               f"({od.checks - od.failed_checks}/{od.checks} checks)")
    if rp.outside_band:
        click.echo(f"error: {outside_band_message(rp, result.settings.band_hz)}", err=True)
    for key, subs in rp.split_steps.items():
        click.echo(f"note: {key} plays as {len(subs)} sub-steps ({', '.join(subs)}): the "
                   "acceleration limit would have weakened its tones", err=True)
    for c in rp.inseparable:
        click.echo(f"error: {c.message}", err=True)
    ver = result.verification
    click.echo(f"re-planned drive: {'PASSED' if result.passed else 'FAILED'} "
               f"({int(ver['passed'].sum())}/{len(ver)} checks); wrote {out_dir}/ "
               f"(see {out_dir}/report.md)")
    if not result.passed:
        sys.exit(1)


def _is_stdf(path) -> bool:
    """Whether ``path`` is a regular file that begins as an STDF V4 file."""
    from planner.afterfab.wafer_file import is_stdf

    try:
        return Path(path).is_file() and is_stdf(path)
    except OSError:
        return False


def _is_wafer(path) -> bool:
    """Whether ``path`` is a wafer's file; only a regular file is looked into (a FIFO
    would block the sniff: the chip's reader refuses it with exit 2)."""
    from planner.afterfab.wafer_file import is_stdf, is_wafer_csv

    try:
        if not Path(path).is_file():
            return False
    except OSError:
        return False
    return is_stdf(path) or is_wafer_csv(path)


# cleandoc: click keeps the docstring's indentation when help is assigned like this
command.help = inspect.cleandoc(command.help).replace("{EXIT}", EXIT_CODES_HELP)
