"""The lab's CSV files (a frequency sweep, measured.csv): header, rows and numbers checked.

:func:`read_csv_rows` reads a CSV file written by hand or by a lab's instrument
software (UTF-8, an optional BOM, blank lines and ``#`` comments skipped) and checks
its header against the columns its reader needs and allows; :func:`csv_number` reads
one cell as a finite number within what a MEMS measurement can be
(:data:`MAX_VALUE`).  Every error names the file, the row (its line in the file) and
the column.  :mod:`planner.lab.calibrate` reads sweeps with them and
:mod:`planner.afterfab.replan` the measured resonances.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

from planner.core.errors import SpecError
from planner.files.inputs import csv_rows

#: Largest value of a lab file's column [its unit]: beyond it the number is no MEMS
#: measurement (a typo, or another unit), and refused with its row and column before it
#: reaches a fit or a model (frequencies: 1 GHz; amplitudes and gaps: 1 cm and 1 mm, the
#: model's own bounds, :mod:`model.devices`; Q: the fit's search bound).
MAX_VALUE = {"frequency_hz": 1e9, "natural_frequency_hz": 1e9, "amplitude_um": 1e4,
             "drive_amplitude_um": 1e4, "gap_um": 1e3, "quality_factor": 1e6,
             "window_lo_hz": 1e9, "window_hi_hz": 1e9, "speed_mm_s": 1e4}


def csv_number(text, line, column, fail):
    """A cell of a lab CSV file (:func:`read_csv_rows`) as a finite float [its column's
    unit], at most :data:`MAX_VALUE` of its column; else the ``fail(line, column,
    message)`` error is raised."""
    try:
        x = float(text)
    except ValueError:
        x = math.nan
    if not math.isfinite(x):
        raise fail(line, column, f"{text!r} is not a finite number")
    high = MAX_VALUE.get(column)
    if high is not None and x > high:
        unit = {"hz": " Hz", "um": " um"}.get(column.rsplit("_", 1)[-1], "")
        raise fail(line, column, f"{text} is beyond any MEMS measurement (at most "
                                 f"{high:g}{unit}): a typo, or another unit?")
    return x


def read_csv_rows(path, required, optional=(), *, what="the file", ignore=None):
    """A lab CSV file's checked header, its rows and a row/column error maker.

    Parameters
    ----------
    path : path
        The CSV file (UTF-8, an optional BOM; blank lines and ``#`` comments skipped).
    required, optional : sequence of str
        The columns the file needs and those it may have (units are in the names).
    what : str
        The file's kind in messages ("a sweep", "measured.csv").
    ignore : callable(str) -> bool, optional
        Extra columns to accept and leave alone (e.g. calibrate's ``*_std``).

    Returns
    -------
    header_line : int
        1-based line of the header.
    header : list of str
        The column names, stripped.
    rows : list of (int, list of str)
        (1-based line, fields) of every data row.
    fail : callable(line, column, message) -> SpecError
        An error naming the file, the row and the column.

    Raises
    ------
    SpecError
        Not a CSV text file, empty, or a header with an unknown, repeated or missing
        column.
    """
    import io

    from planner.files import read_input

    path = Path(path)
    source = str(path)

    def fail(line, column, message):
        return SpecError(message, path=f"row {line}, column {column}", source=source)

    raw = read_input(path)
    if b"\0" in raw:
        raise SpecError("not a CSV text file (it holds binary data)", source=source)
    try:
        with io.StringIO(raw.decode("utf-8-sig"), newline="") as fh:
            lines = list(csv_rows(fh))
    except (UnicodeDecodeError, csv.Error) as exc:
        raise SpecError(f"not a CSV text file: {exc}", source=source) from None
    if not lines:
        raise SpecError(f"empty file: {what} needs the header {','.join(required)}",
                        source=source)
    header_line, header = lines[0]
    header = [h.strip() for h in header]
    for column in header:
        if ignore is not None and ignore(column):
            continue
        if column not in list(required) + list(optional):
            raise fail(header_line, column or "(empty)",
                       f"unknown column ({what} has {', '.join(required)} and optionally "
                       f"{', '.join(optional)}; units are in the names)")
        if header.count(column) > 1:
            raise fail(header_line, column, "column given twice")
    for column in required:
        if column not in header:
            raise fail(header_line, column, f"missing (the header has: {','.join(header)})")
    return header_line, header, lines[1:], fail


def row_values(header, line, row, fail, *, strip=True) -> dict:
    """One CSV row as ``{column: text}`` (each value stripped unless ``strip`` is false);
    a row of another length than the header is ``fail(line, column, message)`` naming
    the first column it lacks or the last it overruns."""
    if len(row) != len(header):
        raise fail(line, header[min(len(row), len(header) - 1)],
                   f"{len(row)} values where the header has {len(header)} columns")
    return dict(zip(header, (v.strip() for v in row) if strip else row))
