"""What the layout reads of a plan: its designs, tones, process rules and trim section.

:func:`read_layout_plan` is the layout's one reader of plan.json; it goes through the
plan reader of the rest of vibroplan (:func:`planner.planfile.reader.read_plan`, which
checks the whole file, and :func:`planner.fabrication.tolerances.design_from_plan`).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

from planner.layout.rules import LayoutRules
from planner.layout.trim import TrimPlan, trim_from_spec


@dataclass(frozen=True)
class LayoutPlan:
    """A plan as the layout sees it.

    Attributes
    ----------
    path : Path
        Its plan.json.
    spec : planner.arrayspec.ArraySpec
        Its spec (process, environment, array, sliders).
    design : planner.fabrication.tolerances.ChipDesign
        Its designed impacters (geometry in SI; a re-planned plan's designs, not its
        as-built models).
    frequencies : dict
        Impacter id -> (drive tone, designed natural frequency) [Hz].
    process : planner.config.ProcessConfig
        The plan's process with the layout fields of ``--spec`` if given.
    rules : LayoutRules
        The process rules and layers the layout is drawn and checked with.
    rules_source : str
        Where they come from (the plan's spec, or the ``--spec`` file).
    trim : TrimPlan or None
        The spec's ``trim:`` section.
    """

    path: Path
    spec: object
    design: object
    frequencies: dict
    process: object
    rules: LayoutRules
    rules_source: str
    trim: TrimPlan | None


def read_layout_plan(plan_path, rules_spec=None) -> LayoutPlan:
    """Read a plan folder or plan.json for the layout.

    Parameters
    ----------
    plan_path : str or Path
        A folder written by ``vibroplan plan`` or its plan.json.
    rules_spec : str or Path, optional
        A spec file whose ``process`` layers and rules (``layers``, ``min_line_um``,
        ``min_space_um``, ``anchor_enclosure_um``) and ``trim`` section replace the
        plan's: the plan's designs drawn and checked with another process's rules.

    Raises
    ------
    FileNotFoundError
        No plan there.
    ValueError
        Not a plan.json, or one whose designs do not follow from its geometry.
    planner.core.errors.SpecError
        ``rules_spec`` is not a valid spec, or sets rules that no design inside its
        own bounds can meet (naming the field).
    """
    from planner.config import LAYOUT_FIELDS
    from planner.fabrication.tolerances import design_from_plan
    from planner.planfile.reader import read_plan
    from planner.planning.settings import resolve_settings
    from planner.arrayspec import load_spec

    record = read_plan(plan_path)
    path, spec = record.path, record.spec
    # the layout draws the designs: a re-planned (or trimmed) plan's impacters are as
    # built (its stiffness from a measured resonance), its geometry the design's, whose
    # natural frequency is what the drawn polygons must reproduce
    design = design_from_plan(record)
    design = dataclasses.replace(design, nodes=tuple(
        dataclasses.replace(n, stiffness_scale=1.0, damping_scale=1.0, damping_shift=0.0,
                            gap_shift=0.0) for n in design.nodes))
    frequencies = {r.id: (r.frequency_hz, record.design_natural_frequency_hz[r.id])
                   for r in record.impacters}
    trim = trim_from_spec(json.loads(spec.model_dump_json()))
    process, source = spec.process, f"the plan's spec ({path})"
    if rules_spec is not None:
        # a spec the planner would refuse (rules no design inside its bounds can meet,
        # with the field and line) is refused here too
        other = resolve_settings(load_spec(Path(rules_spec))).chip_spec
        process = process.model_copy(update={k: getattr(other.process, k)
                                             for k in LAYOUT_FIELDS})
        source = str(rules_spec)
        trim = trim_from_spec(json.loads(other.model_dump_json()))
    return LayoutPlan(path, spec, design, frequencies, process,
                      LayoutRules.from_process(process), source, trim)
