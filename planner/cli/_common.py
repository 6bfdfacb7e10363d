"""What every CLI command shares: exit codes, signal handling, error messages.

Exit codes (the same for every command, listed in ``vibroplan --help`` and the README):

====  ==========================================================================
0     success
1     verification failed (the plan or the check was computed and written, but
      some step does not do what it should; the report says which and why)
2     bad input: a spec, config, CSV, plan.json or option that cannot be used, a
      request beyond the machine (memory, cores), or an output vibroplan refuses
      to write (nothing is computed, nothing written)
3     an OS, I/O or environment error (a permission, a full disk, a missing
      package, memory exhausted) or a dask scheduler that cannot be reached or
      went away, with the path or address, no traceback
129   interrupted by SIGHUP (the terminal closed); 130 by SIGINT (Ctrl-C); 143 by
      SIGTERM.  Workers are stopped, temporaries removed, nothing written.
====  ==========================================================================
"""

from __future__ import annotations

import contextlib
import functools
import math
import signal
import sys
from pathlib import Path

import click

from planner.files import (
    check_not_input,
    check_output_file,
    check_output_folder,
    check_parent,
    output_files,
    output_folder,
    version_string,
)
from planner.core.errors import Interrupted, OutputError, PlanningError, SpecError

__all__ = ["EXIT_CODES_HELP", "FORCE_FILES_HELP", "Finite", "check_output_files",
           "check_output_folder", "chip_inputs", "handle_errors", "output_file", "output_files",
           "output_folder", "version_string"]

EXIT_OK, EXIT_FAILED, EXIT_INPUT, EXIT_OS = 0, 1, 2, 3

#: The exit-code table as shown at the end of ``--help`` (click keeps \b blocks verbatim).
EXIT_CODES_HELP = """\b
Exit codes: 0 success; 1 verification failed; 2 bad input or refused
output; 3 OS, I/O, environment or scheduler error; 129 / 130 / 143
interrupted (SIGHUP / SIGINT / SIGTERM)."""

#: The ``--force`` help of a command with file outputs.
FORCE_FILES_HELP = ("Write an output file even if it exists and this command did not write "
                    "it (or it was changed since), or if it lies inside a vibroplan output "
                    "folder.  An input is never replaced, not even with --force.")

_NAMES = {signal.SIGINT: "SIGINT", signal.SIGTERM: "SIGTERM"}
if hasattr(signal, "SIGHUP"):
    _NAMES[signal.SIGHUP] = "SIGHUP"


#: Seconds a run has to answer a signal before its watchdog ends it: the main thread
#: stuck in a long compiled call (a numba kernel, which Python cannot interrupt) gets
#: :data:`STUCK_S`; one already unwinding (closing workers, removing temporaries) gets
#: :data:`UNWIND_S`, beyond a Dask cluster's close timeout.
STUCK_S = 3.0
UNWIND_S = 30.0


#: What a command must still say when the watchdog ends it (its main thread did not
#: answer a signal in time, so its own ``except KeyboardInterrupt`` does not run):
#: functions of no arguments returning a line, registered by :func:`exit_note`.
_EXIT_NOTES: list = []


@contextlib.contextmanager
def exit_note(note):
    """Within the block, ``note()`` (a line of text) is also written to stderr when the
    signal watchdog ends the run (e.g. a wafer batch's "N finished dies kept in WORK:
    run the same command again to resume")."""
    _EXIT_NOTES.append(note)
    try:
        yield
    finally:
        _EXIT_NOTES.remove(note)


