"""Inputs read safely, outputs that never destroy a user's data, and the version string.

Every command that reads or writes goes through this module, the library as well as the CLI.

Inputs: :func:`read_input` reads a regular file of at most
:data:`planner._limits.MAX_INPUT_BYTES` (not a device such as /dev/zero, not a FIFO that
would block forever).

Output folders (``vibroplan plan --out DIR`` and the like):

- :func:`check_output_folder` refuses, before any work, a folder that this command may
  not replace: the current directory or one of its ancestors, a folder holding an input
  file, a file, a folder inside another vibroplan output folder, a non-empty folder that
  no vibroplan run wrote, one that another command wrote (the :data:`MARKER` file every
  run leaves records which), or one holding files this command did not write (the
  marker lists the files it wrote, with their SHA-256) -- all but the first three
  unless ``force``.
- :func:`output_folder` writes a folder beside the target and swaps it in atomically at
  the end (rename the old one aside, rename the new one in, remove the old one), under
  a lock that makes a concurrent writer of the same folder fail at once with a clear
  message instead of corrupting it.  Taking the lock also cleans what a dead run of the
  same target left (:func:`clean_stale`).

Output files (``--out FILE``, ``--plot FILE``, a drive file's JSON sidecar):

- :func:`check_output_file` refuses, before any work, a file that is one of the
  command's inputs (even with ``force``), lies inside a vibroplan output folder, or
  exists and was not written by this command (the :data:`REGISTRY` file of its folder
  records which command wrote which file, with its SHA-256) -- the last two unless
  ``force``.
- :func:`output_files` writes files beside their targets and moves each into place when
  the block succeeds, recording them in the registry.

On any exception, ``KeyboardInterrupt`` and the CLI's signal exceptions included,
the temporaries are removed and the targets are left as they were.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import shutil
import signal
import stat
import tempfile
from pathlib import Path

from planner.errors import OutputError, SpecError

#: File every output folder written by vibroplan carries: the command that wrote it and
#: the files it wrote (path -> SHA-256).
MARKER = ".vibroplan-output"
#: File beside single output files (``--out FILE``): which command wrote which file.
REGISTRY = ".vibroplan-files"
#: How many offending names an error message lists.
SHOWN = 5


def version_string() -> str:
    """The installed vibroplan version (``0+unknown`` when run from an uninstalled tree)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("vibroplan")
    except PackageNotFoundError:  # running from a source tree that is not installed
        return "0+unknown"


# ----------------------------------------------------------------------------- inputs


def read_input(path: str | os.PathLike, *, limit: int | None = None) -> bytes:
    """The bytes of an input file: a regular file of at most ``limit`` bytes.

    Parameters
    ----------
    path : str or PathLike
        The file.
    limit : int, optional
        Largest size [bytes]; default :data:`planner._limits.MAX_INPUT_BYTES`.

    Raises
    ------
    FileNotFoundError
        No such file.
    planner.errors.SpecError
        A folder, a device (/dev/zero), a FIFO or socket (which would block), or a
        file over the limit, naming the file.
    OSError
        It cannot be read (permissions), with the path.
    """
    from planner._limits import MAX_INPUT_BYTES

    limit = MAX_INPUT_BYTES if limit is None else int(limit)
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


# ----------------------------------------------------------------------------- helpers


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _read_json(path: Path):
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) and data.get("written_by") == "vibroplan" else None


def folder_marker(folder: Path) -> dict | None:
    """The marker of a vibroplan output folder (``command``, ``files``), or None.

    A marker from before the files were listed counts every file of the folder as
    the command's; one from before the command was recorded, as ``plan``'s.
    """
    data = _read_json(Path(folder) / MARKER)
    if data is None:
        return None
    files = data.get("files")
    return {"command": str(data.get("command") or "plan"),
            "files": files if isinstance(files, dict) else None}


def _marked_ancestor(path: Path) -> Path | None:
    """The nearest folder at or above ``path`` that is a vibroplan output folder."""
    for folder in (path, *path.parents):
        if (folder / MARKER).is_file() and folder_marker(folder) is not None:
            return folder
    return None


def _names(paths) -> str:
    paths = list(paths)
    text = ", ".join(str(p) for p in paths[:SHOWN])
    return text + (f" and {len(paths) - SHOWN} more" if len(paths) > SHOWN else "")


