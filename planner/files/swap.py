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


#: The temporaries and locks this process holds now: what a run stopped by force
#: (:func:`remove_held`, the CLI's last resort when a signal is not answered) must not
#: leave behind.  Only the main thread adds and removes; the remover runs at the end.
_HELD: dict = {}


def hold(path) -> None:
    """Note a temporary or lock ``path`` this process made (see :func:`remove_held`)."""
    _HELD[str(path)] = True


def release(path) -> None:
    """Forget ``path`` (it was removed, or swapped in as an output)."""
    _HELD.pop(str(path), None)


#: The signal that interrupted this process, once one did (:func:`note_interrupt`).
_INTERRUPT: list = []


def note_interrupt(signum: int) -> None:
    """Record that a signal interrupted the run (the CLI's handler calls this)."""
    if not _INTERRUPT:
        _INTERRUPT.append(int(signum))


def clear_interrupt() -> None:
    """Forget a recorded interrupt (a command's end: the next command in this process,
    a test runner's, starts afresh)."""
    _INTERRUPT.clear()


def check_interrupt() -> None:
    """Raise :class:`planner.core.errors.Interrupted` if a signal interrupted the run.

    Called before an output is swapped in: the handler's exception can be swallowed
    where Python cannot raise it (a finalizer, a callback: "Exception ignored in ..."),
    and the run would then go on and write its outputs (issue 44:
    ``test_sigint_while_outputs_are_written`` ended with exit 0)."""
    if _INTERRUPT:
        from planner.core.errors import Interrupted

        raise Interrupted(_INTERRUPT[0])


def remove_held() -> list:
    """Remove every temporary and lock this process holds; returns their paths.  For a
    process about to end without its clean-up (``os._exit``): a dead run's leftovers
    would be cleaned by the next run anyway, but none should be left at all."""
    removed = []
    for path in list(_HELD):
        p = Path(path)
        with contextlib.suppress(OSError):
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p, ignore_errors=True)
            else:
                p.unlink()
            removed.append(path)
        _HELD.pop(path, None)
    return removed


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
        hold(path)
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        yield
    finally:
        with contextlib.suppress(OSError):
            os.unlink(path)
        release(path)
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