class _SignalGuard:
    """Turn the first SIGINT, SIGTERM or SIGHUP into :class:`Interrupted` in the main
    thread (SIGHUP: the terminal went away; its default would end the process without
    stopping its workers).

    Later signals are only recorded, so that the clean-up the first one started
    (terminating workers, removing temporaries) runs to its end.

    Python runs a signal handler only between two bytecodes of the main thread: a
    compiled call (a numba kernel's simulation, tens of seconds on a hostile chip) holds
    it off.  A watchdog thread wakes on the signal itself (``signal.set_wakeup_fd``; the
    kernels release the GIL, ``nogil=True``) and, if the main thread has not answered
    within :data:`STUCK_S` (or finished unwinding within :data:`UNWIND_S`), removes this
    process's temporaries and locks (:func:`planner.files.swap.remove_held`) and ends it
    with the signal's exit code; worker processes follow their parent.
    """

    def __init__(self):
        self.signum = None
        #: the exit notes registered when the signal came (:func:`exit_note`), said
        #: however the run then unwinds (a wafer batch interrupted between two dies
        #: unwound through an error raised by the interrupt, and said only "stopped")
        self.notes = ()
        self.saved = {}
        self._wakeup = None
        self._done = None

    def _handler(self, signum, frame):
        from planner.files.swap import note_interrupt

        if self.signum is None:
            self.signum = signum
            self.notes = tuple(_EXIT_NOTES)
            note_interrupt(signum)
            raise Interrupted(signum)

    def __enter__(self):
        for sig in _NAMES:
            try:
                self.saved[sig] = signal.signal(sig, self._handler)
            except ValueError:  # not the main thread (e.g. a test runner's worker)
                pass
        if self.saved:
            self._start_watchdog()
        return self

    def _start_watchdog(self):
        import os
        import threading

        r, w = os.pipe()
        os.set_blocking(w, False)
        try:
            old = signal.set_wakeup_fd(w, warn_on_full_buffer=False)
        except ValueError:
            os.close(r)
            os.close(w)
            return
        self._wakeup = (r, w, old)
        self._done = threading.Event()
        threading.Thread(target=self._watch, args=(r, self._done), daemon=True,
                         name="vibroplan-signal-watchdog").start()

    def _watch(self, r, done):
        import os
        import time

        try:
            signum = None
            while signum is None:   # the wakeup fd carries every handled signal's number
                data = os.read(r, 1)
                if not data or done.is_set():
                    return
                if data[0] in _NAMES:
                    signum = data[0]
        except OSError:
            return
        finally:
            if done.is_set() or signum is None:
                with contextlib.suppress(OSError):
                    os.close(r)
        start = time.monotonic()
        while not done.wait(0.1):
            waited = time.monotonic() - start
            if waited > (UNWIND_S if self.signum is not None else STUCK_S):
                from planner.files.swap import remove_held

                remove_held()
                name = _NAMES.get(signum, signum)
                try:
                    os.write(2, f"interrupted ({name}): stopped, nothing written\n".encode())
                    for note in list(_EXIT_NOTES):
                        with contextlib.suppress(Exception):
                            os.write(2, (note() + "\n").encode())
                finally:
                    os._exit(128 + signum)
        with contextlib.suppress(OSError):
            os.close(r)

    def __exit__(self, *exc):
        import os

        from planner.files.swap import clear_interrupt

        if self._wakeup is not None:
            r, w, old = self._wakeup
            self._done.set()
            with contextlib.suppress(ValueError, OSError):
                signal.set_wakeup_fd(old)
            os.close(w)         # the watchdog's read ends
            self._wakeup = None
        for sig, old in self.saved.items():
            signal.signal(sig, old)
        clear_interrupt()
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


class Finite(click.FloatRange):
    """A float option that must be finite (click's FloatRange lets nan and inf through),
    optionally within a range."""

    name = "finite float"

    def convert(self, value, param, ctx):
        rv = super().convert(value, param, ctx)
        if not math.isfinite(rv):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return rv


def check_output_files(command: str, outputs, *, inputs=(), force: bool = False):
    """Check every output file of a command before any work.

    ``outputs``: (label, path or None) pairs, the label naming it in messages
    (``--out``, ``--plot``); two of them may not name one file.
    """
    outputs = [(label, path) for label, path in outputs if path is not None]
    for label, path in outputs:     # the refusal --force cannot lift comes first
        check_not_input(path, inputs, label)
    seen = {}
    for label, path in outputs:
        check_output_file(path, command=command, inputs=inputs, force=force, option=label)
        key = Path(path).absolute().resolve()
        if key in seen:
            raise OutputError(f"{label} {path}: {seen[key]} names the same file")
        seen[key] = label


