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
              help="Seed of the Monte Carlo: chip i at sigma scale s draws from the "
                   "SeedSequence of (seed, s's exact value, i), whatever --jobs, "
                   "--scheduler or the order of --sigma-scale.")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), required=True,
              help="Output folder (yield.json, report.md, figures/): a new or empty folder, "
                   "or one an earlier `vibroplan yield` wrote and nothing else was added "
                   "to (a folder with files it did not write is refused, not emptied); "
                   "replaced atomically when the run is complete. Never the current "
                   "directory, the plan's folder or another command's output folder.")
@click.option("--spec", "spec_file", type=click.Path(dir_okay=False), default=None,
              help="Take the fabrication: tolerance model from this spec instead of the "
                   "plan's own spec (everything else still comes from the plan).")
@click.option("--jobs", type=int, default=1, show_default=True,
              help="Local Dask worker processes, at most the cores (1: run in this "
                   "process, no Dask).")
@click.option("--scheduler", default=None, metavar="ADDRESS",
              help="Run the chips on an existing dask.distributed scheduler, e.g. "
                   "tcp://10.0.0.5:8786 (overrides --jobs). Checked before any work; "
                   "a scheduler that stops answering ends the run (exit 3).")
@click.option("--sigma-scale", "sigma_scale", default=None, metavar="LIST",
              help="Comma-separated factors on every sigma, e.g. 0.5,1,2: the yield against "
                   "the tolerance scale (chips per scale: --chips).")
@click.option("--replan", is_flag=True,
              help="Also measure every chip (its true natural frequencies, plus "
                   "--measure-noise), re-plan its drive from the measurement "
                   "(vibroplan replan, in memory) and verify the re-planned drive on the "
                   "chip's true models: the yield with re-planning beside the nominal one.")
@click.option("--measure-noise", "measure_noise", default=None, metavar="PCT",
              help="With --replan: one sigma of the Gaussian noise of each measured "
                   "natural frequency [%], seeded per chip.  [default: the spec's "
                   "fabrication.measurement_noise_pct, 0.05 unless set]")
@click.option("--trim", is_flag=True,
              help="With --replan: a chip the re-plan cannot rescue because two of its "
                   "impacters cannot be told apart is trimmed (vibroplan trim: one-way "
                   "moves within the spec's trim.range_pct), measured again, re-planned and "
                   "verified on its trimmed true models; yield.json gets a trim block.")
@click.option("--trim-precision", "trim_precision", default=None, metavar="PCT",
              help="With --trim: one sigma of each trim's error [%] (default: the spec's "
                   "trim.precision_pct, else 0.1).")
@click.option("--tune", is_flag=True,
              help="With --replan: tune every re-planned chip as a lab would with the piezo "
                   "on: a speed-against-tone sweep around each re-planned tone on the chip "
                   "(its true models, a speed reading's noise), the working windows fitted "
                   "(vibroplan calibrate --motion), the drive re-planned with each tone in "
                   "its window's middle and verified again, then played on the chip: the "
                   "re-plan before the sweep kept where the tuned drive fails there and it "
                   "worked, a slider too slow there given its tone raised (x1.03-1.15), a "
                   "positioning step's gates timed there (docs/yield.md 2b); yield.json gets "
                   "a tune block, and --trim trims from the tuned re-plan.")
@click.option("--tune-tones", "tune_tones", type=int, default=7, show_default=True,
              metavar="N", help="With --tune: tones of each impacter's first sweep "
                                "(3-50); a window reaching the sweep's end is followed on "
                                "that side by up to N more.")
@click.option("--tune-noise", "tune_noise", default="5", show_default=True, metavar="PCT",
              help="With --tune: one sigma of a speed reading's relative noise [%].")
@click.option("--allow-zero", is_flag=True,
              help="Run even when every fabrication tolerance is 0 (no fabrication: "
                   "section in the plan's spec or --spec) or a --sigma-scale is 0: every "
                   "chip is then the nominal one and the yield 1 or 0 by construction. "
                   "Refused without it.")
@click.option("--force", is_flag=True,
              help="Replace --out even if vibroplan did not write it, another command "
                   "wrote it, or it holds files `vibroplan yield` did not write (they are "
                   "deleted).")
