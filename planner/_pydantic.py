"""The strict pydantic base of every config section (device, array spec, design)."""

from pydantic import BaseModel, ConfigDict


class Strict(BaseModel):
    """Unknown keys are errors (a misspelt key is never silently ignored); frozen."""

    model_config = ConfigDict(extra="forbid", frozen=True)
