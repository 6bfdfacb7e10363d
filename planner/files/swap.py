"""Temporaries beside a target, the lock on it, and what dead runs left behind.

A run writing ``NAME`` writes its temporary ``.NAME.new-PID-*`` beside it, holds the
lock ``.NAME.lock`` (:func:`lock`: a second writer of the same target fails at once),
and swaps the temporary in with signals held back (:func:`signals_deferred`), renaming
the old ``NAME`` to ``.NAME.old-PID-*`` for the instant of the swap.  A run that died
(SIGKILL, a power cut) leaves these behind: :func:`clean_stale` removes them, or puts a
complete old output back.
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import signal
from pathlib import Path

from planner.core.errors import OutputError


def umask() -> int:
    """The process's file-mode creation mask (read without changing it)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _pid_alive(pid: int) -> bool:
    """Whether the process ``pid`` lives (someone else's included)."""
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


def temp_prefix(target: Path, kind: str) -> str:
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
    lock_file = target.parent / f".{target.name}.lock"
    if not locked and lock_file.exists() and not _lock_held(lock_file):
        with contextlib.suppress(OSError):
            lock_file.unlink()
            removed.append(lock_file)
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


@contextlib.contextmanager
def lock(target: Path):
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
def signals_deferred():
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
