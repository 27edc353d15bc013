"""Saving fitted models with a model card: joblib pickle + JSON (lineage, hyperparameters, scores, versions).

``save_model(est, path, card)`` writes ``<path>`` (joblib) and ``<path minus .joblib>.card.json``; ``load_model``
refuses a pickle without its card and warns when the scikit-learn version differs from the one that wrote it
(pickles are not portable across scikit-learn versions).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import joblib
import numpy as np
import sklearn

from pipeline import __version__
from pipeline.errors import ModelError
from pipeline.tableio import atomic_path, file_sha256, write_json

log = logging.getLogger(__name__)

__all__ = ["versions", "lineage", "card_path", "save_model", "load_model"]


def versions() -> dict[str, str]:
    return {"auvid": __version__, "scikit-learn": sklearn.__version__, "numpy": np.__version__,
            "joblib": joblib.__version__}


def lineage(files: list[Path], root: Path | None = None) -> list[dict[str, str]]:
    """Data lineage: each input file (relative to ``root`` when given) with its sha256."""
    out = []
    for f in sorted(Path(p) for p in files):
        name = str(f.relative_to(root)) if root is not None and f.is_relative_to(root) else str(f)
        out.append({"file": name, "sha256": file_sha256(f)})
    return out


def card_path(model_path: str | Path) -> Path:
    p = Path(model_path)
    return p.with_name(p.name.removesuffix(".joblib") + ".card.json")


def save_model(estimator: Any, path: str | Path, card: dict[str, Any]) -> tuple[Path, Path]:
    """Write the estimator (joblib, atomically) and its card (``versions`` added, sha256 of the pickle)."""
    path = Path(path)
    with atomic_path(path) as tmp:
        joblib.dump(estimator, tmp)
    full = {**card, "versions": versions(), "model_file": path.name, "model_sha256": file_sha256(path),
            "estimator": type(estimator).__name__}
    return path, write_json(full, card_path(path))


def load_model(path: str | Path) -> tuple[Any, dict[str, Any]]:
    """Load an estimator and its card; ModelError if the card is missing or the pickle does not match it."""
    import json

    path = Path(path)
    cpath = card_path(path)
    if not cpath.exists():
        raise ModelError("model has no card (refusing an undocumented pickle)", file=path)
    card = json.loads(cpath.read_text())
    if not path.exists():
        raise ModelError("the model file of this card does not exist", file=path)
    if card.get("model_sha256") != file_sha256(path):
        raise ModelError("model file does not match the sha256 in its card", file=path)
    written = card.get("versions", {}).get("scikit-learn")
    if written != sklearn.__version__:
        log.warning("%s was written with scikit-learn %s, running %s", path, written, sklearn.__version__)
    return joblib.load(path), card
