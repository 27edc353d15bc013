"""The configs' JSON Schemas: written from the models (``python -m pipeline.config``), shipped in the package,
copied beside a generated config and named by its first line so that editors validate it. Imports no pydantic until
:func:`write_schemas` runs."""

from __future__ import annotations

import json
import os
from pathlib import Path

MODELINE = "# yaml-language-server: $schema="


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


def schema_modeline(kind: str = "vehicle", *, beside: bool = False) -> str:
    """The first line of a generated config: editors with the YAML language server (VS Code's YAML extension,
    neovim's yamlls, ...) then validate and complete the file against its JSON Schema as it is typed.

    ``beside``: the line names ``./<kind>.schema.json``, a copy of the schema in the config's own directory
    (:func:`copy_schema`): the language server resolves it relative to the config, so the line stays valid when
    the directory is moved, copied or committed. Otherwise it names the installed package's schema by its absolute
    path (for a config printed to stdout), which breaks when that install moves."""
    if beside:
        return f"{MODELINE}./{kind}.schema.json"
    return f"{MODELINE}{schema_path(kind).as_posix()}"


def copy_schema(directory: str | Path, kind: str = "vehicle") -> Path:
    """Put the package's JSON Schema of ``kind`` into ``directory`` as ``<kind>.schema.json`` (written atomically,
    only when it differs: a run of another auvid version refreshes it), for a config whose first line is
    ``schema_modeline(kind, beside=True)``."""
    target = Path(directory) / f"{kind}.schema.json"
    data = schema_path(kind).read_bytes()
    if not target.is_file() or target.read_bytes() != data:
        tmp = target.with_name(f".{target.name}.tmp")
        tmp.write_bytes(data)
        os.replace(tmp, target)
    return target