def _same_file(a: Path, b: Path) -> bool:
    """Whether ``a`` and ``b`` are one file (a hard link or symlink included), or would be."""
    try:
        return os.path.samefile(a, b)
    except OSError:     # one of them does not exist (yet)
        return a.absolute().resolve() == b.absolute().resolve()


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _pid_alive(pid: int) -> bool:
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:   # someone else's live process
        return True
    except OSError:
        return False
    return True


def _temp_prefix(target: Path, kind: str) -> str:
    """``.NAME.new-PID-`` (``kind`` new or old): whose temporary it is, for clean_stale."""
    return f".{target.name}.{kind}-{os.getpid()}-"


def clean_stale(target: str | os.PathLike, *, locked: bool = False) -> list[Path]:
    """Remove what dead runs writing ``target`` left beside it; returns what was removed.

    A run writes ``.NAME.new-PID-*`` (its temporary), renames the old ``NAME`` to
    ``.NAME.old-PID-*`` for the instant of the swap, and holds ``.NAME.lock``.  One that
    died (SIGKILL, a power cut) leaves them.  A temporary is stale when its PID is not
    alive, or, with ``locked`` (the caller holds ``NAME``'s lock, so no live run writes
    ``NAME``), always.  An ``.old-`` folder with no ``NAME`` beside it is the previous
    complete output of a run that died between its two renames: it is put back.
    """
    target = Path(target).absolute()
    removed = []
    for path in sorted(target.parent.glob(f".{target.name}.*-*")):
        kind, _, rest = path.name[len(target.name) + 2:].partition("-")
        if kind not in ("new", "old"):
            continue
        pid = rest.split("-", 1)[0]
        stale = locked or (pid.isdigit() and not _pid_alive(int(pid)))
        if not stale or (pid.isdigit() and int(pid) == os.getpid()):
            continue
        if kind == "old" and not target.exists() and path.is_dir():
            os.rename(path, target)   # the swap died half-way: the old output comes back
            continue
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            with contextlib.suppress(OSError):
                path.unlink()
        removed.append(path)
    lock = target.parent / f".{target.name}.lock"
    if not locked and lock.exists() and not _lock_held(lock):
        with contextlib.suppress(OSError):
            lock.unlink()
            removed.append(lock)
    return removed


def _lock_held(path: Path) -> bool:
    """Whether a live run holds the lock file ``path``."""
    try:
        import fcntl
    except ImportError:  # not POSIX: the lock is the file; its PID says whether it lives
        try:
            return _pid_alive(int(path.read_text().strip() or 0))
        except (OSError, ValueError):
            return False
    try:
        fd = os.open(path, os.O_RDWR)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return True
    finally:
        os.close(fd)
    return False


# ----------------------------------------------------------------------------- folders


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
        if want is None or p.is_symlink() or _sha256(p) != want:
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
    outer = _marked_ancestor(target.parent)
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
                              f"write ({_names(foreign)}); move them out, choose a new "
                              "folder, or pass --force to replace the folder with them")
    return target


@contextlib.contextmanager
def _lock(target: Path):
    """Hold an exclusive lock on ``target`` for the life of the block.

    The lock is a file beside the target (``.NAME.lock``, holding the PID), removed on
    release.  A second writer of the same target fails at once with
    :class:`OutputError`; a lock file that no live run holds (its run died) is taken
    over.
    """
    path = target.parent / f".{target.name}.lock"
    try:
        import fcntl
    except ImportError:  # not POSIX: an exclusive create is the lock
        fcntl = None
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | (os.O_EXCL if fcntl is None else 0),
                         0o644)
        except FileExistsError:   # not POSIX: a dead holder's lock is taken over
            if _lock_held(path):
                raise OutputError(f"{target}: another vibroplan run is writing this folder "
                                  f"(lock {path}); wait for it or choose another --out") from None
            with contextlib.suppress(OSError):
                path.unlink()
            continue
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
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        yield
    finally:
        with contextlib.suppress(OSError):
            os.unlink(path)
        os.close(fd)


