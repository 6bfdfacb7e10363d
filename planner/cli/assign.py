"""``vibroplan assign``: channels and frequencies for every impacter of an array spec."""

from __future__ import annotations

import json
from pathlib import Path

import click

from planner.cli._common import (FORCE_FILES_HELP, Finite, check_output_files, handle_errors,
                                 output_file, output_files)


@click.command("assign")
@click.argument("spec", required=False, type=click.Path(dir_okay=False))
@click.option("--out", type=click.Path(dir_okay=False), callback=output_file, default=None,
              help="Write the assignment table: .csv, or .json (with graph size and span).")
@click.option("--plot", type=click.Path(dir_okay=False), callback=output_file, default=None,
              help="PNG of the array with each device's forward/backward frequencies.")
@click.option("--method", type=click.Choice(["auto", "dsatur", "milp"]), default="auto",
              show_default=True, help="Colouring strategy.")
@click.option("--time-limit", type=Finite(min=0, min_open=True), default=None,
              help="Colouring time limit [s].")
@click.option("--force", is_flag=True, help=FORCE_FILES_HELP)
@handle_errors
def command(spec, out, plot, method, time_limit, force):
    """Assign channels and frequencies to every impacter of an array SPEC.

    Builds the conflict graph (impacters that must be told apart), colours it with
    separations (bandwidth colouring: DSATUR heuristic + tabu search, exact MILP for
    small graphs), spreads the colours over the channel grid inside the band and checks
    harmonic and intermodulation products of tones that play together.  Without SPEC,
    the embedded default (configs/array_5x5.yaml) is used.
    """
    from planner.assignment.assign import assign, verify_assignment
    from planner.planning.settings import resolve_settings
    from planner.arrayspec import default_spec_path, load_spec

    path = Path(spec) if spec else default_spec_path()
    check_output_files("assign", [("--out", out), ("--plot", plot)], inputs=[path],
                       force=force)
    settings = resolve_settings(load_spec(path))
    result = assign(settings, settings.steps, method=method, time_limit=time_limit)
    table = result.table()
    problems = verify_assignment(result)
    g = result.graph
    click.echo(table.to_string(index=False, float_format=lambda v: f"{v:.1f}"))
    click.echo(f"\nconflict graph: {g.number_of_nodes()} channel groups "
               f"({len(result.channels)} impacters), {g.number_of_edges()} edges")
    click.echo(f"span: {result.span} channels (lower bound {result.lower_bound}, "
               f"{'proven optimal' if result.optimal else 'not proven optimal'}), "
               f"method {result.method}, {result.seconds:.2f} s; spread with stride "
               f"{result.stride} from channel {result.offset}")
    click.echo(f"separations: {'all met' if not problems else '; '.join(problems)}")
    if result.violations:
        click.echo(f"guard-rule violations ({len(result.violations)}):")
        for v in result.violations[:20]:
            click.echo(f"  {v}")
    else:
        click.echo("guard rules: no harmonic or intermodulation product lands in an idle band")
    if out:
        with output_files([out], command="assign", inputs=[path], force=force) as (tmp,):
            if str(out).endswith(".json"):
                tmp.write_text(json.dumps({
                    "impacters": table.to_dict(orient="records"),
                    "span": result.span, "lower_bound": result.lower_bound,
                    "optimal": result.optimal, "method": result.method,
                    "graph": {"nodes": g.number_of_nodes(), "edges": g.number_of_edges()},
                    "violations": [str(v) for v in result.violations],
                }, indent=2))
            else:
                table.to_csv(tmp, index=False)
        click.echo(f"wrote {out}")
    if plot:
        from planner.figures.plan import array_map

        with output_files([plot], command="assign", inputs=[path], force=force) as (tmp,):
            array_map(settings, table, tmp)
        click.echo(f"wrote {plot}")
