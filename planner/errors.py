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
    """

    def __init__(self, message: str, path: str | None = None, line: int | None = None,
                 source: str | None = None):
        self.message = message
        self.path = path
        self.line = line
        self.source = source
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
        return text


class PlanningError(RuntimeError):
    """A spec that is valid but cannot be planned (e.g. the band cannot hold the graph)."""
