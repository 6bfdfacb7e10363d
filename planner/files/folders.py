"""Output folders (``vibroplan plan --out DIR`` and the like): checked, then swapped in.

:func:`check_output_folder` refuses, before any work, a folder that a command may not
replace; :func:`output_folder` writes a temporary folder beside the target and swaps
it in atomically at the end, under the target's lock (see :mod:`planner.files`).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path

from planner.files.marks import MARKER, folder_marker, marked_ancestor, marker_text, sha256
from planner.files.swap import (check_interrupt, clean_stale, hold, lock, release,
                              signals_deferred, temp_prefix, umask)
from planner.files.targets import check_parent, names
from planner.core.errors import OutputError


def _foreign_files(target: Path, marker: dict) -> list[str]:
    """Files of an output folder that its command did not write (or that changed)."""
    if marker["files"] is None:     # a marker from before files were listed
        return []
    out = []
    for p in sorted(target.rglob("*")):
        if p.is_dir() and not p.is_symlink():
            continue
        rel = p.relative_to(target).as_posix()
        if rel == MARKER:
            continue
        want = marker["files"].get(rel)
        if want is None or p.is_symlink() or sha256(p) != want:
            out.append(rel)
    return out


def check_output_folder(out_dir: str | os.PathLike, *, command: str = "plan", inputs=(),
                        force: bool = False) -> Path:
    """Check, before any work, that ``command`` may write ``out_dir``; returns it resolved.

    Parameters
    ----------
    out_dir : str or PathLike
        The output folder.
    command : str
        The command that writes it (``plan``, ``replan``, ``yield``): it replaces only
        folders it wrote itself, and only when they hold nothing but its own files.
    inputs : iterable of path, optional
        Files the run reads (the spec, a plan, a CSV); a folder holding one is refused.
    force : bool
        Replace the folder anyway when it is not empty and vibroplan did not write it,
        another command wrote it, it holds files the command did not write (they are
        deleted), or it lies inside another vibroplan output folder.  The current
        directory, its ancestors and folders holding an input are refused even then.

    Raises
    ------
    OutputError
        The folder may not be written, with the reason and what to do instead.
    """
    given = Path(out_dir)
    if str(out_dir).strip() == "":
        raise OutputError("--out is empty: name an output folder")
    check_parent(given)
    target = given.resolve()
    cwd = Path.cwd().resolve()
    if target == cwd or cwd.is_relative_to(target):
        raise OutputError(f"--out {out_dir}: refusing to write into the current directory or "
                          "one of its ancestors (its contents would be replaced); "
                          "name a new folder, e.g. --out plan_out")
    for inp in inputs:
        if inp is None:
            continue
        p = Path(inp).resolve()
        if p.is_relative_to(target):
            raise OutputError(f"--out {out_dir}: refusing to replace a folder that holds the "
                              f"input {inp}; name a new folder")
    outer = marked_ancestor(target.parent)
    if outer is not None and not force:
        raise OutputError(f"--out {out_dir}: inside {outer}, an output folder of `vibroplan "
                          f"{folder_marker(outer)['command']}` (it would be refused or lost "
                          "when that folder is written again); choose a folder elsewhere, "
                          "or pass --force")
    if target.exists() or target.is_symlink():
        if not target.is_dir() or target.is_symlink():
            raise OutputError(f"--out {out_dir}: exists and is not a folder")
        marker = folder_marker(target)
        if force or not any(target.iterdir()):
            return target
        if marker is None:
            raise OutputError(f"--out {out_dir}: the folder exists, is not empty and was not "
                              "written by vibroplan; refusing to replace it (choose a new "
                              "folder, or pass --force to replace it)")
        if marker["command"] != command:
            raise OutputError(f"--out {out_dir}: written by `vibroplan {marker['command']}`; "
                              f"`vibroplan {command}` replaces only its own output folders "
                              "(choose a new folder, or pass --force to replace it)")
        foreign = _foreign_files(target, marker)
        if foreign:
            raise OutputError(f"--out {out_dir}: holds files `vibroplan {command}` did not "
                              f"write ({names(foreign)}); move them out, choose a new "
                              "folder, or pass --force to replace the folder with them")
    return target


@contextlib.contextmanager
def output_folder(out_dir: str | os.PathLike, *, command: str = "plan", inputs=(),
                  force: bool = False):
    """Yield a temporary folder; swap it in as ``out_dir`` when the block succeeds.

    Checks ``out_dir`` with :func:`check_output_folder` (call that yourself first to
    refuse before any work), takes the folder's lock, cleans what dead runs left
    (:func:`clean_stale`), and yields an empty folder beside it.  On success the
    :data:`MARKER` (the command and the files it wrote) is written into it and it
    replaces ``out_dir`` atomically; on any exception the temporary is removed and
    ``out_dir`` is untouched.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> out = pathlib.Path(tempfile.mkdtemp()) / "plan_out"
    >>> with output_folder(out) as tmp:
    ...     _ = (tmp / "plan.json").write_text("{}")
    >>> sorted(p.name for p in out.iterdir())
    ['.vibroplan-output', 'plan.json']
    """
    target = check_output_folder(out_dir, command=command, inputs=inputs, force=force)
    with lock(target):
        clean_stale(target, locked=True)
        # re-check under the lock: another run may have changed the folder meanwhile
        target = check_output_folder(out_dir, command=command, inputs=inputs, force=force)
        tmp = Path(tempfile.mkdtemp(prefix=temp_prefix(target, "new"), dir=target.parent))
        hold(tmp)
        os.chmod(tmp, 0o777 & ~umask())  # mkdtemp's 0700 is for the temporary only
        old = None
        try:
            yield tmp
            (tmp / MARKER).write_text(marker_text(command, tmp), encoding="utf-8")
            check_interrupt()   # an interrupt whose exception was swallowed
            with signals_deferred():
                if target.exists():
                    old = Path(tempfile.mkdtemp(prefix=temp_prefix(target, "old"),
                                                dir=target.parent))
                    old.rmdir()
                    os.rename(target, old)
                try:
                    os.rename(tmp, target)
                except BaseException:
                    if old is not None:
                        os.rename(old, target)
                        old = None
                    raise
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
            release(tmp)
            if old is not None:
                shutil.rmtree(old, ignore_errors=True)
