"""Saving fitted models with a model card: joblib pickle + JSON (lineage, hyperparameters, scores, versions).

``save_model(est, path, card)`` writes ``<path>`` (joblib) and ``<path minus .joblib>.card.json``; ``load_model``
refuses a pickle without its card and warns when the scikit-learn version differs from the one that wrote it
(pickles are not portable across scikit-learn versions).

Unpickling runs code, so ``load_model`` is the only way the project loads a model file (docs/security.md): the
card must exist, name this file and record the sha256 of its bytes, and the bytes are checked *before*
``joblib.load`` sees them. A ``.joblib`` dropped beside the real models, or one edited after it was written, is
refused with a ModelError naming the file.
"""

from __future__ import annotations

import hashlib
import io
import json
import logging
import sys
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
    # a pickle writes a string or a dtype once and refers back to it where the same object comes again; which equal
    # ones are one object depends on where the model was built, fitted and passed through (unpickling interns
    # attribute names, not a dict's keys; an unpickled array holds its own dtype). The file is the pickle of the
    # model made canonical (equal values, nothing unpickled here), so a model fitted here, in a worker or on a
    # cluster is the same bytes
    canonical = _canonical(estimator, {})
    with atomic_path(path) as tmp:
        joblib.dump(canonical, tmp)
    full = {**card, "versions": {**card.get("versions", {}), **versions()}, "model_file": path.name,
            "model_sha256": file_sha256(path),
            "estimator": type(estimator).__name__}
    return path, write_json(full, card_path(path))


def _canonical(obj: Any, done: dict[int, Any]) -> Any:
    """``obj`` with every string interned and every array of a plain dtype holding numpy's own instance of that
    dtype (an unpickled array holds a copy of it), through attributes, dicts, lists, tuples and object arrays.
    Dicts, lists and object arrays are changed in place; tuples and arrays are replaced (one replacement per
    object, so what was shared stays shared)."""
    if type(obj) is str:
        return sys.intern(obj)
    if id(obj) in done or isinstance(obj, type):
        return done.get(id(obj), obj)
    done[id(obj)] = obj
    if isinstance(obj, dict):
        items = [(_canonical(k, done), _canonical(v, done)) for k, v in obj.items()]
        obj.clear()
        obj.update(items)
    elif isinstance(obj, list):
        obj[:] = [_canonical(v, done) for v in obj]
    elif type(obj) is tuple:
        done[id(obj)] = tuple(_canonical(v, done) for v in obj)
    elif isinstance(obj, np.ndarray):
        if obj.dtype == object:
            for i, v in enumerate(obj.flat):
                obj.flat[i] = _canonical(v, done)
        elif obj.dtype.fields is None and np.dtype(obj.dtype.str) is not obj.dtype:
            done[id(obj)] = obj.view(np.dtype(obj.dtype.str))
    elif hasattr(obj, "__dict__"):
        _canonical(vars(obj), done)
    return done[id(obj)]


def load_model(path: str | Path) -> tuple[Any, dict[str, Any]]:
    """Load an estimator and its card; ModelError if the card is missing, unreadable, names another file, or the
    pickle's sha256 differs from the card's. The check reads the bytes once and unpickles those same bytes, so the
    file cannot be swapped between the check and the load."""
    path = Path(path)
    cpath = card_path(path)
    if not cpath.is_file():
        raise ModelError(f"model has no card {cpath.name} (refusing to unpickle an undocumented model file; "
                         "only models written by auvid, with their card, are loaded: docs/security.md)", file=path)
    try:
        card = json.loads(cpath.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ModelError(f"model card {cpath.name} is not valid JSON ({err}); refusing the model", file=path) from None
    if not isinstance(card, dict) or not isinstance(card.get("model_sha256"), str):
        raise ModelError(f"model card {cpath.name} records no model_sha256; refusing the model", file=path)
    if card.get("model_file", path.name) != path.name:
        raise ModelError(f"model card {cpath.name} is the card of {card.get('model_file')!r}, not of this file",
                         file=path)
    if not path.is_file():
        raise ModelError("the model file of this card does not exist", file=path)
    data = path.read_bytes()
    if hashlib.sha256(data).hexdigest() != card["model_sha256"]:
        raise ModelError(f"model file does not match the sha256 in its card {cpath.name} (changed or replaced "
                         "after it was written); refusing to unpickle it", file=path)
    written = card.get("versions", {}).get("scikit-learn")
    if written != sklearn.__version__:
        log.warning("%s was written with scikit-learn %s, running %s", path, written, sklearn.__version__)
    return joblib.load(io.BytesIO(data)), card
