"""``vibroplan layout``: the GDSII layout of a planned array, read back and checked."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from planner.cli._common import EXIT_CODES_HELP, EXIT_FAILED, handle_errors, output_file


@click.command("layout")
@click.argument("plan_path", metavar="PLAN", type=click.Path(path_type=Path))
@click.option("--out", "out_file", required=True, metavar="FILE.gds",
              type=click.Path(dir_okay=False, path_type=Path), callback=output_file,
              help="The GDSII file to write; STEM.md, STEM.png, STEM_<device>.png (and with "
                   "--check STEM_drc.json) are written beside it.")
@click.option("--check", is_flag=True,
              help="Run the design-rule check (KLayout): width and space per mask, anchor "
                   "and via enclosures, every device inside its pitch cell; exit 1 when it "
                   "finds a violation.")
@click.option("--spec", "spec_file", type=click.Path(dir_okay=False, path_type=Path),
              default=None,
              help="Take the process layers and rules (process.layers, min_line_um, "
                   "min_space_um, anchor_enclosure_um) and the trim: section from this spec "
                   "instead of the plan's (the designs still come from the plan).")
@click.option("--force", is_flag=True,
              help="Replace existing output files that vibroplan layout did not write "
                   "(never the plan's or the spec's own files).")
@click.option("--device", default=None, metavar="ID",
              help="The device of the zoomed picture.  [default: the first]")
@handle_errors
def command(plan_path, out_file, check, spec_file, device, force):
    """Draw a plan's chip as a GDSII layout, read it back, and check it.

    PLAN is a `vibroplan plan` output folder or its plan.json.  One cell per
    designed impacter pair (named by its id, e.g. A1.forward: two placements of its
    cantilever, a plate on two double-V beams at the process's beam angle, its tip at
    its gap from the slider wall at its impact angle), one per slider with its guides
    and anchors (A1.slider), one per device (A1) on the array's pitch, labels with
    every id and its drive frequency, on the masks of the spec's process.layers.
    With a trim: section (direction up) every plate gets trim tabs of known area.

    The file is then read back (gdstk): every impacter's beam width and length, plate
    area and gap are measured on its polygons and must give its natural frequency
    within 0.5 % through eqs. (2)-(4) (exit 1 otherwise).  STEM.md reports it with
    the pictures and the check.

    {EXIT}
    """
    from planner.files import version_string
    from planner.layout.run import run_layout

    result = run_layout(plan_path, out_file, check=check, rules_spec=spec_file, device=device,
                        force=force,
                        version=version_string())
    rows = result.round_trip
    worst = max(abs(r["error"]) for r in rows)
    chip = result.chip
    click.echo(f"wrote {out_file} ({result.gds_bytes / 1024:.0f} KiB: "
               f"{len(chip.device_origins)} devices, {len(chip.impacters)} impacter pairs) "
               "and beside it " + ", ".join(p.name for k, p in result.files.items()
                                            if k != "gds"))
    click.echo(f"round trip: nu_n within {100 * worst:.3g} % of the plan "
               + ("(passed)" if result.round_trip_passed else "(FAILED: criterion 0.5 %)"))
    if result.drc is not None:
        drc = result.drc
        if drc.clean:
            click.echo(f"design-rule check: clean ({len(drc.rules)} rules)")
        else:
            counts = ", ".join(f"{k} {v}" for k, v in drc.counts().items())
            click.echo(f"design-rule check: {len(drc.violations)} violations ({counts})")
            if drc.impacters:
                click.echo("impacters in a violation: " + ", ".join(drc.impacters))
            if drc.devices:
                click.echo("devices in a violation: " + ", ".join(drc.devices))
    if not result.passed:
        sys.exit(EXIT_FAILED)


command.help = command.help.replace("{EXIT}", EXIT_CODES_HELP.replace("\n", "\n    "))
