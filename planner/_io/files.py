"""Output files (``--out FILE``, ``--plot FILE``, a drive file's JSON sidecar).

:func:`check_output_file` refuses, before any work, a file that a command may not
replace; :func:`output_files` writes temporaries beside the targets and moves each into
place when the block succeeds, recording it in the folder's registry
(:data:`planner._io.marks.REGISTRY`).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path

from planner._io.marks import folder_marker, marked_ancestor, record, written_by
from planner._io.swap import clean_stale, signals_deferred, temp_prefix
from planner._io.targets import check_not_input, check_parent
from planner.errors import OutputError


def check_output_file(target: str | os.PathLike, *, command: str, inputs=(),
                      force: bool = False, option: str = "--out") -> Path:
    """Check, before any work, that ``command`` may write the file ``target``.

    Parameters
    ----------
    target : str or PathLike
        The file to write.
    command : str
        The command that writes it (``sweep``, ``drive``, ...).
    inputs : iterable of path, optional
        Files the command reads: never replaced, not even with ``force``.
    force : bool
        Write it even when it lies inside a vibroplan output folder, or exists and was
        not written by ``command`` (or was changed since).
    option : str
        The option that names it, for the messages (``--out``, ``--plot``; empty: the
        path alone).

    Returns
    -------
    Path
        ``target``.

    Raises
    ------
    OutputError
        Refused, with the reason and what to do instead.
    OSError
        Its folder cannot be written.
    """
    path = Path(target)
    if str(target).strip() == "":
        raise OutputError(f"{option or 'the output'} is empty: name a file")
    where = f"{option} {target}" if option else str(target)
    check_parent(path)
    if path.is_dir():
        raise OutputError(f"{where}: is a folder; name a file")
    check_not_input(path, inputs, option)
    if force:
        return path
    outer = marked_ancestor(path.absolute().parent)
    if outer is not None:
        raise OutputError(f"{where}: inside {outer}, an output folder of `vibroplan "
                          f"{folder_marker(outer)['command']}`; write elsewhere, or pass "
                          "--force")
    if path.exists() or path.is_symlink():
        who = written_by(path)
        if who != command:
            by = (f"written by `vibroplan {who}`" if who else
                  "not written by vibroplan (or changed since)")
            raise OutputError(f"{where}: the file exists, {by}; refusing to "
                              f"replace it with the output of `vibroplan {command}` (choose "
                              "another name, or pass --force)")
    return path


@contextlib.contextmanager
def output_files(targets, *, command: str, inputs=(), force: bool = False):
    """Yield temporary paths for ``targets``; move each into place when the block succeeds.

    Each target is checked with :func:`check_output_file` (call that yourself first, to
    refuse before any work); the temporaries have the targets' own names, in a hidden
    folder beside each (so that a writer may derive one file's name from another's, as
    a drive file's JSON sidecar), and what the block wrote is moved in and recorded in
    the folder's :data:`~planner._io.marks.REGISTRY`.  A temporary the block did not
    write is skipped.  On any exception nothing is moved.

    Yields
    ------
    list of Path
        The temporary path of each target, in order.
    """
    targets = [Path(t) for t in targets]
    for t in targets:
        check_output_file(t, command=command, inputs=inputs, force=force, option="")
        clean_stale(t)
    dirs = {}
    try:
        tmps = []
        for t in targets:
            parent = t.absolute().parent
            if parent not in dirs:
                dirs[parent] = Path(tempfile.mkdtemp(prefix=temp_prefix(t, "new"), dir=parent))
            tmps.append(dirs[parent] / t.name)
        yield tmps
        for t, tmp in zip(targets, tmps):
            if tmp.exists():
                with signals_deferred():
                    os.replace(tmp, t)
                record(t.absolute(), command)
    finally:
        for d in dirs.values():
            shutil.rmtree(d, ignore_errors=True)
