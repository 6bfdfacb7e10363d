"""Errors a user can cause and fix: bad configs, bad specs, impossible plans."""

from __future__ import annotations


class SpecError(ValueError):
    """A config or spec that cannot be used, with where the problem is.

    Parameters
    ----------
    message : str
        What is wrong, in the user's terms.
    path : str, optional
        Dotted field path, e.g. ``drive.band_hz[1]``.
    line : int, optional
        1-based line in the YAML file.
    source : str, optional
        The file name.
    also : sequence of str, optional
        Further problems of the same file, each with its own path and line, listed after
        the first one's line.
    """

    def __init__(self, message: str, path: str | None = None, line: int | None = None,
                 source: str | None = None, also=()):
        self.message = message
        self.path = path
        self.line = line
        self.source = source
        self.also = tuple(also)
        super().__init__(str(self))

    def __str__(self) -> str:
        where = ""
        if self.source:
            where += f"{self.source}: "
        if self.path:
            where += f"{self.path}: "
        text = f"{where}{self.message}"
        if self.line is not None:
            text += f" (line {self.line})"
        if self.also:
            text += "; also " + "; ".join(self.also)
        return text


class PlanningError(RuntimeError):
    """A spec that is valid but cannot be planned (e.g. the band cannot hold the graph)."""


class OutputError(ValueError):
    """An output path vibroplan refuses to write (it would destroy a user's files, its
    parent folder is missing, or another run is writing it).  Raised before any work."""


class LimitError(ValueError):
    """A request beyond what the machine can give: more memory than it has, more worker
    processes than cores, an input file over the size limit.  Raised before any work."""


class NotWritableError(OSError):
    """An output folder nothing can be written in (permissions, a read-only or special
    file system such as /proc), found before any work; ``filename`` is the folder.

    Its own class: ``OSError(errno.ENOENT, ...)`` would become a
    :class:`FileNotFoundError`, which the CLI reads as a missing *input* (exit 2); an
    output that cannot be written is an OS error (exit 3) in every command."""


class SchedulerError(OSError):
    """A dask.distributed scheduler that cannot be reached, does not answer, or went away
    during the run; ``filename`` is its address (the CLI's exit 3 names it)."""


class Interrupted(KeyboardInterrupt):
    """The run was stopped by a signal (SIGINT, SIGTERM or SIGHUP); ``signum`` says which.

    A ``KeyboardInterrupt`` so that every clean-up written for Ctrl-C runs for SIGTERM too.
    """

    def __init__(self, signum: int):
        self.signum = int(signum)
        super().__init__(f"interrupted by signal {self.signum}")

    @property
    def exit_code(self) -> int:
        """128 + the signal number: 130 for SIGINT, 143 for SIGTERM, 129 for SIGHUP."""
        return 128 + self.signum
