"""``vibroplan yield``: the fraction of fabricated chips on which a plan works."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from planner.cli._common import EXIT_CODES_HELP, check_output_folder, handle_errors, output_folder


@click.command("yield")
@click.argument("plan_path", metavar="PLAN", type=click.Path())
@click.option("--chips", type=click.IntRange(min=1), default=100, show_default=True,
              help="Chips sampled per sigma scale.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Seed of the Monte Carlo: chip i at scale index j draws from "
                   "SeedSequence([seed, j, i]), whatever --jobs or --scheduler.")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), required=True,
              help="Output folder (yield.json, report.md, figures/); replaced atomically "
                   "when the run is complete. Never the current directory or the plan's folder.")
@click.option("--spec", "spec_file", type=click.Path(dir_okay=False), default=None,
              help="Take the fabrication: tolerance model from this spec instead of the "
                   "plan's own spec (everything else still comes from the plan).")
@click.option("--jobs", type=click.IntRange(min=1), default=1, show_default=True,
              help="Local Dask worker processes (1: run in this process, no Dask).")
@click.option("--scheduler", default=None, metavar="ADDRESS",
              help="Run the chips on an existing dask.distributed scheduler, e.g. "
                   "tcp://10.0.0.5:8786 (overrides --jobs).")
@click.option("--sigma-scale", "sigma_scale", default=None, metavar="LIST",
              help="Comma-separated factors on every sigma, e.g. 0.5,1,2: the yield against "
                   "the tolerance scale (chips per scale: --chips).")
@click.option("--force", is_flag=True,
              help="Replace --out even if it is a non-empty folder vibroplan did not write.")
@click.option("--quiet", is_flag=True, help="No progress bar.")
@handle_errors
def command(plan_path, chips, seed, out_dir, spec_file, jobs, scheduler, sigma_scale, force,
            quiet):
    """Yield of a plan under fabrication variation (Monte Carlo over sampled chips).

    PLAN is a plan folder written by ``vibroplan plan`` or its plan.json.  Each chip
    rebuilds every designed impacter pair and slider from the plan's geometry with
    sampled errors of line width, thickness, gap, Young's modulus and natural
    frequency (the spec's fabrication: section: a per-die part shared by the chip and
    a per-device part), then re-verifies every step of the plan with the plan's own
    checks, and every scene with the state carried across steps.

    Writes OUT/yield.json (chips, passed, yield, ci95 (Wilson), seed, tolerance,
    failures, impacters, by_sigma_scale) and OUT/report.md with figures.  Exit status
    0 when written; 1 when the nominal chip (no error) already fails (the plan does
    not verify; the outputs are still written).

    {EXIT}
    """
    from tqdm import tqdm

    from planner.spec import load_spec
    from planner.yield_ import make_payload, parse_scales, read_plan, run_yield, write_outputs

    scales = parse_scales(sigma_scale)
    data, plan_file = read_plan(plan_path)
    fab = load_spec(Path(spec_file)).spec.fabrication if spec_file else None
    inputs = [plan_file] + ([spec_file] if spec_file else [])
    check_output_folder(out_dir, inputs=inputs, force=force)
    payload = make_payload(data, seed, fab)
    total = 1 + chips * len(scales)
    bar = tqdm(total=total, desc="  chips", unit="chip", disable=quiet, file=sys.stderr)
    try:
        result = run_yield(payload, chips, scales=scales, jobs=jobs, scheduler=scheduler,
                           progress=lambda: bar.update(1))
    finally:
        bar.close()
    result = {"plan": str(plan_file), **result}
    with output_folder(out_dir, command="yield", inputs=inputs, force=force) as tmp:
        write_outputs(result, payload.loaded.spec, tmp, str(plan_file))
    lo, hi = result["ci95"]
    click.echo(f"yield {result['yield']:.3f} ({result['passed']}/{result['chips']} chips, "
               f"95 % CI [{lo:.3f}, {hi:.3f}], sigma scale {result['sigma_scale']:g})")
    for s, v in result.get("by_sigma_scale", {}).items():
        click.echo(f"  scale {s}: yield {v['yield']:.3f} [{v['ci95'][0]:.3f}, {v['ci95'][1]:.3f}]")
    if result["failures"]:
        click.echo("failing checks: " + ", ".join(f"{k} ({v} chips)"
                                                 for k, v in result["failures"].items()))
    click.echo(f"wrote {out_dir}/ (see {out_dir}/report.md)")
    if not result["nominal"]["passed"]:
        click.echo("the nominal chip fails: " + ", ".join(result["nominal"]["failures"]),
                   err=True)
        sys.exit(1)


command.help = command.help.replace("{EXIT}", EXIT_CODES_HELP.replace("\n", "\n    "))
