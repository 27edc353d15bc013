"""``auvid export``: one MCAP file per trial for Foxglove and PlotJuggler (JSON messages, JSON-schema channels).

What a run wrote about a trial, on the trial's own time axis (``t_ns`` of the synced grid, the log's clock, as
log time and publish time of every message):

========================================  =====================================================================
topic                                     source (one message per row)
========================================  =====================================================================
``/auvid/synced``                         ``data/synced/<trial>.parquet``: every column (``__valid`` as booleans)
``/auvid/kinematics``                     ``data/kinematics/<trial>.parquet``: every column, names as in Parquet
``/auvid/velocity``                       per DOF ``{estimate, sd, lower, upper, measured}``; band = estimate -+ 2 sd
``/auvid/acceleration``                   per DOF ``{estimate, sd, lower, upper}`` of the accelerations
``/auvid/prediction/coupled/<model>``     per output ``{predicted, measured}``: the model on ``data/derived``'s rows
``/auvid/prediction/decoupled/<model>``   per DOF's damping column ``{predicted, measured}`` (measured: the target)
``/auvid/free_run/<model>``               per velocity ``{predicted, measured[, lower, upper]}``
                                          (``data/simulation/<trial>/free_run.parquet``: test trials only)
========================================  =====================================================================

A value that is NaN in the source is ``null``. Each channel names its source file in its metadata; one metadata
record ``auvid`` holds the trial, the package version and each source's sha256. Models load only through their
card (:func:`pipeline.models.card.load_model`), and only those the run's params name (``models``, from
:func:`named_models`): a carded file the run did not produce (an earlier run's, one copied in) is never unpickled.
The file is written to a temporary path beside the target and renamed; the same inputs give the same bytes (no
wall-clock time is written; messages in (time, channel) order).
"""

from __future__ import annotations

import json
import logging
import math
import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from mcap.writer import CompressionType, IndexType, Writer

from pipeline import __version__, layout
from pipeline.errors import PipelineError
from pipeline.tableio import atomic_path, file_sha256

log = logging.getLogger(__name__)

__all__ = ["BAND_SIGMAS", "TOPICS", "ExportResult", "export_trial", "export_trials", "named_models",
           "trials_available"]

BAND_SIGMAS = 2.0
TOPICS = ("/auvid/synced", "/auvid/kinematics", "/auvid/velocity", "/auvid/acceleration",
          "/auvid/prediction/coupled/<model>", "/auvid/prediction/decoupled/<model>", "/auvid/free_run/<model>")
_DOF_UNITS = (("u", "mps"), ("v", "mps"), ("w", "mps"), ("p", "radps"), ("q", "radps"), ("r", "radps"))
_SAFE = re.compile(r"[^A-Za-z0-9_.-]")

Progress = Callable[..., Any]


class ExportError(PipelineError):
    """A trial cannot be exported (no synced table, an unreadable source)."""


@dataclass
class Channel:
    """One topic: its JSON schema, its time stamps and one message (a dict) per stamp."""

    topic: str
    schema_name: str
    schema: dict[str, Any]
    t_ns: np.ndarray
    rows: Callable[[], Iterator[dict[str, Any]]]
    source: str


@dataclass
class ExportResult:
    trial: str
    path: Path
    messages: dict[str, int] = field(default_factory=dict)  # topic -> message count
    skipped: list[str] = field(default_factory=list)  # what could not be exported, with the reason


# ------------------------------------------------------------------------------------------------ helpers

def _number(x: Any) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def _json_type(arrow_type: pa.DataType) -> str:
    if pa.types.is_boolean(arrow_type):
        return "boolean"
    if pa.types.is_integer(arrow_type):
        return "integer"
    if pa.types.is_floating(arrow_type):
        return "number"
    return "string"


def _convert(column: pa.ChunkedArray) -> list[Any]:
    """A column as JSON-ready Python values: NaN and missing as None, numpy scalars as Python ones."""
    kind = _json_type(column.type)
    if kind == "number":
        return [_number(v) for v in column.to_numpy(zero_copy_only=False)]
    values = column.to_pylist()
    return values if kind != "string" else [None if v is None else str(v) for v in values]


def _flat_channel(topic: str, schema_name: str, path: Path, root: Path) -> Channel:
    """Every column of a Parquet table, one message per row (``t_ns`` stays an integer)."""
    table = pq.read_table(path)
    if "t_ns" not in table.column_names:
        raise ExportError("table has no t_ns column", file=path)
    props = {name: {"type": [_json_type(table.schema.field(name).type), "null"]} for name in table.column_names}
    props["t_ns"] = {"type": "integer", "description": "time stamp [ns], the log's clock"}
    schema = {"title": schema_name, "type": "object", "properties": props}
    names = table.column_names

    def rows() -> Iterator[dict[str, Any]]:
        columns = [_convert(table.column(n)) for n in names]
        for values in zip(*columns, strict=True):
            yield dict(zip(names, values, strict=True))

    return Channel(topic, schema_name, schema, table.column("t_ns").to_numpy().astype(np.int64), rows,
                   _rel(path, root))


