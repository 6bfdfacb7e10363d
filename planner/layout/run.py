"""``vibroplan layout`` as a library call: plan -> GDSII, round trip, DRC, pictures, report.

Outputs, all beside the GDSII file ``STEM.gds`` and written atomically together (a
failed run, one that fails while moving them in included, leaves every one of them as
it was; a run without the check removes the ``STEM_drc.json`` an earlier layout wrote):

- ``STEM.gds`` the layout;
- ``STEM.png`` the chip, ``STEM_<device>.png`` one device;
- ``STEM.md`` the report (round trip, devices, trim tabs, the check);
- ``STEM_drc.json`` the check's violations (with ``check=True``).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from planner.core.errors import OutputError
from planner.layout.drc import DrcResult, check as run_check
from planner.layout.gds import read_gds, write_gds
from planner.layout.geometry import ChipLayout, build_chip
from planner.layout.measure import measure, round_trip
from planner.layout.plots import chip_figure, device_figure
from planner.layout.report import write_report
from planner.layout.source import LayoutPlan, read_layout_plan


@dataclass(frozen=True)
class LayoutResult:
    """What :func:`run_layout` made.

    Attributes
    ----------
    plan : LayoutPlan
    chip : ChipLayout
    round_trip : list of dict
        :func:`planner.layout.measure.round_trip`.
    drc : DrcResult or None
    files : dict
        Output kind (``gds``, ``report``, ``chip_png``, ``device_png``, ``drc_json``)
        -> its path.
    gds_bytes : int
        Size of the GDSII file.
    """

    plan: LayoutPlan
    chip: ChipLayout
    round_trip: list
    drc: DrcResult | None
    files: dict
    gds_bytes: int

    @property
    def round_trip_passed(self) -> bool:
        return all(r["passed"] for r in self.round_trip)

    @property
    def passed(self) -> bool:
        """The round trip reproduces the plan and (if run) the check is clean."""
        return self.round_trip_passed and (self.drc is None or self.drc.clean)


def output_paths(out, device: str, check: bool) -> dict:
    """The output files of ``--out out`` (see the module docstring).

    Raises
    ------
    OutputError
        ``out`` does not end in ``.gds``.
    """
    out = _gds_name(out)
    stem = out.with_suffix("")
    paths = {"gds": out, "report": Path(f"{stem}.md"), "chip_png": Path(f"{stem}.png"),
             "device_png": Path(f"{stem}_{device}.png")}
    if check:
        paths["drc_json"] = Path(f"{stem}_drc.json")
    return paths


def _gds_name(out) -> Path:
    out = Path(out)
    if out.suffix.lower() != ".gds":
        raise OutputError(f"--out {out}: name a .gds file (the report and pictures are "
                          "written beside it)")
    return out


def run_layout(plan_path, out, *, check: bool = False, rules_spec=None,
               device: str | None = None, version: str = "", force: bool = False) -> LayoutResult:
    """Draw a plan's chip, read it back, optionally check it, and write the outputs.

    Parameters
    ----------
    plan_path : str or Path
        A plan folder or its plan.json.
    out : str or Path
        The GDSII file to write (``.gds``); the other outputs go beside it.
    check : bool
        Run the design-rule check (:func:`planner.layout.drc.check`).
    rules_spec : str or Path, optional
        Take the process layers, rules and trim section from this spec
        (:func:`planner.layout.source.read_layout_plan`).
    device : str, optional
        The device of the zoomed picture (default: the first).
    version : str
        vibroplan's version, for the report.
    force : bool
        Replace existing files this command did not write (never an input, and never a
        file inside another command's folder unless forced: :mod:`planner.files`).

    Returns
    -------
    LayoutResult

    Raises
    ------
    FileNotFoundError, ValueError, planner.core.errors.SpecError, OutputError
        Bad input or output name; nothing is written.
    """
    from planner.files import check_output_file, output_files

    _gds_name(out)                         # refused before any work
    plan = read_layout_plan(plan_path, rules_spec)
    chip = build_chip(plan.design, plan.frequencies, plan.rules, plan.trim)
    devices = list(chip.device_origins)
    device = devices[0] if device is None else device
    if device not in chip.device_origins:
        raise ValueError(f"--device {device}: the plan has no designed device {device!r} "
                         f"(devices {devices[0]} ... {devices[-1]})")
    paths = output_paths(out, device, check)
    inputs = [plan.path] + ([rules_spec] if rules_spec is not None else [])
    for p in paths.values():                  # every output refused before any work
        check_output_file(p, command="layout", inputs=inputs, force=force, option="--out")
    # a layout not checked this time drops the check of the chip it replaces: an old
    # STEM_drc.json saying clean must not stand beside a new chip (layout's own only)
    stale = [] if check else [output_paths(out, device, True)["drc_json"]]
    with output_files(list(paths.values()), command="layout", inputs=inputs,
                      force=force, stale=stale) as tmps:
        tmp = dict(zip(paths, tmps))
        write_gds(chip, tmp["gds"])
        lib = read_gds(tmp["gds"])
        rows = round_trip(plan.spec, plan.design, measure(lib, plan.rules.layers))
        drc = run_check(tmp["gds"], plan.rules, chip.pitch) if check else None
        chip_figure(lib, plan.rules.layers, tmp["chip_png"],
                    f"{plan.spec.name}: {len(devices)} devices, "
                    f"{plan.spec.array.pitch_um:g} um pitch")
        device_figure(lib, plan.rules.layers, device, tmp["device_png"],
                      f"{plan.spec.name}: device {device}")
        if drc is not None:
            tmp["drc_json"].write_text(json.dumps(drc.to_dict(), indent=1) + "\n",
                                       encoding="utf-8")
        size = tmp["gds"].stat().st_size
        names = {k: p.name for k, p in paths.items()}
        names["device"] = device
        write_report(tmp["report"], plan=plan, chip=chip, rows=rows, drc=drc, files=names,
                     gds_bytes=size, version=version)
    return LayoutResult(plan, chip, rows, drc, paths, size)
