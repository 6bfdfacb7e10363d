"""``vibroplan trim``: trims that make a fabricated chip's resonances separable, and its drive."""

from __future__ import annotations

import inspect
import sys
from pathlib import Path

import click

from planner.cli._common import EXIT_CODES_HELP, chip_inputs, handle_errors


@click.command("trim")
@click.argument("plan_path", metavar="PLAN", type=click.Path(path_type=Path))
@click.option("--measured", "measured_path", required=True,
              type=click.Path(dir_okay=False, path_type=Path),
              help="measured.csv of the chip, as `vibroplan replan` reads it "
                   "(impacter,natural_frequency_hz[,quality_factor][,gap_um][,half]).")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default="trim_out",
              show_default=True,
              help="Output folder (the same rules as `vibroplan plan --out`).")
@click.option("--seed", type=click.IntRange(min=0), default=None,
              help="Seeds the trims' errors (trim.precision_pct) and the drive's phases "
                   "(default: the plan's).")
@click.option("--force", is_flag=True,
              help="Replace --out even if it is a non-empty folder vibroplan did not write.")
@click.option("--no-figures", is_flag=True, help="Skip the PNG figures (faster).")
@click.option("--quiet", is_flag=True, help="No progress output.")
@handle_errors
def command(plan_path, measured_path, out_dir, seed, force, no_figures, quiet):
    """Trim a fabricated chip so that every pair of impacters can be told apart again.

    PLAN is the `vibroplan plan` folder (or plan.json) the chip was made by.  A trim
    moves a resonance one way only, by at most trim.range_pct of the spec (default
    1 %): direction `up` removes plate mass (the layout's trim tabs), `down` frees a
    length of beam from its anchor.  From the measured resonances the command chooses
    the fewest and smallest moves that make every pair the steps must tell apart
    separable (by the plan's measured silent bands and tone windows, with a margin of
    two trim.precision_pct sigmas), and writes what to cut:

    \b
    OUT/trim.csv: impacter,measured_hz,target_hz,change_pct,cut_area_um2,cut_length_um
      (zeros for an impacter left as it is)

    It then re-plans the drive for the trimmed chip (as `vibroplan replan` does, from
    the targets) and verifies it on the trimmed models: each trimmed resonance off its
    target by trim.precision_pct (one normal draw per trim, --seed).  OUT/ holds the
    re-plan as `vibroplan replan` writes it (plan.json with a `trim` block, report.md,
    waveforms/).  A chip that no trim within the range can fix is named, impacter by
    impacter, with the move it would need; then only trim.csv and report.md are
    written, and the exit status is 1, as it is when the re-planned drive fails.

    {EXIT}
    """
    from planner.core.markdown import Report
    from planner.files import output_folder
    from planner.afterfab.replan import write_replan_outputs
    from planner.afterfab.trim import trim_chip
    from planner.afterfab.trim import write_trim_csv

    plan, measured, inputs, progress = chip_inputs(plan_path, measured_path, out_dir,
                                                   command="trim", force=force, quiet=quiet)

    with output_folder(out_dir, command="trim", inputs=inputs, force=force) as tmp:
        res = trim_chip(plan, measured, seed=seed, progress=progress)
        if res.plan is not None:
            write_replan_outputs(res.plan, tmp, figures=not no_figures,
                                 sections=[_trim_section(res)])
        else:
            Report(f"vibroplan trim: {plan.spec.name}", [],
                   [_trim_section(res)]).write(tmp / "report.md")
        write_trim_csv(res.rows, tmp / "trim.csv")
    tp = res.trims
    click.echo(f"{plan.spec.name}: {len(tp.moved)} of {len(tp.target)} impacters to trim "
               f"{res.spec.direction} (range {res.spec.range_pct:g} %, precision "
               f"{res.spec.precision_pct:g} %)" + (": " + ", ".join(
                   f"{n} {tp.change_pct(n):+.2f} %" for n in tp.moved) if tp.moved else ""))
    for f in tp.failures:
        click.echo(f"error: cannot be trimmed: {f['impacter']}: {f['why']}", err=True)
    if res.plan is not None:
        tm = res.plan.data["trim"]["trimmed_models"]
        ver = res.plan.verification
        click.echo(f"re-planned drive: {'PASSED' if res.plan.passed else 'FAILED'} "
                   f"({int(ver['passed'].sum())}/{len(ver)} checks on the targets); on the "
                   f"trimmed models (precision error drawn): "
                   f"{'PASSED' if tm['passed'] else 'FAILED'}")
    click.echo(f"wrote {out_dir}/trim.csv (see {out_dir}/report.md)")
    if not res.passed:
        sys.exit(1)


def _trim_section(res):
    """The trim's section of report.md: what to cut, and whether the re-planned drive
    passes on the trimmed models."""
    from planner.core.markdown import Section

    tp = res.trims
    lines = [f"Direction {res.spec.direction} ({'plate mass removed: the resonance rises' if res.spec.direction == 'up' else 'beam freed from its anchor: the resonance falls'}), "
             f"range {res.spec.range_pct:g} %, precision {res.spec.precision_pct:g} % "
             "(one sigma of a cut's error).", ""]
    if tp.failures:
        lines += ["**This chip cannot be trimmed:**", ""]
        lines += [f"- {f['impacter']}: {f['why']}" for f in tp.failures] + [""]
    moved = [r for r in res.rows if r["impacter"] in tp.moved]
    if moved:
        lines += ["| impacter | measured [Hz] | target [Hz] | change [%] | cut area [um^2] | "
                  "cut length [um] |", "|---|---|---|---|---|---|"]
        lines += [f"| {r['impacter']} | {r['measured_hz']:.1f} | {r['target_hz']:.1f} | "
                  f"{r['change_pct']:+.3f} | {r['cut_area_um2']:.1f} | "
                  f"{r['cut_length_um']:.2f} |" for r in moved]
    elif not tp.failures:
        lines.append("No impacter needs a trim: every pair is separable as measured.")
    lines.append("")
    if res.plan is not None:
        tm = res.plan.data["trim"]["trimmed_models"]
        lines += [f"**The re-planned drive on the trimmed models: "
                  f"{'PASSES' if tm['passed'] else 'FAILS'}**"
                  + ("" if tm["passed"] else " (" + ", ".join(
                      f"{k}: {v}" for k, v in tm["failures"].items()) + ")"), ""]
    return Section("Trim", lines)


# cleandoc: click keeps the docstring's indentation when help is assigned like this
command.help = inspect.cleandoc(command.help).replace("{EXIT}", EXIT_CODES_HELP)
