"""The per-chip worker of a yield run: sample a chip, check the plan's drive on it and,
with ``--replan``, measure it, re-plan it and (with ``--trim``) trim it."""

from __future__ import annotations

import numpy as np

from model import halves
from planner._random import chip_seed
from planner.fabrication import sample_chip
from planner.planning.plan_file import plan_record
from planner.afterfab.checks import check_drive, drive_of
from planner.yield_.inputs import Payload

#: Why a re-plan failed, in the order reports list them (a chip may have several):
#: two impacters the spec must tell apart can no longer be (the re-plan's unresolved
#: conflict: the idle one responds at every candidate tone of the other -- close
#: resonances, or response bands that overlap although the resonances do not); a
#: scaled tone fell beyond ``drive.band_hz``; the re-plan does not verify even on the
#: measured models it was made for; it verifies there but not on the chip's true
#: models (measurement noise, or what the re-plan's model does not know: the as-built
#: mass, damping, gap and sliders); its steps pass on the true models but the
#: carried-state check fails (the re-plan does not simulate the scenes); the chip
#: cannot be built.
REPLAN_CAUSES = ("cannot be told apart", "outside band", "fails on the measured models",
                 "fails only on the true models", "carried state", "unbuildable",
                 "drive not playable")


def verify_chip(payload: Payload, scale_index: int, chip_index: int, scale: float) -> dict:
    """Sample chip ``chip_index`` at sigma scale ``scale`` and run every check on it.

    Returns
    -------
    dict
        ``passed``, ``carried_passed`` (equal to ``passed``: the carried-state check is
        part of the pass), ``failures`` (kind -> failing rows), ``nodes`` (the
        impacter pairs implicated in a failure: sorted :class:`~planner.nodes.Node`),
        ``scale_index``, ``chip``; with
        ``payload.replan`` also ``replan`` (see :func:`replan_chip_on`) and
        ``seconds`` (wall time of the nominal checks and of the re-plan [s]).
    """
    import time

    if payload.threads:
        import numba

        # per thread: every task sets it in the worker thread that runs it
        numba.set_num_threads(min(payload.threads, numba.config.NUMBA_NUM_THREADS))
    t0 = time.perf_counter()
    rng = np.random.default_rng(chip_seed(payload.seed, scale, chip_index))
    chip = sample_chip(payload.design, payload.fabrication, rng, scale)
    out = {"scale_index": scale_index, "chip": chip_index}
    if chip.unbuildable:
        # a node or a device (its slider) that cannot be built
        nodes = {n for n in payload.nodes for x in chip.unbuildable
                 if n.text == x or n.device == x}
        out.update(passed=False, carried_passed=False,
                   failures={"unbuildable": len(chip.unbuildable)}, nodes=sorted(nodes))
        if payload.replan:
            out["replan"] = {"passed": False, "measured_passed": False,
                             "causes": ["unbuildable"], "failures": {"unbuildable": 1},
                             "collisions": [], "outside_band": []}
            if payload.trim:
                out["trim"] = {"passed": False, "trimmed": [], "causes": ["unbuildable"],
                               "failures": {"unbuildable": 1}}
            out["seconds"] = {"nominal": time.perf_counter() - t0, "replan": 0.0}
        return out
    settings = payload.settings
    # re-planning, the plan's own drive is only a reference: its checks stop at the
    # first failing step (a chip the die moved fails the first one it plays)
    got = check_drive(settings, payload.loaded.steps, payload.waveforms, payload.dwells,
                      chip.impacters, chip.sliders, first_failure=payload.replan)
    out.update(passed=got["passed"], carried_passed=got["passed"],
               failures=got["failures"], nodes=sorted(got["nodes"]))
    if payload.replan:
        t1 = time.perf_counter()
        out["replan"] = replan_chip_on(payload, settings, scale, chip_index, chip, got)
        out["seconds"] = {"nominal": t1 - t0, "replan": time.perf_counter() - t1}
        if payload.trim:
            t2 = time.perf_counter()
            out["trim"] = trim_chip_on(payload, settings, scale, chip_index, chip, got,
                                       out["replan"])
            out["seconds"]["trim"] = time.perf_counter() - t2
    return out


