"""The statistics of a yield run: yields with Wilson intervals, the failing checks and
causes tallied over the chips, and the content of ``yield.json``."""

from __future__ import annotations

import json

from planner.arrayspec import TrimSpec
from planner.afterfab.checks import KINDS
from planner.afterfab.outcome import CAUSES, REPLAN_CAUSES
from planner.yield_.results import ChipResult
from planner.core.intervals import wilson_interval


def scale_key(scale: float) -> str:
    """yield.json's key of a sigma scale: its short form (``"1"``, ``"0.5"``) when that
    reads back as the same number, else its full one (``"1.0000001"``)."""
    short = f"{scale:g}"
    return short if float(short) == scale else repr(float(scale))


def _ordered(counts: dict, order) -> dict:
    rank = {k: i for i, k in enumerate(order)}
    return dict(sorted(counts.items(), key=lambda kv: (-kv[1], rank.get(kv[0], 99), kv[0])))


def _tally(lists, order) -> dict:
    """How many of ``lists`` (each a chip's causes or failing checks) name each item,
    most frequent first (:func:`_ordered`)."""
    counts = {}
    for items in lists:
        for k in items:
            counts[k] = counts.get(k, 0) + 1
    return _ordered(counts, order)


def _summary(results, chips):
    """The yields and tallies of one scale's chips (:class:`ChipResult`)."""
    passed = sum(r.passed for r in results)
    failures = _tally((r.failures for r in results), KINDS)
    both = sum(r.carried_passed for r in results)
    out = {"chips": chips, "passed": passed, "yield": passed / chips,
           "ci95": wilson_interval(passed, chips), "failures": failures,
           "carried_state": {"passed": both, "yield": both / chips,
                             "ci95": wilson_interval(both, chips)}}
    if results and results[0].replan is not None:
        out["replan"] = _replan_summary(results, chips)
        if results[0].replan.tuned is not None:
            out["tune"] = _tune_summary(results, chips)
    if results and results[0].trim is not None:
        out["trim"] = _trim_summary(results, chips)
    return out


def _trim_summary(results, chips):
    """The yield with trims: chips the re-plan passed, or that a trim and a re-plan of
    the trimmed chip rescued."""
    ok = sum(r.trim.passed for r in results)
    failed = [r.trim for r in results if not r.trim.passed]
    return {"chips": chips, "passed": ok, "yield": ok / chips,
            "ci95": wilson_interval(ok, chips),
            "trimmed": sum(1 for r in results if r.trim.trimmed),
            "rescued": sum(1 for r in results if r.trim.passed and not r.replan.passed),
            "causes": _tally((t.causes for t in failed), CAUSES),
            "failures": _tally((t.failures for t in failed), KINDS)}


def _replan_summary(results, chips):
    """The re-plan's yield, its failure causes and the chips it rescued or lost."""
    ok = sum(r.replan.passed for r in results)
    return {"chips": chips, "passed": ok, "yield": ok / chips,
            "ci95": wilson_interval(ok, chips),
            "rescued": sum(1 for r in results if r.replan.passed and not r.passed),
            "lost": sum(1 for r in results if r.passed and not r.replan.passed),
            "measured_passed": sum(r.replan.measured_passed for r in results),
            "causes": _tally((r.replan.causes for r in results), REPLAN_CAUSES),
            "failures": _tally((r.replan.failures for r in results), KINDS),
            **_repairs_summary([r.replan for r in results])}


def _repairs_summary(outcomes) -> dict:
    """``repairs`` (kind -> repairs made over the chips) and ``repaired_chips`` (kind ->
    chips with one), kinds in :data:`planner.afterfab.replan.REPAIR_KINDS`' order; empty
    when no re-plan repaired anything (yield.json then as before)."""
    from planner.afterfab.replan import REPAIR_KINDS

    made, chips = dict.fromkeys(REPAIR_KINDS, 0), dict.fromkeys(REPAIR_KINDS, 0)
    for o in outcomes:
        for k, v in (o.repairs or {}).items():
            made[k] += int(v)
            chips[k] += 1
    if not any(made.values()):
        return {}
    return {"repairs": {k: v for k, v in made.items() if v},
            "repaired_chips": {k: v for k, v in chips.items() if v}}


def _tune_summary(results, chips):
    """The yield with the re-planned chips tuned on the chip (:mod:`planner.afterfab.tune`)."""
    tuned = [r.replan.tuned for r in results]
    ok = sum(t.passed for t in tuned)
    return {"chips": chips, "passed": ok, "yield": ok / chips,
            "ci95": wilson_interval(ok, chips),
            "rescued": sum(1 for r, t in zip(results, tuned)
                           if t.passed and not r.replan.passed),
            "lost": sum(1 for r, t in zip(results, tuned)
                        if r.replan.passed and not t.passed),
            "kept_replan": sum(1 for t in tuned if t.kept_replan),
            "causes": _tally((t.causes for t in tuned), REPLAN_CAUSES),
            "failures": _tally((t.failures for t in tuned), KINDS),
            **_repairs_summary(tuned)}


