"""Reading an array spec: YAML in, a validated spec with its resolved steps out.

:func:`load_spec` reads the YAML (a file or text), refuses a key with the wrong unit
suffix with a hint (``band_khz``: use ``band_hz``), validates it against the schema
(:mod:`planner.arrayspec.schema`) and resolves its steps (:mod:`planner.arrayspec.steps`); every
error names the field's path and its YAML line.  :func:`default_spec_path` is the
embedded default spec.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from planner.core.data import DEFAULT_SPEC
from planner.core.errors import SpecError
from planner.arrayspec.schema import ArraySpec
from planner.arrayspec.steps import Step, resolve_steps
from planner.files.yamlio import check_kind, format_loc, line_of, load_yaml, validate


@dataclass(frozen=True)
class LoadedSpec:
    """A validated spec with its resolved steps and source."""

    spec: ArraySpec
    steps: tuple[Step, ...]
    source: str
    #: YAML location -> line, for errors found after validation (None if unknown).
    lines: dict | None = field(default=None, compare=False, repr=False)

    @property
    def device_ids(self) -> list[str]:
        return self.spec.array.device_ids()


def _check_units(data, lines, source):
    """Catch keys with the wrong unit suffix early, with a hint (e.g. band_khz)."""
    if not isinstance(data, dict):
        return
    hints = {"band_khz": "band_hz", "gap_nm": "gap_um", "duration_s": "duration_ms",
             "viscosity_pa_s": "viscosity_mpa_s", "pitch_mm": "pitch_um"}

    def walk(node, path):
        if isinstance(node, dict):
            for key, value in node.items():
                if key in hints:
                    loc = path + (key,)
                    raise SpecError(f"wrong unit: use {hints[key]} (in its unit)",
                                    path=format_loc(loc), line=line_of(lines, loc), source=source)
                walk(value, path + (key,))
        elif isinstance(node, list):
            for i, item in enumerate(node):
                walk(item, path + (i,))
    walk(data, ())


def load_spec(path_or_text: str | Path, *, source: str | None = None) -> LoadedSpec:
    """Read, validate and resolve an array spec.

    Parameters
    ----------
    path_or_text : str or Path
        A YAML file, or YAML text.

    Raises
    ------
    SpecError
        With the field path and YAML line of the first problem.
    """
    data, lines = load_yaml(path_or_text, source=source)
    src = source or (str(path_or_text) if isinstance(path_or_text, Path)
                     or "\n" not in str(path_or_text) else "<spec>")
    if data is not None and not isinstance(data, dict):
        raise SpecError("an array spec must be a YAML mapping", line=1, source=src)
    check_kind(data, "array spec", source=src)
    _check_units(data, lines, src)
    _read_chain_table(data, lines, src, path_or_text)
    spec = validate(ArraySpec, data, lines, source=src)
    check_sections(spec, lines, src)
    return LoadedSpec(spec, resolve_steps(spec, lines, src), src, lines)


def _read_chain_table(data, lines, source, path_or_text):
    """``drive.chain.transfer: chain.csv``: the CSV, relative to the spec's folder (the
    working folder for a spec given as text), read into the inline table in ``data``;
    an error in it names the CSV's row and column and the spec's line."""
    from planner.arrayspec.chain_table import read_transfer_table

    chain = ((data or {}).get("drive") or {}).get("chain") if isinstance(
        (data or {}).get("drive"), dict) else None
    if not isinstance(chain, dict) or not isinstance(chain.get("transfer"), str):
        return
    is_path = isinstance(path_or_text, Path) or "\n" not in str(path_or_text)
    base = Path(path_or_text).resolve().parent if is_path else Path.cwd()
    loc = ("drive", "chain", "transfer")
    try:
        table = read_transfer_table(base / chain["transfer"])
        # the path as the spec gives it: plan.json is the same wherever the spec lies
        chain["transfer"] = {**table, "file": chain["transfer"]}
    except SpecError as exc:
        raise SpecError(exc.message, path=format_loc(loc), line=line_of(lines, loc),
                        source=source) from None


def check_sections(spec: ArraySpec, lines=None, source: str | None = None,
                   prefix: tuple = ()) -> None:
    """What one section of a valid spec needs of another, with the field and its line.

    ``drive.channels.spacing: tolerance`` spaces the channels by the fabrication scatter
    of ``fabrication:``; without a non-zero tolerance there it would silently be a fixed
    grid of ``separation_hz``.

    Raises
    ------
    SpecError
    """
    if spec.drive.channels.spacing == "tolerance" and spec.fabrication.zero:
        loc = ("drive", "channels", "spacing")
        raise SpecError("tolerance spaces the channels by the fabrication scatter, and the "
                        "spec has no fabrication: section (or only zero sigmas): give the "
                        "fabrication tolerances, or spacing: log or linear with a count",
                        path=format_loc(prefix + loc), line=line_of(lines or {}, loc),
                        source=source)


def default_spec_path() -> Path:
    """The embedded default spec (a copy of configs/array_5x5.yaml shipped in the package)."""
    return DEFAULT_SPEC