def _rel(path: Path, root: Path) -> str:
    return path.relative_to(root).as_posix() if path.is_relative_to(root) else str(path)


def _nested_schema(title: str, groups: dict[str, list[str]], description: str) -> dict[str, Any]:
    item = {"type": ["number", "null"]}
    return {"title": title, "type": "object", "description": description,
            "properties": {"t_ns": {"type": "integer", "description": "time stamp [ns], the log's clock"},
                           **{g: {"type": "object", "properties": {k: item for k in keys}}
                              for g, keys in groups.items()}}}


def _nested_channel(topic: str, schema_name: str, description: str, t_ns: np.ndarray,
                    groups: dict[str, dict[str, np.ndarray]], source: str) -> Channel:
    """One message per stamp: ``{"t_ns": .., group: {key: value}}`` from equally long arrays."""
    schema = _nested_schema(schema_name, {g: list(v) for g, v in groups.items()}, description)

    def rows() -> Iterator[dict[str, Any]]:
        conv = {g: {k: [_number(x) for x in np.asarray(a, float)] for k, a in keys.items()}
                for g, keys in groups.items()}
        for i, t in enumerate(t_ns.tolist()):
            yield {"t_ns": t, **{g: {k: vals[i] for k, vals in keys.items()} for g, keys in conv.items()}}

    return Channel(topic, schema_name, schema, t_ns, rows, source)


# ---------------------------------------------------------------------------------------------- channels

def _band_channels(path: Path, root: Path) -> list[Channel]:
    """Estimated velocities and accelerations with their bands (estimate -+ BAND_SIGMAS sd)."""
    table = pq.read_table(path)
    cols = set(table.column_names)
    t_ns = table.column("t_ns").to_numpy().astype(np.int64)

    def col(name: str) -> np.ndarray:
        return table.column(name).to_numpy(zero_copy_only=False).astype(float)

    velocity: dict[str, dict[str, np.ndarray]] = {}
    acceleration: dict[str, dict[str, np.ndarray]] = {}
    for dof, unit in _DOF_UNITS:
        est = f"{dof}_smooth_{unit}" if f"{dof}_smooth_{unit}" in cols else f"{dof}_{unit}"
        if est not in cols:
            continue
        entry = {"estimate": col(est)}
        sd_name = f"{dof}_smooth_std_{unit}"
        if sd_name in cols:
            sd = col(sd_name)
            entry |= {"sd": sd, "lower": entry["estimate"] - BAND_SIGMAS * sd,
                      "upper": entry["estimate"] + BAND_SIGMAS * sd}
        meas = f"{dof}_meas_{unit}" if f"{dof}_meas_{unit}" in cols else f"{dof}_{unit}"
        entry["measured"] = col(meas)
        velocity[dof] = entry
        acc = f"{dof}dot_{unit}2"
        acc_sd = f"{dof}dot_std_{unit}2"
        if acc in cols:
            a = {"estimate": col(acc)}
            if acc_sd in cols:
                s = col(acc_sd)
                a |= {"sd": s, "lower": a["estimate"] - BAND_SIGMAS * s, "upper": a["estimate"] + BAND_SIGMAS * s}
            acceleration[dof] = a
    source = _rel(path, root)
    band = f"band: estimate -+ {BAND_SIGMAS:g} sd"
    out = []
    if velocity:
        out.append(_nested_channel("/auvid/velocity", "auvid.Velocity", f"estimated body velocities; {band}",
                                   t_ns, velocity, source))
    if acceleration:
        out.append(_nested_channel("/auvid/acceleration", "auvid.Acceleration",
                                   f"estimated body accelerations; {band}", t_ns, acceleration, source))
    return out


def named_models(params: Any) -> set[str]:
    """The model files a run with ``params`` fits, as ``<kind>/<file>``: ``coupled/<model>.joblib`` for each of
    ``coupled.models``, ``decoupled/<dof>_<model>.joblib`` for each of ``decoupled.dofs`` x ``decoupled.models``."""
    decoupled = params.decoupled
    return ({f"coupled/{m}.joblib" for m in params.coupled.models}
            | {f"decoupled/{d}_{m}.joblib" for d in decoupled.dofs for m in decoupled.models})


