"""``vibroplan plan``: the end-to-end array plan, verified by simulation."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from planner.cli._common import EXIT_CODES_HELP, check_output_folder, handle_errors
from planner.core.data import DEFAULT_SPEC


class _Bars:
    """One tqdm progress bar per pipeline stage."""

    def __init__(self, quiet):
        self.quiet = quiet
        self.bar = None
        self.stage = None

    def __call__(self, stage, item=None, total=None):
        from tqdm import tqdm

        if stage == "probe":
            # a reach probe's verdict, as it comes: above the bar, which it does not count
            if not self.quiet and item:
                tqdm.write(str(item), file=sys.stderr)
            return
        if total is not None:
            self.close()
            self.stage = stage
            self.bar = tqdm(total=total, desc=f"{stage:>7}", unit="item", disable=self.quiet,
                            file=sys.stderr, leave=True)
        elif self.bar is not None and item is not None:
            self.bar.update(1)

    def close(self):
        if self.bar is not None:
            self.bar.close()
            self.bar = None


@click.command("plan")
@click.argument("spec", required=False, type=click.Path(dir_okay=False))
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default="plan_out",
              show_default=True,
              help="Output folder: a new or empty folder, or one an earlier `vibroplan plan` "
                   "wrote and nothing else was added to (a folder with files it did not "
                   "write is refused, not emptied); replaced atomically when the plan is "
                   "complete. Never the current directory, a folder holding the spec, or "
                   "another command's output folder.")
@click.option("--force", is_flag=True,
              help="Replace --out even if vibroplan did not write it, another command "
                   "wrote it, or it holds files `vibroplan plan` did not write (they are "
                   "deleted).")
@click.option("--seed", type=click.IntRange(min=0), default=None, help="Seed (default: the spec's design.seed).")
@click.option("--jobs", type=int, default=None,
              help="Worker processes for the designs and threads for the simulation "
                   "kernels, at most the cores (default: all cores). The plan does not "
                   "depend on it.")
@click.option("--no-figures", is_flag=True, help="Skip the PNG figures (faster).")
@click.option("--quiet", is_flag=True, help="No progress bars.")
@click.option("--dry-run", is_flag=True,
              help="Stop after the frequency assignment: print the tones a design can "
                   "serve (measured by a few probe designs, kept in the design cache), "
                   "the assignment, the designs and verification runs that remain and an "
                   "estimate of their time; write no output; exit 0, or 2 when the spec "
                   "cannot be planned (seconds to a minute).")
@click.option("--scheduler", metavar="ADDRESS", default=None,
              help="Run the designs and the verification steps on an existing "
                   "dask.distributed cluster at ADDRESS (tcp://host:8786; its workers "
                   "need vibroplan installed) instead of --jobs local worker processes. "
                   "Checked before any work; a scheduler that stops answering ends the "
                   "run (exit 3).")
@click.option("--cache-dir", type=click.Path(file_okay=False), default=None,
              help="Folder of the design cache: a design, reach probe, verified step, "
                   "coupling matrix, yield prediction or set of figures already computed "
                   "for the same inputs and code is read from it, not recomputed (the "
                   "plan is byte-identical either way). Default: $VIBROPLAN_CACHE_DIR, "
                   "else ~/.cache/vibroplan.")
@click.option("--no-cache", is_flag=True,
              help="Compute every design; neither read nor write the design cache.")
@handle_errors
def command(spec, out_dir, seed, jobs, no_figures, quiet, force, dry_run, scheduler,
            cache_dir, no_cache):
    """Plan an array from a YAML SPEC: channels, designs, drives, verification.

    Without SPEC, plans the embedded default: a 5 x 5 array (configs/array_5x5.yaml)
    with every impacter independently addressable and a scene that positions all 25
    chips at once, then releases one row.

    Writes OUT/plan.json (the contract), designs.csv, coupling.csv, waveforms/ (WAV,
    int16 WAV, CSV and Keysight .arb per step, each with a JSON sidecar), figures/
    and report.md.  Exit status 0 when every step passes re-simulation, 1 when some
    step fails (the report says which and why; the plan is still written).

    Each scene is also simulated in order with every state carried across steps,
    each step followed by its settle dwell with the drive off; an idle slider moved
    by the state a previous step left, a travel over verification.max_travel_um or
    a step that does not settle fails the verification like any other check.

    {EXIT}
    """
    from planner.runtime.limits import check_jobs
    from planner.runtime.engine import check_scheduler

    if no_cache and cache_dir is not None:
        raise click.UsageError("--cache-dir and --no-cache exclude each other")
    if jobs is not None:
        check_jobs(jobs)
    path = Path(spec) if spec else DEFAULT_SPEC
    # refuse the output folder before the spec is read and the solver imported (the
    # refusal then takes a fraction of a second, the plan a minute); a dry run refuses
    # what the real run would, so that its "nothing in the way" means the real run starts
    check_output_folder(out_dir, command="plan", inputs=[path], force=force)

    import numba

    from planner.planning import plan
    from planner.planning.design_store import default_cache_dir
    from planner.arrayspec import load_spec

    cache = None if no_cache else Path(cache_dir) if cache_dir else default_cache_dir()
    if jobs is not None:
        numba.set_num_threads(min(jobs, numba.config.NUMBA_NUM_THREADS))
    else:
        jobs = numba.config.NUMBA_NUM_THREADS
    loaded = load_spec(path)
    # and an unusable scheduler, before any work
    if scheduler:
        check_scheduler(scheduler)
    if dry_run:
        _dry_run(loaded, seed, jobs, cache, quiet)
        return
    bars = _Bars(quiet)

    def announce(settings, steps, assignment):
        # after the assignment, before any design: what is left and how long it may take
        from planner.planning.estimate import estimate

        bars.close()
        if assignment.reach is not None:
            for line in assignment.reach.lines():
                click.echo(line, err=True)
        for line in estimate(settings, steps, assignment, jobs).lines():
            click.echo(line, err=True)
        from planner.manufacturability import prediction_lines, predict_from_channels

        for line in prediction_lines(predict_from_channels(settings.chip_spec, assignment,
                                                           seed=settings.seed),
                                     settings.target_yield, before_designs=True):
            click.echo(line, err=True)

    try:
        result = plan(loaded, out_dir=out_dir, seed=seed, progress=bars,
                      figures=not no_figures, jobs=jobs, force=force,
                      on_assignment=announce, scheduler=scheduler, cache_dir=cache)
    finally:
        bars.close()
    d = result.data
    a = d["assignment"]
    ver = result.verification
    click.echo(f"\n{d['spec']['name']}: {len(d['impacters'])} impacters on {len(d['devices'])} "
               f"devices, {len(d['steps'])} steps; span {a['span']} channels "
               f"({'optimal' if a['optimal'] else 'not proven optimal'})")
    summary = ver.groupby(["scene", "step"], sort=False).agg(
        devices=("device", "size"), passed=("passed", "sum"))
    shown = summary[summary.index.get_level_values(0) != "independent"]
    if not shown.empty:
        click.echo(shown.to_string())
    ind = summary[summary.index.get_level_values(0) == "independent"]
    if not ind.empty:
        click.echo(f"independent single-impacter steps: {int((ind['passed'] == ind['devices']).sum())}"
                   f" of {len(ind)} pass")
    for line in _scene_lines(d["scenes"]):
        click.echo(line)
    t = result.timings
    click.echo("time: " + ", ".join(f"{k} {v:.1f} s" for k, v in t.items()))
    from planner.manufacturability import YieldPrediction, prediction_lines

    m = d.get("manufacturability") or {}
    for line in prediction_lines(YieldPrediction.from_block(m), m.get("target_yield", 0.95),
                                 before_designs=False):
        click.echo(line)
    dc = result.design_cache
    if dc is not None:
        probes = dc.get("probes") or {}
        # the reach's probes are entries of the same cache, counted apart from the designs
        probed = (f"; reach probes: {probes['read']} read, {probes['written']} computed and "
                  "stored" if probes.get("read") or probes.get("written") else "")
        click.echo(f"designs: {dc['designed']} distinct, {dc['read']} read from the design "
                   f"cache ({dc['path']}), {dc['written']} computed and stored{probed}")
        st = dc.get("stages") or {}
        if st:
            click.echo("from the same cache: " + ", ".join(
                f"{name} {c['read']} read, {c['written']} computed and stored"
                for name, c in st.items()))
    # a plan fails on an infeasible design even when every simulated check passes: say so
    problems = (result.data.get("verification") or {}).get("design_problems") or []
    why = (f"; {len(problems)} design(s) infeasible: "
           + ", ".join(p["impacter"] for p in problems)) if problems else ""
    click.echo(f"verification: {'PASSED' if result.passed else 'FAILED'} "
               f"({int(ver['passed'].sum())}/{len(ver)} checks{why}); wrote {out_dir}/ "
               f"(see {out_dir}/report.md)")
    if not result.passed:
        sys.exit(1)


# indented like the docstring around it, so that click still dedents the whole help
command.help = command.help.replace("{EXIT}", EXIT_CODES_HELP.replace("\n", "\n    "))


def _dry_run(loaded, seed, jobs, cache, quiet):
    """``--dry-run``: the reach, the assignment, the work left and its estimated time;
    no files but the design cache's (the reach's probe designs)."""
    import time

    from planner.planning.design_store import DesignStore
    from planner.planning.estimate import estimate
    from planner.planning.pipeline import plan_pool
    from planner.planning.reach import measure_reach
    from planner.planning.settings import resolve_settings

    settings = resolve_settings(loaded, seed)
    steps = settings.steps
    bars = _Bars(quiet)
    t0 = time.perf_counter()
    try:
        # the plan's worker pool, started only if a probe must be designed (none when the
        # cache holds the reach), this process designing probes while its workers start
        with plan_pool(jobs, eager=False) as pool:
            reach, a = measure_reach(settings, jobs=jobs, progress=bars, pool=pool,
                                     store=None if cache is None else DesignStore(cache))
    finally:
        bars.close()
    seconds = time.perf_counter() - t0
    for line in reach.lines():
        click.echo(line)
    freqs = sorted(set(a.frequencies.values()))
    click.echo(f"{settings.name}: {len(a.frequencies)} impacters on {len(settings.sliders)} devices, "
               f"{len(steps)} steps; {a.graph.number_of_nodes()} channel groups, "
               f"{len(freqs)} tones {freqs[0]:g}-{freqs[-1]:g} Hz; span {a.span} positions "
               f"({'optimal' if a.optimal else 'not proven optimal'}, {a.method}), stride "
               f"{a.stride}; {len(a.violations)} guard-rule warnings; reach and assignment "
               f"in {seconds:.1f} s")
    for line in estimate(settings, steps, a, jobs).lines():
        click.echo(line)
    from planner.manufacturability import prediction_lines, predict_from_channels

    for line in prediction_lines(predict_from_channels(settings.chip_spec, a,
                                                       seed=settings.seed),
                                 settings.target_yield, before_designs=True):
        click.echo(line)
    click.echo("dry run: nothing written")


def _scene_lines(scene_rows):
    """One line per scene: the largest overshoot once the drive stops, and the steps in
    which idle sliders moved beyond the tolerance from the state they inherited."""
    from planner.planning.scenes import scene_overshoot

    overshoot = scene_overshoot(scene_rows)
    out = []
    for scene in dict.fromkeys(r["scene"] for r in scene_rows):
        driven = [r for r in scene_rows if r["scene"] == scene and r["driven"]]
        text = f"scene {scene}:"
        if driven and overshoot.get(scene):
            over = max(abs(z) for z in overshoot[scene].values())
            text += f" overshoot after the drive stops up to {over * 1e6:.2f} um;"
        carried = [f"{r['step']} ({len(r['idle_moved_m'])} sliders, up to "
                   f"{max(abs(z) for z in r['idle_moved_m'].values()) * 1e6:.1f} um)"
                   for r in driven if r["idle_moved_m"]]
        text += (" idle sliders moved beyond the idle tolerance from the state the previous "
                 "step left in: " + ", ".join(carried) if carried else
                 " no idle slider moved beyond the idle tolerance")
        out.append(text)
    return out
