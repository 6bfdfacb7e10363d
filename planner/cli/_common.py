"""Helpers shared by the CLI commands: error reporting and atomic output."""

from __future__ import annotations

import contextlib
import functools
import os
import shutil
import sys
import tempfile
from pathlib import Path

import click

from planner.errors import PlanningError, SpecError


def version_string() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("vibroplan")
    except PackageNotFoundError:  # running from a source tree that is not installed
        return "0+unknown"


def handle_errors(func):
    """Turn user errors into a one-line message on stderr and exit code 2.

    ``SpecError`` (a bad config or spec, with field path and YAML line) and
    ``ValueError`` (a bad argument caught by the model's validation) and
    ``PlanningError`` (a valid spec that cannot be planned, with what would fix it)
    are the user's to act on: they get ``error: ...`` and exit 2, never a traceback.
    Anything else is a bug and propagates.
    """

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            return func(*args, **kwargs)
        except (SpecError, PlanningError, ValueError, FileNotFoundError) as exc:
            click.echo(f"error: {exc}", err=True)
            sys.exit(2)

    return wrapper


@contextlib.contextmanager
def atomic_path(target: str | os.PathLike):
    """Yield a temporary path next to ``target``; move it into place on success.

    Works for a file or a directory: whatever the body writes at the yielded
    path replaces ``target`` only when the body completes.  On any exception
    (including ``KeyboardInterrupt``) the temporary is removed and ``target``
    is left as it was, so no half-written output is ever visible.
    """
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmpdir = Path(tempfile.mkdtemp(prefix=f".{target.name}.", dir=target.parent))
    tmp = tmpdir / target.name
    try:
        yield tmp
        if tmp.exists():
            if target.is_dir() and not target.is_symlink():
                shutil.rmtree(target)
            os.replace(tmp, target)
    finally:
        shutil.rmtree(tmpdir, ignore_errors=True)
