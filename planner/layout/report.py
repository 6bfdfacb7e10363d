"""The layout's report (markdown): what was drawn, the round trip, the pictures, the DRC,
section by section (:class:`planner.core.markdown.Report`)."""

from __future__ import annotations

import math

from planner.layout.measure import ROUND_TRIP_RTOL
from planner.core.markdown import Report, Section, md_table
from planner.core.units import UM

#: First line of every layout report: a later run may replace a report that has it.
HEADER = "<!-- written by vibroplan layout -->"
#: Violations listed one by one in the report (all are in the JSON).
LISTED = 60


def _g(x, digits=5):
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{digits}g}"


def fits(box, pitch, space) -> bool:
    """Whether a device's structures (``box`` in its own frame [m]) keep half a space
    inside its pitch cell on every side."""
    half = (pitch - space) / 2.0
    return box[0] >= -half and box[1] >= -half and box[2] <= half and box[3] <= half


def write_report(path, *, plan, chip, rows, drc, files, gds_bytes, version) -> None:
    """Write the layout report.

    Parameters
    ----------
    path : Path
        The markdown file.
    plan, chip, rows, drc, files, gds_bytes, version :
        As :func:`layout_report`.
    """
    layout_report(plan=plan, chip=chip, rows=rows, drc=drc, files=files,
                  gds_bytes=gds_bytes, version=version).write(path)


def layout_report(*, plan, chip, rows, drc, files, gds_bytes, version) -> Report:
    """The layout report.

    Parameters
    ----------
    plan : planner.layout.source.LayoutPlan
    chip : planner.layout.geometry.ChipLayout
    rows : list of dict
        :func:`planner.layout.measure.round_trip`.
    drc : planner.layout.drc.DrcResult or None
        None: the check was not asked for.
    files : dict
        ``gds``, ``chip_png``, ``device_png`` (and ``drc_json``) -> their file names.
    gds_bytes : int
        Size of the GDSII file.
    version : str
        vibroplan's version.

    Returns
    -------
    planner.core.markdown.Report
    """
    spec = plan.spec
    devices = list(chip.device_origins)
    lines = [f"`{files['gds']}`: {gds_bytes / 1024:.0f} KiB GDSII (user unit 1 um, database "
             f"unit 1 nm), written by vibroplan {version} from `{plan.path}`. Top cell "
             f"`{chip.top}`: {len(devices)} device cells (`{devices[0]}` ... "
             f"`{devices[-1]}`) on a {chip.pitch / UM:g} um pitch, row A at the top; in each "
             "a slider cell (`<device>.slider`) and one cell per designed impacter pair "
             "(`<device>.forward`, `<device>.backward`) holding two placements of its "
             "cantilever cell (`<id>.cantilever`), one above the slider and its mirror image "
             f"below: {len(chip.impacters)} impacter pairs. Labels (mask LABEL) give every "
             "id with its drive tone and natural frequency.", ""]
    missing = [f"{d}.{k}" for d in devices for k in ("forward", "backward")
               if f"{d}.{k}" not in chip.impacters]
    if missing:
        lines += [f"Not drawn (the plan designs no impacter for them, none is ever driven): "
                  f"{', '.join(missing)}.", ""]
    lines += [f"![The chip]({files['chip_png']})", "",
              f"![Device {files['device']}]({files['device_png']})", ""]
    sections = [_process(plan, chip), _round_trip(rows), _devices(chip)]
    if chip.trim is not None:
        sections.append(_trim(chip))
    sections.append(_drc(drc, files))
    return Report(f"Chip layout: {spec.name}", lines, sections, preamble=[HEADER])


def _process(plan, chip) -> Section:
    r = chip.rules
    proc = plan.process
    lines = [f"Rules and layers from {plan.rules_source}:", ""]

    def rule(value, given):
        text = f"{value / UM:g} um"
        return text if given is not None else text + " (unset: the paper's minimum feature)"

    lines += [f"- min line {rule(r.min_line, proc.min_line_um)}, min space "
              f"{rule(r.min_space, proc.min_space_um)}, anchor enclosure "
              f"{r.anchor_enclosure / UM:g} um;",
              f"- beams: double-V, half angle {proc.beam_angle_deg:.4g} deg between the two "
              f"legs of a V; plates POLY1 + POLY2 ({proc.mass_thickness_um:g} um), beams "
              f"POLY1 ({proc.beam_height_um:g} um).", ""]
    lines += md_table(["mask", "GDS layer", "datatype"],
                      [(k, v[0], v[1]) for k, v in r.layers.items()]) + [""]
    return Section("Process", lines)