def _fail(code: int, message: str):
    click.echo(message, err=True)
    sys.exit(code)


def _interrupted(signum, notes):
    """Exit 128 + ``signum``: "interrupted (SIGINT): stopped, nothing written", then
    each exit note (:func:`exit_note`) registered when the signal came, as the signal
    watchdog says them."""
    click.echo(f"interrupted ({_NAMES.get(signum, signum)}): stopped, nothing written",
               err=True)
    for note in notes:
        with contextlib.suppress(Exception):
            click.echo(note(), err=True)
    sys.exit(128 + signum)


class _solver_warnings:
    """Collect the solver's :class:`model.SolverWarning` of a command into one line at
    its end (``warning: the solver stopped N simulations ...``): Python would print
    each with the source path and line that raised it, which says nothing to a user;
    every other warning is shown as it comes."""

    def __enter__(self):
        import warnings

        self._catch = warnings.catch_warnings()
        self._catch.__enter__()
        shown = warnings.showwarning
        self.messages = []

        def show(message, category, filename, lineno, file=None, line=None):
            # the solver's warning class, if the solver was imported at all: a command
            # refused before it imports the solver (numba, a third of a second) is not
            # made to import it here
            solver = sys.modules.get("model.impacter")
            if solver is not None and issubclass(category, solver.SolverWarning):
                self.messages.append(str(message))
            else:
                shown(message, category, filename, lineno, file, line)

        warnings.showwarning = show
        return self

    def __exit__(self, *exc):
        self._catch.__exit__(*exc)
        if self.messages:
            first = self.messages[0]
            more = len(self.messages) - 1
            click.echo(f"warning: the solver stopped early in some simulations (a run "
                       f"ended on its event cap or a non-finite state: {first}"
                       + (f"; and {more} more such warnings" if more else "")
                       + "); the results are those of the runs as far as they went", err=True)
        return False


#: The parameters that name an input file, in every command that has them.  A device,
#: a FIFO, a socket or a file over the input limit given there is refused before the
#: command body imports the solver and the planner (over a second): in a fraction of
#: a second, with the message :func:`planner.files.read_input` would give.  A path that
#: does not exist or is a folder is left to the command (some take a plan's folder).
INPUT_PARAMETERS = ("spec", "config", "sweep_csv", "spec_or_plan", "file", "plan_path",
                    "measured_path", "windows_path", "spec_file")


def _refuse_unreadable_inputs(kwargs):
    """:func:`planner.files.check_input` on every :data:`INPUT_PARAMETERS` value that
    exists and is not a folder."""
    import os

    from planner.files import check_input

    for name in INPUT_PARAMETERS:
        value = kwargs.get(name)
        if value is None or not isinstance(value, (str, os.PathLike)):
            continue
        if os.path.exists(value) and not os.path.isdir(value):
            check_input(value)


