"""Read YAML keeping each value's line, and report validation errors by field and line.

pydantic validates the plain data; when it fails, :func:`validate` maps each
error's location (``("drive", "band_hz", 1)``) back to the line of the YAML file
where that value (or the nearest enclosing key) was written.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, TypeVar

import pydantic
import yaml

from planner.core.errors import SpecError

T = TypeVar("T", bound=pydantic.BaseModel)

LineMap = dict[tuple, int]


class Loader(yaml.SafeLoader):
    """PyYAML's safe loader with YAML 1.2's floats: ``1.6e5`` and ``1e-6`` are numbers.

    PyYAML follows YAML 1.1, whose floats need a dot and a signed exponent, so it reads
    ``1.6e5`` as the string "1.6e5".  The configs are validated strictly (a string is
    never taken for a number: :class:`planner.core.strict.Strict`), so a number written
    like that must be read as the number it is; a quoted ``"0.05"`` stays a string.
    """


Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."))


def _walk(node: yaml.Node, path: tuple, lines: LineMap, source: str | None = None) -> None:
    lines.setdefault(path, node.start_mark.line + 1)
    if isinstance(node, yaml.MappingNode):
        seen = {}
        for key_node, value_node in node.value:
            key = key_node.value
            if key in seen:
                # YAML resolves a repeated key to its last value without a word; a spec
                # whose author wrote a setting twice gets neither silently
                raise SpecError(f"duplicate key {key!r} (lines {seen[key]} and "
                                f"{key_node.start_mark.line + 1}): keep one",
                                path=format_loc(path + (key,)),
                                line=key_node.start_mark.line + 1, source=source)
            seen[key] = key_node.start_mark.line + 1
            # the line of a mapping value is the line of its key
            lines[path + (key,)] = key_node.start_mark.line + 1
            _walk(value_node, path + (key,), lines, source)
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            lines[path + (i,)] = item.start_mark.line + 1
            _walk(item, path + (i,), lines, source)


def load_yaml(text_or_path: str | Path, *, source: str | None = None) -> tuple[Any, LineMap]:
    """Parse YAML, returning the data and a map from field path to 1-based line.

    Parameters
    ----------
    text_or_path : str or Path
        A path to a YAML file, or YAML text (a ``str`` containing a newline).

    Raises
    ------
    SpecError
        The file is missing, unreadable, not a regular file (a device, a FIFO), over
        the size limit, not text, not valid YAML (with the line of the fault), empty
        (only blanks and comments), or repeats a key.
    """
    if isinstance(text_or_path, Path) or "\n" not in str(text_or_path):
        from planner.files import read_input

        path = Path(text_or_path)
        source = source or str(path)
        if not path.exists():
            raise SpecError(f"no such file: {path}")
        try:
            raw = read_input(path)
        except SpecError as exc:
            raise SpecError(exc.message, source=source) from None
        except OSError as exc:
            raise SpecError(f"cannot read the file: {exc.strerror or exc}", source=source) from None
        if b"\0" in raw:
            raise SpecError("not a text file (it holds binary data); expected a YAML file",
                            source=source)
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise SpecError(f"not a UTF-8 text file (byte {exc.start}); expected a YAML file",
                            source=source) from None
    else:
        text = str(text_or_path)
    try:
        node = yaml.compose(text, Loader=Loader)
        data = yaml.load(text, Loader=Loader)  # noqa: S506 - a SafeLoader
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = mark.line + 1 if mark is not None else None
        problem = getattr(exc, "problem", None) or str(exc)
        raise SpecError(f"not valid YAML: {problem}", line=line, source=source) from None
    if data is None:
        raise SpecError("the file is empty (nothing but blank lines and comments)",
                        source=source or "<text>")
    lines: LineMap = {}
    if node is not None:
        _walk(node, (), lines, source)
    return data, lines


#: Top-level keys that only one kind of file has, and the command that reads that kind.
KINDS = {
    "array spec": ({"array", "device", "devices", "scenes", "independent", "verification"},
                   "vibroplan plan (or assign, drive)"),
    "device config": ({"impacter", "simulation", "forward", "backward"},
                      "vibroplan simulate or vibroplan sweep"),
}

#: Keys every plan.json has (:mod:`planner.planfile.reader`): a file with them all is a
#: plan, not a YAML spec or config.
PLAN_KEYS = frozenset({"spec", "impacters", "steps"})


def check_kind(data: Any, expected: str, *, source: str | None = None) -> None:
    """Refuse a file of another kind with one line saying which command reads it.

    ``expected`` is a key of :data:`KINDS` or ``"design config"`` (a file with neither
    kind's keys).  Without this an array spec given to ``vibroplan simulate`` would be
    answered with a wall of unknown-key errors.
    """
    if not isinstance(data, dict):
        return
    keys = set(data)
    if keys >= PLAN_KEYS:
        # a plan.json is JSON, which YAML reads: without this its spec's units would be
        # named as wrong ones, far down the file
        raise SpecError(f"this is a plan.json (a vibroplan plan: it has "
                        f"{', '.join(sorted(PLAN_KEYS))}), not "
                        f"{'an' if expected[0] in 'aeiou' else 'a'} {expected}: give a YAML "
                        f"{expected} here (a plan.json is the PLAN argument of replan, "
                        "trim, yield, layout and drive)",
                        source=source)
    for kind, (markers, command) in KINDS.items():
        if kind != expected and keys & markers and not (
                expected in KINDS and keys & KINDS[expected][0]):
            found = ", ".join(sorted(keys & markers))
            raise SpecError(f"this is {'an' if kind[0] in 'aeiou' else 'a'} {kind} (it has "
                            f"{found}), not {'an' if expected[0] in 'aeiou' else 'a'} "
                            f"{expected}: use {command}", source=source)


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
            # drop pydantic's internal tags such as "function-after[...]", and a tagged
            # union's tag (drive.chain.transfer's "model"), which is no key of the spec
            loc = _spec_loc(data, tuple(p for p in err["loc"]
                                        if not (isinstance(p, str) and "[" in p)))
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
        raise SpecError(messages[0], path=first_path or None, line=first_line, source=source,
                        also=messages[1:]) from None


def _spec_loc(data, loc):
    """``loc`` without the elements that are no key of ``data`` on the way down: a
    tagged union's tag sits between a key and the fields of its value (the last element
    is kept: a missing or unknown key is named by it)."""
    out, here = [], data
    for i, p in enumerate(loc):
        if isinstance(here, dict) and p in here:
            here = here[p]
        elif isinstance(here, (list, tuple)) and isinstance(p, int) and 0 <= p < len(here):
            here = here[p]
        elif i < len(loc) - 1:
            continue
        out.append(p)
    return tuple(out)

