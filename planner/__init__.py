"""vibroplan's planner: design, frequency assignment, drive synthesis, verification.

The public API (SI units throughout: m, s, kg, N, Hz, rad):

- :func:`design_impacter`, :func:`design_pair` -- the annealing designer (eqs. 13-18).
- :func:`color_bandwidth` -- bandwidth colouring of a conflict graph.
- :func:`synthesize`, :func:`export` -- summed-tone drive signals and their files.
- :func:`plan` -- the end-to-end array plan with verification by simulation.

Names are resolved lazily so that ``import planner`` stays cheap.
"""

from __future__ import annotations

import importlib

_API = {
    "design_impacter": "planner.designer",
    "design_pair": "planner.designer",
    "DesignResult": "planner.designer",
    "color_bandwidth": "planner.coloring",
    "verify_coloring": "planner.coloring",
    "synthesize": "planner.synthesis",
    "Waveform": "planner.synthesis",
    "export": "planner.lab.exporters",
    "plan": "planner.planning",
    "Plan": "planner.planning",
    "load_spec": "planner.arrayspec",
    "ArraySpec": "planner.arrayspec",
    "SpecError": "planner.core.errors",
}

__all__ = sorted(_API)


def __getattr__(name):
    module = _API.get(name)
    if module is None:
        raise AttributeError(f"module 'planner' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_API))
