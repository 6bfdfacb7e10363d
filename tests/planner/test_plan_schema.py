"""plan.json's one schema (issue 44, item 2): every block declared once
(:mod:`planner.planfile.schema`), written through it (:func:`planner.planning.record.
build_record`), read back through it (:func:`planner.planfile.reader.read_plan`), and a
re-plan's block read as its typed record (``Plan.replan``), never as the dict.

The tests that would fail if the writer and the schema drifted apart:

- every plan.json written (a plan, a re-plan, a trimmed re-plan) gives itself back,
  byte for byte, through the schema;
- a key the writer adds and the schema does not declare, an int written where a float
  is declared and keys in another order are refused, naming the key;
- every field the schema declares is one some writer writes (no field declared for a
  key nothing writes any longer).
"""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest

from planner.planfile import schema
from planner.planfile.schema import (PlanFile, PlanSchemaError, Replan, difference,
                                     through_schema, to_file)

#: The modules that write plan.json's blocks (the record, the blocks its stages hand it)
WRITERS = ("planner/planning/record.py", "planner/afterfab/replan.py",
           "planner/afterfab/trim.py", "planner/afterfab/as_built.py",
           "planner/afterfab/drive.py", "planner/designer/result.py",
           "planner/planning/manufacture.py", "planner/manufacturability/separation.py",
           "planner/planning/pipeline.py")
ROOT = Path(__file__).resolve().parents[2]


def _measured(plan, shift=None) -> dict:
    """A chip of ``plan`` measured at its design, ``shift`` (id -> factor) applied."""
    from planner.afterfab.measurement import Measurement

    shift = shift or {}
    return {r.id: Measurement((r.natural_frequency_hz * shift.get(r.id, 1.0),))
            for r in plan.impacters}


def _same_text(data: dict):
    """``data`` through the schema: the same JSON text, and the record."""
    record, back = through_schema(data)
    assert json.dumps(back, indent=2) == json.dumps(data, indent=2)
    assert difference(data, back) is None
    return record


@pytest.fixture(scope="module")
def replanned(tiny_plan_dir):
    """The tiny plan re-planned for a chip whose first impacter came out 0.4 % high."""
    from planner.afterfab.replan import replan
    from planner.planfile.reader import read_plan

    plan = read_plan(tiny_plan_dir)
    return plan, replan(plan, _measured(plan, {plan.impacter_ids[0]: 1.004}))


def test_a_plan_json_as_written_is_its_schemas_dump(tiny_plan_dir):
    """The tiny plan's file, read as text, gives itself back through the schema."""
    data = json.loads((tiny_plan_dir / "plan.json").read_text())
    record = _same_text(data)
    assert isinstance(record, PlanFile) and record.replan is None
    assert [r.id for r in record.impacters] == [r["id"] for r in data["impacters"]]


def test_a_replans_plan_json_is_its_schemas_dump_and_its_block_is_typed(replanned,
                                                                          tmp_path):
    """A re-plan's plan.json (as_built, replan) round-trips; the result carries the
    same block as its typed record, which is what the after-fabrication code reads."""
    from planner.afterfab.replan import write_replan_outputs

    plan, result = replanned
    assert isinstance(result.replan, Replan)
    assert to_file(result.replan) == result.data["replan"]
    assert to_file(result.plan_file) == result.data
    write_replan_outputs(result, tmp_path / "out", figures=False)
    written = json.loads((tmp_path / "out" / "plan.json").read_text())
    _same_text(written)
    moved = {m.id: m for m in result.replan.moved}
    first = plan.impacter_ids[0]
    assert moved[first].natural_frequency_shift == pytest.approx(0.004, rel=1e-6)
    od = result.replan.original_drive
    assert od.failed_checks == len(od.failures) <= od.checks


def test_a_trims_plan_json_is_its_schemas_dump(close_plan_dir):
    """The close plan's two nearest impacters measured 30 Hz closer than they can be
    told apart (as tests/planner/test_trim.py's colliding chip): the trimmed chip's
    re-plan carries a ``trim`` block, declared as the rest (:class:`TrimRecord`)."""
    from planner.afterfab.separations import separations_of
    from planner.afterfab.trim import trim_chip
    from planner.planfile.reader import read_plan
    from planner.planning.settings import resolve_settings

    plan = read_plan(close_plan_dir)
    seps = separations_of(plan, resolve_settings(plan.loaded))
    f = {r.id: r.natural_frequency_hz for r in plan.impacters}
    up = sorted(f, key=f.get)
    lo, hi = min(zip(up, up[1:]), key=lambda p: f[p[1]] - f[p[0]])
    need = seps.needed(seps.ids.index(lo), seps.ids.index(hi), f[lo])
    res = trim_chip(plan, _measured(plan, {hi: (need - 30.0) / f[hi]}), draws=4)
    assert res.plan is not None
    record = _same_text(json.loads(json.dumps(res.plan.data)))
    assert record.trim is not None and record.trim.next_step
    assert res.plan.plan_file.trim == record.trim