@click.option("--quiet", is_flag=True, help="No progress bar.")
@handle_errors
def command(plan_path, chips, seed, out_dir, spec_file, jobs, scheduler, sigma_scale, replan,
            measure_noise, trim, trim_precision, tune, tune_tones, tune_noise, allow_zero,
            force, quiet):
    """Yield of a plan under fabrication variation (Monte Carlo over sampled chips).

    PLAN is a plan folder written by ``vibroplan plan`` or ``vibroplan replan``, or its
    plan.json (a re-planned plan's chips are its as-built chip with the errors on top).
    Each chip
    rebuilds every designed impacter pair and slider from the plan's geometry with
    sampled errors of line width, thickness, gap, Young's modulus and natural
    frequency (the spec's fabrication: section: a per-die part shared by the chip and
    a per-device part), then re-verifies every step of the plan with the plan's own
    checks, and every scene with the state carried across steps.

    A chip passes when every step passes and the carried-state check passes, as
    ``vibroplan plan``'s verification.  With --replan every chip is also measured,
    re-planned and re-verified on its true models (docs/yield.md; about as costly per
    chip as ``vibroplan replan``).

    Writes OUT/yield.json (chips, passed, yield, ci95 (Wilson), seed, tolerance,
    failures, impacters, by_sigma_scale; replan with --replan) and OUT/report.md with
    figures.  Exit status 0 when written; 1 when the nominal chip (no error) already
    fails (the plan does not verify; the outputs are still written).

    {EXIT}
    """
    from tqdm import tqdm

    from planner.runtime.limits import check_jobs
    from planner.runtime.engine import check_scheduler
    from planner.planfile.reader import read_plan
    from planner.arrayspec import load_spec
    from planner.yield_ import (check_chip_count, check_noise, make_payload, parse_scales,
                                run_yield, scale_key)
    from planner.yield_.dies import write_wafer_files
    from planner.yield_.report import write_yield_outputs

    scales = parse_scales(sigma_scale)
    if 0.0 in scales and not allow_zero:
        # every sigma times 0: the nominal chip, whose yield is 1 or 0 by construction
        # (the same refusal as a tolerance model of zeros)
        raise click.BadParameter("a scale of 0 makes every chip the nominal one (the yield "
                                 "is 1 or 0 by construction); pass --allow-zero to check "
                                 "the nominal chip alone", param_hint="'--sigma-scale'")
    check_jobs(jobs)
    check_chip_count(chips, len(scales))
    if measure_noise is not None and not replan:
        raise click.UsageError("--measure-noise needs --replan (only a re-plan measures "
                               "the chip)")
    if trim and not replan:
        raise click.UsageError("--trim needs --replan (a trimmed chip's drive is re-planned)")
    if trim_precision is not None and not trim:
        raise click.UsageError("--trim-precision needs --trim")
    if tune and not replan:
        raise click.UsageError("--tune needs --replan (the sweep is around the re-planned "
                               "tones)")
    ctx = click.get_current_context()
    for flag, name in (("--tune-tones", "tune_tones"), ("--tune-noise", "tune_noise")):
        # their defaults show in --help; given without --tune they would be ignored
        if not tune and ctx.get_parameter_source(name) is not click.core.ParameterSource.DEFAULT:
            raise click.UsageError(f"{flag} needs --tune (it sets the tuning sweep)")
    if not 3 <= tune_tones <= 50:
        raise click.BadParameter(f"must be 3-50 tones per impacter, {tune_tones} was given",
                                 param_hint="'--tune-tones'")
    try:
        speed_noise = check_noise(tune_noise, "--tune-noise")
    except ValueError as exc:
        raise click.BadParameter(str(exc).split(": ", 1)[-1],
                                 param_hint="'--tune-noise'") from None
    try:
        noise = None if measure_noise is None else check_noise(measure_noise)
    except ValueError as exc:
        raise click.BadParameter(str(exc).split(": ", 1)[-1],
                                 param_hint="'--measure-noise'") from None
    try:
        precision = (None if trim_precision is None else
                     check_noise(trim_precision, "--trim-precision"))
    except ValueError as exc:
        raise click.BadParameter(str(exc).split(": ", 1)[-1],
                                 param_hint="'--trim-precision'") from None
    record = read_plan(plan_path)
    plan_file = record.path
    fab = load_spec(Path(spec_file)).spec.fabrication if spec_file else None
    if noise is None:
        # the lab's noise as the spec declares it (a study's --spec, else the plan's)
        noise = (fab or record.spec.fabrication).measurement_noise_pct if replan else 0.0
    inputs = [plan_file] + ([spec_file] if spec_file else [])
    check_output_folder(out_dir, command="yield", inputs=inputs, force=force)
    payload = make_payload(record, seed, fab, replan=replan, measure_noise_pct=noise,
                           allow_zero=allow_zero, trim=trim, trim_precision_pct=precision,
                           tune=tune, tune_tones=tune_tones, tune_noise_pct=speed_noise)
    if scheduler:
        check_scheduler(scheduler)
    total = 1 + chips * len(scales)
    timings = {}
    # the folder's lock is held for the whole run, as plan, replan and trim hold theirs:
    # a second run writing the same folder is refused at once, not after its chips
    with output_folder(out_dir, command="yield", inputs=inputs, force=force) as tmp:
        bar = tqdm(total=total, desc="  chips" + (" (re-planned)" if replan else ""),
                   unit="chip", disable=quiet, file=sys.stderr)
        try:
            result = run_yield(payload, chips, scales=scales, jobs=jobs, scheduler=scheduler,
                               progress=lambda: bar.update(1), timings=timings)
        finally:
            bar.close()
        result = {"plan": str(plan_file), **result}
        write_yield_outputs(result, payload.loaded.spec, tmp, str(plan_file), timings=timings)
        if "wafer" in result:   # each wafer's dies as a prober measures them (issue 39)
            write_wafer_files(payload, result, tmp)
    lo, hi = result["ci95"]
    click.echo(f"yield {result['yield']:.3f} ({result['passed']}/{result['chips']} chips, "
               f"95 % CI [{lo:.3f}, {hi:.3f}], sigma scale {scale_key(result['sigma_scale'])})")
    for s, v in result.get("by_sigma_scale", {}).items():
        click.echo(f"  scale {s}: yield {v['yield']:.3f} [{v['ci95'][0]:.3f}, {v['ci95'][1]:.3f}]"
                   + (f", re-planned {v['replan']['yield']:.3f}" if "replan" in v else ""))
    if "wafer" in result and len(result.get("by_sigma_scale", {})) > 1:
        click.echo(f"the wafer map, its files and yield.json's wafer block are the dies of "
                   f"sigma scale {scale_key(result['wafer']['sigma_scale'])}; every scale's "
                   "outcomes are in by_sigma_scale (wafer_outcomes)")
    if result["failures"]:
        click.echo("failing checks: " + ", ".join(f"{k} ({v} chips)"
                                                 for k, v in result["failures"].items()))
    if "replan" in result:
        rp = result["replan"]
        click.echo(f"re-planned yield {rp['yield']:.3f} ({rp['passed']}/{rp['chips']} chips, "
                   f"95 % CI [{rp['ci95'][0]:.3f}, {rp['ci95'][1]:.3f}], measurement noise "
                   f"{rp['measure_noise_pct']:g} %); rescued {rp['rescued']}, lost {rp['lost']}")
        if rp["causes"]:
            click.echo("re-plan failures: " + ", ".join(f"{k} ({v} chips)"
                                                        for k, v in rp["causes"].items()))
        if "tune" in result:
            tu = result["tune"]
            click.echo(f"tuned yield {tu['yield']:.3f} ({tu['passed']}/{tu['chips']} chips, "
                       f"95 % CI [{tu['ci95'][0]:.3f}, {tu['ci95'][1]:.3f}], "
                       f"{tu['tones_per_impacter']} tones per impacter); rescued "
                       f"{tu['rescued']}, lost {tu['lost']}"
                       + ("; " + ", ".join(f"{k} ({v} chips)" for k, v in tu["causes"].items())
                          if tu["causes"] else ""))
        if "trim" in result:
            tr = result["trim"]
            click.echo(f"trimmed yield {tr['yield']:.3f} ({tr['passed']}/{tr['chips']} chips, "
                       f"95 % CI [{tr['ci95'][0]:.3f}, {tr['ci95'][1]:.3f}]); {tr['trimmed']} "
                       f"chips trimmed, {tr['rescued']} rescued by it"
                       + ("; " + ", ".join(f"{k} ({v} chips)" for k, v in tr["causes"].items())
                          if tr["causes"] else ""))
        if timings.get("replan_s"):
            t = timings["replan_s"]
            click.echo(f"re-plan cost: {sum(t) / len(t):.1f} s per chip (mean of {len(t)}), "
                       f"{60 * (1 + chips * len(scales)) / timings['wall_s']:.2f} chips/min")
    click.echo(f"wrote {out_dir}/ (see {out_dir}/report.md)")
    if not result["nominal"]["passed"]:
        click.echo("the nominal chip fails: " + ", ".join(result["nominal"]["failures"]),
                   err=True)
        sys.exit(1)


command.help = command.help.replace("{EXIT}", EXIT_CODES_HELP.replace("\n", "\n    "))
