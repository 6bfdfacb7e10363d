"""A tester's STDF V4 file of a wafer: the parametric results of every die, read
through the maintained reader ``pystdf`` and written by a small writer of our own.

A wafer prober writes one STDF (Standard Test Data Format, V4) file per wafer: per die
a Part Information Record (PIR), its tests' Parametric Test Records (PTR: a test number,
a name ``TEST_TXT``, a ``RESULT`` in the test's ``UNITS``) and a Part Results Record
(PRR, with the die's ``X_COORD`` and ``Y_COORD``).  :func:`read_stdf` reads such a file
with ``pystdf`` (an optional dependency, ``pip install vibroplan[stdf]``; GPL-licensed,
so vibroplan does not need it unless a tester's file is read) and maps every PTR whose
test name names an impacter to its measured resonance (:data:`DEFAULT_MAPPING`, or a
``--test-map`` file, :func:`read_test_map`); other tests are left alone.

:func:`write_stdf` writes the same records (FAR, MIR, WIR, PIR, PTR, PRR, WRR, MRR)
with ``struct``: ``vibroplan yield`` on wafers writes each wafer's measurement as a
tester would, and the tests read it back with ``pystdf``.  STDF's RESULT is a 4-byte
float (R*4): a resonance keeps about 7 digits (3 mHz at 44 kHz), far below any lab's
measurement noise.
"""

from __future__ import annotations

import struct
from pathlib import Path

from planner.core.errors import SpecError

#: CPU_TYPE of the FAR: 2 is little-endian (x86), how this writer packs every record.
CPU_TYPE = 2
#: Units a resonance's PTR may give (STDF's RESULT is in the UNITS' base unit; the
#: scaling exponent RES_SCAL only says how to print it).
HZ_UNITS = ("", "hz", "Hz", "HZ")
#: The separator of a pair half in a default test name: ``A1.forward:a``.
HALF_SEP = ":"
#: X_COORD / Y_COORD of a PRR that does not know where its die sat (STDF's invalid).
NO_COORD = -32768
#: TEST_FLG bits of a PTR whose RESULT was measured but is not to be trusted (STDF V4,
#: PTR: bit 2 unreliable, bit 3 timed out, bit 4 not executed, bit 5 aborted): the test
#: is skipped, with a note naming the die, test and record, and its impacter is read
#: as not measured (the die counted ``partly measured``, :mod:`planner.afterfab.batch`).
#: A tester sets them in its normal flow (a test the flow skipped, one stopped on a
#: fault); bit 1 (RESULT invalid) is a damaged record and stays an error.
SKIP_FLAGS = {0x04: "unreliable", 0x08: "timed out", 0x10: "not executed",
              0x20: "aborted"}
#: A record's header: REC_LEN (2 bytes), REC_TYP, REC_SUB.
HEADER_BYTES = 4
#: STDF V4 record names by (REC_TYP, REC_SUB), for a record cut short.
RECORD_NAMES = {(0, 10): "FAR", (0, 20): "ATR", (1, 10): "MIR", (1, 20): "MRR",
                (1, 30): "PCR", (1, 40): "HBR", (1, 50): "SBR", (1, 60): "PMR",
                (1, 62): "PGR", (1, 63): "PLR", (1, 70): "RDR", (1, 80): "SDR",
                (2, 10): "WIR", (2, 20): "WRR", (2, 30): "WCR", (5, 10): "PIR",
                (5, 20): "PRR", (10, 30): "TSR", (15, 10): "PTR", (15, 15): "MPR",
                (15, 20): "FTR", (20, 10): "BPS", (20, 20): "EPS", (50, 10): "GDR",
                (50, 30): "DTR"}


def default_test_name(impacter: str, half: str = "") -> str:
    """The test name a resonance is written and read under without a map: the
    impacter's id, ``:a`` / ``:b`` appended for a half of a pair measured apart."""
    return f"{impacter}{HALF_SEP}{half}" if half else impacter