def trim_chip_on(payload: Payload, settings, scale: float, chip_index: int, chip,
                 nominal: dict, replanned: dict) -> dict:
    """Trim a chip the re-plan could not rescue because two of its impacters cannot be
    told apart, re-measure it, re-plan it and verify the drive on its trimmed true models.

    A chip the re-plan rescued needs no trim (its result is the re-plan's); a chip the
    re-plan lost for another reason is not helped by one.  The trims are chosen from the
    chip's measurement (:func:`planner.afterfab.trim.plan_trim`); each lands on its target times
    (1 + precision z / 100) of the true resonance's move, z from the chip's seed
    (:func:`planner.afterfab.trim.trimmed_resonances`); the trimmed chip is measured again (the
    same noise level, new draws) and re-planned.

    Returns
    -------
    dict
        ``passed``, ``trimmed`` (impacters trimmed), ``causes`` (``cannot be trimmed``
        naming the moves beyond the range, or the re-plan's causes after the trim),
        ``failures`` (kind -> rows on the trimmed true models).
    """
    from planner.afterfab.replan import measured_resonances
    from planner.afterfab.drive import must_differ
    from planner.afterfab.separations import separations_of
    from planner.spec import TrimSpec
    from planner.afterfab.trim import plan_trim, trim_models, trimmed_resonances

    if replanned["passed"] or not replanned["collisions"]:
        return {**{k: replanned[k] for k in ("passed", "causes", "failures")}, "trimmed": []}
    spec = payload.record.spec.trim or TrimSpec()
    precision = (spec.precision_pct if payload.trim_precision_pct is None
                 else payload.trim_precision_pct)
    freqs = measured_frequencies(payload, scale, chip_index, chip)
    measured = measured_resonances(payload.record, _as_measured(freqs))
    mean = {n: float(np.mean(v)) if isinstance(v, tuple) else v for n, v in measured.items()}
    tp = plan_trim(separations_of(payload.record, settings), mean, must_differ(settings.steps),
                   range_pct=spec.range_pct, direction=spec.direction,
                   precision_pct=precision)
    if not tp.ok:
        return {"passed": False, "trimmed": [], "failures": {},
                "causes": ["cannot be trimmed"],
                "beyond_range": [f["impacter"] for f in tp.failures]}
    seq = chip_seed(payload.seed, scale, chip_index).spawn(3)
    actual = trimmed_resonances(tp, precision, np.random.default_rng(seq[1]))
    ratios = {n: actual[n] / tp.measured[n] for n in tp.moved}
    true = trim_models(chip.impacters, ratios, spec.direction)
    again = _as_measured(_measure(payload, true, seq[2]))     # the trimmed chip measured again
    got = _replan_and_check(payload, settings, again, true, chip.sliders,
                            (nominal["steps_passed"], nominal["rows"]), remeasure=tp.moved)
    return {"passed": got["passed"], "trimmed": list(tp.moved), "causes": got["causes"],
            "failures": got["failures"]}


def measured_frequencies(payload: Payload, scale: float, chip_index: int, chip) -> dict:
    """Node id -> (true, measured) natural frequency [Hz] of a sampled chip; for a pair
    of unequal halves each is a tuple (half a, half b).

    measured = true (1 + pct z / 100), z standard normal from the first child of the
    chip's SeedSequence (two draws per node in the design's order, the second for its
    second half, whatever pct, so the same chip gets the same normals at every noise
    level), floored at a tenth of the true frequency (a measurement never finds a
    resonance at or below 0 Hz; only a noise of tens of per cent reaches the floor).
    """
    seq = chip_seed(payload.seed, scale, chip_index).spawn(1)[0]
    return _measure(payload, chip.impacters, seq)


def _measure(payload: Payload, impacters: dict, seq) -> dict:
    """:func:`measured_frequencies` of the models ``impacters`` (node id ->
    :class:`model.Impacter`), with the normals drawn from the SeedSequence ``seq``."""
    z = np.random.default_rng(seq).standard_normal((len(payload.design.nodes), 2))
    out = {}
    for node, zi in zip(payload.design.nodes, z):
        parts = halves(impacters[node.id])
        true = [float(h.natural_frequency) for h, _ in parts]
        meas = [nu * max(1.0 + payload.measure_noise_pct / 100.0 * float(zk), 0.1)
                for nu, zk in zip(true, zi)]
        out[node.id] = ((true[0], meas[0]) if len(parts) == 1 else
                        (tuple(true), tuple(meas)))
    return out


