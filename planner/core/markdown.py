"""Markdown reports built from named sections: report.md of a plan, a re-plan, a trim
and a layout.

A :class:`Report` is a title, the paragraphs under it and a list of :class:`Section` s,
each a heading and its lines.  A command that adds to a report adds a section by its
title (:meth:`Report.insert`), never by searching the written text for a heading; the
text is made once, by :meth:`Report.text`.  :func:`md_table` and :func:`fmt` are the
tables' and numbers' shapes every report shares.

Examples
--------
>>> r = Report("vibroplan plan: tiny", ["Two devices."], [Section("Designs", ["A1."])])
>>> r.insert(Section("Frequency assignment", ["60 channels."]), before="Designs")
>>> print(r.text(), end="")
# vibroplan plan: tiny
<BLANKLINE>
Two devices.
## Frequency assignment
<BLANKLINE>
60 channels.
## Designs
<BLANKLINE>
A1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path


@dataclass(frozen=True)
class Section:
    """One section of a report: its heading and the lines under it.

    Attributes
    ----------
    title : str
        The heading's text, without the ``#`` s; a report finds the section by it.
    lines : tuple of str
        The markdown under the heading, one line each (a blank line under the heading
        comes with the heading; a blank line that closes the section is its own last
        line).
    level : int
        The heading's level: 2 for ``##``, 3 for a subsection (``###``).
    """

    title: str
    lines: tuple[str, ...] = ()
    level: int = 2

    def __post_init__(self):
        if not self.title or "\n" in self.title:
            raise ValueError(f"title must be one non-empty line, {self.title!r} was given")
        if self.level not in (2, 3, 4):
            raise ValueError(f"level must be 2, 3 or 4, {self.level!r} was given")
        object.__setattr__(self, "lines", tuple(self.lines))

    def render(self) -> list[str]:
        """The section's markdown lines: its heading, a blank line, its lines."""
        return ["#" * self.level + " " + self.title, "", *self.lines]


@dataclass
class Report:
    """A markdown report: a title, the lines under it, and its sections in order.

    Attributes
    ----------
    title : str
        The ``#`` heading's text.
    head : list of str
        The lines between the title (and its blank line) and the first section.
    sections : list of Section
        In the order they are written; titles are unique.
    preamble : list of str
        Lines above the title (an HTML comment naming the command that wrote it).
    """

    title: str
    head: list[str] = field(default_factory=list)
    sections: list[Section] = field(default_factory=list)
    preamble: list[str] = field(default_factory=list)

    def __post_init__(self):
        given, self.sections = list(self.sections), []
        self.head, self.preamble = list(self.head), list(self.preamble)
        for s in given:
            # each checked as a later one is: a Section, its title not taken
            self.insert(s)

    @property
    def titles(self) -> list[str]:
        """The sections' titles, in order."""
        return [s.title for s in self.sections]

    def index(self, title: str) -> int:
        """Position of the section titled ``title``; KeyError naming the titles there are."""
        for k, s in enumerate(self.sections):
            if s.title == title:
                return k
        raise KeyError(f"no section {title!r} in the report (its sections: "
                       f"{', '.join(map(repr, self.titles)) or 'none'})")

    def section(self, title: str) -> Section:
        """The section titled ``title``."""
        return self.sections[self.index(title)]

    def insert(self, section: Section, *, before: str | None = None,
               after: str | None = None) -> None:
        """Add ``section`` before the section titled ``before``, after the one titled
        ``after``, or at the end (neither given).

        Raises
        ------
        ValueError
            A section of that title is there already, or both places are given.
        KeyError
            No section has the title ``before`` or ``after`` names.
        """
        if not isinstance(section, Section):
            raise TypeError(f"section must be a Section, {type(section).__name__} was given")
        if section.title in self.titles:
            raise ValueError(f"the report has a section {section.title!r} already")
        if before is not None and after is not None:
            raise ValueError("give before or after, not both")
        if before is not None:
            k = self.index(before)
        elif after is not None:
            k = self.index(after) + 1
        else:
            k = len(self.sections)
        self.sections.insert(k, section)

    def text(self) -> str:
        """The whole report as markdown text, ending in one newline (a last section's
        closing blank lines are not written)."""
        lines = [*self.preamble, "# " + self.title, "", *self.head]
        for s in self.sections:
            lines += s.render()
        return "\n".join(lines).rstrip("\n") + "\n"

    def write(self, path: Path) -> None:
        """Write :meth:`text` to ``path`` (UTF-8)."""
        Path(path).write_text(self.text(), encoding="utf-8")


def md_table(header, rows) -> list[str]:
    """Lines of a markdown table: a header row, its rule and one line per row.

    >>> md_table(["a", "b"], [[1, 2]])
    ['| a | b |', '|---|---|', '| 1 | 2 |']
    """
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    return out + ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]


def fmt(x, spec):
    """A number for a report table; '-' where there is none (None, NaN, infinite).

    >>> fmt(1234.5, ".1f"), fmt(None, ".1f"), fmt(float("nan"), "g")
    ('1234.5', '-', '-')
    """
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    return format(x, spec)