def read_test_map(path, impacter_ids) -> dict:
    """A ``--test-map`` CSV: ``test_name,impacter[,half]``, one row per test that
    measures a resonance (its RESULT in Hz).

    Returns
    -------
    dict
        Test name -> (impacter id, half: ``""``, ``"a"`` or ``"b"``).

    Raises
    ------
    SpecError
        Naming the row and column (an unknown impacter, a repeated test name, a half
        that is not a or b).
    """
    from planner.lab.csv_files import read_csv_rows, row_values

    _, header, rows, fail = read_csv_rows(path, ("test_name", "impacter"), ("half",),
                                          what="a test map")
    known = set(impacter_ids)
    out, first = {}, {}
    for line, row in rows:
        v = row_values(header, line, row, fail)
        name, imp, half = v["test_name"], v["impacter"], v.get("half", "").lower()
        if not name:
            raise fail(line, "test_name", "empty test name")
        if name in first:
            raise fail(line, "test_name", f"{name!r} mapped twice (rows {first[name]} and "
                                          f"{line})")
        if imp not in known:
            raise fail(line, "impacter", f"unknown impacter {imp!r}")
        if half not in ("", "a", "b"):
            raise fail(line, "half", f"must be a or b, {v['half']!r} was given")
        first[name] = line
        out[name] = (imp, half)
    return out


def _default_map(impacter_ids) -> dict:
    out = {}
    for n in impacter_ids:
        out[default_test_name(n)] = (n, "")
        for h in ("a", "b"):
            out[default_test_name(n, h)] = (n, h)
    return out


def _check_whole(raw: bytes, source: str) -> None:
    """Walk the records' headers: a record whose REC_LEN runs past the end of the file
    was cut short (pystdf reads what is there and stops quietly, so a PRR cut inside
    its coordinates would read as a die without them)."""
    order = "<" if raw[4] == 2 else ">"     # the FAR's CPU_TYPE: 1 big-, 2 little-endian
    at, k = 0, 0
    while at < len(raw):
        k += 1
        if len(raw) - at < HEADER_BYTES:
            raise SpecError(f"the file is cut short: record {k}'s header has "
                            f"{len(raw) - at} of its {HEADER_BYTES} bytes (after byte {at})",
                            source=source)
        (length,) = struct.unpack(order + "H", raw[at:at + 2])
        name = RECORD_NAMES.get((raw[at + 2], raw[at + 3]),
                                f"type {raw[at + 2]}, sub-type {raw[at + 3]}")
        have = len(raw) - at - HEADER_BYTES
        if length > have:
            raise SpecError(f"the file is cut short inside record {k} ({name}): its "
                            f"REC_LEN says {length} bytes, {have} are there", source=source)
        at += HEADER_BYTES + length


