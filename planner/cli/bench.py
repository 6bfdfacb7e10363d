"""``vibroplan bench``: the work-precision benchmark of the exact impacter solver."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import click

from planner.cli._common import handle_errors

SCRIPT = Path("benchmarks") / "work_precision.py"


def _find_script():
    """benchmarks/work_precision.py of the source tree (an editable install or a clone)."""
    import planner

    candidates = [Path(planner.__file__).resolve().parents[1] / SCRIPT, Path.cwd() / SCRIPT]
    for path in candidates:
        if path.is_file():
            return path
    raise FileNotFoundError(
        f"{SCRIPT} not found (looked in {', '.join(str(p.parent) for p in candidates)}): "
        "the benchmark lives in the repository, run it from a clone")


def _load(path):
    import sys

    name = "vibroplan_work_precision"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up while it runs
    spec.loader.exec_module(module)
    return module


@click.command("bench")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default=None,
              help="Directory for work_precision.{csv,md,png} "
                   "[default: benchmarks/results of the source tree].")
@click.option("--quick", is_flag=True,
              help="Fewer settings and short timings: a smoke run, not for the record.")
@handle_errors
def command(out_dir, quick):
    """Work-precision benchmark: the exact solver against RK4 and solve_ivp.

    Four cases (the Fig. 7 device at 6.2 and 5.2 kHz, Table II's impacter in air,
    a chattering case), errors of r, impact times and velocities against a 50-digit
    evaluation of the same closed form, and the speed targets.  Takes a few minutes
    (about one with --quick).

    \b
    Example:
      vibroplan bench --quick --out /tmp/bench
    """
    module = _load(_find_script())
    module.run(module.RESULTS if out_dir is None else Path(out_dir), quick=quick,
               echo=click.echo)
