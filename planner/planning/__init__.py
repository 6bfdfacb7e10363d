"""The end-to-end array plan: spec -> settings -> graph -> channels -> drives -> designs
-> verification -> record -> outputs, one module per stage.

- :mod:`~planner.planning.settings` -- the spec in SI units, once; fields the planner
  cannot honour are refused; every later stage reads the settings, not the spec;
- :mod:`~planner.planning.pipeline` -- the stage order and the repair loop;
- :mod:`~planner.planning.drives`, :mod:`~planner.planning.exposure` (what each impacter
  must stay silent under), :mod:`~planner.planning.designs`,
  :mod:`~planner.planning.motion`, :mod:`~planner.planning.targets` (the gated bursts of
  ``targets_um`` steps), :mod:`~planner.planning.verify`,
  :mod:`~planner.planning.scenes`, :mod:`~planner.planning.repair`,
  :mod:`~planner.planning.manufacture` -- the stages;
- :mod:`~planner.planning.record` -- the plan.json dict (read back by
  :mod:`planner.planfile.reader`);
- :mod:`~planner.planning.outputs` -- files and figures;
  :mod:`~planner.planning.report` -- report.md;
- :mod:`~planner.planning.result` -- :class:`Plan`, the declared (frozen) result;
- :mod:`~planner.planning.estimate` -- the work and time left after the assignment;
- :mod:`~planner.planning.reach` -- the tones a design can serve, measured before the
  assignment.

After fabrication (measure, re-plan, trim) is :mod:`planner.afterfab`.

Inside, impacters are keyed by :class:`planner.core.nodes.Node`; plan.json and the CSVs carry
a node's text.  pyproject.toml's ``planning-layers`` contract keeps the stages importing
downwards only.

(The package is ``planner.planning`` rather than ``planner.plan`` so that the lazy
function ``planner.plan`` is never shadowed by a submodule.)
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from planner.files import output_folder
from planner.planning.outputs import write_outputs
from planner.planning.pipeline import run_plan
from planner.planning.result import Plan
from planner.planning.settings import Settings, resolve_settings
from planner.arrayspec import LoadedSpec, default_spec_path, load_spec

__all__ = ["Plan", "Settings", "plan", "resolve_settings", "run_plan", "step_tones",
           "write_outputs"]


def plan(spec=None, out_dir=None, seed=None, *, progress=None, figures=True, jobs=None,
         force=False, on_assignment=None, scheduler=None, cache_dir=None):
    """Plan an array: the whole pipeline, optionally writing every output.

    Parameters
    ----------
    spec : str, Path, LoadedSpec or None
        An array spec file, YAML text, or an already loaded spec; None plans the
        embedded default (configs/array_5x5.yaml).
    out_dir : str or Path, optional
        Where to write plan.json, CSVs, waveforms, figures and report.md.  Checked
        before any work (:func:`planner.files.check_output_folder`: never the current
        directory or its ancestors, nor a folder holding the spec; an existing
        non-empty folder only if a previous vibroplan run wrote it, or with
        ``force``).  The files are written to a temporary folder beside it and
        swapped in atomically only when complete.
    seed : int, optional
        Overrides the spec's ``design.seed``: the designs' seed and the drive phases'
        (so ``vibroplan plan --seed N`` gives different designs, not only phases); same
        spec and seed give a byte-identical plan.json.
    jobs : int, optional
        Worker processes for the designs (default 1; the CLI uses every core).  The
        plan does not depend on it.  As with any ``multiprocessing`` code, a script
        that passes jobs > 1 needs an ``if __name__ == "__main__":`` guard.
    force : bool
        Replace an existing non-empty ``out_dir`` that vibroplan did not write.
    on_assignment : callable, optional
        ``on_assignment(settings, steps, assignment)``, called once after the first
        assignment, before any design (see :func:`run_plan`).
    scheduler : str, optional
        Address of an existing ``dask.distributed`` scheduler (``tcp://host:8786``) to
        run the designs on; default: a local cluster of ``jobs`` workers (none for 1).
    cache_dir : str or Path, optional
        Folder of the on-disk design cache
        (:mod:`planner.planning.design_store`): designs it holds for the same inputs
        and code are read instead of computed, new ones are written to it.  Default
        None: no disk cache (the CLI uses one, see ``vibroplan plan --help``).  The
        plan is byte-identical either way.

    Returns
    -------
    Plan
        With ``out_dir`` when written there (and the ``outputs`` time in ``timings``).
    """
    if isinstance(spec, LoadedSpec):
        loaded = spec
    else:
        loaded = load_spec(Path(spec) if spec is None or isinstance(spec, Path) or "\n" not in str(spec)
                           else spec) if spec is not None else load_spec(default_spec_path())
    # the settings first: a spec field the planner cannot honour fails before any work
    settings = resolve_settings(loaded, seed)
    if out_dir is None:
        return run_plan(loaded, seed=seed, progress=progress, jobs=jobs, settings=settings,
                        on_assignment=on_assignment, scheduler=scheduler, cache_dir=cache_dir)
    source = Path(loaded.source) if getattr(loaded, "source", None) else None
    inputs = [source] if source is not None and source.exists() else []
    with output_folder(out_dir, command="plan", inputs=inputs, force=force) as tmp:
        result = run_plan(loaded, seed=seed, progress=progress, jobs=jobs, settings=settings,
                          on_assignment=on_assignment, scheduler=scheduler, cache_dir=cache_dir)
        seconds = write_outputs(result, tmp, figures=figures, cache_dir=cache_dir)
    return dataclasses.replace(result, out_dir=Path(out_dir),
                               timings={**result.timings, "outputs": seconds})


def step_tones(spec_path):
    """Steps with their tones for ``vibroplan drive SPEC``: runs the plan without files."""
    return plan(spec_path).data["steps"]
