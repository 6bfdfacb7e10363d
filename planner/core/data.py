"""Files shipped inside the package, named without importing what reads them."""

from __future__ import annotations

from pathlib import Path

#: The embedded default spec, a copy of configs/array_5x5.yaml
#: (:func:`planner.arrayspec.default_spec_path`).  Named here so that a command can check
#: its output folder against it before the spec's schema and the solver are imported.
DEFAULT_SPEC = Path(__file__).resolve().parent.parent / "data" / "array_5x5.yaml"
