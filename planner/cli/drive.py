"""``vibroplan drive``: one step's drive signal as a file for a generator, DAQ or sound card."""

from __future__ import annotations

import warnings
from pathlib import Path

import click

from planner.cli._common import (FORCE_FILES_HELP, Finite, check_output_files, handle_errors,
                                 output_file, output_files)

#: The exporters' registry names (``planner.lab.exporters.EXPORTERS``), spelled out here so that
#: ``vibroplan --help`` need not import numpy and scipy; a test keeps the two equal.
FORMATS = ("wav", "wav16", "csv", "arb")

#: Snapping tolerance for a plan's own tones, relative [-]: they are already on their loop's
#: grid (to plan.json's 12 significant digits), so they must land on it again.
PLAN_SNAP_REL = 1e-9

#: Stretch of the waveform the plot shows [s].
PLOT_STRETCH = 5e-3

from planner.core.units import UM  # noqa: E402


@click.command("drive")
@click.argument("spec_or_plan", type=click.Path(exists=True, path_type=Path))
@click.option("--step", "step_name", required=True,
              help="The step: NAME, or SCENE/NAME when several scenes have a step NAME.")
@click.option("--format", "fmt", type=click.Choice(FORMATS), default="wav", show_default=True,
              help="wav: float32 WAV; wav16: int16 WAV; csv: time_s,displacement_m (time_s,input_v "
                   "for a plan with a drive chain); "
                   "arb: Keysight 33500/33600 text file.")
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), callback=output_file,
              help="Output file (default SCENE__NAME with the format's suffix, here). "
                   "A JSON sidecar NAME.json goes next to it. Neither may replace the plan, "
                   "lie inside a plan folder, or replace a file this command did not write "
                   "(exit 2; see --force).")
@click.option("--plot", type=click.Path(dir_okay=False, path_type=Path), callback=output_file,
              help="PNG: a few ms of the waveform and its spectrum with the tones marked.")
@click.option("--sample-rate", type=Finite(min=0, min_open=True),
              help="Sample rate [Hz] (default: the spec's sample_rate_hz, else 192 kHz for "
                   "WAV and 200 kHz otherwise).")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Seed of the phase optimisation's random starts.")
@click.option("--reoptimise", is_flag=True,
              help="Optimise the phases afresh instead of using the plan's (the plan's are the "
                   "ones its verification simulated).")
@click.option("--peak-limit-um", type=Finite(min=0, min_open=True),
              help="Piezo peak displacement [um] (default: the spec's drive.peak_limit_um).")
@click.option("--over-limit", type=click.Choice(["scale", "split"]), default=None,
              help="Above the peak limit: scale every tone down, or split the step into "
                   "sub-steps written as NAME.sub1, NAME.sub2, ... (default: the spec's).")
@click.option("--um-per-v", type=Finite(min=0, min_open=True),
              help="Piezo displacement per volt [um/V], for volts in the sidecar and .arb levels.")
@click.option("--amplifier-gain", type=Finite(min=0, min_open=True),
              help="Piezo amplifier voltage gain [V/V].")
@click.option("--memory-points", type=click.IntRange(min=1),
              help="Instrument memory [points] for the warning (default 1 M, a 33500B; "
                   "16000000 with its memory option).")