def read_stdf(path, impacter_ids, test_map=None, *, skipped=None) -> list:
    """The dies of a tester's STDF V4 file and their measured resonances.

    Parameters
    ----------
    path : path
        The STDF file (at most :data:`planner.runtime.limits.MAX_INPUT_BYTES`).
    impacter_ids : iterable of str
        The plan's impacters.
    test_map : dict, optional
        Test name -> (impacter id, half) (:func:`read_test_map`); default every
        impacter id is its own test name (:func:`default_test_name`).
    skipped : list, optional
        Gets one line per mapped PTR not used because its TEST_FLG says it is not to
        be trusted (:data:`SKIP_FLAGS`): ``die (x, y): record K (PTR): test 'A1.forward'
        not executed (TEST_FLG 0x10): skipped``.

    Returns
    -------
    list of (int, int, list)
        ``(die_x, die_y, rows)`` in the file's order; ``rows`` are ``(record,
        impacter, natural_frequency_hz as text, half)`` for
        :func:`planner.afterfab.wafer_file.dies_from_rows`, ``record`` the PTR's
        1-based record number in the file.

    Raises
    ------
    SpecError
        Not an STDF V4 file, a file cut short (naming the record), a PTR without a
        valid result or in another unit than Hz, a part begun again before its PRR, a
        die without coordinates or tested twice, a die none of whose tests is mapped
        (or all skipped); naming the record.
    ModuleNotFoundError
        ``pystdf`` is not installed (the CLI says how to install it).
    """
    import io

    from pystdf import V4
    from pystdf.IO import Parser

    from planner.files import read_input

    path = Path(path)
    source = str(path)
    raw = read_input(path)
    if len(raw) < 6 or raw[2:4] != b"\x00\x0a" or raw[5] != 4:
        raise SpecError("not an STDF V4 file (it must begin with a FAR record of "
                        "STDF_VER 4)", source=source)
    _check_whole(raw, source)
    mapping = test_map if test_map is not None else _default_map(impacter_ids)
    records = []

    class _Sink:
        def after_send(self, _source, data):
            rectype, fields = data
            records.append((rectype, fields))

    parser = Parser(inp=io.BytesIO(raw))
    parser.addSink(_Sink())
    try:
        parser.parse()
    except Exception as exc:  # noqa: BLE001 - pystdf raises what struct and it raise
        raise SpecError(f"not a readable STDF V4 file: record {len(records) + 1}: "
                        f"{type(exc).__name__}: {exc}", source=source) from None
    names = {}          # TEST_NUM -> TEST_TXT of its first PTR (STDF's default)
    open_parts, dies, seen = {}, [], {}
    for k, (rectype, fields) in enumerate(records, start=1):
        rec = dict(zip(rectype.fieldNames, fields))

        def fail(message, _k=k, _name=type(rectype).__name__.upper()):
            return SpecError(message, path=f"record {_k} ({_name})", source=source)

        if isinstance(rectype, V4.Pir):
            where = (rec["HEAD_NUM"], rec["SITE_NUM"])
            if where in open_parts:
                # STDF gives a part's die only in its PRR: without it, the tests before
                # this PIR belong to no known die (a record lost, files spliced)
                raise fail(f"a part begins on head {where[0]}, site {where[1]} while the "
                           f"part begun at record {open_parts[where][0]} (PIR) has no "
                           "PRR: its die's X_COORD and Y_COORD are unknown (a record "
                           "lost?)")
            open_parts[where] = (k, [], [])
        elif isinstance(rectype, V4.Ptr):
            name = rec["TEST_TXT"] or names.get(rec["TEST_NUM"], "")
            names.setdefault(rec["TEST_NUM"], name)
            if name not in mapping:
                continue
            part = open_parts.get((rec["HEAD_NUM"], rec["SITE_NUM"]))
            if part is None:
                raise fail(f"test {name!r} outside a part (no PIR for head "
                           f"{rec['HEAD_NUM']}, site {rec['SITE_NUM']} before it)")
            flags = rec["TEST_FLG"] or 0
            why = [w for bit, w in SKIP_FLAGS.items() if flags & bit]
            if why:
                part[2].append((k, name, flags, why))
                continue
            if flags & 0b10 or rec["RESULT"] is None:
                raise fail(f"test {name!r}: its RESULT is flagged invalid (TEST_FLG bit 1)")
            units = (rec["UNITS"] or "").strip()
            if units not in HZ_UNITS:
                raise fail(f"test {name!r}: UNITS {units!r}; a resonance's result is in Hz")
            imp, half = mapping[name]
            part[1].append((k, imp, repr(float(rec["RESULT"])), half))
        elif isinstance(rectype, V4.Prr):
            part = open_parts.pop((rec["HEAD_NUM"], rec["SITE_NUM"]), None)
            if part is None:
                raise fail(f"a part's results without its PIR (head {rec['HEAD_NUM']}, "
                           f"site {rec['SITE_NUM']})")
            x, y = rec["X_COORD"], rec["Y_COORD"]
            if x is None or y is None or x == NO_COORD or y == NO_COORD:
                raise fail("the die's X_COORD and Y_COORD are not given: a wafer's file "
                           "says where each die sat")
            if (x, y) in seen:
                raise fail(f"die ({x}, {y}) tested twice (records {seen[(x, y)]} and {k})")
            seen[(x, y)] = k
            _, rows, skips = part
            notes = [f"die ({x}, {y}): record {j} (PTR): test {t!r} {' and '.join(why)} "
                     f"(TEST_FLG 0x{flags:02x}): skipped" for j, t, flags, why in skips]
            if not rows and skips:
                raise fail(f"die ({x}, {y}): every test naming an impacter is flagged not "
                           f"to be used ({notes[0].split(': ', 1)[1]}"
                           + (f", and {len(skips) - 1} more" if len(skips) > 1 else "")
                           + ")")
            if not rows:
                raise fail(f"die ({x}, {y}): none of its tests names an impacter (test "
                           "names are the impacters' ids, e.g. A1.forward, or give "
                           "--test-map)")
            if skipped is not None:
                skipped.extend(notes)
            dies.append((int(x), int(y), rows))
    # pystdf stops quietly at a record cut short: a file that ends inside a part, or
    # before its Master Results Record, was cut off (a copy or a test run interrupted)
    if open_parts:
        (head, site), _ = next(iter(open_parts.items()))
        raise SpecError(f"the file ends inside a part (head {head}, site {site} has no PRR "
                        f"after record {len(records)}): truncated?", source=source)
    if not records or not isinstance(records[-1][0], V4.Mrr):
        raise SpecError(f"the file ends after record {len(records)} without its MRR: "
                        "truncated?", source=source)
    if not dies:
        raise SpecError("no die with a PRR in the file", source=source)
    return dies


