"""A stage that has nothing to do on this run still leaves its outputs: ``skipped.json`` in each of its output
directories, saying which stages skipped and why, so that DVC finds the outputs ``dvc.yaml`` declares, the stages
after it and the report read the reason, and the same inputs give the same bytes (no time stamp in it).

Skipping empties the directories first (what an earlier run of the stage left there would otherwise be read as
this run's); a stage that runs removes the marker (:func:`clear_skip`).
"""

from __future__ import annotations

import json
import logging
import shutil
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from pipeline.tableio import write_json

log = logging.getLogger(__name__)

SKIPPED = "skipped.json"


def write_skip(directories: Iterable[Path], stages: Sequence[str], reason: str) -> list[Path]:
    """Empty each of ``directories`` and write its marker ``{"skipped": reason, "stages": [...]}``; the markers."""
    out = []
    for directory in directories:
        directory = Path(directory)
        if directory.is_dir():
            stale = sorted(p.name for p in directory.iterdir() if p.name != SKIPPED)
            if stale:
                log.info("%s: removing the outputs of an earlier run (%s): %s skipped", directory,
                         ", ".join(stale), "/".join(stages))
            for name in stale:
                path = directory / name
                if path.is_dir() and not path.is_symlink():
                    shutil.rmtree(path)
                else:
                    path.unlink()
        out.append(write_json({"skipped": reason, "stages": list(stages)}, directory / SKIPPED))
    return out


def read_skip(directory: Path) -> dict[str, Any] | None:
    """The marker of ``directory`` (``{"skipped": reason, "stages": [...]}``), or None when its stages ran."""
    try:
        doc = json.loads((Path(directory) / SKIPPED).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) and isinstance(doc.get("skipped"), str) else None


def clear_skip(directories: Iterable[Path]) -> None:
    """Remove the marker a skipped run left in ``directories`` (the stage runs this time)."""
    for directory in directories:
        (Path(directory) / SKIPPED).unlink(missing_ok=True)