def _as_measured(freqs: dict) -> dict:
    """The re-plan's ``measured`` of :func:`measured_frequencies`' pairs."""
    out = {}
    for n, (_, m) in freqs.items():
        if isinstance(m, tuple):
            out[n] = {"natural_frequency_hz": float(np.mean(m)), "halves_hz": m}
        else:
            out[n] = {"natural_frequency_hz": m}
    return out


def replan_chip_on(payload: Payload, settings, scale: float, chip_index: int, chip,
                   nominal: dict) -> dict:
    """Measure a sampled chip, re-plan its drive, verify it on the chip's true models.

    Parameters
    ----------
    payload : Payload
        With ``record`` and ``measure_noise_pct``.
    settings : Settings
        The plan's settings (the checks).
    scale : float
        The chip's sigma scale.
    chip_index : int
        The chip's index (its measurement noise is seeded from both, :func:`chip_seed`).
    chip : planner.fabrication.Chip
        The sampled chip (its impacters and sliders are the truth).
    nominal : dict
        :func:`check_drive` of the original drive on this chip: passed on as the
        re-plan's ``original`` so that it is not verified a second time.

    Returns
    -------
    dict
        ``passed`` (the re-planned drive passes every check on the true models),
        ``measured_passed`` (the re-plan verified on the models it was made from),
        ``causes`` (:data:`REPLAN_CAUSES` that apply when it fails), ``failures``
        (kind -> rows on the true models), ``collisions`` (pairs no drive tells apart:
        ``pair``, their measured resonances ``as_built_hz``, ``apart_hz`` and the
        ``needs_hz`` they would need), ``outside_band`` (impacters whose tone fell
        beyond the band), ``split_steps`` (steps played as sub-steps),
        ``tones_moved``.
    """
    freqs = measured_frequencies(payload, scale, chip_index, chip)
    return _replan_and_check(payload, settings, _as_measured(freqs), chip.impacters,
                             chip.sliders, (nominal["steps_passed"], nominal["rows"]))


def _replan_and_check(payload, settings, measured, impacters, sliders, original,
                      remeasure=()):
    """Re-plan from ``measured`` and verify the drive on the true models (a yield's
    re-plan and its trim's; ``remeasure``: the trimmed impacters, whose separations the
    re-plan measures again)."""
    from planner.afterfab.replan import replan_chip
    from planner.synthesis import LoopLengthError

    try:
        ok, plan = replan_chip(payload.record, measured, settings=settings,
                               original=original, record=False, remeasure=remeasure)
    except LoopLengthError:
        # this chip's tones fit no loop the synthesis may play: the chip fails (with
        # that cause), the study goes on
        return {"passed": False, "measured_passed": False, "causes": ["drive not playable"],
                "failures": {}, "collisions": [], "outside_band": [], "split_steps": [],
                "tones_moved": 0}
    data = plan.data
    rp = data["replan"]
    collisions = [{k: c[k] for k in ("pair", "as_built_hz", "apart_hz", "needs_hz")}
                  for c in rp["inseparable"]]
    if collisions:      # no drive can pass: not simulated on the true models
        return {"passed": False, "measured_passed": False,
                "causes": ["cannot be told apart"], "failures": {}, "collisions": collisions,
                "outside_band": list(rp["outside_band"]),
                "split_steps": sorted(rp["split_steps"]), "tones_moved": len(rp["moved"])}
    # the re-plan's plan.json, read back as any plan is
    steps, waveforms, dwells = drive_of(plan_record(data, source="the chip's re-plan"))
    got = check_drive(settings, steps, waveforms, dwells, impacters, sliders)
    causes = []
    if not got["passed"]:
        if rp["outside_band"]:
            causes.append("outside band")
        if not ok:
            causes.append("fails on the measured models")
        elif got["steps_passed"]:
            causes.append("carried state")
        else:
            causes.append("fails only on the true models")
    return {"passed": got["passed"], "measured_passed": bool(ok), "causes": causes,
            "failures": got["failures"], "collisions": collisions,
            "outside_band": list(rp["outside_band"]),
            "split_steps": sorted(rp["split_steps"]),
            "tones_moved": sum(1 for m in rp["moved"]
                               if m["frequency_hz"] != m["original_frequency_hz"])}