@click.option("--force", is_flag=True, help=FORCE_FILES_HELP)
@handle_errors
def command(spec_or_plan, step_name, fmt, out, plot, sample_rate, seed, reoptimise,
            peak_limit_um, over_limit, um_per_v, amplifier_gain, memory_points, force):
    """Synthesise one step's drive and write it for a generator, DAQ or sound card.

    SPEC_OR_PLAN is a plan (plan.json, or the folder `vibroplan plan` wrote) or an
    array spec (YAML), which is planned first.  The drive is the sum of the step's
    tones as a seamless loop (every tone makes whole cycles; frequencies snapped to
    the loop's grid, shifts reported), with the plan's phases or phases optimised
    for a low crest factor.  The file is read back and its spectrum checked against
    the tone table (amplitude within 0.1 %, phase within 1 mrad, continuous loop).

    \b
    Examples:
      vibroplan drive plan_out/plan.json --step s1/forward --format arb --out s1.arb
      vibroplan drive plan_out --step forward --format wav --plot forward.png
    """
    from planner.lab.exporters import EXPORTERS, export, read_sidecar, sidecar_path, verify_export
    from planner.planfile.reader import step_drive
    from planner.synthesis import MAX_LOOP_LENGTH, check_loop_memory

    exporter = EXPORTERS[fmt]

    def check_outputs(out, inputs):
        check_output_files("drive", [("--out", out), ("--out's sidecar", sidecar_path(out)),
                                     ("--plot", plot)], inputs=inputs, force=force)

    if out is not None:   # before any work (a spec is planned first: minutes)
        check_outputs(out, [spec_or_plan / "plan.json" if spec_or_plan.is_dir()
                            else spec_or_plan])
    record, inputs = _load_plan(spec_or_plan)
    step = _select_step(record.steps, step_name)
    if out is None:
        out = Path(f"{step.scene}__{step.name}{exporter.suffix}".replace("/", "_"))
    check_outputs(out, inputs)
    tones = step_drive(step)

    spec_drive = record.spec.drive
    rate = sample_rate or spec_drive.sample_rate_hz or exporter.default_sample_rate
    check_loop_memory(int(rate * MAX_LOOP_LENGTH),
                      f"--sample-rate {rate:g}: a loop of up to {MAX_LOOP_LENGTH:g} s")
    limit_um = peak_limit_um or spec_drive.peak_limit_um
    mode = over_limit or spec_drive.over_limit or "scale"
    from planner.planning.settings import drive_chain

    # a plan with a drive chain (issue 46) plays the amplifier input in volts: each
    # tone divided by the chain's transfer, so that the die feels the plan's tones
    chain = drive_chain(spec_drive)
    if chain is not None and um_per_v is not None:
        raise ValueError("--um-per-v: the plan has a drive chain (drive.chain), whose "
                         "transfer gives the amplifier input's volts; leave it out")
    um_per_v = um_per_v or spec_drive.piezo_um_per_v
    gain = amplifier_gain or spec_drive.amplifier_gain
    if chain is None and (um_per_v is None) != (gain is None):
        raise ValueError("--um-per-v and --amplifier-gain go together (volts need both)")
    limit = None if limit_um is None else limit_um * UM
    # phases optimised afresh (--reoptimise) through a chain with an input limit: for
    # the amplifier input's peak against it (and the die's against peak_limit_um)
    through = {}
    if chain is not None and chain.input_limit is not None:
        through = {"transfer": chain.transfer, "input_limit": chain.input_limit[0]}

    notes = []
    if step.playback == "once":
        # a targets step: its tones gated one after the other, as the plan verified them
        parts = _burst(step, tones, None if reoptimise else tones.phases, rate, seed, notes,
                       through)
    else:
        parts = _synthesise(tones.frequencies, tones.amplitudes,
                            None if reoptimise else tones.phases, rate, seed, limit, mode,
                            notes, through)
    written = []
    for i, (idx, wf) in enumerate(parts, 1):
        path = out if len(parts) == 1 else _sub_path(out, exporter.suffix, i)
        # the file and its sidecar are written, read back and checked beside their
        # targets, and moved in only then
        with output_files([path, sidecar_path(path)], command="drive", inputs=inputs,
                          force=force) as (tmp, _):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")   # the sidecar and the summary carry them
                if chain is not None:
                    export(_amplifier_input(chain, wf, step.key), tmp, fmt, die=wf,
                           amplifier_gain=gain, memory_points=memory_points)
                else:
                    export(wf, tmp, fmt, um_per_v=um_per_v, amplifier_gain=gain,
                           memory_points=memory_points)
            sidecar = read_sidecar(tmp)
            check = verify_export(tmp)
        written.append((path, idx, wf, sidecar, check))

    _summary(step, written, tones.frequencies, limit, notes)
    if plot is not None:
        from planner.figures.plan import waveform_and_spectrum

        with output_files([plot], command="drive", inputs=inputs, force=force) as (tmp,):
            waveform_and_spectrum(written[0][2], tmp, step.key, peak_limit=limit,
                                  stretch=PLOT_STRETCH)
        click.echo(f"plot: {plot}")
    failed = [str(p) for p, *_, check in written if not check.ok]
    if failed:
        raise click.ClickException(f"read-back check failed for {', '.join(failed)}")