def _model_cards(root: Path, models: set[str] | None,
                 skipped: list[str]) -> Iterator[tuple[str, Path, dict[str, Any]]]:
    """(kind, model file, card) of every carded model under data/models/{coupled,decoupled} that ``models`` names
    (None: all); the others are listed in ``skipped``, their cards not even read."""
    for kind in ("coupled", "decoupled"):
        base = root / layout.MODELS / kind
        for cpath in sorted(base.glob("*.card.json")) if base.is_dir() else []:
            model_file = cpath.name.removesuffix(".card.json") + ".joblib"
            if models is not None and f"{kind}/{model_file}" not in models:
                skipped.append(f"{kind} model {model_file}: not named by the run's params ({kind}.models)")
                continue
            try:
                card = json.loads(cpath.read_text(encoding="utf-8"))
            except (OSError, UnicodeDecodeError, json.JSONDecodeError):
                log.warning("unreadable model card %s; its model is not exported", cpath)
                continue
            if isinstance(card, dict):
                yield kind, cpath.with_name(cpath.name.removesuffix(".card.json") + ".joblib"), card


def _prediction_channels(root: Path, trial: str, skipped: list[str], models: set[str] | None) -> list[Channel]:
    """Each carded model's predictions on the trial's derived rows, beside what it predicts."""
    from pipeline.models.card import load_model

    path = layout.derived_path(root, trial)
    if not path.is_file():
        return []
    table = pq.read_table(path)
    cols = set(table.column_names)
    t_ns = table.column("t_ns").to_numpy().astype(np.int64)
    groups: dict[tuple[str, str], dict[str, dict[str, np.ndarray]]] = {}
    for kind, model_path, card in _model_cards(root, models, skipped):
        inputs = card.get("inputs")
        outputs = card.get("outputs") or ([card["output"]] if isinstance(card.get("output"), str) else None)
        name = str(card.get("model") or model_path.stem.split("_", 1)[-1]) if kind == "decoupled" \
            else model_path.name.removesuffix(".joblib")
        if not isinstance(inputs, list) or not isinstance(outputs, list) or not set(inputs) <= cols:
            skipped.append(f"{kind} model {model_path.name}: inputs {inputs} not all in {_rel(path, root)}")
            continue
        estimator, _ = load_model(model_path)  # sha256 checked against the card before unpickling
        x = np.column_stack([table.column(c).to_numpy(zero_copy_only=False).astype(float) for c in inputs])
        ok = np.isfinite(x).all(axis=1)
        pred = np.full((len(x), len(outputs)), np.nan)
        if ok.any():
            try:
                pred[ok] = np.asarray(estimator.predict(x[ok]), float).reshape(int(ok.sum()), len(outputs))
            except Exception as err:  # noqa: BLE001 - one model's failure must not stop the export
                skipped.append(f"{kind} model {model_path.name}: predict failed ({type(err).__name__}: {err})")
                continue
        group = groups.setdefault((kind, name), {})
        for j, out in enumerate(outputs):
            measured = table.column(out).to_numpy(zero_copy_only=False).astype(float) if out in cols \
                else np.full(len(x), np.nan)
            group[str(out)] = {"predicted": pred[:, j], "measured": measured}
    return [_nested_channel(f"/auvid/prediction/{kind}/{_SAFE.sub('_', name)}", "auvid.Prediction",
                            f"{kind} model {name}: predicted vs measured per output", t_ns, values,
                            _rel(path, root))
            for (kind, name), values in sorted(groups.items())]


def _free_run_channels(root: Path, trial: str) -> list[Channel]:
    path = root / layout.SIMULATION / trial / "free_run.parquet"
    if not path.is_file():
        return []
    table = pq.read_table(path)
    t_ns = table.column("t_ns").to_numpy().astype(np.int64)
    models: dict[str, dict[str, dict[str, np.ndarray]]] = {}
    for name in table.column_names:
        parts = name.split("/")
        if len(parts) < 2:
            continue
        model, column = parts[0], parts[1]
        key = parts[2] if len(parts) == 3 else "predicted"
        entry = models.setdefault(model, {}).setdefault(column, {})
        entry[key] = table.column(name).to_numpy(zero_copy_only=False).astype(float)
        if "measured" not in entry and column in table.column_names:
            entry["measured"] = table.column(column).to_numpy(zero_copy_only=False).astype(float)
    return [_nested_channel(f"/auvid/free_run/{_SAFE.sub('_', model)}", "auvid.FreeRun",
                            f"free run of {model} from the measured initial velocity of each valid run; "
                            "band (GP): mean -+ 2 sd of the posterior members", t_ns, values, _rel(path, root))
            for model, values in sorted(models.items())]


# --------------------------------------------------------------------------------------------- the writer

def trials_available(root: str | Path) -> list[str]:
    """Trials with a synced table (what export can write)."""
    base = Path(root) / layout.SYNCED
    return sorted(p.stem for p in base.glob("*.parquet")) if base.is_dir() else []


