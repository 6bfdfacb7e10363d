"""``vibroplan bench``: the work-precision benchmark of the exact impacter solver."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import click

from planner.cli._common import FORCE_FILES_HELP, check_output_files, handle_errors, output_files

SCRIPT = Path("benchmarks") / "work_precision.py"
#: The files the benchmark writes into its folder.
OUTPUTS = ("work_precision.csv", "work_precision.md", "work_precision.png")


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
              help="Existing folder for work_precision.{csv,md,png} "
                   "[default: benchmarks/results of the source tree]. Each file is "
                   "replaced only if `vibroplan bench` wrote it (see --force).")
@click.option("--quick", is_flag=True,
              help="Fewer settings and short timings: a smoke run, not for the record.")
@click.option("--force", is_flag=True,
              help=FORCE_FILES_HELP + " (The committed results in benchmarks/results need "
                   "it the first time.)")
@handle_errors
def command(out_dir, quick, force):
    """Work-precision benchmark: the exact solver against RK4 and solve_ivp.

    Four cases (the Fig. 7 device at 6.2 and 5.2 kHz, Table II's impacter in air,
    a chattering case), errors of r, impact times and velocities against a 50-digit
    evaluation of the same closed form, and the speed targets.  Takes a few minutes
    (about one with --quick).

    \b
    Example:
      vibroplan bench --quick --out /tmp/bench
    """
    script = _find_script()
    folder = script.parent / "results" if out_dir is None else Path(out_dir)
    targets = [folder / name for name in OUTPUTS]
    check_output_files("bench", [("--out", t) for t in targets], force=force)
    module = _load(script)
    with output_files(targets, command="bench", force=force) as tmps:
        tmp = tmps[0].parent
        # the benchmark writes into the temporary folder; say where the files will be
        module.run(tmp, quick=quick,
                   echo=lambda text: click.echo(str(text).replace(str(tmp), str(folder))))
