"""Vehicle config and run params: frozen pydantic models, loaded from YAML, hashed, with JSON Schemas.

``load_vehicle(path)`` and ``load_params(path)`` validate a file and raise :class:`ConfigError` naming
the file and the key (``thrusters.1.direction``) on any problem: bytes that are not UTF-8, YAML the parser
refuses or cannot nest, a key given twice (:mod:`pipeline.config.yamlload`), or a value the models refuse.
``config_hash`` is the sha256 of the canonical JSON of a model: it goes into every output's provenance.
``python -m pipeline.config`` writes the JSON Schemas into ``schemas/``.

The names below are loaded on first use (PEP 562): pydantic and the models are imported by the first
``from pipeline.config import Vehicle`` (or ``load_vehicle``, ...), not by importing a light submodule such
as :mod:`pipeline.config.checks` or :mod:`pipeline.config.snapshot`, which ``auvid ingest`` reads its configs
through when they were validated before (:mod:`pipeline.config.snapshot`).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from pipeline.config.hashing import config_hash
    from pipeline.config.loading import (
        check_params_against_vehicle,
        coupled_skip_reason,
        load_params,
        load_vehicle,
        measured_dofs,
        parse,
        todo_markers,
    )
    from pipeline.config.params import EXPLICIT_MODELS, Params
    from pipeline.config.schemas import write_schemas
    from pipeline.config.vehicle import THRUST_COLUMN, Vehicle, thrust_column

#: Each exported name -> the submodule defining it.
_WHERE = {"config_hash": "hashing", "check_params_against_vehicle": "loading", "coupled_skip_reason": "loading",
          "load_params": "loading", "load_vehicle": "loading", "measured_dofs": "loading", "parse": "loading",
          "todo_markers": "loading", "EXPLICIT_MODELS": "params", "Params": "params", "write_schemas": "schemas",
          "THRUST_COLUMN": "vehicle", "Vehicle": "vehicle", "thrust_column": "vehicle"}

__all__ = ["EXPLICIT_MODELS", "THRUST_COLUMN", "Params", "Vehicle", "check_params_against_vehicle", "config_hash",
           "coupled_skip_reason", "load_params", "load_vehicle", "measured_dofs", "parse", "thrust_column",
           "todo_markers", "write_schemas"]


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        return getattr(importlib.import_module(f"pipeline.config.{_WHERE[name]}"), name)
    raise AttributeError(f"module 'pipeline.config' has no attribute {name!r}")
