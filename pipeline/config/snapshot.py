"""Validated configs kept between runs: ``auvid ingest`` reads a vehicle config and params.yaml it has validated
before without importing pydantic.

Validating takes pydantic: importing it and building the config models is a large share of a short log's whole
ingest (docs/benchmarks.md). So after validating a pair of files, :func:`load_for_ingest` writes a *snapshot* of
the result: each model's fields as the model holds them, the YAML as read (to build the real model where a
trial's overrides need it) and the warnings the checks gave. A later run given the same files reads the snapshot
back as :class:`ConfigView` objects, which have the model's fields as attributes, ``model_dump(mode="json")`` (so
:func:`~pipeline.config.hashing.config_hash`, and with it every output's provenance, is the same) and
``model_copy(update=...)``; the vehicle's view has its methods that ingest uses. The warnings are logged again.

A snapshot is found by the sha256 of the two files' paths and bytes, the Python version and where this
interpreter's auvid, PyYAML and pydantic live (another checkout or environment sharing the cache keeps its own),
and used only while the code that validated it is the same: the sha256 of every ``pipeline`` module loaded when it
was written and of PyYAML's and pydantic's version files are stored and compared (none is written when one of
those files changed on disk after the process started). Anything else is a miss: the files are validated again
and the snapshot rewritten. A snapshot that cannot be read, or whose parts have another shape, is a miss; one that
cannot be written is not an error (a read-only home works, at the old cost). A config given as a pipe
(``--vehicle /dev/stdin``) is validated every time. The warnings of the checks are kept whatever the logging level
of the run that validated them (``-q``) and given by every run.

Where: ``$AUVID_CACHE_DIR/configs/`` (default ``$XDG_CACHE_HOME/auvid``, else ``~/.cache/auvid``);
``AUVID_CACHE_DIR=off`` validates every time. The newest :data:`KEEP` snapshots are kept. This module imports no
pydantic and no YAML parser.
"""

from __future__ import annotations

import copy
import hashlib
import importlib.util
import json
import logging
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pipeline.config.vehicle_methods import VehicleMethods
from pipeline.tableio import atomic_path, file_sha256

if TYPE_CHECKING:
    from pipeline.config.params import Params
    from pipeline.config.vehicle import Vehicle

log = logging.getLogger(__name__)

CACHE_ENV = "AUVID_CACHE_DIR"
#: Bumped when the layout of a snapshot changes: an older one is then a miss.
FORMAT = 1
#: Snapshots kept: writing one more removes the oldest beyond this many (each is a few tens of kB).
KEEP = 64
#: Third-party code whose version decides what a config validates to (each package's file that names its version).
_DEPENDENCIES = (("yaml", "__init__.py"), ("pydantic", "version.py"))


def cache_dir() -> Path | None:
    """Where snapshots go, or None when ``AUVID_CACHE_DIR=off``."""
    given = os.environ.get(CACHE_ENV, "").strip()
    if given.lower() == "off":
        return None
    if given:
        return Path(given) / "configs"
    base = os.environ.get("XDG_CACHE_HOME", "").strip()
    if not base:
        try:
            base = str(Path.home() / ".cache")
        except RuntimeError:  # no HOME and no passwd entry: nowhere to keep them, validate every time
            return None
    return Path(base) / "auvid" / "configs"


class ConfigView:
    """The validated values of one config model, read from a snapshot: its fields as attributes (nested models as
    views; lists, tuples and dicts as the model holds them). Read-only, like the model."""

    def __init__(self, model: str, fields: dict[str, Any], dump: dict[str, Any] | None = None) -> None:
        self.__dict__.update(fields)
        object.__setattr__(self, "_model", model)
        object.__setattr__(self, "_fields", tuple(fields))
        object.__setattr__(self, "_dump", dump)  # the model's own model_dump(mode="json"), where stored

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError(f"{self._model} is frozen: cannot set {name!r}")

    def __repr__(self) -> str:
        return f"{self._model}View({', '.join(f'{k}={getattr(self, k)!r}' for k in self._fields)})"

    def model_dump(self, *, mode: str = "python") -> dict[str, Any]:
        """The fields as JSON values: what the model's ``model_dump(mode="json")`` gave when the snapshot was written
        (the vehicle and the params; :func:`config_hash` hashes it), else built from the fields."""
        if mode != "json":
            raise TypeError(f"a snapshot's {self._model} gives JSON values only: model_dump(mode='json')")
        if self._dump is not None:
            return copy.deepcopy(self._dump)
        return {k: _json_value(getattr(self, k)) for k in self._fields}

    def model_copy(self, *, update: dict[str, Any] | None = None) -> ConfigView:
        """A copy with some fields replaced (not validated, as with the model's ``model_copy``)."""
        update = dict(update or {})
        unknown = sorted(set(update) - set(self._fields))
        if unknown:
            raise AttributeError(f"{self._model} has no field(s) {unknown}")
        clone = copy.copy(self)
        clone.__dict__.update(update)
        if self._dump is not None:
            object.__setattr__(clone, "_dump", {**self._dump, **{k: _json_value(v) for k, v in update.items()}})
        return clone


