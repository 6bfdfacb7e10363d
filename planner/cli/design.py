"""``vibroplan design``: design a forward/backward impacter pair (Section III-C, Table II)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click

from planner.cli._common import (FORCE_FILES_HELP, Finite, check_output_files, handle_errors,
                                 output_file, output_files)

from planner.core.units import UM  # noqa: E402


def _rows(pair):
    """(label, forward text, backward text) rows of the printed report."""
    f, b = pair.forward, pair.backward

    def both(fmt, get):
        return fmt(get(f)), fmt(get(b))

    rows = [
        ("drive frequency [Hz]",) + both("{:.1f}".format, lambda d: d.frequency_hz),
        ("forbidden frequency [Hz]",) + both(lambda v: ", ".join(f"{x:.1f}" for x in v),
                                             lambda d: d.forbidden_hz),
        ("area A [um^2]",) + both("{:.1f}".format, lambda d: d.geometry.area / UM**2),
        ("beam width w [um]",) + both("{:.4f}".format, lambda d: d.geometry.width / UM),
        ("beam length l [um]",) + both("{:.2f}".format, lambda d: d.geometry.length / UM),
        ("gap c [um]",) + both("{:.4f}".format, lambda d: d.geometry.gap / UM),
        ("natural frequency [Hz]",) + both("{:.1f}".format, lambda d: d.natural_frequency_hz),
        ("mass m [kg]",) + both("{:.4e}".format, lambda d: d.mass_kg),
        ("stiffness k [N/m]",) + both("{:.4g}".format, lambda d: d.stiffness_n_per_m),
        ("damping b [N s/m]",) + both("{:.4g}".format, lambda d: d.damping_ns_per_m),
        ("worst x0 [um]",) + both("{:.4f}".format, lambda d: d.worst_x0_m / UM),
        ("r_min at own frequency [N]",) + both("{:.4e}".format, lambda d: d.r_min_n),
        ("r_max at forbidden [N]",) + both(lambda v: ", ".join(f"{x:.3g}" for x in v),
                                           lambda d: d.r_max_forbidden_n),
        ("margin to forbidden [Hz]",) + both(lambda v: ", ".join(f"{x:.1f}" for x in v),
                                             lambda d: d.margins_hz),
        ("response band [Hz]",) + both(lambda v: f"{v[0]:.0f} - {v[1]:.0f}",
                                       lambda d: d.response_band_hz),
        ("slider speed [mm/s]",) + both("{:.3f}".format,
                                        lambda d: d.predicted_slider_speed_m_s * 1e3),
        ("feasible (fine grid)",) + both(str, lambda d: d.feasible),
        ("re-check x0 points",) + both(str, lambda d: d.checks.get("recheck_x0_points")),
        ("silent over long window",) + both(str, lambda d: d.checks.get("long_window_passed")),
        ("coarse-grid-only designs",) + both(str, lambda d: d.checks.get("coarse_only_designs")),
        ("evaluations",) + both(str, lambda d: d.evaluations),
        ("time [s]",) + both("{:.1f}".format, lambda d: d.seconds),
    ]
    return rows


def _table(pair):
    rows = _rows(pair)
    w0 = max(len(r[0]) for r in rows)
    w1 = max(len("forward"), *(len(r[1]) for r in rows))
    w2 = max(len("backward"), *(len(r[2]) for r in rows))
    lines = [f"{'':<{w0}}  {'forward':>{w1}}  {'backward':>{w2}}"]
    lines += [f"{a:<{w0}}  {b:>{w1}}  {c:>{w2}}" for a, b, c in rows]
    return "\n".join(lines)


def _write(data, out, inputs, force):
    suffix = Path(out).suffix.lower()
    if suffix not in (".yaml", ".yml", ".json"):
        raise ValueError(f"--out must end in .yaml, .yml or .json, {out!r} was given")
    with output_files([out], command="design", inputs=inputs, force=force) as (tmp,):
        if suffix == ".json":
            tmp.write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")
        else:
            import yaml

            tmp.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")


@click.command("design")
@click.argument("config", type=click.Path(dir_okay=False))
@click.option("--forward", "forward_hz", type=Finite(), default=None,
              help="Forward drive frequency nu_f [Hz] (default: the config's design.forward_hz).")
@click.option("--backward", "backward_hz", type=Finite(), default=None,
              help="Backward drive frequency nu_b [Hz] (default: the config's design.backward_hz).")
@click.option("--seed", type=click.IntRange(min=0), default=None, help="Seed (default: the config's design.seed).")
@click.option("--budget", type=click.Choice(["full", "fast"]), default=None,
              help="Search effort (default: the config's design.budget, full).")
@click.option("--out", type=click.Path(dir_okay=False), callback=output_file, default=None,
              help="Write both designs to a .yaml/.yml or .json file (keys forward, backward).")
@click.option("--plot", type=click.Path(dir_okay=False), callback=output_file, default=None,
              help="Write a Fig. 10-style PNG: both responses against frequency.")
@click.option("--quiet", is_flag=True, help="No progress bar.")
@click.option("--force", is_flag=True, help=FORCE_FILES_HELP)
@handle_errors
def command(config, forward_hz, backward_hz, seed, budget, out, plot, quiet, force):
    """Design a forward/backward impacter pair by the paper's max-min problem.

    For each pair: maximise the worst response r (eq. 12) over initial positions
    x0 in [-c, c] at its own frequency, subject to no response at the other pair's
    frequency from any x0 (eqs. 13-18), over the geometry (A, w, l, c) within the
    config's bounds.  Simulated annealing finds the region, SQP polishes, and the
    result is re-checked on a finer x0 grid and over a 10x longer window.

    Exit status 0 when both designs are feasible, 1 when one is not (outputs are
    still written), 2 for a bad config or argument.

    \b
    Example (Table II and Fig. 10 of the paper):
      vibroplan design configs/paper_table2.yaml --forward 6000 --backward 3000 \\
          --out table2.yaml --plot fig10.png
    """
    from tqdm import tqdm

    from planner.designer.config import load_design_config
    from planner.designer import design_pair

    cfg = load_design_config(config)
    forward_hz = cfg.design.forward_hz if forward_hz is None else forward_hz
    backward_hz = cfg.design.backward_hz if backward_hz is None else backward_hz
    if forward_hz is None or backward_hz is None:
        raise ValueError("give --forward and --backward (or design.forward_hz and "
                         "design.backward_hz in the config)")
    for name, value in (("--forward", forward_hz), ("--backward", backward_hz)):
        if not value > 0:
            raise ValueError(f"{name} must be > 0 Hz, {value!r} was given")
    if out is not None and Path(out).suffix.lower() not in (".yaml", ".yml", ".json"):
        raise ValueError(f"--out must end in .yaml, .yml or .json, {out!r} was given")
    check_output_files("design", [("--out", out), ("--plot", plot)], inputs=[config],
                       force=force)
    kwargs = cfg.design_kwargs()
    if budget is not None:
        kwargs["budget"] = budget
    seed = cfg.design.seed if seed is None else seed
    with tqdm(total=1000, desc="design", unit="", bar_format="{l_bar}{bar}| {elapsed}",
              disable=quiet, file=sys.stderr) as bar:
        pair = design_pair(forward_hz, backward_hz, seed=seed, progress=bar, **kwargs)
    click.echo(f"{cfg.name or config}: forward {forward_hz:g} Hz, backward {backward_hz:g} Hz, "
               f"seed {seed}, budget {kwargs['budget']}, {pair.seconds:.1f} s")
    click.echo(_table(pair))
    for name, d in (("forward", pair.forward), ("backward", pair.backward)):
        if not d.feasible:
            click.echo(f"warning: {name} design is infeasible: {d.message}", err=True)
        elif not d.checks.get("long_window_passed", True):
            click.echo(f"warning: {name} design: {d.message}", err=True)
    if out is not None:
        _write(pair.to_dict(), out, [config], force)
        click.echo(f"wrote {out}")
    if plot is not None:
        from planner.figures.design import pair_response

        with output_files([plot], command="design", inputs=[config], force=force) as (tmp,):
            pair_response(pair, tmp, power=kwargs["power"], amplitude=kwargs["amplitude"],
                          window=kwargs["window"],
                          title=f"{cfg.name or Path(config).stem}: forward {forward_hz:g} Hz, "
                                f"backward {backward_hz:g} Hz")
        click.echo(f"wrote {plot}")
    if not pair.feasible:
        sys.exit(1)