# --------------------------------------------------------------------------- input


def _load_plan(path: Path):
    """(the plan, the files read) of a plan (plan.json or its folder) or a spec (YAML),
    which is planned first."""
    from planner.planfile.reader import plan_record, read_plan

    if path.is_file() and path.suffix.lower() in (".yaml", ".yml"):
        from planner.planning import plan

        click.echo(f"planning {path} (the whole pipeline; `vibroplan plan` keeps its result)...")
        return plan_record(plan(path).data, source=f"the plan of {path}"), [path]
    record = read_plan(path)
    return record, [record.path]


def _select_step(steps, name):
    """The step called NAME or SCENE/NAME; ValueError listing the names if none or several."""
    found = [s for s in steps if s.key == name] or [s for s in steps if s.name == name]
    if len(found) == 1:
        return found[0]
    if found:
        which = ", ".join(s.key for s in found)
        raise ValueError(f"--step {name!r} is in several scenes; give one of: {which}")
    raise ValueError(f"--step {name!r}: no such step; the plan has: "
                     f"{', '.join(s.key for s in steps)}")


# --------------------------------------------------------------------------- synthesis


def _synthesise(freqs, amps, phases, rate, seed, limit, mode, notes, through=None):
    """[(tone indices, Waveform)]: one part, or several sub-steps when splitting
    (``through``: a drive chain's ``transfer`` and ``input_limit``, for phases optimised
    afresh against its input's peak too, :func:`planner.synthesis.synthesize`)."""
    import numpy as np

    from planner.synthesis import LoopLengthError, split_tones, synthesize

    f = np.asarray(freqs)
    if phases is not None:
        try:
            # the plan's tones are already on a loop grid: keep it, and the verified phases
            wf = synthesize(f, amps, rate, seed=seed, peak_limit=limit, phases=phases,
                            frequency_tolerance=PLAN_SNAP_REL * f)
        except LoopLengthError:
            notes.append(f"the plan's tones are not on a loop grid at {rate:g} Hz: snapped "
                         f"within 0.1 % and phases optimised afresh, so this drive is not "
                         f"the one the plan verified")
            phases = None
    if phases is None:
        wf = synthesize(f, amps, rate, seed=seed, peak_limit=limit, **(through or {}))
    if wf.scale < 1 and mode == "split":
        groups = split_tones(f, amps, rate, limit, seed=seed, **(through or {}))
        notes.append(f"peak limit {limit / UM:g} um: split into {len(groups)} sub-steps "
                     f"instead of scaling by {wf.scale:.4f}")
        return groups
    return [(np.arange(len(f)), wf)]


def _burst(step, drive, phases, rate, seed, notes, through=None):
    """[(tone indices, Burst)] of a gated step (``playback: once``): its tones, each
    gated at its recorded ``start_s`` and ``gate_s`` with the step's ramp
    (:func:`planner.synthesis.gating.gate`); one tone plays at a time, so no peak limit applies
    to the sum."""
    import numpy as np

    from planner.synthesis.gating import gate

    starts = [t.start_s for t in step.tones]
    gates = [t.gate_s for t in step.tones]
    ramp = (step.gating or {}).get("ramp_s")
    if any(not isinstance(x, (int, float)) for x in starts + gates + [ramp]):
        raise ValueError(f"step {step.key}: a gated step (playback: once) needs each "
                         "tone's start_s and gate_s and gating.ramp_s")
    [(idx, wf)] = _synthesise(drive.frequencies, drive.amplitudes, phases, rate, seed, None,
                              "scale", notes, through)
    notes.append("a gated burst, played once (not looped): each tone fades in at its "
                 f"start_s and out at its gate_s over {ramp * 1e3:g} ms")
    return [(idx, gate(wf, np.asarray(starts), np.asarray(gates), ramp))]