def _round_trip(rows) -> Section:
    worst = max(abs(x["error"]) for x in rows)
    passed = all(x["passed"] for x in rows)
    out = ["The GDSII file read back with gdstk; every impacter's plate area A (its POLY2), "
           "beam width w and length l (its POLY1 legs) and gap c (its tip's space to the "
           "slider polygon over the sine of the impact angle) measured on the polygons of "
           "both cantilevers, and its natural frequency by eqs. (2)-(4) with the plan's "
           f"process: largest |error| {100 * worst:.3g} % against plan.json (criterion "
           f"{100 * ROUND_TRIP_RTOL:g} %): **{'PASSED' if passed else 'FAILED'}**.", ""]
    table = []
    for x in rows:
        table.append((x["id"],
                      f"{x['area_m2_plan'] / UM**2:.1f} / {_g(x['area_m2_layout'] / UM**2, 6)}",
                      f"{x['width_m_plan'] / UM:.4f} / {_g(x['width_m_layout'] / UM, 6)}",
                      f"{x['length_m_plan'] / UM:.2f} / {_g(x['length_m_layout'] / UM, 6)}",
                      f"{x['gap_m_plan'] / UM:.4f} / {_g(x['gap_m_layout'] / UM, 6)}",
                      f"{x['natural_frequency_hz_plan']:.1f}",
                      _g(x["natural_frequency_hz_layout"], 7),
                      f"{100 * x['error']:+.4f}" if math.isfinite(x["error"]) else "-"))
    out += md_table(["impacter", "A [um^2] plan / layout", "w [um]", "l [um]", "c [um]",
                     "nu_n plan [Hz]", "nu_n layout [Hz]", "error [%]"], table) + [""]
    return Section("Geometry round trip", out)


def _devices(chip) -> Section:
    space = chip.rules.min_space
    rows, out_of = [], []
    for d, box in chip.footprints.items():
        ok = fits(box, chip.pitch, space)
        if not ok:
            out_of.append(d)
        length, width = chip.sliders[d]
        rows.append((d, f"{length / UM:.0f} x {width / UM:.0f}",
                     f"{(box[2] - box[0]) / UM:.0f} x {(box[3] - box[1]) / UM:.0f}",
                     "yes" if ok else "**no**"))
    out = []
    if out_of:
        out += [f"{len(out_of)} of {len(rows)} devices do not fit their "
                f"{chip.pitch / UM:g} um pitch cell ({', '.join(out_of)}): their beams and "
                "plates reach into their neighbours'. The designer's bounds (design.bounds) "
                "do not limit a device's footprint; shorter beams (length_um), smaller plates "
                "(area_um2) or a larger array.pitch_um would.", ""]
    out += md_table(["device", "slider L x W [um]", "footprint W x H [um]", "fits the pitch"],
                    rows) + [""]
    return Section("Devices", out)


def _trim(chip) -> Section:
    t = chip.trim
    if t.direction != "up":
        return Section("Trim tabs", [
            f"trim: direction {t.direction} ({100 * t.range:g} %): trimming down cuts into a "
            "beam, which needs no drawn feature; no tabs drawn.", ""])
    out = [f"trim: up by {100 * t.range:g} % in {t.tabs} steps of "
           f"{100 * ((1 + t.range) ** (1 / t.tabs) - 1):.3g} % (precision "
           f"{100 * t.precision:g} %): {t.tabs} POLY1 + POLY2 tabs on the rear edge of every "
           "plate (outlined on TRIM), part of the designed area A. Cutting the first k tabs "
           f"raises nu_n by (1 + {t.range:g})^(k / {t.tabs}) (eq. (2): only the mass moves).",
           ""]
    rows = [(i, f"{sum(d.tabs) / UM**2:.1f}", ", ".join(f"{a / UM**2:.1f}" for a in d.tabs))
            for i, d in chip.impacters.items()]
    return Section("Trim tabs", out + md_table(
        ["impacter", "tabs total [um^2]", "each, in cutting order [um^2]"], rows) + [""])


def _drc(drc, files) -> Section:
    out = []
    if drc is None:
        return Section("Design-rule check",
                       ["Not run (`vibroplan layout PLAN --out FILE --check` runs it).", ""])
    import klayout

    version = getattr(klayout, "__version__", "")
    if drc.clean:
        out += [f"KLayout {version}: **clean**, {len(drc.rules)} rules checked.", ""]
    else:
        out += [f"KLayout {version}: **{len(drc.violations)} violations** of "
                f"{len(drc.counts())} of {len(drc.rules)} rules (all in "
                f"`{files['drc_json']}`).", "",
                "Impacters in a violation: " + (", ".join(drc.impacters) or "none") + ".", "",
                "Devices in a violation: " + (", ".join(drc.devices) or "none") + ".", ""]
    counts = drc.counts()
    out += md_table(["rule", "limit [um]", "violations"],
                    [(k, f"{v / UM:g}", counts.get(k, 0)) for k, v in drc.rules.items()]) + [""]
    if drc.violations:
        shown = drc.violations[:LISTED]
        out += [f"The first {len(shown)} violations:" if len(shown) < len(drc.violations)
                else "The violations:", ""]
        out += md_table(["rule", "where [um]", "measured [um]", "impacters", "devices"],
                        [(v.rule, ", ".join(f"{c / UM:.1f}" for c in v.box),
                          _g(v.value / UM, 4), " ".join(v.impacters) or "-",
                          " ".join(v.devices) or "-") for v in shown]) + [""]
    return Section("Design-rule check", out)