class VehicleView(VehicleMethods, ConfigView):
    """A snapshot's vehicle: the fields, and the methods of :class:`~pipeline.config.vehicle.Vehicle` that ingest
    uses (:class:`~pipeline.config.vehicle_methods.VehicleMethods`). A trial that an override applies to gets the
    real model (pydantic is imported then)."""

    def __init__(self, model: str, fields: dict[str, Any], dump: dict[str, Any], *, base_dir: Path,
                 overrides: dict[str, Any], raw: Any, source: str) -> None:
        super().__init__(model, fields, dump)
        for name, value in (("_base_dir", base_dir), ("_overrides", overrides), ("_raw", raw), ("_source", source)):
            object.__setattr__(self, name, value)

    def override_keys(self) -> dict[str, dict[str, dict[str, Any]]]:
        """The model's overrides as the snapshot stored them."""
        return copy.deepcopy(self._overrides)

    def _apply_overrides(self, trial: str) -> Vehicle:
        return self.model().for_trial(trial)

    def model_copy(self, *, update: dict[str, Any] | None = None) -> Vehicle:  # type: ignore[override]
        """The real model's copy: its overrides and file follow the update (nothing on the ingest path copies it)."""
        return self.model().model_copy(update=update)

    def model(self) -> Vehicle:
        """The real model, validated again from the YAML the snapshot keeps (pydantic is imported here)."""
        from pipeline.config.loading import parse
        from pipeline.config.vehicle import Vehicle

        vehicle = parse(Vehicle, self._raw, self._source)
        vehicle._base_dir, vehicle._source = self._base_dir, self._source
        return vehicle


def _json_value(value: Any) -> Any:
    if isinstance(value, ConfigView):
        return value.model_dump(mode="json")
    if isinstance(value, list | tuple):
        return [_json_value(v) for v in value]
    if isinstance(value, dict):
        return {k: _json_value(v) for k, v in value.items()}
    return value


def _encode(value: Any, model_type: type) -> Any:
    """A model's value as JSON that keeps its Python types: models, dicts and tuples tagged, lists as lists."""
    if isinstance(value, model_type):
        return {"model": type(value).__name__,
                "fields": {k: _encode(getattr(value, k), model_type) for k in type(value).model_fields}}
    if isinstance(value, dict):
        if not all(isinstance(k, str) for k in value):
            raise TypeError("a dict with keys that are not strings")
        return {"dict": {k: _encode(v, model_type) for k, v in value.items()}}
    if isinstance(value, tuple):
        return {"tuple": [_encode(v, model_type) for v in value]}
    if isinstance(value, list):
        return [_encode(v, model_type) for v in value]
    if value is None or isinstance(value, str | int | float | bool):
        return value
    raise TypeError(f"a value of type {type(value).__name__}")


def _decode(value: Any) -> Any:
    if isinstance(value, list):
        return [_decode(v) for v in value]
    if not isinstance(value, dict):
        return value
    if "model" in value:
        return ConfigView(value["model"], {k: _decode(v) for k, v in value["fields"].items()})
    if "dict" in value:
        return {k: _decode(v) for k, v in value["dict"].items()}
    return tuple(_decode(v) for v in value["tuple"])


def _file_digest(path: str) -> str:
    """sha256 of a source file's bytes; "" for anything that is not a regular file (never read: a device)."""
    return file_sha256(path) if os.path.isfile(path) else ""


def _code_files() -> list[str]:
    """The source files whose code decides what a config validates to: every loaded ``pipeline`` module (the
    config models and what they import, and more: a change to any of them is a miss) and the dependencies'
    version files."""
    files = {m.__file__ for name, m in list(sys.modules.items())
             if (name == "pipeline" or name.startswith("pipeline.")) and getattr(m, "__file__", None)}
    return sorted(str(f) for f in files | set(_dependency_files()))


