"""The records that say which vibroplan command wrote an output, and what it wrote.

An output folder carries a :data:`MARKER` file: the command that wrote it and the files
it wrote, each with its SHA-256.  Single output files (``--out FILE``) are recorded in
the :data:`REGISTRY` file of their folder: which command wrote which file, with its
SHA-256.  A command replaces only what it wrote itself, unchanged since
(:mod:`planner.files.folders`, :mod:`planner.files.files`).
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

from planner.files.version import version_string

#: File every output folder written by vibroplan carries: the command that wrote it and
#: the files it wrote (path -> SHA-256).
MARKER = ".vibroplan-output"
#: File beside single output files (``--out FILE``): which command wrote which file.
REGISTRY = ".vibroplan-files"


def sha256(path: Path) -> str:
    """The SHA-256 of the file ``path``, as hex."""
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


# ----------------------------------------------------------------------------- folders


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


def marked_ancestor(path: Path) -> Path | None:
    """The nearest folder at or above ``path`` that is a vibroplan output folder."""
    for folder in (path, *path.parents):
        if (folder / MARKER).is_file() and folder_marker(folder) is not None:
            return folder
    return None


def marker_text(command: str, folder: Path) -> str:
    """The :data:`MARKER` of ``folder`` as ``command`` wrote it: every file but the
    marker, with its SHA-256."""
    files = {p.relative_to(folder).as_posix(): sha256(p)
             for p in sorted(folder.rglob("*")) if p.is_file() and p.name != MARKER}
    return json.dumps({"written_by": "vibroplan", "version": version_string(),
                       "command": command, "files": files}, indent=2) + "\n"


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
    return entry.get("command") if entry.get("sha256") == sha256(path) else None


def record(path: Path, command: str) -> None:
    """Note in the folder's :data:`REGISTRY` that ``command`` wrote ``path`` as it is."""
    record_all([path], command)


def record_all(paths, command: str) -> None:
    """Note in their folder's :data:`REGISTRY`, in one write, that ``command`` wrote each
    of ``paths`` (files of one folder) as it is; entries of files that no longer exist
    are dropped."""
    paths = [Path(p) for p in paths]
    if not paths:
        return
    folder = paths[0].parent
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
            for path in paths:
                files[path.name] = {"command": command, "sha256": sha256(path)}
            fh.seek(0)
            fh.truncate()
            fh.write(json.dumps({"written_by": "vibroplan", "files": dict(sorted(files.items()))},
                                indent=1) + "\n")
    finally:
        os.close(fd)
