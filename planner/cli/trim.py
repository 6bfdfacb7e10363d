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
    OUT/trim.csv: impacter,measured_hz,target_hz,change_pct,cut_area_um2,cut_length_um,
      failed_draws (zeros for an impacter left as it is; failed_draws: of the odds'
      draws, those on which a failed check implicated it)

    It then re-plans the drive for the trimmed chip (as `vibroplan replan` does, from
    the targets), verifies it on the targets, and gives its odds: the share of 100
    draws of the cuts' errors (each trimmed resonance off its target by
    trim.precision_pct, one normal draw per trim, --seed) on which it works on the
    trimmed models, with its 95 % interval, how often a re-plan after measuring again
    could tell every pair apart, and, where the odds fall short, a smaller move that
    raises them.  OUT/ holds the re-plan as `vibroplan replan` writes it (plan.json with
    a `trim` block, report.md, waveforms/).  The exit status is 0 when the drive
    verifies on the targets and its odds reach fabrication.target_yield (default
    0.95), 1 otherwise.  A chip that no trim within the range can fix is named,
    impacter by impacter, with the move it would need; then only trim.csv and
    report.md are written, and the exit status is 1.

    After cutting, measure the chip again and run `vibroplan replan` on the new
    measurement: its tones then follow where the cuts really left the resonances.

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
        ver = res.plan.verification
        click.echo(f"re-planned drive: {'PASSED' if res.plan.passed else 'FAILED'} "
                   f"({int(ver['passed'].sum())}/{len(ver)} checks on the targets)")
        for line in _odds_lines(res):
            click.echo(line)
        click.echo(f"next: {res.plan.plan_file.trim.next_step}")
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
        ver = res.plan.verification
        lines += [(f"**The re-planned drive on the targets: "
                   f"{'PASSES' if res.plan.passed else 'FAILS'}** "
                   f"({int(ver['passed'].sum())}/{len(ver)} checks)."), ""]
        lines += [f"- {x}" for x in _odds_lines(res)] + [""]
        lines += [f"**Next step:** {res.plan.plan_file.trim.next_step}.", ""]
    return Section("Trim", lines)


def _odds_lines(res):
    """The odds in words: the share of the cuts' error draws the drive works on, against
    the spec's target yield, what fails, the lab's re-plan after the cut and the cuts
    that raise the odds (stdout and the report say the same)."""
    from planner.core.markdown import fmt

    o = res.odds
    lo, hi = o.ci95
    lines = [f"odds on the trimmed models: the drive works on {o.passed} of {o.draws} "
             f"draws of the cuts' errors ({o.share:.2f}, 95 % CI {lo:.2f}-{hi:.2f}) "
             f"against fabrication.target_yield {o.target_yield:g}: "
             + ("meets it" if o.meets_target else "BELOW it")]
    if o.failures:
        lines.append("draws failing, by kind: " + ", ".join(
            f"{k} {v}" for k, v in o.failures.items()) + "; implicating " + ", ".join(
            f"{n} {v}" for n, v in o.implicated.items()))
    lines.append(f"measured again after the cut, every pair can be told apart on "
                 f"{o.separable} of {o.draws} draws (a re-plan then places every "
                 f"tone), {o.second_pass} with a second trim pass "
                 "within the range left")
    for a in res.alternatives:
        ao = a["odds"]
        lines.append(f"a cut that raises the odds: {a['cut']} ({a['why']}: " + ", ".join(
            f"{m['impacter']} to {fmt(m['target_hz'], '.1f')} Hz, {m['change_pct']:+.3f} %"
            for m in a["moved"]) + f"): {ao['passed']} of {ao['draws']} draws "
            f"({ao['share']:.2f}, 95 % CI {ao['ci95'][0]:.2f}-{ao['ci95'][1]:.2f})")
    if res.plan.passed and not o.meets_target and not res.alternatives:
        lines.append("no smaller move raises the odds; measuring again and re-planning "
                     "after the cut is the way to a working drive")
    return lines


# cleandoc: click keeps the docstring's indentation when help is assigned like this
command.help = inspect.cleandoc(command.help).replace("{EXIT}", EXIT_CODES_HELP)
