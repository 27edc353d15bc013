"""What the per-trial shells of sync, differentiate, derive and features share: trial discovery, provenance,
DataFrame -> Arrow, quarantine entries, the ``--trial`` option."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow as pa
from pydantic import BaseModel

from pipeline.config import Vehicle, config_hash
from pipeline.errors import PipelineError
from pipeline.tableio import file_sha256

log = logging.getLogger(__name__)


def shown(path: Path, root: Path) -> str:
    """A path as provenance shows it: relative to the run root (so outputs do not depend on where it is)."""
    try:
        return Path(path).relative_to(root).as_posix()
    except ValueError:
        return Path(path).as_posix()


def provenance(root: Path, stage: str, trial: str, inputs: list[Path], vehicle: Vehicle,
               section: BaseModel | None) -> dict[str, Any]:
    """Inputs with their sha256, the vehicle config hash and the params section the stage used (if any)."""
    out: dict[str, Any] = {
        "stage": stage,
        "trial": trial,
        "inputs": [{"file": shown(p, root), "sha256": file_sha256(p)} for p in sorted(inputs)],
        "config_hash": config_hash(vehicle),
    }
    if section is not None:
        out["params"] = section.model_dump(mode="json")
        out["params_hash"] = config_hash(section)
    return out


def to_arrow(frame: pd.DataFrame) -> pa.Table:
    """Arrow table of a DataFrame without the index or pandas metadata (bytes depend on the data only)."""
    return pa.Table.from_pandas(frame, preserve_index=False).replace_schema_metadata(None)


def trials_in(directory: Path, trial: str | None, *, dirs: bool = False) -> list[str]:
    """Trials with input in ``directory`` (sub-directories, or ``*.parquet`` stems), or just ``trial``."""
    if trial is not None:
        return [trial]
    if not directory.is_dir():
        return []
    if dirs:
        return sorted(p.name for p in directory.iterdir() if p.is_dir() and not p.name.startswith("."))
    return sorted(p.stem for p in directory.glob("*.parquet") if not p.name.startswith("."))


def quarantine(err: PipelineError, trial: str, file: str) -> dict[str, Any]:
    entry = {**err.as_dict(), "trial": trial}
    entry["file"] = err.file or file
    log.warning("quarantined trial %s (%s): %s", trial, entry["file"], err.reason)
    return entry


def drop_stale(target: Path) -> None:
    """A quarantined trial leaves no output behind from an earlier run."""
    if target.exists():
        target.unlink()


def add_trial_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--trial", default=None, help="process only this trial (default: every trial found)")
