"""The configs' JSON Schemas: written from the models (``python -m pipeline.config``), shipped in the package and
named by the first line of a generated config so that editors validate it. Imports no pydantic until
:func:`write_schemas` runs."""

from __future__ import annotations

import json
from pathlib import Path


def write_schemas(directory: str | Path) -> list[Path]:
    """Write the JSON Schemas of the vehicle config and the params into ``directory``."""
    from pipeline.config.params import Params
    from pipeline.config.vehicle import Vehicle

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    written = []
    for name, model in (("vehicle", Vehicle), ("params", Params)):
        target = directory / f"{name}.schema.json"
        target.write_text(json.dumps(model.model_json_schema(), indent=2, sort_keys=True) + "\n")
        written.append(target)
    return written


def schema_path(kind: str = "vehicle") -> Path:
    """The JSON Schema of a config (``vehicle`` or ``params``) that ships with the package (``pipeline/schemas/``;
    in a checkout a link to the repository's ``schemas/``, which ``python -m pipeline.config`` regenerates)."""
    from importlib.resources import files

    return Path(str(files("pipeline") / "schemas" / f"{kind}.schema.json")).resolve()


def schema_modeline(kind: str = "vehicle") -> str:
    """The first line of a generated config: editors with the YAML language server (VS Code's YAML extension,
    neovim's yamlls, ...) then validate and complete the file against its JSON Schema as it is typed."""
    return f"# yaml-language-server: $schema={schema_path(kind).as_posix()}"