def handle_errors(func):
    """Run a command with the exit codes of this module and one-line messages.

    ``SpecError`` (a bad config or spec, with field path and YAML line),
    ``OutputError`` (an output path refused before any work), ``PlanningError`` (a
    valid spec that cannot be planned, with what would fix it), ``ValueError`` (a bad
    argument caught by the model's validation, a request beyond the machine) and
    ``FileNotFoundError`` (a missing input) are the user's to act on: ``error: ...``
    and exit 2.  ``OSError`` (a scheduler's included: its address is the
    ``filename``), ``MemoryError`` and a missing package: one line, exit 3.
    SIGHUP / SIGINT / SIGTERM: ``interrupted``, exit 129 / 130 / 143.  Anything else is
    a bug and propagates with its traceback.
    """

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        with _SignalGuard() as guard, _solver_warnings():
            try:
                _refuse_unreadable_inputs(kwargs)
                return func(*args, **kwargs)
            except KeyboardInterrupt as exc:
                signum = exc.signum if isinstance(exc, Interrupted) else signal.SIGINT
                _interrupted(signum, guard.notes or tuple(_EXIT_NOTES))
            except (SpecError, OutputError, PlanningError, ValueError,
                    FileNotFoundError) as exc:  # a missing input file is bad input
                if guard.signum is not None:  # an error raised while unwinding a signal
                    _interrupted(guard.signum, guard.notes)
                if isinstance(exc, FileNotFoundError):
                    _fail(EXIT_INPUT, f"error: {exc.filename}: no such file")
                _fail(EXIT_INPUT, f"error: {exc}")
            except OSError as exc:
                if guard.signum is not None:
                    _interrupted(guard.signum, guard.notes)
                where = exc.filename or ""
                what = exc.strerror or str(exc)
                _fail(EXIT_OS, f"error: {where}: {what}" if where else f"error: {what}")
            except MemoryError:
                _fail(EXIT_OS, "error: out of memory (the machine could not give this run "
                               "the memory it needed; ask for less, or free some)")
            except ModuleNotFoundError as exc:
                top = (exc.name or "?").split(".")[0]
                if top in ("model", "planner"):
                    _fail(EXIT_OS, f"error: this vibroplan installation lacks {exc.name}: "
                                   "reinstall vibroplan (python -m pip install .)")
                _fail(EXIT_OS, f"error: the Python package {top!r} is not installed, and "
                               f"this command needs it: python -m pip install {top}")
            except Exception:
                if guard.signum is not None:
                    _interrupted(guard.signum, guard.notes)
                raise

    return wrapper


def chip_inputs(plan_path, measured_path, out_dir, *, command: str, force: bool, quiet: bool,
                windows_path=None):
    """What ``vibroplan replan`` and ``vibroplan trim`` start from: the plan, the chip's
    measurement (read and checked; with ``windows_path``, a tuning sweep's working
    windows, ``calibrate --motion``, attached to it), the inputs the output folder must
    not replace (the folder checked before any work) and a progress callback printing
    each stage.

    Returns
    -------
    (plan, measured, inputs, progress)
    """
    from planner.planfile.reader import read_plan
    from planner.afterfab.measurement import read_measured

    plan = read_plan(plan_path)
    measured = read_measured(measured_path, plan.impacter_ids,
                             design_hz=plan.design_natural_frequency_hz)
    inputs = [plan.path, measured_path]
    if windows_path is not None:
        measured = _with_windows(plan, measured, windows_path)
        inputs.append(windows_path)
    check_output_folder(out_dir, command=command, inputs=inputs, force=force)

    def progress(stage, item=None, total=None):
        if total is not None and not quiet:
            click.echo(f"{stage}...", err=True)

    return plan, measured, inputs, progress


def _with_windows(plan, measured, windows_path):
    """``measured`` with windows.csv's working windows (``replan --windows``): a window
    without a measured resonance is an error naming its row; a flagged window is used
    with a warning."""
    from planner.afterfab.tune import read_windows
    from planner.core.errors import SpecError

    # each tone where the chip puts it: moved with its measured resonance, as a re-plan
    # moves it (a window is checked against its own impacter's tone and the others')
    design = plan.design_natural_frequency_hz
    tones = {r.id: r.frequency_hz * (measured[r.id].natural_frequency_hz / design[r.id]
                                     if r.id in measured else 1.0) for r in plan.impacters}
    windows, flagged = read_windows(windows_path, plan.impacter_ids, tones,
                                    band_hz=tuple(plan.spec.drive.band_hz))
    unmeasured = sorted(set(windows) - set(measured))
    if unmeasured:
        raise SpecError(f"a working window for {', '.join(unmeasured)}, which measured.csv "
                        "does not measure: a tuned tone moves from a measured resonance "
                        "(measure it, or drop its window)", source=str(windows_path))
    for name, status in flagged.items():
        click.echo(f"warning: {name}: its window is flagged ({status}); used as given",
                   err=True)
    return {n: (m.with_window(windows[n]) if n in windows else m)
            for n, m in measured.items()}