@pytest.mark.parametrize("edit, says", [
    # a key the writer adds that the schema does not declare
    (lambda d: d["impacters"][0].update(spring_constant_n_per_m=1.0),
     "impacters[0].spring_constant_n_per_m: written but not declared"),
    (lambda d: d.update(new_block={"a": 1}), "new_block: written but not declared"),
    (lambda d: d["steps"][0]["tones"][0].update(chirp_hz=1.0),
     "steps[0].tones[0].chirp_hz: written but not declared"),
    # an int where a float is declared: 3 would be written 3.0
    (lambda d: d["devices"][0].update(slider_mass_kg=3), "devices[0].slider_mass_kg: int 3"),
    # keys in another order than the schema's
    (lambda d: d["impacters"].__setitem__(0, dict(reversed(list(d["impacters"][0].items())))),
     "impacters[0]: keys written in the order"),
])
def test_a_writer_that_drifts_from_the_schema_is_refused_naming_the_key(
        tiny_plan_dir, edit, says):
    data = json.loads((tiny_plan_dir / "plan.json").read_text())
    edit(data)
    with pytest.raises(PlanSchemaError) as err:
        through_schema(data)
    assert says in str(err.value), str(err.value)


def test_the_writer_itself_is_held_to_the_schema(tiny_plan_dir, monkeypatch):
    """A key added to an impacter's record by record.py (and not to the schema) fails
    the write: the re-plan builds its plan.json through :func:`build_record`."""
    from planner.afterfab.replan import replan
    from planner.planfile.reader import read_plan
    from planner.planning import record as rec

    plan = read_plan(tiny_plan_dir)
    inner = rec.impacter_record
    monkeypatch.setattr(rec, "impacter_record",
                        lambda *a: {**inner(*a), "undeclared_hz": 1.0})
    with pytest.raises(PlanSchemaError, match="undeclared_hz: written but not declared"):
        replan(plan, _measured(plan), record=False)


def test_the_bounds_are_the_readers_and_the_types_everyones(tiny_plan_dir):
    """Reading, a mass of 0 is no plan (pydantic's words); writing, the bound is not
    checked (a failed plan is written as it is) but the type is."""
    from planner.planfile.reader import PlanFileError, plan_record

    data = json.loads((tiny_plan_dir / "plan.json").read_text())
    bad = copy.deepcopy(data)
    bad["devices"][0]["slider_mass_kg"] = 0.0
    with pytest.raises(PlanFileError, match="slider_mass_kg: Input should be greater than 0"):
        plan_record(bad)
    through_schema(bad)
    bad["devices"][0]["slider_mass_kg"] = "heavy"
    with pytest.raises(PlanSchemaError, match="devices.0.slider_mass_kg"):
        through_schema(bad)


def _records():
    out, todo = [], [PlanFile]
    while todo:
        model = todo.pop()
        if model in out:
            continue
        out.append(model)
        for value in vars(schema).values():
            if (isinstance(value, type) and issubclass(value, schema._Record)
                    and value not in out and value is not schema._Record):
                todo.append(value)
    return out


def test_every_declared_field_is_one_a_writer_writes():
    """No field declared for a key that nothing writes any longer: each of the
    schema's field names is a key some writer of plan.json spells out."""
    text = "".join((ROOT / p).read_text() for p in WRITERS)
    missing = [f"{m.__name__}.{name}" for m in _records() for name in m.model_fields
               if f'"{name}"' not in text and f"{name}=" not in text]
    assert not missing, f"declared in planner/planfile/schema.py, written nowhere: {missing}"


def test_the_reader_declares_nothing_of_its_own():
    """The reader reads through the schema: it declares no record of plan.json's
    blocks itself (one declaration)."""
    import pydantic

    from planner.planfile import reader

    own = [name for name, value in vars(reader).items()
           if isinstance(value, type) and value.__module__ == reader.__name__
           and (issubclass(value, pydantic.BaseModel)
                or getattr(value, "__pydantic_config__", None) is not None)]
    assert own == []
    assert reader.ImpacterRecord is schema.ImpacterRecord
