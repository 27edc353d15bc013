"""Frozen, strict pydantic base for every config model."""

from __future__ import annotations

from typing import Any, get_args

from pydantic import BaseModel, ConfigDict, model_validator

from pipeline.config.checks import KeyedError

#: A point or vector in body axes: [x, y, z].
Vec3 = tuple[float, float, float]


def _admits_bool(annotation: Any) -> bool:
    """Whether a field of this type may hold a boolean itself or checks its own (a nested model)."""
    if annotation is bool or (isinstance(annotation, type) and issubclass(annotation, BaseModel)):
        return True
    return any(_admits_bool(arg) for arg in get_args(annotation))


def _bool_at(value: Any, key: str) -> str | None:
    """The key of the first boolean inside ``value`` (a number, a list or a mapping of them), or None."""
    if isinstance(value, bool):
        return key
    items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, list | tuple) else ()
    for k, v in items:
        found = _bool_at(v, f"{key}.{k}")
        if found is not None:
            return found
    return None


class Frozen(BaseModel):
    """Immutable, unknown keys rejected, numbers finite (no .inf / .nan) and never booleans."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    @model_validator(mode="before")
    @classmethod
    def _no_booleans_as_numbers(cls, data: Any) -> Any:
        """pydantic reads ``true`` as 1 where a number is expected; a config never means that."""
        if isinstance(data, dict):
            for name, field in cls.model_fields.items():
                if name in data and not _admits_bool(field.annotation):
                    key = _bool_at(data[name], name)
                    if key is not None:
                        raise KeyedError(key, "found a boolean (true/false, or YAML's yes/no/on/off) where this "
                                         "key takes a number or a name")
        return data
