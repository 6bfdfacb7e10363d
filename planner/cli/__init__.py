"""The ``vibroplan`` command line.

Each sub-command lives in its own module of this package and exports a click
command named ``command``.  Modules are imported only when their command runs
(or when ``--help`` lists them), so ``vibroplan --help`` does not pay for numba
compilation or matplotlib imports.
"""

from __future__ import annotations

import importlib
import importlib.util

import click

from planner.cli._common import EXIT_CODES_HELP, version_string

#: Sub-command name -> module of this package that defines it, in the order
#: ``--help`` lists them (the pipeline's order).
COMMANDS = {
    "plan": "plan",
    "simulate": "simulate",
    "sweep": "sweep",
    "design": "design",
    "assign": "assign",
    "color": "color",
    "drive": "drive",
    "calibrate": "calibrate",
    "replan": "replan",
    "trim": "trim",
    "bench": "bench",
    "yield": "yield_",
    "layout": "layout",
}


class _LazyGroup(click.Group):
    """A click group that imports a sub-command's module on first use."""

    def list_commands(self, ctx):
        return [
            name
            for name, mod in COMMANDS.items()
            if importlib.util.find_spec(f"planner.cli.{mod}") is not None
        ]

    def get_command(self, ctx, name):
        mod = COMMANDS.get(name)
        if mod is None or importlib.util.find_spec(f"planner.cli.{mod}") is None:
            return None
        return importlib.import_module(f"planner.cli.{mod}").command


@click.group(cls=_LazyGroup, context_settings={"help_option_names": ["-h", "--help"]},
             epilog=EXIT_CODES_HELP)
@click.version_option(version_string(), prog_name="vibroplan")
def main():
    """Plan how to drive arrays of externally resonated linear microvibromotors.

    vibroplan designs the impacters of every device (simulated annealing + SQP,
    the max-min design of Saitou et al., JMEMS 2000), gives every impacter a drive
    frequency by bandwidth colouring of the array's conflict graph, synthesises
    the summed-tone drive signal of every step, and verifies by exact simulation
    that every step moves the sliders it should and no other.

    Start with ``vibroplan plan`` (plans the embedded 5 x 5 default) or
    ``vibroplan simulate configs/paper_fig7.yaml --freq 6200``.
    """
