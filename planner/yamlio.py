"""Read YAML keeping each value's line, and report validation errors by field and line.

pydantic validates the plain data; when it fails, :func:`validate` maps each
error's location (``("drive", "band_hz", 1)``) back to the line of the YAML file
where that value (or the nearest enclosing key) was written.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, TypeVar

import pydantic
import yaml

from planner.errors import SpecError

T = TypeVar("T", bound=pydantic.BaseModel)

LineMap = dict[tuple, int]


def _walk(node: yaml.Node, path: tuple, lines: LineMap) -> None:
    lines.setdefault(path, node.start_mark.line + 1)
    if isinstance(node, yaml.MappingNode):
        for key_node, value_node in node.value:
            key = key_node.value
            # the line of a mapping value is the line of its key
            lines[path + (key,)] = key_node.start_mark.line + 1
            _walk(value_node, path + (key,), lines)
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            lines[path + (i,)] = item.start_mark.line + 1
            _walk(item, path + (i,), lines)


def load_yaml(text_or_path: str | Path, *, source: str | None = None) -> tuple[Any, LineMap]:
    """Parse YAML, returning the data and a map from field path to 1-based line.

    Parameters
    ----------
    text_or_path : str or Path
        A path to a YAML file, or YAML text (a ``str`` containing a newline).

    Raises
    ------
    SpecError
        The file is missing or is not valid YAML (with the line of the fault).
    """
    if isinstance(text_or_path, Path) or "\n" not in str(text_or_path):
        path = Path(text_or_path)
        if not path.is_file():
            raise SpecError(f"no such file: {path}")
        text = path.read_text(encoding="utf-8")
        source = source or str(path)
    else:
        text = str(text_or_path)
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = mark.line + 1 if mark is not None else None
        problem = getattr(exc, "problem", None) or str(exc)
        raise SpecError(f"not valid YAML: {problem}", line=line, source=source) from None
    lines: LineMap = {}
    if node is not None:
        _walk(node, (), lines)
    return data, lines


def line_of(lines: LineMap, loc: tuple) -> int | None:
    """Line of the deepest prefix of ``loc`` that the YAML file wrote."""
    loc = tuple(loc)
    while loc:
        if loc in lines:
            return lines[loc]
        loc = loc[:-1]
    return lines.get(())


def format_loc(loc: tuple) -> str:
    """``("drive", "band_hz", 1)`` -> ``drive.band_hz[1]``."""
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out


def validate(model: type[T], data: Any, lines: LineMap | None = None, *,
             source: str | None = None, prefix: tuple = ()) -> T:
    """Validate ``data`` with a pydantic model; raise :class:`SpecError` on failure.

    The error names the first failing field's path and its YAML line; further
    failures are listed after it.
    """
    lines = lines or {}
    if data is None:
        data = {}
    try:
        return model.model_validate(data)
    except pydantic.ValidationError as exc:
        errors = exc.errors()
        messages = []
        first_line = None
        first_path = None
        for err in errors:
            # drop pydantic's internal tags such as "function-after[...]"
            loc = tuple(p for p in err["loc"] if not (isinstance(p, str) and "[" in p))
            full = prefix + loc
            line = line_of(lines, full)
            msg = err["msg"]
            if err["type"] == "extra_forbidden":
                msg = "unknown key (not a field of this section)"
            msg = msg.removeprefix("Value error, ")
            if first_path is None:
                first_path, first_line = format_loc(full), line
                messages.append(msg)
            else:
                where = f"{format_loc(full)}: {msg}"
                messages.append(where + (f" (line {line})" if line else ""))
        text = messages[0]
        if len(messages) > 1:
            text += "; also " + "; ".join(messages[1:])
        raise SpecError(text, path=first_path or None, line=first_line, source=source) from None
