"""``vibroplan color``: bandwidth colouring of a ``band`` file (GEOM format)."""

from __future__ import annotations

import json

import click

from planner.cli._common import handle_errors


@click.command("color")
@click.argument("file", type=click.Path(dir_okay=False))
@click.option("--method", type=click.Choice(["auto", "dsatur", "milp", "exact"]), default="auto",
              show_default=True,
              help="auto: exact MILP up to 80 vertices, heuristic above; dsatur: greedy + "
                   "tabu search; milp/exact: HiGHS MILP started from the heuristic's span.")
@click.option("--time-limit", "time_limit", type=click.FloatRange(min=0, min_open=True),
              default=None,
              help="Wall-clock budget [s] (default: 10 s exact, 5 s heuristic). When it runs "
                   "out, the best colouring found is reported, not proven optimal.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Seed of the heuristic's random choices.")
@click.option("--colors", "show_colors", is_flag=True,
              help="Also print every vertex's colour (1-based vertex, 0-based colour).")
@click.option("--json", "as_json", is_flag=True,
              help="Print one JSON object (with the colouring) instead of a table.")
@handle_errors
def command(file, method, time_limit, seed, show_colors, as_json):
    """Colour a bandwidth-colouring instance: |c(i) - c(j)| >= d for every edge.

    FILE is in the DIMACS-like band format of the GEOM instances: 'p band V E',
    'e i j d' edges with separation d (self-loops and 'n' lines are node weights
    and are ignored), 'c' comments.  Prints the span (largest colour + 1), the
    proven lower bound, whether the span is proven optimal, the method and the
    time.

    \b
    Examples:
      vibroplan color GEOM20b.col
      vibroplan color GEOM20a.col --method dsatur --time-limit 2 --json
    """
    from planner.coloring import read_band, solve_bandwidth

    graph = read_band(file)
    result = solve_bandwidth(graph, method=method, time_limit=time_limit, seed=seed)
    edges = sum(1 for u, v in graph.edges if u != v)
    if as_json:
        click.echo(json.dumps({
            "file": str(file),
            "vertices": graph.number_of_nodes(),
            "edges": edges,
            "span": result.span,
            "lower_bound": result.lower_bound,
            "optimal": result.optimal,
            "method": result.method,
            "requested_method": method,
            "seconds": round(result.seconds, 4),
            "message": result.message,
            "coloring": {str(v): c for v, c in sorted(result.coloring.items())},
        }))
        return
    proof = "proven optimal" if result.optimal else "not proven optimal"
    click.echo(f"{file}: {graph.number_of_nodes()} vertices, {edges} edges")
    click.echo(f"  span         {result.span}")
    click.echo(f"  lower bound  {result.lower_bound} ({proof})")
    click.echo(f"  method       {result.method} (requested: {method})")
    click.echo(f"  time         {result.seconds:.3f} s")
    click.echo(f"  status       {result.message}")
    if show_colors:
        for v, c in sorted(result.coloring.items()):
            click.echo(f"  {v} {c}")
