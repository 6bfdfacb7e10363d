"""The strict pydantic base of every config section (device, array spec, design)."""

import types
import typing

from pydantic import BaseModel, ConfigDict, ValidationInfo, field_validator


def _is_tuple(annotation) -> bool:
    """Whether a field's type is a tuple (or an optional one)."""
    origin = typing.get_origin(annotation)
    if origin is tuple:
        return True
    if origin in (typing.Union, types.UnionType):
        return any(_is_tuple(arg) for arg in typing.get_args(annotation))
    return False


class Strict(BaseModel):
    """Unknown keys are errors (a misspelt key is never silently ignored); frozen; and
    every value must already have its field's type: no ``true`` read as 1.0, no
    ``"0.05"`` read as a number, no 1.5 truncated to an int (pydantic's strict mode).
    An int is a float (``count: 60`` and ``gap_um: 3``), and a list is a tuple: YAML and
    JSON have lists only."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

    @field_validator("*", mode="before")
    @classmethod
    def _lists_as_tuples(cls, value, info: ValidationInfo):
        # strict mode takes a tuple field only from a tuple; a file can only write a list
        if isinstance(value, list) and _is_tuple(cls.model_fields[info.field_name].annotation):
            return tuple(value)
        return value
