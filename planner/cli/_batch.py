"""``vibroplan replan`` of a whole wafer: the dies read, re-planned in batch on Dask,
the outputs written (:mod:`planner.afterfab.batch`)."""

from __future__ import annotations

import sys

import click

from planner.cli._common import check_output_folder, exit_note, output_folder

#: Warning lines printed at most before a batch (the report lists every die).
MAX_WARNINGS = 20


def replan_wafer_command(plan_path, measured, out_dir, *, trim, jobs, scheduler, test_map,
                         seed, force, quiet):
    """Read the plan and the wafer's measurement, check the outputs and the workers
    before any work, re-plan every die (resuming a run that was interrupted) and print
    the outcome per kind; exit 1 when a die is scrapped."""
    from pathlib import Path

    from planner.runtime.limits import check_jobs, cores
    from planner.afterfab.stdf import read_test_map
    from planner.afterfab.batch import (PARTLY_MEASURED, check_work_folder, counts, remove_work,
                                        replan_wafer, scrapped_causes, work_folder)
    from planner.afterfab.wafer_file import DIE_FILE, not_measured, read_wafer
    from planner.runtime.engine import check_scheduler
    from planner.planfile.reader import read_plan

    if seed is not None:
        raise click.UsageError("--seed applies to one chip: a wafer's dies are re-planned "
                               "with the plan's seed (as a yield study re-plans its chips)")
    jobs = check_jobs(cores() if jobs is None else jobs)
    plan = read_plan(plan_path)
    mapping = read_test_map(test_map, plan.impacter_ids) if test_map is not None else None
    notes = []
    dies = read_wafer(measured, plan.impacter_ids, plan.design_natural_frequency_hz,
                      test_map=mapping, notes=notes)
    measured = Path(measured)
    files = (sorted(p for p in measured.iterdir() if p.suffix.lower() == ".csv")
             if measured.is_dir() else [measured])
    inputs = [plan.path, *files] + ([test_map] if test_map is not None else [])
    check_output_folder(out_dir, command="replan", inputs=inputs, force=force)
    work = work_folder(out_dir)
    check_work_folder(work, [measured, *inputs])
    if scheduler:
        check_scheduler(scheduler)
    # said before any work, and whatever --quiet: the outcome of such a die rests on
    # a design value, not on the die
    warnings = [f"warning: {n}" for n in notes] + [
        f"warning: die ({x}, {y}): not measured, taken as designed: {' '.join(ids)} "
        f"(counted {PARTLY_MEASURED} if it works)"
        for x, y, ids in not_measured(dies, plan.impacter_ids)]
    for line in warnings[:MAX_WARNINGS]:
        click.echo(line, err=True)
    if len(warnings) > MAX_WARNINGS:
        click.echo(f"warning: and {len(warnings) - MAX_WARNINGS} more such lines (every "
                   f"die's in {out_dir}/report.md)", err=True)
    # a die of a folder of measured.csv files is keyed on its own file's bytes too
    sources = {}
    for p in files if measured.is_dir() else ():
        m = DIE_FILE.match(p.name)
        if m is not None:
            sources[(int(m.group(1)), int(m.group(2)))] = p

    def progress(done, total, resumed):
        if quiet:
            return
        if done == resumed and resumed:
            click.echo(f"resuming: {resumed} of {total} dies already re-planned "
                       f"({work})", err=True)
        elif done > resumed:
            click.echo(f"  die {done}/{total}", err=True)

    def kept_note():
        kept = sum(1 for p in work.glob("die_*") if (p / "result.json").is_file()) \
            if work.is_dir() else 0
        return f"{kept} finished dies kept in {work}: run the same command again to resume"

    # said when a signal stops the run, however it unwinds (cli._common.handle_errors)
    # or the signal watchdog ends it stuck in a kernel
    with exit_note(kept_note), output_folder(out_dir, command="replan", inputs=inputs,
                                             force=force) as tmp:
        results = replan_wafer(plan, dies, tmp, plan_path=plan.path,
                               measured_paths=files + ([test_map] if test_map else []),
                               trim=trim, jobs=jobs, scheduler=scheduler,
                               progress=progress, work=work, sources=sources)
    remove_work(work)
    c = counts(results)
    click.echo(f"{plan.spec.name}: {len(results)} dies: " + ", ".join(
        f"{k} {v}" for k, v in c.items()) + f"; wrote {out_dir}/ (see {out_dir}/report.md, "
        f"{out_dir}/summary.csv)")
    if c.get(PARTLY_MEASURED):
        click.echo(f"{PARTLY_MEASURED}: {c[PARTLY_MEASURED]} dies work only if their "
                   "unmeasured impacters are as designed (see the warnings above)",
                   err=True)
    if c["scrapped"]:
        causes = scrapped_causes(results)
        click.echo("scrapped: " + ", ".join(f"{k} ({v} dies)" for k, v in causes.items()),
                   err=True)
        sys.exit(1)