@contextlib.contextmanager
def _signals_deferred():
    """Hold SIGINT, SIGTERM and SIGHUP back during the few renames of a swap, so that an
    interruption cannot leave the target half-swapped (they are delivered after)."""
    sigs = {signal.SIGINT, signal.SIGTERM} | ({signal.SIGHUP} if hasattr(signal, "SIGHUP")
                                              else set())
    try:
        old = signal.pthread_sigmask(signal.SIG_BLOCK, sigs)
    except (AttributeError, ValueError, OSError):  # not POSIX, or not the main thread
        old = None
    try:
        yield
    finally:
        if old is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _marker_text(command: str, folder: Path) -> str:
    files = {p.relative_to(folder).as_posix(): _sha256(p)
             for p in sorted(folder.rglob("*")) if p.is_file() and p.name != MARKER}
    return json.dumps({"written_by": "vibroplan", "version": version_string(),
                       "command": command, "files": files}, indent=2) + "\n"


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
    with _lock(target):
        clean_stale(target, locked=True)
        # re-check under the lock: another run may have changed the folder meanwhile
        target = check_output_folder(out_dir, command=command, inputs=inputs, force=force)
        tmp = Path(tempfile.mkdtemp(prefix=_temp_prefix(target, "new"), dir=target.parent))
        os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp's 0700 is for the temporary only
        old = None
        try:
            yield tmp
            (tmp / MARKER).write_text(_marker_text(command, tmp), encoding="utf-8")
            with _signals_deferred():
                if target.exists():
                    old = Path(tempfile.mkdtemp(prefix=_temp_prefix(target, "old"),
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


# ----------------------------------------------------------------------------- files


def _registry(folder: Path) -> dict:
    data = _read_json(folder / REGISTRY)
    files = (data or {}).get("files")
    return files if isinstance(files, dict) else {}


def written_by(path: str | os.PathLike) -> str | None:
    """The command that wrote the file ``path`` as it is now, or None (another writer,
    or changed since)."""
    path = Path(path).absolute()
    entry = _registry(path.parent).get(path.name)
    if not isinstance(entry, dict) or not path.is_file() or path.is_symlink():
        return None
    return entry.get("command") if entry.get("sha256") == _sha256(path) else None


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
    outer = _marked_ancestor(path.absolute().parent)
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


def _record(path: Path, command: str) -> None:
    """Note in the folder's :data:`REGISTRY` that ``command`` wrote ``path`` as it is."""
    folder = path.parent
    reg = folder / REGISTRY
    try:
        import fcntl
    except ImportError:
        fcntl = None
    fd = os.open(reg, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        if fcntl is not None:
            fcntl.flock(fd, fcntl.LOCK_EX)   # short: other writers of this folder wait
        with os.fdopen(os.dup(fd), "r+", encoding="utf-8") as fh:
            try:
                data = json.loads(fh.read() or "{}")
            except ValueError:
                data = {}
            files = data.get("files") if isinstance(data, dict) else None
            files = {k: v for k, v in (files or {}).items() if (folder / k).is_file()}
            files[path.name] = {"command": command, "sha256": _sha256(path)}
            fh.seek(0)
            fh.truncate()
            fh.write(json.dumps({"written_by": "vibroplan", "files": dict(sorted(files.items()))},
                                indent=1) + "\n")
    finally:
        os.close(fd)


@contextlib.contextmanager
def output_files(targets, *, command: str, inputs=(), force: bool = False):
    """Yield temporary paths for ``targets``; move each into place when the block succeeds.

    Each target is checked with :func:`check_output_file` (call that yourself first, to
    refuse before any work); the temporaries have the targets' own names, in a hidden
    folder beside each (so that a writer may derive one file's name from another's, as
    a drive file's JSON sidecar), and what the block wrote is moved in and recorded in
    the folder's :data:`REGISTRY`.  A temporary the block did not write is skipped.  On
    any exception nothing is moved.

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
                dirs[parent] = Path(tempfile.mkdtemp(prefix=_temp_prefix(t, "new"), dir=parent))
            tmps.append(dirs[parent] / t.name)
        yield tmps
        for t, tmp in zip(targets, tmps):
            if tmp.exists():
                with _signals_deferred():
                    os.replace(tmp, t)
                _record(t.absolute(), command)
    finally:
        for d in dirs.values():
            shutil.rmtree(d, ignore_errors=True)