# --------------------------------------------------------------------------- writing

def _cn(text: str) -> bytes:
    data = text.encode("ascii")
    if len(data) > 255:
        raise ValueError(f"an STDF C*n string holds at most 255 characters: {text[:40]!r}...")
    return bytes([len(data)]) + data


def _record(typ: int, sub: int, body: bytes) -> bytes:
    return struct.pack("<HBB", len(body), typ, sub) + body


def write_stdf(path, dies, *, lot_id: str = "vibroplan", wafer_id: str = "1",
               part_type: str = "") -> None:
    """Write a wafer's measured resonances as a tester's STDF V4 file.

    Parameters
    ----------
    path : path
        The file.
    dies : iterable of (int, int, dict)
        ``(die_x, die_y, tests)``, ``tests`` test name -> result [Hz] in the order
        written (:func:`default_test_name`); test numbers are given in the order test
        names are first met, from 1.
    lot_id, wafer_id, part_type : str
        The MIR's LOT_ID and PART_TYP, the WIR's and WRR's WAFER_ID.

    Every time stamp is 0: the same dies give the same bytes.
    """
    out = [_record(0, 10, struct.pack("<BB", CPU_TYPE, 4))]
    out.append(_record(1, 10, struct.pack("<IIBcccHc", 0, 0, 1, b" ", b" ", b" ", 0, b" ")
                       + _cn(lot_id) + _cn(part_type) + _cn("") + _cn("") + _cn("")))
    out.append(_record(2, 10, struct.pack("<BBI", 1, 255, 0) + _cn(wafer_id)))
    numbers = {}
    count = 0
    for x, y, tests in dies:
        count += 1
        out.append(_record(5, 10, struct.pack("<BB", 1, 1)))
        for name, value in tests.items():
            num = numbers.setdefault(name, len(numbers) + 1)
            # OPT_FLAG 0xCE: RES_SCAL valid (0), no limits and no specification limits
            out.append(_record(15, 10, struct.pack("<IBBBBf", num, 1, 1, 0, 0, value)
                               + _cn(name) + _cn("")
                               + struct.pack("<BbbbffB", 0xCE, 0, 0, 0, 0.0, 0.0, 2)
                               + b"Hz" + _cn("") + _cn("") + _cn("")
                               + struct.pack("<ff", 0.0, 0.0)))
        out.append(_record(5, 20, struct.pack("<BBBHHHhhI", 1, 1, 0, len(tests), 1, 1,
                                              int(x), int(y), 0)
                           + _cn(f"{x},{y}") + _cn("") + b"\x00"))
    out.append(_record(2, 20, struct.pack("<BBIIIIII", 1, 255, 0, count, 0, 0, count, 0)
                       + _cn(wafer_id) + _cn("") + _cn("") + _cn("") + _cn("") + _cn("")))
    out.append(_record(1, 20, struct.pack("<Ic", 0, b" ") + _cn("") + _cn("")))
    Path(path).write_bytes(b"".join(out))