def _channels(root: Path, trial: str, skipped: list[str], models: set[str] | None) -> list[Channel]:
    synced = layout.synced_path(root, trial)
    if not synced.is_file():
        raise ExportError(f"trial {trial!r} has no synced table (run `auvid sync` first)", file=synced)
    channels = [_flat_channel("/auvid/synced", "auvid.Synced", synced, root)]
    kin = layout.kinematics_path(root, trial)
    if kin.is_file():
        channels.append(_flat_channel("/auvid/kinematics", "auvid.Kinematics", kin, root))
        channels += _band_channels(kin, root)
    else:
        skipped.append(f"no {_rel(kin, root)}: no velocity, acceleration or prediction channels")
        return channels
    channels += _prediction_channels(root, trial, skipped, models)
    channels += _free_run_channels(root, trial)
    return channels


def _write(stream: Any, trial: str, channels: list[Channel], sources: dict[str, str],
           progress: Progress | None) -> dict[str, int]:
    writer = Writer(stream, compression=CompressionType.ZSTD, index_types=IndexType.ALL)
    writer.start(profile="", library=f"auvid {__version__}")
    writer.add_metadata("auvid", {"trial": trial, "package_version": __version__,
                                  **{f"sha256:{k}": v for k, v in sorted(sources.items())}})
    ids = []
    for ch in channels:
        sid = writer.register_schema(ch.schema_name, "jsonschema", json.dumps(ch.schema, sort_keys=True).encode())
        ids.append(writer.register_channel(ch.topic, "json", sid, {"source": ch.source}))
    # every message in (time, channel) order: readers that do not sort (PlotJuggler, plain iteration) see a
    # time-ordered stream
    stamps = np.concatenate([c.t_ns for c in channels])
    which = np.concatenate([np.full(len(c.t_ns), k, np.int64) for k, c in enumerate(channels)])
    order = np.lexsort((which, stamps))
    iters = [c.rows() for c in channels]
    counts = [0] * len(channels)
    encode = json.JSONEncoder(separators=(",", ":"), allow_nan=False).encode
    total, step = len(order), max(1, len(order) // 100)
    for n, k in enumerate(which[order].tolist()):
        row = next(iters[k])
        t = int(row["t_ns"])
        writer.add_message(ids[k], log_time=t, data=encode(row).encode(), publish_time=t, sequence=counts[k])
        counts[k] += 1
        if progress is not None and (n % step == 0 or n == total - 1):
            progress(n + 1, total, f"{trial}: messages")
    writer.finish()
    return {c.topic: counts[k] for k, c in enumerate(channels)}


def export_trial(root: str | Path, trial: str, out_dir: str | Path, progress: Progress | None = None,
                 models: set[str] | None = None) -> ExportResult:
    """Write ``<out_dir>/<trial>.mcap`` (atomically) and return what it holds; ``models``: the model files to
    load (:func:`named_models`; None: every carded one)."""
    root = Path(root)
    if _SAFE.search(trial) or trial in (".", ".."):
        raise ExportError(f"trial name {trial!r} is not a plain file name")
    skipped: list[str] = []
    channels = _channels(root, trial, skipped, models)
    sources = {c.source: "" for c in channels}
    for src in sources:
        sources[src] = file_sha256(root / src) if (root / src).is_file() else ""
    target = Path(out_dir) / f"{trial}.mcap"
    with atomic_path(target) as tmp:
        with open(tmp, "wb") as stream:
            messages = _write(stream, trial, channels, sources, progress)
        tmp.chmod(0o644)  # mkstemp makes 0600; the file is for viewers, often another user's
    for reason in skipped:
        log.warning("export %s: %s", trial, reason)
    return ExportResult(trial, target, messages, skipped)


def export_trials(root: str | Path, trials: list[str] | None = None, out_dir: str | Path | None = None,
                  progress_factory: Callable[[str], Progress] | None = None,
                  models: set[str] | None = None) -> list[ExportResult]:
    """Export every trial with a synced table (or ``trials``) into ``out_dir`` (default ``<root>/exports``);
    ``models``: as :func:`export_trial`."""
    root = Path(root)
    have = trials_available(root)
    wanted = have if trials is None else list(trials)
    unknown = [t for t in wanted if t not in have]
    if unknown:
        raise ExportError(f"no synced table for trial(s) {unknown}; available: {have}", file=root / layout.SYNCED)
    out = Path(out_dir) if out_dir is not None else root / "exports"
    results = []
    for trial in wanted:
        progress = progress_factory(f"export {trial}") if progress_factory else None
        try:
            results.append(export_trial(root, trial, out, progress, models))
        finally:
            if progress is not None and hasattr(progress, "close"):
                progress.close()
    return results