def _chip_record(r: ChipResult) -> dict:
    """One chip's line of yield.json's ``replan.per_chip``."""
    rp, tu, tr = r.replan, r.replan.tuned, r.trim
    return {"chip": r.chip, "nominal_passed": r.passed, "replan_passed": rp.passed,
            "measured_passed": rp.measured_passed, "causes": list(rp.causes),
            "failures": _ordered(rp.failures, KINDS),
            "collisions": [c.to_dict() for c in rp.collisions],
            "outside_band": list(rp.outside_band),
            "split_steps": list(rp.split_steps or ()), "tones_moved": rp.tones_moved or 0,
            **({"repairs": dict(rp.repairs)} if rp.repairs else {}),
            **({"tuned_passed": tu.passed, "tuned_causes": list(tu.causes),
                "tuned_windows": tu.windows,
                **({"tuned_kept_replan": True} if tu.kept_replan else {})}
               if tu is not None else {}),
            **({"trim_passed": tr.passed, "trimmed": list(tr.trimmed),
                "trim_causes": list(tr.causes)} if tr is not None else {})}


def yield_record(payload, chips: int, scales: list[float], nominal: ChipResult,
                 results: list) -> dict:
    """The content of ``yield.json`` (docs/yield.md) from the chips' results.

    Parameters
    ----------
    payload : planner.yield_.Payload
        The run's payload (its seed, tolerance model, options and impacters).
    chips : int
        Chips per sigma scale.
    scales : list of float
        The sigma scales, in the order given; the one of 1 (else the first) is the
        headline's.
    nominal : ChipResult
        :func:`planner.yield_.verify_chip`'s result of the nominal chip.
    results : list of ChipResult
        Those of every other chip, of every scale.
    """
    main = scales.index(1.0) if 1.0 in scales else 0
    out_scale = {}
    for j, s in enumerate(scales):
        mine = [r for r in results if r.scale_index == j]
        out_scale[j] = (_summary(mine, chips), mine)
    summary, mine = out_scale[main]
    counts = dict.fromkeys(payload.nodes, 0)
    for r in mine:
        for n in r.nodes:
            counts[n] += 1
    data = {
        "chips": chips, "passed": summary["passed"], "yield": summary["yield"],
        "ci95": summary["ci95"], "ci95_method": "wilson", "seed": payload.seed,
        "sigma_scale": scales[main],
        "tolerance": json.loads(payload.fabrication.model_dump_json()),
        "failures": summary["failures"],
        "impacters": {n.text: counts[n] / chips for n in counts},
        "carried_state": summary["carried_state"],
        "nominal": {"passed": nominal.passed, "failures": nominal.failures,
                    "carried_passed": nominal.carried_passed},
        "failed_chips": [r.chip for r in mine if not r.passed],
    }
    if payload.replan:
        rp = summary["replan"]
        data["replan"] = {
            "measure_noise_pct": payload.measure_noise_pct,
            "chips": chips, "passed": rp["passed"], "yield": rp["yield"], "ci95": rp["ci95"],
            "nominal_drive": {"passed": summary["passed"], "yield": summary["yield"],
                              "ci95": summary["ci95"]},
            "rescued": rp["rescued"], "lost": rp["lost"],
            "measured_passed": rp["measured_passed"],
            "causes": rp["causes"], "failures": rp["failures"],
            **{k: rp[k] for k in ("repairs", "repaired_chips") if k in rp},
            "nominal": _chip_record(nominal),
            "failed_chips": [r.chip for r in mine if not r.replan.passed],
            "per_chip": [_chip_record(r) for r in mine],
        }
    if payload.tune:
        tu = summary["tune"]
        data["tune"] = {
            "tones_per_impacter": payload.tune_tones,
            "speed_noise_pct": payload.tune_noise_pct,
            **{k: tu[k] for k in ("chips", "passed", "yield", "ci95", "rescued", "lost",
                                  "kept_replan", "causes", "failures")},
            **{k: tu[k] for k in ("repairs", "repaired_chips") if k in tu},
            "failed_chips": [r.chip for r in mine if not r.replan.tuned.passed],
        }
    if payload.trim:
        tr = summary["trim"]
        spec_trim = payload.record.spec.trim
        data["trim"] = {
            "precision_pct": (payload.trim_precision_pct if payload.trim_precision_pct
                              is not None else (spec_trim.precision_pct if spec_trim
                                                else TrimSpec().precision_pct)),
            **{k: tr[k] for k in ("chips", "passed", "yield", "ci95", "trimmed", "rescued",
                                  "causes", "failures")},
            "failed_chips": [r.chip for r in mine if not r.trim.passed],
        }
    if len(scales) > 1 or scales != [1.0]:
        keys = ("yield", "ci95", "passed", "failures", "carried_state")
        data["by_sigma_scale"] = {}
        for j, s in enumerate(scales):
            entry = {k: out_scale[j][0][k] for k in keys}
            if payload.replan:
                entry["replan"] = {k: out_scale[j][0]["replan"][k]
                                   for k in ("yield", "ci95", "passed", "rescued", "causes")}
            if payload.tune:
                entry["tune"] = {k: out_scale[j][0]["tune"][k]
                                 for k in ("yield", "ci95", "passed", "rescued", "causes")}
            if payload.trim:
                entry["trim"] = {k: out_scale[j][0]["trim"][k]
                                 for k in ("yield", "ci95", "passed", "rescued", "causes")}
            if payload.fabrication.wafer is not None:
                # every scale's dies counted; the wafer block maps the headline's
                from planner.yield_.dies import chip_outcome, outcome_counts

                entry["wafer_outcomes"] = outcome_counts(chip_outcome(r)[0]
                                                         for r in out_scale[j][1])
            data["by_sigma_scale"][scale_key(s)] = entry
    if payload.fabrication.wafer is not None:
        from planner.yield_.dies import wafer_record

        data["wafer"] = {**wafer_record(payload, mine), "sigma_scale": scales[main]}
    return data
