"""The model registry of scheduled retraining: one JSON document, written atomically.

Layout of a retraining home (``ROOT``)::

    ROOT/registry.json        this document (the single commit point: nothing counts until it says so)
    ROOT/stores/<version>/    the run directory (data/raw, data/signals, ..., data/models, reports/) built
                              for a version; the registry's ``store`` names the current one
    ROOT/models/<version>/    the models, evaluation and report of every candidate (promoted or not)
    ROOT/current              symlink to models/<current version> (a convenience; the registry is the truth)
    ROOT/staging/             candidates under construction (removed at the start of the next run)

The document::

    {"format": 1, "current": "v0002" | null, "store": "stores/v0003" | null,
     "holdout": {"trials": [...], "logs": {trial: sha256}, "metric": "...", "mode": "max"},
     "seen_logs": {sha256: {"name": ..., "trial": ..., "version": ..., "seen_at": ...}},
     "versions": [{"version", "created_at", "status": "promoted" | "rejected", "reason", "metrics",
                   "holdout_score", "parent", "lineage": {...}}]}
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import Any

from pipeline.errors import PipelineError
from pipeline.tableio import write_json

log = logging.getLogger(__name__)

FORMAT = 1
REGISTRY_FILE = "registry.json"


class RegistryError(PipelineError):
    """The registry document is unreadable or of an unknown format."""


def empty() -> dict[str, Any]:
    return {"format": FORMAT, "current": None, "store": None, "holdout": None, "seen_logs": {}, "versions": []}


def registry_path(root: str | Path) -> Path:
    return Path(root) / REGISTRY_FILE


def load(root: str | Path) -> dict[str, Any]:
    """The registry of ``root`` (an empty one if there is none yet)."""
    path = registry_path(root)
    if not path.exists():
        return empty()
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as err:
        raise RegistryError(f"cannot read the registry: {err}", file=path) from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise RegistryError(f"unknown registry format {data.get('format') if isinstance(data, dict) else data!r}; "
                            f"expected {FORMAT}", file=path)
    return {**empty(), **data}


def save(root: str | Path, data: dict[str, Any]) -> Path:
    """Write the registry atomically (temp file + ``os.replace``): readers see the old or the new, never half."""
    path = write_json(data, registry_path(root))
    path.chmod(0o644)  # mkstemp makes 0600; dashboards and other users read the registry
    return path


def next_version(data: dict[str, Any]) -> str:
    numbers = [int(v["version"].lstrip("v")) for v in data["versions"] if str(v.get("version", "")).startswith("v")]
    return f"v{max(numbers, default=0) + 1:04d}"


def version(data: dict[str, Any], name: str | None) -> dict[str, Any] | None:
    return next((v for v in data["versions"] if v["version"] == name), None) if name else None


def current(data: dict[str, Any]) -> dict[str, Any] | None:
    """The entry of the current (promoted) model, or None."""
    return version(data, data.get("current"))


def current_model_dir(root: str | Path) -> Path | None:
    """Directory of the current model's artifacts, from the registry (not the convenience symlink)."""
    data = load(root)
    return Path(root) / "models" / data["current"] if data.get("current") else None


def point_current(root: str | Path, name: str) -> None:
    """Atomically repoint the ``current`` symlink at ``models/<name>``."""
    root = Path(root)
    tmp = root / f".current.{os.getpid()}.tmp"
    if tmp.is_symlink() or tmp.exists():
        tmp.unlink()
    os.symlink(Path("models") / name, tmp)
    os.replace(tmp, root / "current")
