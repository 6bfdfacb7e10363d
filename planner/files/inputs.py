"""Input files read safely: a regular file of bounded size, never a device or a FIFO.

:func:`read_input` is how every command reads a spec, a plan, a sweep or a band file:
a folder, a device (/dev/zero would never end), a FIFO or socket (which would block
forever) or a file over :data:`planner.runtime.limits.MAX_INPUT_BYTES` is refused with a
:class:`~planner.core.errors.SpecError` naming the file.
"""

from __future__ import annotations

import csv
import os
import stat
from pathlib import Path

from planner.core.errors import SpecError


def read_input(path: str | os.PathLike, *, limit: int | None = None) -> bytes:
    """The bytes of an input file: a regular file of at most ``limit`` bytes.

    Parameters
    ----------
    path : str or PathLike
        The file.
    limit : int, optional
        Largest size [bytes]; default :data:`planner.runtime.limits.MAX_INPUT_BYTES`.

    Raises
    ------
    FileNotFoundError
        No such file.
    planner.core.errors.SpecError
        A folder, a device (/dev/zero), a FIFO or socket (which would block), or a
        file over the limit, naming the file.
    OSError
        It cannot be read (permissions), with the path.
    """
    limit = _limit(limit)
    fd = _open_checked(path, limit)
    try:
        with os.fdopen(fd, "rb", closefd=True) as fh:
            fd = None
            data = fh.read(limit + 1)
    finally:
        if fd is not None:
            os.close(fd)
    if len(data) > limit:   # it grew while we read
        raise SpecError(f"over the {limit / 2**20:.0f} MiB an input may have",
                        source=str(path))
    return data


def check_input(path: str | os.PathLike, *, limit: int | None = None) -> None:
    """Refuse, unread, an input :func:`read_input` would refuse (the same errors).

    A command calls it on its input files before it imports the solver and the
    planner (over a second): a folder, a device, a FIFO or an oversized file is then
    refused in a fraction of a second.  :func:`read_input` checks again when it reads.
    """
    os.close(_open_checked(path, _limit(limit)))


def _limit(limit):
    from planner.runtime.limits import MAX_INPUT_BYTES

    return MAX_INPUT_BYTES if limit is None else int(limit)


def _open_checked(path, limit) -> int:
    """A read-only descriptor of ``path``, checked a regular file of at most ``limit``
    bytes (closed again when it is not; see :func:`read_input` for the errors)."""
    path = Path(path)
    # O_NONBLOCK: opening a FIFO must not wait for a writer; the type is checked on the
    # open descriptor, so the file cannot be swapped for another kind in between
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0)
    try:
        fd = os.open(path, flags)
    except IsADirectoryError:
        raise SpecError("is a folder, not a file", source=str(path)) from None
    try:
        info = os.fstat(fd)
        if stat.S_ISDIR(info.st_mode):
            raise SpecError("is a folder, not a file", source=str(path))
        if not stat.S_ISREG(info.st_mode):
            kind = ("a FIFO (named pipe)" if stat.S_ISFIFO(info.st_mode) else
                    "a device" if stat.S_ISCHR(info.st_mode) or stat.S_ISBLK(info.st_mode)
                    else "a socket" if stat.S_ISSOCK(info.st_mode) else "not a regular file")
            raise SpecError(f"is {kind}, not a regular file: give a file", source=str(path))
        if info.st_size > limit:
            raise SpecError(f"{info.st_size / 2**20:.1f} MiB is over the {limit / 2**20:.0f} MiB "
                            "an input may have: is this the right file?", source=str(path))
    except BaseException:
        os.close(fd)
        raise
    return fd


def csv_rows(fh):
    """(1-based line, fields) of each non-blank, non-comment (``#``) row of a CSV file
    opened with ``newline=""``: what every CSV reader of vibroplan's names its rows by."""
    reader = csv.reader(fh)
    start = 1
    for row in reader:
        # reader.line_num is the line the row ended on; a row starts one past the last
        line, start = start, reader.line_num + 1
        if not row or all(not v.strip() for v in row) or row[0].lstrip().startswith("#"):
            continue
        yield line, row
