"""Output files and folders that never destroy a user's data, and the version string.

Every command that writes goes through this module, the library as well as the CLI:

- :func:`check_output_folder` refuses, before any work, a folder that vibroplan may
  not replace: the current directory or one of its ancestors, a folder holding an
  input file, an existing file, or a non-empty folder that no vibroplan run wrote
  (recognised by the :data:`MARKER` file every run leaves), unless ``force``.
- :func:`output_folder` writes a folder beside the target and swaps it in
  atomically at the end (rename the old one aside, rename the new one in, remove the
  old one), under a lock that makes a concurrent writer of the same folder fail at
  once with a clear message instead of corrupting it.
- :func:`atomic_path` does the same for a single file.

On any exception, ``KeyboardInterrupt`` and the CLI's signal exceptions included,
the temporary is removed and the target is left as it was.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
import signal
import tempfile
from pathlib import Path

from planner.errors import OutputError

#: File every output folder written by vibroplan carries; a folder holding it may be
#: replaced by a later run without ``--force``.
MARKER = ".vibroplan-output"


def version_string() -> str:
    """The installed vibroplan version (``0+unknown`` when run from an uninstalled tree)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("vibroplan")
    except PackageNotFoundError:  # running from a source tree that is not installed
        return "0+unknown"


def _is_vibroplan_output(folder: Path) -> bool:
    try:
        data = json.loads((folder / MARKER).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(data, dict) and data.get("written_by") == "vibroplan"


def check_parent(target: str | os.PathLike) -> Path:
    """The folder ``target`` will be written in; it must exist (nothing is created
    silently, e.g. a mistyped absolute path at the file-system root).

    Raises
    ------
    OutputError
        The parent folder does not exist or is not a folder.
    OSError
        Nothing can be written in it (permissions, a read-only or special file
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
        raise OSError(exc.errno, f"cannot write here ({exc.strerror})", str(parent)) from None
    return parent


def check_output_folder(out_dir: str | os.PathLike, *, inputs=(), force: bool = False) -> Path:
    """Check, before any work, that ``out_dir`` may be written; returns it resolved.

    Parameters
    ----------
    out_dir : str or PathLike
        The output folder.
    inputs : iterable of path, optional
        Files the run reads (the spec, a plan, a CSV); a folder holding one is refused.
    force : bool
        Allow replacing an existing non-empty folder that no vibroplan run wrote.
        The current directory, its ancestors and folders holding an input are
        refused even then.

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
    if target.exists() or target.is_symlink():
        if not target.is_dir() or target.is_symlink():
            raise OutputError(f"--out {out_dir}: exists and is not a folder")
        if any(target.iterdir()) and not _is_vibroplan_output(target) and not force:
            raise OutputError(f"--out {out_dir}: the folder exists, is not empty and was not "
                              "written by vibroplan; refusing to replace it (choose a new "
                              "folder, or pass --force to replace it)")
    return target


@contextlib.contextmanager
def _lock(target: Path):
    """Hold an exclusive lock on ``target`` for the life of the block.

    The lock is a file beside the target (``.NAME.lock``), removed on release.  A
    second writer of the same target fails at once with :class:`OutputError`.
    """
    path = target.parent / f".{target.name}.lock"
    try:
        import fcntl
    except ImportError:  # not POSIX: an exclusive create is the lock
        fcntl = None
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | (os.O_EXCL if fcntl is None else 0), 0o644)
        if fcntl is None:
            break
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno in (errno.EAGAIN, errno.EACCES):
                raise OutputError(f"{target}: another vibroplan run is writing this folder "
                                  f"(lock {path}); wait for it or choose another --out") from None
            raise
        # the holder before us may have removed the file between our open and our
        # lock: then we hold a lock on a dead inode and must take the new file's
        try:
            if os.fstat(fd).st_ino == os.stat(path).st_ino:
                break
        except FileNotFoundError:
            pass
        os.close(fd)
    try:
        os.write(fd, f"{os.getpid()}\n".encode())
        yield
    finally:
        with contextlib.suppress(OSError):
            os.unlink(path)
        os.close(fd)


@contextlib.contextmanager
def _signals_deferred():
    """Hold SIGINT and SIGTERM back during the few renames of a swap, so that an
    interruption cannot leave the target half-swapped (they are delivered after)."""
    sigs = {signal.SIGINT, signal.SIGTERM}
    try:
        old = signal.pthread_sigmask(signal.SIG_BLOCK, sigs)
    except (AttributeError, ValueError, OSError):  # not POSIX, or not the main thread
        old = None
    try:
        yield
    finally:
        if old is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _marker_text(command: str) -> str:
    return json.dumps({"written_by": "vibroplan", "version": version_string(),
                       "command": command}, indent=2) + "\n"


@contextlib.contextmanager
def output_folder(out_dir: str | os.PathLike, *, command: str = "plan", inputs=(),
                  force: bool = False):
    """Yield a temporary folder; swap it in as ``out_dir`` when the block succeeds.

    Checks ``out_dir`` with :func:`check_output_folder` (call that yourself first to
    refuse before any work), takes the folder's lock, and yields an empty folder
    beside it.  On success the :data:`MARKER` is written into it and it replaces
    ``out_dir`` atomically; on any exception the temporary is removed and ``out_dir``
    is untouched.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> out = pathlib.Path(tempfile.mkdtemp()) / "plan_out"
    >>> with output_folder(out) as tmp:
    ...     _ = (tmp / "plan.json").write_text("{}")
    >>> sorted(p.name for p in out.iterdir())
    ['.vibroplan-output', 'plan.json']
    """
    target = check_output_folder(out_dir, inputs=inputs, force=force)
    with _lock(target):
        # re-check under the lock: another run may have changed the folder meanwhile
        target = check_output_folder(out_dir, inputs=inputs, force=force)
        tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.new-", dir=target.parent))
        os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp's 0700 is for the temporary only
        old = None
        try:
            yield tmp
            (tmp / MARKER).write_text(_marker_text(command), encoding="utf-8")
            with _signals_deferred():
                if target.exists():
                    old = Path(tempfile.mkdtemp(prefix=f".{target.name}.old-",
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
            if old is not None:
                shutil.rmtree(old, ignore_errors=True)


@contextlib.contextmanager
def atomic_path(target: str | os.PathLike):
    """Yield a temporary path beside the file ``target``; move it into place on success.

    Whatever the body writes at the yielded path replaces ``target`` only when the
    body completes; on any exception the temporary is removed and ``target`` is left
    as it was.  The parent folder must exist (:func:`check_parent`); an existing
    folder at ``target`` is refused.
    """
    target = Path(target)
    check_parent(target)
    if target.is_dir():
        raise OutputError(f"{target}: is a folder; name a file")
    tmpdir = Path(tempfile.mkdtemp(prefix=f".{target.name}.", dir=target.absolute().parent))
    tmp = tmpdir / target.name
    try:
        yield tmp
        if tmp.exists():
            with _signals_deferred():
                os.replace(tmp, target)
    finally:
        shutil.rmtree(tmpdir, ignore_errors=True)
