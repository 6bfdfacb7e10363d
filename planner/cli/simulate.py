"""``vibroplan simulate``: one device under one tone, like the paper's Fig. 7."""

from __future__ import annotations

import json

import click

from planner.cli._common import (FORCE_FILES_HELP, Finite, check_output_files, handle_errors,
                                 output_file, output_files)

from planner.core.units import UM  # noqa: E402


@click.command("simulate")
@click.argument("config", type=click.Path(dir_okay=False))
@click.option("--freq", "freqs", type=Finite(min=0, min_open=True), multiple=True, required=True,
              help="Drive frequency [Hz]; repeat to compare several (as in Fig. 7).")
@click.option("--x0", "x0_um", type=Finite(), default=None,
              help="Initial impacter position [um] (default: the config's, 0).")
@click.option("--duration", "duration_ms", type=Finite(min=0, min_open=True), default=None,
              help="Simulated time [ms] (default: the config's, 3 ms as in the paper).")
@click.option("--pair", type=click.Choice(["forward", "backward"]), default="forward",
              show_default=True, help="Which impacter pair to drive.")
@click.option("--amplitude-um", type=Finite(min=0, min_open=True), default=None,
              help="Drive amplitude Z0 [um], instead of the config's power convention.")
@click.option("--method", type=click.Choice(["exact", "rk4"]), default="exact", show_default=True,
              help="exact: closed-form event-driven solver; rk4: the paper's fixed-step RK4.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object instead of a table.")
@click.option("--plot", type=click.Path(dir_okay=False), callback=output_file, default=None,
              help="Write a Fig. 7-style PNG: slider and impacter position against time.")
@click.option("--force", is_flag=True, help=FORCE_FILES_HELP)
@handle_errors
def command(config, freqs, x0_um, duration_ms, pair, amplitude_um, method, as_json, plot,
            force):
    """Simulate a device's impacter and slider under a one-tone drive.

    Reports every impact (time and velocity v- just before it), the response r
    of eq. (12) (first impact excluded), and the slider's displacement and mean
    velocity with stick-slip friction.

    \b
    Example (the paper's Fig. 7: 6.2 kHz moves the slider ~4x faster than 5.2 kHz):
      vibroplan simulate configs/paper_fig7.yaml --freq 6200 --freq 5200 --plot fig7.png
    """
    from model import Drive, simulate_slider
    from planner.config import load_device

    check_output_files("simulate", [("--plot", plot)], inputs=[config], force=force)
    device = load_device(config)
    sim = device.config.simulation
    x0 = (sim.x0_um if x0_um is None else x0_um) * UM
    duration = (sim.duration_ms if duration_ms is None else duration_ms) * 1e-3
    impacter = device.impacter(pair)
    direction = 1.0 if pair == "forward" else -1.0
    runs = []
    results = []
    for f in freqs:
        drive = Drive([f], [amplitude_um * UM], [0.0]) if amplitude_um else device.drive(f)
        res = simulate_slider(impacter, device.slider, drive, x0, sim.v0_m_s, duration,
                              direction=direction, trajectory=plot is not None, method=method)
        runs.append((f"{f:g} Hz", res, impacter.gap))
        results.append({
            "config": str(config),
            "pair": pair,
            "method": method,
            "frequency_hz": f,
            "amplitude_m": float(drive.amplitudes[0]),
            "natural_frequency_hz": impacter.natural_frequency,
            "x0_m": x0,
            "duration_s": duration,
            "status": res.status,
            "n_impacts": res.impacts.n_impacts,
            "impacts": [{"t_s": float(t), "v_minus_m_s": float(v)}
                        for t, v in zip(res.impacts.times, res.impacts.velocities)],
            "chatter": [{"t_s": float(t), "v_minus_sum_m_s": float(v)}
                        for t, v in zip(res.impacts.chatter_times, res.impacts.chatter_sums)],
            "response_n": res.impacts.response,
            "slider_displacement_m": res.displacement,
            "slider_mean_velocity_m_s": res.mean_velocity,
        })
    if plot:
        from planner.figures.device import time_response

        with output_files([plot], command="simulate", inputs=[config], force=force) as (tmp,):
            time_response(runs, tmp, title=f"{device.config.name or config}: {pair} pair, "
                          f"nu_n = {impacter.natural_frequency:.4g} Hz")
    if as_json:
        out = results[0] if len(results) == 1 else {"runs": results}
        click.echo(json.dumps(out, indent=2))
        return
    click.echo(f"{device.config.name or config}: {pair} impacter, m = {impacter.mass:.4g} kg, "
               f"k = {impacter.stiffness:.4g} N/m, nu_n = {impacter.natural_frequency:.1f} Hz, "
               f"gap = {impacter.gap / UM:g} um, x0 = {x0 / UM:g} um, {duration * 1e3:g} ms")
    click.echo(f"{'freq [Hz]':>10} {'Z0 [um]':>8} {'impacts':>8} {'r [nN]':>10} "
               f"{'slider [um]':>12} {'speed [mm/s]':>13}  status")
    for item in results:
        click.echo(f"{item['frequency_hz']:>10.1f} {item['amplitude_m'] / UM:>8.3f} "
                   f"{item['n_impacts']:>8d} {item['response_n'] * 1e9:>10.3f} "
                   f"{item['slider_displacement_m'] / UM:>12.3f} "
                   f"{item['slider_mean_velocity_m_s'] * 1e3:>13.3f}  {item['status']}")
    if len(results) == 1 and results[0]["impacts"]:
        click.echo("impacts (t [ms], v- [m/s]): " + ", ".join(
            f"({i['t_s'] * 1e3:.4f}, {i['v_minus_m_s']:.4g})" for i in results[0]["impacts"]))
    if plot:
        click.echo(f"wrote {plot}")
