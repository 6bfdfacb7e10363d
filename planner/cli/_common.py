"""What every CLI command shares: exit codes, signal handling, error messages.

Exit codes (the same for every command, listed in ``vibroplan --help`` and the README):

====  ==========================================================================
0     success
1     verification failed (the plan or the check was computed and written, but
      some step does not do what it should; the report says which and why)
2     bad input: a spec, config, CSV or option that cannot be used, or an output
      folder vibroplan refuses to write (nothing is computed, nothing written)
3     an OS or I/O error (a permission, a full disk), with the path, no traceback
130   interrupted by SIGINT (Ctrl-C); 143 by SIGTERM.  Workers are stopped,
      temporaries removed, nothing written.
====  ==========================================================================
"""

from __future__ import annotations

import functools
import signal
import sys

import click

from planner._io import (
    atomic_path,
    check_output_folder,
    check_parent,
    output_folder,
    version_string,
)
from planner.errors import Interrupted, OutputError, PlanningError, SpecError

__all__ = ["EXIT_CODES_HELP", "atomic_path", "check_output_folder", "handle_errors",
           "output_file", "output_folder", "version_string"]

EXIT_OK, EXIT_FAILED, EXIT_INPUT, EXIT_OS = 0, 1, 2, 3

#: The exit-code table as shown at the end of ``--help`` (click keeps \b blocks verbatim).
EXIT_CODES_HELP = """\b
Exit codes: 0 success; 1 verification failed; 2 bad input or refused
output folder; 3 OS or I/O error; 130 / 143 interrupted (SIGINT / SIGTERM)."""

_NAMES = {signal.SIGINT: "SIGINT", signal.SIGTERM: "SIGTERM"}


class _SignalGuard:
    """Turn the first SIGINT or SIGTERM into :class:`Interrupted` in the main thread.

    Later signals are only recorded, so that the clean-up the first one started
    (terminating workers, removing temporaries) runs to its end.
    """

    def __init__(self):
        self.signum = None
        self.saved = {}

    def _handler(self, signum, frame):
        if self.signum is None:
            self.signum = signum
            raise Interrupted(signum)

    def __enter__(self):
        for sig in _NAMES:
            try:
                self.saved[sig] = signal.signal(sig, self._handler)
            except ValueError:  # not the main thread (e.g. a test runner's worker)
                pass
        return self

    def __exit__(self, *exc):
        for sig, old in self.saved.items():
            signal.signal(sig, old)
        return False


def output_file(ctx, param, value):
    """click callback for an output file option: its folder must exist and be writable,
    checked while the options are parsed, before any work (exit 2 / exit 3)."""
    if value is None:
        return value
    try:
        check_parent(value)
    except OutputError as exc:
        raise click.BadParameter(str(exc), ctx=ctx, param=param) from None
    except OSError as exc:
        click.echo(f"error: {exc.filename}: {exc.strerror}", err=True)
        ctx.exit(EXIT_OS)
    return value


def _fail(code: int, message: str):
    click.echo(message, err=True)
    sys.exit(code)


def handle_errors(func):
    """Run a command with the exit codes of this module and one-line messages.

    ``SpecError`` (a bad config or spec, with field path and YAML line),
    ``OutputError`` (an output path refused before any work), ``PlanningError`` (a
    valid spec that cannot be planned, with what would fix it) and ``ValueError``
    (a bad argument caught by the model's validation) and ``FileNotFoundError`` (a
    missing input) are the user's to act on: ``error: ...`` and exit 2.  ``OSError``: one line naming the path, exit 3.
    SIGINT / SIGTERM: ``interrupted``, exit 130 / 143.  Anything else is a bug and
    propagates with its traceback.
    """

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        with _SignalGuard() as guard:
            try:
                return func(*args, **kwargs)
            except KeyboardInterrupt as exc:
                signum = exc.signum if isinstance(exc, Interrupted) else signal.SIGINT
                _fail(128 + signum, f"interrupted ({_NAMES.get(signum, signum)}): "
                                    "stopped, nothing written")
            except (SpecError, OutputError, PlanningError, ValueError,
                    FileNotFoundError) as exc:  # a missing input file is bad input
                if guard.signum is not None:  # an error raised while unwinding a signal
                    _fail(128 + guard.signum, f"interrupted ({_NAMES[guard.signum]}): "
                                              "stopped, nothing written")
                if isinstance(exc, FileNotFoundError):
                    _fail(EXIT_INPUT, f"error: {exc.filename}: no such file")
                _fail(EXIT_INPUT, f"error: {exc}")
            except OSError as exc:
                if guard.signum is not None:
                    _fail(128 + guard.signum, f"interrupted ({_NAMES[guard.signum]}): "
                                              "stopped, nothing written")
                where = exc.filename or ""
                what = exc.strerror or str(exc)
                _fail(EXIT_OS, f"error: {where}: {what}" if where else f"error: {what}")
            except Exception:
                if guard.signum is not None:
                    _fail(128 + guard.signum, f"interrupted ({_NAMES[guard.signum]}): "
                                              "stopped, nothing written")
                raise

    return wrapper
