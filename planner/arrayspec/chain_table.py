"""The drive chain's measured transfer table: ``transfer: chain.csv`` read at load.

A spec's ``drive.chain.transfer`` may name a CSV file, relative to the spec's folder,
with the header ``frequency_hz,gain_um_per_v,phase_deg`` and one row per measured
frequency (blank lines and ``#`` comments skipped; rows in increasing frequency).
:func:`read_transfer_table` reads it into the inline table
(:class:`planner.arrayspec.schema.TransferTableSpec`'s fields), so that what a plan
records needs no file.  Every error names the CSV, its row (line in the file) and
column.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

from planner.core.errors import SpecError
from planner.files.inputs import csv_rows

#: The columns of a transfer table, in their units.
COLUMNS = ("frequency_hz", "gain_um_per_v", "phase_deg")


def read_transfer_table(path) -> dict:
    """The transfer table of CSV ``path`` as ``{frequency_hz, gain_um_per_v, phase_deg,
    file}`` (lists of floats [Hz], [um/V], [deg]; ``file``: the path as given).

    Raises
    ------
    SpecError
        The file is missing or not a CSV text, its header lacks or repeats a column or
        has another, a row is short or long, a value is not a finite number, a gain is
        not positive, or the frequencies do not increase: with the file, row and column.
    FileNotFoundError
        Never: a missing file is a SpecError naming it (bad input, exit 2).
    """
    from planner.files import read_input

    path = Path(path)
    source = str(path)

    def fail(line, column, message):
        return SpecError(f"{source}: row {line}, column {column}: {message}")

    if not path.exists():
        raise SpecError(f"{source}: no such file (the transfer table's path is relative "
                        "to the spec's folder)")
    try:
        raw = read_input(path)
    except SpecError as exc:
        raise SpecError(f"{source}: {exc.message}") from None
    except OSError as exc:
        raise SpecError(f"{source}: cannot read the file: {exc.strerror or exc}") from None
    if b"\0" in raw:
        raise SpecError(f"{source}: not a CSV text file (it holds binary data)")
    try:
        rows = list(csv_rows(io.StringIO(raw.decode("utf-8-sig"), newline="")))
    except (UnicodeDecodeError, csv.Error) as exc:
        raise SpecError(f"{source}: not a CSV text file: {exc}") from None
    if not rows:
        raise SpecError(f"{source}: empty file: a transfer table needs the header "
                        f"{','.join(COLUMNS)}")
    header_line, header = rows[0]
    header = [h.strip() for h in header]
    for column in header:
        if column not in COLUMNS:
            raise fail(header_line, column or "(empty)",
                       f"unknown column (a transfer table has {','.join(COLUMNS)}; units "
                       "are in the names)")
        if header.count(column) > 1:
            raise fail(header_line, column, "column given twice")
    for column in COLUMNS:
        if column not in header:
            raise fail(header_line, column, f"missing (the header has: {','.join(header)})")
    out = {c: [] for c in COLUMNS}
    for line, row in rows[1:]:
        if len(row) != len(header):
            raise fail(line, header[min(len(row), len(header) - 1)],
                       f"{len(row)} values where the header has {len(header)} columns")
        for column, text in zip(header, row):
            try:
                x = float(text)
            except ValueError:
                x = math.nan
            if not math.isfinite(x):
                raise fail(line, column, f"{text.strip()!r} is not a finite number")
            if column != "phase_deg" and x <= 0:
                raise fail(line, column, f"{text.strip()} must be positive")
            out[column].append(x)
        f = out["frequency_hz"]
        if len(f) > 1 and f[-1] <= f[-2]:
            raise fail(line, "frequency_hz", f"{f[-1]:g} Hz after {f[-2]:g} Hz: the rows "
                                             "must be in increasing frequency")
    if len(out["frequency_hz"]) < 2:
        raise SpecError(f"{source}: a transfer table needs at least 2 rows, "
                        f"{len(out['frequency_hz'])} given")
    out["file"] = str(path)
    return out
