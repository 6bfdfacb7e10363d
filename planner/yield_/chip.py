"""The per-chip worker of a yield run: sample a chip and run the after-fabrication loop
on it with its truth known (:func:`planner.afterfab.loop.run_loop`: the plan's drive
checked on it and, with ``--replan``, the chip measured, re-planned, tuned with
``--tune`` and trimmed with ``--trim``)."""

from __future__ import annotations

import dataclasses

import numpy as np

from planner.core.rng import chip_seed
from planner.fabrication.tolerances import sample_chip
from planner.fabrication.wafer import line_width_offsets
from planner.afterfab.loop import LoopJob, Truth, run_loop
from planner.yield_.inputs import Payload
from planner.yield_.results import ChipResult


def verify_chip(payload: Payload, scale_index: int, chip_index: int,
                scale: float) -> ChipResult:
    """Sample chip ``chip_index`` at sigma scale ``scale`` and run the after-fabrication
    loop on it (:func:`planner.afterfab.loop.run_loop`, its truth known).

    Returns
    -------
    ChipResult
        ``passed``, ``carried_passed`` (equal to ``passed``: the carried-state check is
        part of the pass), ``failures`` (kind -> failed checks), ``nodes`` (the
        impacter pairs implicated in a failure: sorted :class:`~planner.core.nodes.Node`),
        ``scale_index``, ``chip``; with ``payload.replan`` also ``replan`` (the chip
        measured, re-planned and verified on its true models; tuned with
        ``payload.tune``) and ``seconds`` (wall time of the nominal checks and of the
        re-plan [s]); with ``payload.trim`` also ``trim``.
    """
    from planner.planning.verify import shared_device_checks

    # one chip is checked several times over (the plan's drive, the re-plan on its
    # measured models and its true ones, the same after the tune and after a trim): a
    # device checked again with the same models, step and drive is answered from memory
    with shared_device_checks():
        return _verify_chip(payload, scale_index, chip_index, scale)


def _verify_chip(payload: Payload, scale_index: int, chip_index: int,
                 scale: float) -> ChipResult:
    """:func:`verify_chip`'s work."""
    import time

    if payload.threads:
        import numba

        # per thread: every task sets it in the worker thread that runs it
        numba.set_num_threads(min(payload.threads, numba.config.NUMBA_NUM_THREADS))
    t0 = time.perf_counter()
    rng = np.random.default_rng(chip_seed(payload.seed, scale, chip_index))
    chip = sample_chip(payload.design, payload.fabrication, rng, scale,
                       line_width_offsets(payload.design.spec, payload.fabrication,
                                          payload.seed, scale, chip_index))
    sampled = time.perf_counter() - t0
    got = run_loop(loop_job(payload), truth=truth_of(payload, scale, chip_index, chip))
    nominal = got.nominal
    seconds = (dataclasses.replace(got.seconds, nominal=sampled + got.seconds.nominal)
               if payload.replan else None)
    return ChipResult(scale_index=scale_index, chip=chip_index, passed=nominal.passed,
                      carried_passed=nominal.passed, failures=nominal.failures,
                      nodes=nominal.nodes, replan=got.replan, trim=got.trim,
                      seconds=seconds)


def loop_job(payload: Payload) -> LoopJob:
    """The after-fabrication loop's job of a yield run: the plan's drive, and the stages
    and noises the command asked for (a study keeps no outputs)."""
    return LoopJob(payload.record, payload.settings, payload.loaded.steps,
                   payload.waveforms, payload.dwells, nodes=payload.nodes,
                   replan=payload.replan, tune=payload.tune, trim=payload.trim,
                   measure_noise_pct=payload.measure_noise_pct,
                   trim_precision_pct=payload.trim_precision_pct,
                   tune_tones=payload.tune_tones, tune_noise_pct=payload.tune_noise_pct)


def truth_of(payload: Payload, scale: float, chip_index: int, chip) -> Truth:
    """A sampled chip (:class:`planner.fabrication.tolerances.Chip`) as the loop's truth,
    its noises drawn from the chip's own seed (:func:`chip_seed`)."""
    return Truth(chip.impacters, chip.sliders, chip_seed(payload.seed, scale, chip_index),
                 tuple(chip.unbuildable))


def measured_frequencies(payload: Payload, scale: float, chip_index: int, chip) -> dict:
    """Node id -> (true, measured) natural frequency [Hz] of a sampled chip; for a pair
    of unequal halves each is a tuple (half a, half b): what the loop measures of it
    (:meth:`planner.afterfab.loop.Truth.measure`, at the payload's noise)."""
    from planner.afterfab.measurement import true_resonances

    measured = truth_of(payload, scale, chip_index, chip).measure(
        payload.design.node_ids, payload.measure_noise_pct)
    true = true_resonances(chip.impacters)
    return {n: (true[n], measured[n].resonance) for n in measured}
