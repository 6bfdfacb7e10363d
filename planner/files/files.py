"""Output files (``--out FILE``, ``--plot FILE``, a drive file's JSON sidecar).

:func:`check_output_file` refuses, before any work, a file that a command may not
replace; :func:`output_files` writes temporaries beside the targets and moves each into
place when the block succeeds, recording it in the folder's registry
(:data:`planner.files.marks.REGISTRY`).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path

from planner.files.marks import folder_marker, marked_ancestor, record_all, written_by
from planner.files.swap import (check_interrupt, clean_stale, hold, release, signals_deferred,
                              temp_prefix)
from planner.files.targets import check_not_input, check_parent
from planner.core.errors import OutputError


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
def output_files(targets, *, command: str, inputs=(), force: bool = False, stale=()):
    """Yield temporary paths for ``targets``; move them into place together when the
    block succeeds.

    Each target is checked with :func:`check_output_file` (call that yourself first, to
    refuse before any work); the temporaries have the targets' own names, in a hidden
    folder beside each (so that a writer may derive one file's name from another's, as
    a drive file's JSON sidecar), and what the block wrote is moved in and recorded in
    the folder's :data:`~planner.files.marks.REGISTRY`.  A temporary the block did not
    write is skipped.  ``stale``: files of an earlier run of ``command`` that this run
    does not write (a layout's ``_drc.json`` when it is not checked again), removed with
    the swap when ``command`` wrote them (another writer's file is left).

    All or nothing: the old files are set aside, the new ones moved in and recorded, and
    the old ones dropped only then; a failure anywhere in the block or the swap (exit 3:
    a full disk, a registry that cannot be written) puts every old file back and
    removes the new ones.

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
                hold(dirs[parent])
            tmps.append(dirs[parent] / t.name)
        yield tmps
        check_interrupt()   # an interrupt whose exception was swallowed
        written = [(t, tmp) for t, tmp in zip(targets, tmps) if tmp.exists()]
        gone = [Path(p) for p in stale
                if Path(p).is_file() and Path(p) not in targets and written_by(p) == command]
        _swap(written, gone, dirs, command)
    finally:
        for d in dirs.values():
            shutil.rmtree(d, ignore_errors=True)
            release(d)


def _swap(written, gone, dirs, command):
    """Move the ``written`` (target, temporary) pairs in and the ``gone`` files out,
    recording the new files; on any failure, undo every step (see
    :func:`output_files`)."""
    done = []          # [target, its old file set aside or None, new file placed]

    def aside(t):
        back = dirs.setdefault(t.absolute().parent, None)
        if back is None:   # a stale file in a folder no target is written in
            back = dirs[t.absolute().parent] = Path(
                tempfile.mkdtemp(prefix=temp_prefix(t, "old"), dir=t.absolute().parent))
        back = back / f".old.{t.name}"
        os.rename(t, back)
        return back

    with signals_deferred():
        try:
            for t, tmp in written:
                entry = [t, aside(t) if (t.exists() or t.is_symlink()) else None, False]
                done.append(entry)
                os.replace(tmp, t)
                entry[2] = True
            for t in gone:
                done.append([t, aside(t), False])
            by_folder = {}
            for t, _ in written:
                by_folder.setdefault(t.absolute().parent, []).append(t.absolute())
            for paths in by_folder.values():
                record_all(paths, command)
        except BaseException:
            for t, back, placed in reversed(done):
                with contextlib.suppress(OSError):
                    if placed:
                        os.unlink(t)
                    if back is not None:
                        os.rename(back, t)
            raise
