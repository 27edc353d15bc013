"""Frozen, strict pydantic base for every config model."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict


class Frozen(BaseModel):
    """Immutable, unknown keys rejected."""

    model_config = ConfigDict(frozen=True, extra="forbid")
