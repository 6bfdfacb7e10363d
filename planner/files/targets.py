"""Where an output may go at all: a folder that exists and takes files, never an input.

The checks every output, folder or file, passes first (:mod:`planner.files.folders`,
:mod:`planner.files.files`), and the way their messages list offending names.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from planner.core.errors import NotWritableError, OutputError

#: How many offending names an error message lists.
SHOWN = 5


def names(paths) -> str:
    """The first :data:`SHOWN` of ``paths``, comma-separated, and how many more."""
    paths = list(paths)
    text = ", ".join(str(p) for p in paths[:SHOWN])
    return text + (f" and {len(paths) - SHOWN} more" if len(paths) > SHOWN else "")


def _same_file(a: Path, b: Path) -> bool:
    """Whether ``a`` and ``b`` are one file (a hard link or symlink included), or would be."""
    try:
        return os.path.samefile(a, b)
    except OSError:     # one of them does not exist (yet)
        return a.absolute().resolve() == b.absolute().resolve()


def check_parent(target: str | os.PathLike) -> Path:
    """The folder ``target`` will be written in; it must exist (nothing is created
    silently, e.g. a mistyped absolute path at the file-system root).

    Raises
    ------
    OutputError
        The parent folder does not exist or is not a folder.
    planner.core.errors.NotWritableError
        (an OSError) Nothing can be written in it (permissions, a read-only or special file
        system), with the folder as ``filename``: found before any work, not after.
    """
    target = Path(target)
    parent = target.absolute().parent
    if not parent.exists():
        raise OutputError(f"{target}: the folder {parent} does not exist "
                          "(create it first; vibroplan does not create missing parents)")
    if not parent.is_dir():
        raise OutputError(f"{target}: {parent} is not a folder")
    try:
        with tempfile.TemporaryFile(dir=parent):
            pass
    except OSError as exc:
        raise NotWritableError(exc.errno, f"cannot write here ({exc.strerror})",
                               str(parent)) from None
    return parent


def check_not_input(target: str | os.PathLike, inputs, option: str = "--out") -> None:
    """Refuse an output that is one of the command's inputs (a hard link or a symlink to
    one included): never replaced, not even with ``--force``.

    Raises
    ------
    OutputError
        Naming the option, the output and the input.
    """
    path = Path(target)
    where = f"{option} {target}" if option else str(target)
    for inp in inputs:
        if inp is not None and _same_file(path, Path(inp)):
            raise OutputError(f"{where}: is an input of this command ({inp}); vibroplan "
                              "never replaces its inputs, not even with --force: name "
                              "another file")