def _amplifier_input(chain, wf, key):
    """The amplifier input [V] of the die's drive ``wf`` through ``chain``, held to the
    chain's input limit (ValueError naming the step, its peak and the limit: the plan's
    own phases were kept under it; phases optimised afresh may not be)."""
    from planner.core.errors import PlanningError
    from planner.planning.chain import played_input

    try:
        v = played_input(chain, wf)
    except PlanningError as exc:
        raise ValueError(str(exc)) from None
    limit = chain.input_limit
    if limit is not None and v.peak > limit[0] * (1 + 1e-9):
        raise ValueError(f"step {key}: the amplifier input peaks at {v.peak:.4g} V, above "
                         f"{limit[0]:.4g} V ({limit[1]}): play the plan's phases (without "
                         "--reoptimise) or lower the drive")
    return v


def _sub_path(out: Path, suffix: str, i: int) -> Path:
    name = out.name
    stem = name[: -len(suffix)] if name.endswith(suffix) else out.stem
    ext = suffix if name.endswith(suffix) else out.suffix
    return out.with_name(f"{stem}.sub{i}{ext}")


# --------------------------------------------------------------------------- output


def _summary(step, written, freqs, limit, notes):
    moving = ", ".join([str(d) for d in step.forward] + [f"{d} (back)" for d in step.backward])
    count = f"{len(freqs)} tone{'s' if len(freqs) != 1 else ''}"
    click.echo(f"step {step.key}: {count}" + (f"; moves {moving}" if moving else ""))
    for path, idx, wf, sidecar, check in written:
        if len(written) > 1:
            click.echo(f"\nsub-step {path.name}: tones {', '.join(str(i + 1) for i in idx)}")
        click.echo(f"  {'f [Hz]':>12} {'shift [Hz]':>11} {'Z [um]':>9} {'phase [rad]':>12}")
        for f, s, a, p in zip(wf.frequencies, wf.frequency_shift, wf.amplitudes, wf.phases):
            click.echo(f"  {f:12.3f} {s:+11.4f} {a / UM:9.4f} {p:+12.6f}")
        click.echo(f"loop {wf.loop_length * 1e3:.6g} ms = {wf.loop_points} points at "
                   f"{wf.sample_rate:g} Hz; crest factor {wf.crest_factor:.3f} (peak "
                   f"{wf.peak / UM:.4g} um, rms {wf.rms / UM:.4g} um"
                   + (f", limit {limit / UM:g} um" if limit else "") + f"); scale {wf.scale:.4f}")
        volts = sidecar.get("volts_full_scale")
        if sidecar.get("signal") == "amplifier_input_v":
            click.echo(f"wrote {path} (+ {path.name}.json): the amplifier input through "
                       f"the plan's drive chain, full scale {sidecar['full_scale_v']:.6g} V "
                       f"(peak {sidecar['peak_v']:.4g} V; the die's peak "
                       f"{sidecar['die_peak_m'] / UM:.4g} um)")
        else:
            click.echo(f"wrote {path} (+ {path.name}.json): full scale "
                       f"{sidecar['full_scale_m'] / UM:.6g} um"
                       + (f" = {volts:.6g} V at the generator" if volts else ""))
        click.echo(f"read back: {check}")
        for message in sidecar["warnings"]:
            click.echo(f"warning: {message}")
    for message in notes:
        click.echo(f"note: {message}")