def _dependency_files() -> list[str]:
    """The version file of each dependency in :data:`_DEPENDENCIES`, where this interpreter imports it from."""
    found = []
    for package, version_file in _DEPENDENCIES:
        spec = importlib.util.find_spec(package)
        if spec is not None and spec.submodule_search_locations:
            found.append(os.path.join(next(iter(spec.submodule_search_locations)), version_file))
    return found


def _key(vehicle_path: Path, vehicle_bytes: bytes, params_path: Path | None, params_bytes: bytes | None) -> str:
    """Which snapshot answers: the files' paths and bytes, and where this interpreter's code comes from (another
    checkout or environment sharing the cache has snapshots of its own; its files' digests are checked on a hit)."""
    running = "\0".join([sys.version, os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                         *_dependency_files()])
    h = hashlib.sha256(f"auvid config snapshot {FORMAT}\0{running}\0{vehicle_path}\0".encode())
    h.update(vehicle_bytes)
    h.update(f"\0{params_path}\0".encode())
    h.update(params_bytes if params_bytes is not None else b"(defaults)")
    return h.hexdigest()


def _read_bytes(vehicle_path: Path, params_path: Path | None) -> tuple[bytes, bytes | None] | None:
    """Both files' bytes; None for a path that is not a regular file (a pipe such as ``--vehicle /dev/stdin`` is
    read once, by the loader) or cannot be read (the loader says what is wrong with it)."""
    paths = [p for p in (vehicle_path, params_path) if p is not None]
    if not all(p.is_file() for p in paths):
        return None
    try:
        return vehicle_path.read_bytes(), params_path.read_bytes() if params_path is not None else None
    except OSError:
        return None


def load_for_ingest(vehicle_path: str | Path, params_path: str | Path | None) -> tuple[Vehicle, Params]:
    """The vehicle config and params (``None``: the defaults), validated and checked against each other as
    :func:`pipeline.config.load_vehicle`, :func:`~pipeline.config.load_params` and
    :func:`~pipeline.config.check_params_against_vehicle` do; from the snapshot when these files were validated
    before by the same code (views), else validated (the models) and a snapshot written."""
    vehicle_path = Path(vehicle_path)
    params_path = Path(params_path) if params_path is not None else None
    directory = cache_dir()
    read = _read_bytes(vehicle_path, params_path) if directory is not None else None
    if directory is None or read is None:
        return _validate(vehicle_path, params_path)[:2]
    target = directory / f"{_key(vehicle_path, read[0], params_path, read[1])}.json"
    found = _load_snapshot(target, vehicle_path)
    if found is not None:
        return found
    vehicle, params, records = _validate(vehicle_path, params_path)
    if _read_bytes(vehicle_path, params_path) == read:  # not rewritten while it was validated
        _write_snapshot(target, vehicle, params, records, vehicle_path, read[0])
    return vehicle, params


@contextmanager
def _kept_warnings() -> Iterator[list[list[Any]]]:
    """The warnings that ``pipeline`` loggers give inside the block, as [logger, level, message], whatever level
    the caller's logging shows (``-q``: errors only): a snapshot keeps them all, and each is logged when the block
    ends, as a run that reads the snapshot logs them, so that both runs log the same."""
    records: list[list[Any]] = []  # every record (debug ones too, under -v), logged again at the end
    kept: list[list[Any]] = []  # the warnings and errors, for the snapshot

    class Keep(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            records.append([record.name, record.levelno, record.getMessage()])
            if record.levelno >= logging.WARNING:
                kept.append(records[-1])

    handler = Keep()
    logger = logging.getLogger("pipeline")
    level, propagate = logger.level, logger.propagate
    logger.addHandler(handler)
    logger.setLevel(min(logger.getEffectiveLevel(), logging.WARNING))
    logger.propagate = False
    try:
        yield kept
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)
        logger.propagate = propagate
        _log_again(records)


def _log_again(records: list[list[Any]] | list[tuple[str, int, str]]) -> None:
    for name, level, message in records:
        logging.getLogger(name).log(level, "%s", message)


def _validate(vehicle_path: Path, params_path: Path | None) -> tuple[Vehicle, Params, list[list[Any]]]:
    from pipeline.config.loading import check_params_against_vehicle, load_params, load_vehicle

    with _kept_warnings() as records:
        vehicle, params = load_vehicle(vehicle_path), load_params(params_path)
        check_params_against_vehicle(vehicle, params, params_path)
    return vehicle, params, records


