"""A wafer's measurement: one file for every die (a prober's CSV or a tester's STDF) or
a folder of one measured.csv per die; read into each die's measurements, and written.

The wafer CSV is measured.csv with the die in front of every row::

    die_x,die_y,impacter,natural_frequency_hz[,quality_factor][,gap_um][,half]
    0,0,A1.forward,10391.2
    0,0,A1.backward,26113.0
    1,0,A1.forward,10402.7
    ...

``die_x`` and ``die_y`` are the die's integer grid indices on the wafer (a prober's
step coordinates); the rest of a row is read and checked exactly as measured.csv's
(:func:`planner.afterfab.measurement.measurements_from_rows`), every error naming its
row and column.  A folder of measured.csv files names each by its die:
``die_<x>_<y>.csv`` (``die_-3_2.csv``).  An STDF V4 file (:mod:`planner.afterfab.stdf`)
gives each die's PRR coordinates and its parametric tests.
"""

from __future__ import annotations

import re
from pathlib import Path

from planner.afterfab.measurement import (MEASURED_OPTIONAL, MEASURED_REQUIRED,
                                          measurements_from_rows, read_measured)
from planner.core.errors import SpecError

#: The die columns in front of measured.csv's in a wafer CSV.
DIE_COLUMNS = ("die_x", "die_y")
#: The file name of a die's measured.csv in a ``--measured-dir`` folder.
DIE_FILE = re.compile(r"^die_(-?[0-9]+)_(-?[0-9]+)\.csv$", re.ASCII)
#: A die index in a wafer CSV: ASCII digits with an optional sign.
DIE_INDEX = re.compile(r"[+-]?[0-9]+", re.ASCII)
#: Bytes of a file read to tell a wafer's CSV from one chip's measured.csv (its header).
SNIFF_BYTES = 64 * 1024
#: The first bytes of an STDF V4 file: a FAR record (REC_LEN 2, type 0, sub-type 10).
STDF_MAGIC = (b"\x02\x00\x00\x0a", b"\x00\x02\x00\x0a")


def not_measured(dies, impacter_ids) -> list:
    """``(die_x, die_y, ids)`` of every die whose measurement leaves impacters out
    (each then taken at its design), in ``dies``' order."""
    return [(x, y, [n for n in impacter_ids if n not in measured])
            for x, y, measured in dies if any(n not in measured for n in impacter_ids)]


def die_name(x: int, y: int) -> str:
    """A die's folder and file stem: ``die_<x>_<y>``."""
    return f"die_{int(x)}_{int(y)}"


def is_stdf(path) -> bool:
    """Whether ``path`` begins as an STDF V4 file does (its FAR)."""
    try:
        with open(path, "rb") as fh:
            return fh.read(4) in STDF_MAGIC
    except OSError:
        return False


def is_wafer_csv(path) -> bool:
    """Whether ``path`` is a CSV whose header has the die columns (a wafer's file, not
    one chip's measured.csv); False for anything it cannot read as such (the chip's
    reader then says what is wrong).

    Only the file's first :data:`SNIFF_BYTES` are read: what kind of file it is does not
    depend on its size (a wafer's file over the input limit is then refused by the
    wafer's reader, naming the limit, not taken for one chip's)."""
    import csv
    import io

    try:
        with open(path, "rb") as fh:
            head = fh.read(SNIFF_BYTES)
    except OSError:
        return False
    if b"\0" in head:
        return False
    text = head.decode("utf-8-sig", errors="replace")
    for row in csv.reader(io.StringIO(text, newline="")):
        if not row or all(not v.strip() for v in row) or row[0].lstrip().startswith("#"):
            continue
        # either die column makes it a wafer's file (whose reader names the other missing)
        return any(c.strip() in DIE_COLUMNS for c in row)
    return False


def _die_index(text, line, column, fail) -> int:
    # int() takes "1_0", " 1 " and other scripts' digits ("\u0661"): a prober's step
    # index is ASCII digits with an optional sign, nothing else
    if DIE_INDEX.fullmatch(text.strip()) is None:
        raise fail(line, column, f"{text!r} is not a die index (an integer grid step "
                                 "of the prober: ASCII digits, an optional sign)")
    return int(text.strip())


def read_wafer_csv(path, impacter_ids, design_hz=None) -> list:
    """A wafer CSV's dies, in the order they first appear.

    Returns
    -------
    list of (int, int, dict)
        ``(die_x, die_y, measured)``, ``measured`` impacter id ->
        :class:`~planner.afterfab.measurement.Measurement`.

    Raises
    ------
    SpecError
        ``FILE: row N, column C: ...`` as measured.csv's reader, and for a die index
        that is not an integer.
    """
    from planner.lab.csv_files import read_csv_rows, row_values

    header_line, header, rows, fail = read_csv_rows(
        path, DIE_COLUMNS + MEASURED_REQUIRED, MEASURED_OPTIONAL, what="a wafer's CSV",
        ignore=lambda c: c.endswith("_std") or c.endswith("_std_hz"))
    groups = {}
    for line, row in rows:
        values = row_values(header, line, row, fail, strip=False)
        key = tuple(_die_index(values[c], line, c, fail) for c in DIE_COLUMNS)
        groups.setdefault(key, []).append((line, row))
    if not groups:
        raise fail(header_line + 1, "die_x", "no dies after the header")
    return [(x, y, measurements_from_rows(header_line, header, group, fail, impacter_ids,
                                          design_hz))
            for (x, y), group in groups.items()]