def _code_changed_since_import(files: list[str]) -> str | None:
    """A source file changed on disk since this process imported ``pipeline`` (a ``git pull`` beside a notebook
    or a service): what ran may not be what the digests would say. 50 ms of margin for coarse file clocks."""
    from pipeline import IMPORTED_NS

    for path in files:
        try:
            if os.stat(path).st_mtime_ns > IMPORTED_NS - 50_000_000:
                return path
        except OSError:
            return path
    return None


def _write_snapshot(target: Path, vehicle: Vehicle, params: Params, records: list[list[Any]],
                    vehicle_path: Path, vehicle_bytes: bytes) -> None:
    from pydantic import BaseModel

    from pipeline.config.yamlload import parse_yaml
    from pipeline.errors import PipelineError

    try:
        files = _code_files()
        changed = _code_changed_since_import(files)
        if changed is not None:
            log.debug("config snapshot %s not written: %s changed since this process started", target, changed)
            return
        doc = {"format": FORMAT, "code": {f: _file_digest(f) for f in files},
               "vehicle": _encode(vehicle, BaseModel), "params": _encode(params, BaseModel),
               "vehicle_dump": vehicle.model_dump(mode="json"), "params_dump": params.model_dump(mode="json"),
               "vehicle_raw": parse_yaml(vehicle_bytes, vehicle_path), "overrides": vehicle.override_keys(),
               "warnings": records}
        text = json.dumps(doc, allow_nan=False)  # not sorted: the order of streams and trials is the config's
        with atomic_path(target) as tmp:
            tmp.write_text(text, encoding="utf-8")
        _prune(target.parent)
    except (OSError, TypeError, ValueError, PipelineError) as err:  # an unwritable cache, a value JSON cannot hold
        log.debug("config snapshot %s not written: %s", target, err)


def _prune(directory: Path) -> None:
    """Remove the oldest snapshots beyond :data:`KEEP` (a config edited many times leaves one per version)."""
    found = []
    for path in directory.glob("*.json"):
        try:
            found.append((path.stat().st_mtime_ns, path.name, path))
        except OSError:  # removed meanwhile by another run
            continue
    for *_, path in sorted(found, reverse=True)[KEEP:]:
        path.unlink(missing_ok=True)


def _load_snapshot(target: Path, vehicle_path: Path) -> tuple[Vehicle, Params] | None:
    """The views of a snapshot whose code is the same as now; None when there is none or it is not usable (a
    snapshot's parts are checked for their shapes, not trusted to be well formed)."""
    try:
        doc = json.loads(target.read_text(encoding="utf-8"))
        if doc["format"] != FORMAT:
            return None
        for path, digest in doc["code"].items():
            if _file_digest(path) != digest:
                log.debug("config snapshot %s: %s changed; validating again", target, path)
                return None
        overrides = doc["overrides"]
        if not all(isinstance(streams, dict) and all(isinstance(v, dict) for v in streams.values())
                   for streams in overrides.values()):
            raise TypeError("overrides of another shape")
        vehicle_doc = doc["vehicle"]
        fields = {k: _decode(v) for k, v in vehicle_doc["fields"].items()}
        dumps = doc["vehicle_dump"], doc["params_dump"]
        if not (isinstance(doc["vehicle_raw"], dict) and all(isinstance(d, dict) for d in dumps)):
            raise TypeError("parts of another shape")
        params_doc = doc["params"]
        params = ConfigView(params_doc["model"], {k: _decode(v) for k, v in params_doc["fields"].items()}, dumps[1])
        vehicle = VehicleView(vehicle_doc["model"], fields, dumps[0], base_dir=vehicle_path.resolve().parent,
                              overrides=overrides, raw=doc["vehicle_raw"], source=str(vehicle_path))
        warnings = [(str(name), int(level), str(message)) for name, level, message in doc["warnings"]]
    except (OSError, ValueError, KeyError, TypeError, AttributeError, RecursionError) as err:
        if not isinstance(err, FileNotFoundError):
            log.debug("config snapshot %s unusable (%s); validating again", target, err)
        return None
    try:
        os.utime(target)  # read: the newest again, the last to be pruned
    except OSError:
        pass
    _log_again(warnings)
    log.debug("configs %s read from snapshot %s", vehicle_path, target)
    return vehicle, params  # type: ignore[return-value]  # views with the models' attributes