def read_measured_dir(folder, impacter_ids, design_hz=None) -> list:
    """A folder of one measured.csv per die, each named ``die_<x>_<y>.csv``, in the
    order of their names' dies (rows top first, then x).

    Raises
    ------
    SpecError
        A CSV file named otherwise, or none at all (naming the folder); a file's own
        errors as :func:`~planner.afterfab.measurement.read_measured` gives them.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise SpecError("not a folder", source=str(folder))
    found = []
    for p in sorted(folder.iterdir()):
        if p.suffix.lower() != ".csv":
            continue
        m = DIE_FILE.match(p.name)
        if m is None:
            raise SpecError(f"{p.name}: a die's measured.csv is named die_<x>_<y>.csv "
                            "(its grid indices on the wafer, e.g. die_-3_2.csv)",
                            source=str(folder))
        found.append((int(m.group(1)), int(m.group(2)), p))
    if not found:
        raise SpecError("no die_<x>_<y>.csv file in the folder", source=str(folder))
    # die_0_3.csv, die_-0_3.csv and die_00_3.csv name one die: refused before any is read
    first = {}
    for x, y, p in found:
        if (x, y) in first:
            raise SpecError(f"{first[(x, y)].name} and {p.name} both name die ({x}, {y}): "
                            "keep one file per die", source=str(folder))
        first[(x, y)] = p
    found.sort(key=lambda t: (-t[1], t[0]))
    return [(x, y, read_measured(p, impacter_ids, design_hz=design_hz)) for x, y, p in found]


def read_wafer_stdf(path, impacter_ids, design_hz=None, test_map=None, *,
                    notes=None) -> list:
    """A tester's STDF V4 file's dies (:func:`planner.afterfab.stdf.read_stdf`), each
    die's resonances checked as measured.csv's, every error naming the record; the
    tests skipped for their TEST_FLG are appended to ``notes`` (a list) if given."""
    from planner.afterfab.stdf import read_stdf

    source = str(path)
    out = []
    for x, y, rows in read_stdf(path, impacter_ids, test_map, skipped=notes):
        header = ["impacter", "natural_frequency_hz", "half"]

        def fail(record, column, message, _x=x, _y=y):
            return SpecError(message, path=f"record {record} (PTR of die ({_x}, {_y})), "
                                           f"{column}", source=source)

        lines = [(k, [imp, value, half]) for k, imp, value, half in rows]
        out.append((x, y, measurements_from_rows(0, header, lines, fail, impacter_ids,
                                                 design_hz)))
    return out


def read_wafer(path, impacter_ids, design_hz=None, *, test_map=None, notes=None) -> list:
    """The dies of a wafer's file or folder: an STDF V4 file, a wafer CSV or a folder
    of measured.csv files (:func:`read_wafer_stdf`, :func:`read_wafer_csv`,
    :func:`read_measured_dir`); ``notes`` (a list, optional) gets a line per test an
    STDF file's flags say not to use.

    Raises
    ------
    SpecError
        Two dies at one place (naming it), or the reader's own errors.
    """
    path = Path(path)
    if path.is_dir():
        dies = read_measured_dir(path, impacter_ids, design_hz)
    elif is_stdf(path):
        dies = read_wafer_stdf(path, impacter_ids, design_hz, test_map, notes=notes)
    else:
        dies = read_wafer_csv(path, impacter_ids, design_hz)
    return dies


# --------------------------------------------------------------------------- writing

def measured_rows(measured: dict) -> list:
    """``(impacter, half, resonance [Hz])`` of a die's measurement (id -> resonance, a
    number or the (a, b) of a pair's halves), in the given order."""
    out = []
    for n, value in measured.items():
        if isinstance(value, tuple):
            out += [(n, h, float(v)) for h, v in zip(("a", "b"), value)]
        else:
            out.append((n, "", float(value)))
    return out


def write_wafer_csv(path, dies) -> None:
    """A wafer CSV (the module docstring) of ``dies``: ``(die_x, die_y, measured)``,
    ``measured`` impacter id -> resonance [Hz] (or (a, b)); every value written with
    the digits that read back as the same float."""
    rows = [(x, y, r) for x, y, measured in dies for r in measured_rows(measured)]
    halves = any(r[1] for _, _, r in rows)
    lines = [",".join(DIE_COLUMNS + MEASURED_REQUIRED + (("half",) if halves else ()))]
    for x, y, (n, h, v) in rows:
        lines.append(f"{x},{y},{n},{v!r}" + (f",{h}" if halves else ""))
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")


def write_wafer_stdf(path, dies, *, lot_id="vibroplan", wafer_id="1", part_type="") -> None:
    """The same dies as a tester's STDF V4 file, each resonance a PTR named by
    :func:`planner.afterfab.stdf.default_test_name`."""
    from planner.afterfab.stdf import default_test_name, write_stdf

    write_stdf(path, [(x, y, {default_test_name(n, h): v for n, h, v in measured_rows(m)})
                      for x, y, m in dies], lot_id=lot_id, wafer_id=wafer_id,
               part_type=part_type)
