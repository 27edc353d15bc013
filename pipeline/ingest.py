"""Ingest: one log (MCAP, ROS 1 bag, ROS 2 bag, a text table or a directory of them) -> one table per configured
stream.

:func:`ingest_log` is the pure-ish core the stage shell calls; it reads, it never writes. For each stream of the
vehicle config it returns a pyarrow Table (``t_ns`` int64 from the configured clock plus the stream's offset,
sorted stably; one float64 column per signal in the unit its name states; a ``*_quat`` signal as four columns
``_w _x _y _z``), the provenance that goes into the Parquet metadata (``docs/contracts.md``), and an ingest
report (JSON-able): per topic messages read vs held by the storage, time span, mean rate, largest gap, decode
path; salvage; failed topics; CSV rows dropped; quarantine reasons; per stream, the time-stamp checks of
:mod:`pipeline.stamps` (``stamps`` counts and ``stamp_warnings``, each with the remedy; also logged as warnings).

The vehicle's per-trial overrides (``trials``) for the log's trial are applied first
(:meth:`~pipeline.config.Vehicle.for_trial`); the report lists them under ``trial_overrides``.

A stream with ``time: {rate_hz: R}`` gets ``t_ns = first + k / R`` (k the row or message index, the first
stamp from its clock) plus its offset, instead of its own stamps. On a text table the rebuilt times must span
what the time column spans, first row to last, within the stamps' rounding; a rate that drifts further is an
IngestError naming the file and the rate the stamps imply (``field`` ``time.rate_hz``, ``topic`` the stream's
configured ``file``: every log refused so is a config error).

Validation happens before anything is decoded: every configured topic (or CSV file and column) must exist, a
``header`` clock needs a message type with a header; the :class:`~pipeline.errors.IngestError` lists what is
available. A configured topic that exists but fails to decode (a type without definition is found before
anything is read: the reason names the file, topic, type and the ``message_definitions`` key that gives it), or
yields no message, makes that stream missing; a stream that is not ``optional`` is needed downstream, so the log
gets **quarantine reasons** (``IngestOutput.quarantine``) and the stage writes none of its streams (the report goes
into the quarantine entry). An ``optional`` stream that is missing for any of these reasons, or whose topic / file
is not in the log at all, is logged as a warning and listed in the report's ``absent_streams`` (source, reason,
signals); the trial goes on without it. Streams whose source kind
does not match the log (a CSV ``file`` stream while reading a bag, or a ``topic`` stream while reading a CSV
directory) are listed as ``skipped_streams``; a log to which no stream applies is an IngestError.
"""

from __future__ import annotations

import fnmatch
import logging
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, get_args

import numpy as np

from pipeline.config.hashing import config_hash
from pipeline.config.mixing import mix_pwm
from pipeline.errors import ConfigError, IngestError
from pipeline.io.base import ReadResult, TopicData, TopicInfo, ascending
from pipeline.io.msgdefs import UserTypes, load_user_types
from pipeline.stamps import check_rebuild, check_stamps, fmt_rate, time_stats, uniform_times
from pipeline.tableio import file_sha256
from pipeline.units import conversion

if TYPE_CHECKING:  # pyarrow is imported where tables are built, not with this module
    import pyarrow as pa

    from pipeline.config import Vehicle  # a model, or the snapshot's view of one (pipeline.config.snapshot)
    from pipeline.config.sources import StreamSource
    from pipeline.io.text import TextLimits

log = logging.getLogger(__name__)

QUAT_COMPONENTS = ("w", "x", "y", "z")
Checksum = Literal["sha256", "none"]  # params ingest.checksum
CHECKSUMS = get_args(Checksum)
_LOG_SUFFIXES = (".mcap", ".bag", ".db3", ".csv", ".tsv", ".txt", ".dat", ".log", ".gz", ".zst", ".zstd", ".active")


@dataclass(frozen=True)
class ColumnPlan:
    column: str  # output column name (unit suffix)
    signal: str  # signal name in the config
    field: str  # field path / CSV column
    unit: str | None  # source unit
    factor: float
    offset: float


@dataclass
class IngestOutput:
    trial: str
    tables: dict[str, pa.Table] = field(default_factory=dict)
    provenance: dict[str, dict[str, Any]] = field(default_factory=dict)
    report: dict[str, Any] = field(default_factory=dict)
    quarantine: list[dict[str, Any]] = field(default_factory=list)


def trial_id(path: str | Path) -> str:
    """The log's name without its (log-format) extensions: ``trial01.csv.gz`` -> ``trial01``."""
    name = Path(path).name
    while True:
        lower = name.lower()
        for suffix in _LOG_SUFFIXES:
            if lower.endswith(suffix) and len(name) > len(suffix):
                name = name[: -len(suffix)]
                break
        else:
            return name


def column_plans(stream: StreamSource) -> list[ColumnPlan]:
    """Output columns of a stream: one per signal, four per quaternion signal (``<field>.w`` -> ``<name>_w``).
    Each maps the raw value x to ``factor * x + offset``: the unit conversion of ``sign * scale * x``."""
    plans = []
    for name, source in stream.signals.items():
        conv = conversion(name, source.unit)
        if name.endswith("_quat"):
            for comp in QUAT_COMPONENTS:
                plans.append(ColumnPlan(f"{name}_{comp}", name, f"{source.field}.{comp}", source.unit,
                                        conv.factor, conv.offset))
        else:  # unit(sign * scale * raw): the signal's sign and scale come before its unit conversion
            plans.append(ColumnPlan(name, name, source.field, source.unit,
                                    conv.factor * source.sign * source.scale, conv.offset))
    return plans


def _open(path: Path, definitions: UserTypes | None = None, text_limits: TextLimits | None = None) -> Any:
    """The reader for ``path``, chosen by content (:func:`pipeline.io.open_log`); a CSV directory -> text."""
    from pipeline.io import open_log

    return open_log(path, definitions, text_limits=text_limits)


def user_types(vehicle: Vehicle) -> UserTypes | None:
    """The vehicle's ``message_definitions`` parsed (directories relative to the vehicle file); None if unset."""
    if not vehicle.message_definitions:
        return None
    dirs = [vehicle.resolve(d) for d in vehicle.message_definitions]
    for i, (given, found) in enumerate(zip(vehicle.message_definitions, dirs, strict=True)):
        if not found.is_dir():
            raise ConfigError(f"message definition directory {given!r} does not exist (looked at {found})",
                              field=f"message_definitions.{i}")
    return load_user_types(dirs)


def _resolve_csv_file(name: str, pattern: str, available: list[str], path: Path,
                      optional: bool = False) -> str | None:
    if pattern in available:
        return pattern
    matches = [a for a in available if fnmatch.fnmatch(a, pattern)]
    if len(matches) == 1:
        return matches[0]
    if not matches and optional:
        return None
    if not matches:
        from pipeline.io.detect import TEXT_TRIAL

        raise IngestError(f"stream {name!r}: no CSV file matches {pattern!r}; available: {available} ({TEXT_TRIAL}: "
                          "`file` names the file, inside the directory or the one file itself)",
                          file=path, topic=pattern)
    raise IngestError(f"stream {name!r}: pattern {pattern!r} matches several files {matches}; make it unique",
                      file=path, topic=pattern)


def ingest_log(path: str | Path, vehicle: Vehicle, *, trial: str | None = None, salvage: bool = True,
               source_name: str | None = None, checksum: Checksum = "sha256",
               text_limits: TextLimits | None = None) -> IngestOutput:
    """Read one log and build one table per configured stream (see the module docstring).

    ``source_name`` is what provenance records as ``source_file`` (the stage passes a root-relative path, so
    that outputs do not depend on where the run directory lives); default: ``str(path)``. ``checksum``: the
    log's sha256 goes into the report and provenance as ``source_sha256`` (a CSV file's also as
    ``file_sha256``), or with ``"none"`` no hash is computed and both are ``None``; ``checksum`` records which.
    ``text_limits``: what a text file may hold (params ``ingest.text_max_*``; default: the defaults of those keys).
    """
    if checksum not in CHECKSUMS:
        raise ValueError(f"checksum must be one of {list(CHECKSUMS)}, got {checksum!r}")
    path = Path(path)
    out = IngestOutput(trial=trial or trial_id(path))
    overrides = vehicle.trial_overrides(out.trial)
    if overrides:
        log.info("%s: per-trial overrides %s", out.trial, overrides)
    # Provenance keeps the hash of the whole vehicle config (overrides included), as every later stage records it.
    chash = config_hash(vehicle)
    vehicle = vehicle.for_trial(out.trial)
    if checksum == "none":
        return _ingest(path, vehicle, out, salvage=salvage, source_name=source_name, sha_job=None,
                       chash=chash, overrides=overrides, text_limits=text_limits)
    # The file's sha256 (provenance) is computed while the log is read: hashlib and file reads release the GIL.
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="sha256") as pool:
        sha_job = pool.submit(file_sha256, path)
        try:
            return _ingest(path, vehicle, out, salvage=salvage, source_name=source_name, sha_job=sha_job,
                           chash=chash, overrides=overrides, text_limits=text_limits)
        finally:
            sha_job.cancel()


def _ingest(path: Path, vehicle: Vehicle, out: IngestOutput, *, salvage: bool, source_name: str | None,
            sha_job: Any | None, chash: str, overrides: dict[str, Any],
            text_limits: TextLimits | None = None) -> IngestOutput:
    """The read and the tables; ``sha_job`` is the sha256's future, None with ``checksum: none``."""
    absent: dict[str, dict[str, Any]] = {}  # optional streams this trial lacks

    def lack(name: str, source: str, reason: str) -> None:
        stream = vehicle.streams[name]
        absent[name] = {"topic" if stream.file is None else "file": source, "reason": reason,
                        "signals": list(stream.signals)}
        log.warning("%s (%s): optional stream %r (%s) is absent: %s; its signals %s are invalid in this trial",
                    out.trial, path.name, name, source, reason, list(stream.signals))

    with _open(path, user_types(vehicle), text_limits) as reader:
        is_csv = reader.format == "csv"
        # The cheap listing (a reader may take counts from the recorder's summary; read() checks them).
        infos: dict[str, TopicInfo] = reader.catalog() if hasattr(reader, "catalog") else reader.topics()
        sources: dict[str, str] = {}  # stream -> topic / file
        skipped: dict[str, str] = {}
        for name, stream in vehicle.streams.items():
            if (stream.file is not None) != is_csv:
                kind = "a CSV file" if stream.file is not None else "a topic"
                skipped[name] = f"reads {kind}; this log is {reader.format}"
                continue
            if is_csv:
                assert stream.file is not None and stream.csv is not None
                found = _resolve_csv_file(name, stream.file, sorted(infos), path, stream.optional)
                if found is None:
                    lack(name, stream.file, f"no CSV file matches {stream.file!r}; available: {sorted(infos)}")
                    continue
                sources[name] = found
            else:
                assert stream.topic is not None
                if stream.optional and stream.topic not in infos:
                    lack(name, stream.topic, f"topic not in {path.name}; available: {sorted(infos)}")
                    continue
                sources[name] = stream.topic
        if not sources:
            why = f"skipped: {skipped}" + (f"; optional and absent: {sorted(absent)}" if absent else "")
            raise IngestError(f"no configured stream applies to this {reader.format} log ({why})", file=path)
        _validate(path, vehicle, sources, infos, reader)
        # Types without a definition are found before anything is decoded.
        for name, source in list(sources.items()):
            why = reader.undecodable(source) if hasattr(reader, "undecodable") else None
            if why is None:
                continue
            reason = f"topic {source!r} in {path.name} ({infos[source].msgtype}) cannot be decoded: {why}"
            del sources[name]
            if vehicle.streams[name].optional:
                lack(name, source, reason)
            else:
                out.quarantine.append({"stream": name, "topic": source, "reason": reason})
        if out.quarantine:  # a needed stream cannot be decoded: the trial is quarantined without a long read
            # debug: the reasons go into the quarantine entry, which the shell prints once
            log.debug("%s (%s): %s", out.trial, path.name, "; ".join(q["reason"] for q in out.quarantine))
            out.report = {"trial": out.trial, "source_file": source_name if source_name is not None else str(path),
                          "format": reader.format, "trial_overrides": overrides, "absent_streams": absent,
                          "skipped_streams": skipped, "quarantine": out.quarantine}
            return out
        if not sources:
            raise IngestError(f"every stream that applies to this log is absent: {sorted(absent)}", file=path)
        requests: dict[str, list[str]] = {}
        for name, source in sources.items():
            fields = requests.setdefault(source, [])
            fields.extend(p.field for p in column_plans(vehicle.streams[name]) if p.field not in fields)
        log.info("%s: reading %d topic(s) for %d stream(s)", path, len(requests), len(sources))
        result: ReadResult = reader.read(requests)
        if hasattr(reader, "catalog"):
            infos = reader.catalog()  # counts checked and time ranges filled in by the read
        fmt = reader.format

    if result.salvage is not None and not salvage:
        raise IngestError(f"file is damaged ({result.salvage.reason}); salvage is disabled in params",
                          file=path)
    sha = sha_job.result() if sha_job is not None else None
    checksum = "none" if sha_job is None else "sha256"
    source_file = source_name if source_name is not None else str(path)
    report: dict[str, Any] = {
        "trial": out.trial, "source_file": source_file, "source_sha256": sha, "checksum": checksum, "format": fmt,
        "config_hash": chash, "salvage": asdict(result.salvage) if result.salvage else None,
        "failed_topics": dict(sorted(result.failed.items())), "skipped_streams": skipped,
        "trial_overrides": overrides, "absent_streams": absent, "topics": {}, "streams": {},
    }
    for topic, data in sorted(result.topics.items()):
        report["topics"][topic] = _topic_report(data, infos.get(topic))

    uses = {source: list(sources.values()).count(source) for source in sources.values()}
    for name, source in sources.items():
        stream = vehicle.streams[name]
        uses[source] -= 1
        # The reader's columns are let go once their last stream's table is built (peak memory).
        data = result.topics.get(source) if uses[source] else result.topics.pop(source, None)
        where = {"stream": name, "topic": source}
        missing = None
        if data is None:
            missing = f"configured topic failed to decode: {result.failed.get(source, 'the reader returned no data')}"
        elif data.read == 0 or data.log_ns.size == 0:
            missing = "configured topic holds no message (or no valid row)"
        if missing is not None:
            if stream.optional:
                lack(name, source, missing)
            else:
                out.quarantine.append({**where, "reason": missing})
            continue
        shown = f"{source_file}/{source}" if is_csv and reader.path.is_dir() else source_file
        table, stamps, checked = _build_table(path, name, stream, data, shown)
        out.tables[name] = table
        stream_report = {"topic" if not is_csv else "file": source, "clock": stream.clock,
                         "offset_s": stream.offset_s, **time_stats(stamps)}
        if stream.time is not None:
            stream_report["time_rate_hz"] = stream.time.rate_hz
        stream_report.update(_stamp_report(out.trial, path, name, source, stream, data, checked))
        report["streams"][name] = stream_report
        prov: dict[str, Any] = {
            "trial": out.trial, "stream": name, "source_file": source_file, "source_sha256": sha, "checksum": checksum,
            "message_type": data.msgtype, "clock": stream.clock, "offset_s": stream.offset_s,
            **({"time_rate_hz": stream.time.rate_hz} if stream.time is not None else {}),
            "config_hash": chash, "decode_path": data.path, "reader_format": fmt,
            "fields": {p.column: {"signal": p.signal, "field": p.field, "unit": p.unit}
                       for p in column_plans(stream)},
        }
        if is_csv:
            prov["file"] = source
            csv_path = reader.path / source if reader.path.is_dir() else reader.path
            prov["file_sha256"] = file_sha256(csv_path) if sha_job is not None else None
        else:
            prov["topic"] = source
        if result.salvage is not None:
            prov["salvage"] = asdict(result.salvage)
        out.provenance[name] = prov
    if not out.tables and not out.quarantine:
        out.quarantine.append({"stream": "(all)", "topic": None,
                               "reason": f"every stream is absent from this trial: {sorted(absent)}"})
    report["quarantine"] = out.quarantine
    out.report = report
    return out


def _validate(path: Path, vehicle: Vehicle, sources: dict[str, str], infos: dict[str, TopicInfo],
              reader: Any) -> None:
    """Every configured topic / file / column exists and a header clock has a header; before any decoding."""
    available = sorted(infos)
    for name, source in sources.items():
        stream = vehicle.streams[name]
        if source not in infos:
            raise IngestError(f"stream {name!r}: topic {source!r} not in {path.name}; available: {available}",
                              file=path, topic=source)
        if stream.clock == "header" and not infos[source].has_header:
            raise IngestError(f"stream {name!r} uses clock: header, but {infos[source].msgtype} has no header; "
                              f"use clock: log", file=path, topic=source)
        if stream.file is not None:
            assert stream.csv is not None
            reader.configure({source: stream.csv})
            columns = reader.fields(source)
            needed = [stream.csv.time_column, *(p.field for p in column_plans(stream))]
            for col in needed:
                if col.strip() not in columns:
                    raise IngestError(f"stream {name!r}: no column {col!r} in {source}; available: {columns}",
                                      file=path, topic=source, field=col)


def _topic_report(data: TopicData, info: TopicInfo | None) -> dict[str, Any]:
    rep: dict[str, Any] = {
        "message_type": data.msgtype, "decode_path": data.path, "messages_read": int(data.read),
        "messages_in_storage": int(info.count) if info is not None else None, "expected": int(data.expected),
        "lost": int(data.expected) - int(data.read), "log_time": time_stats(np.asarray(data.log_ns)),
    }
    dropped = getattr(data, "dropped_count", 0)
    if dropped:
        rep["rows_dropped"] = int(dropped)
        rep["rows_dropped_lines"] = list(getattr(data, "dropped_lines", []))
    if getattr(data, "line_counts", None):  # a text file: its data lines by kind, the dropped ones by number
        rep["lines"] = dict(data.line_counts)  # type: ignore[attr-defined]
        rep["lines_dropped"] = dict(data.line_numbers)  # type: ignore[attr-defined]
    return rep


def _stamp_report(trial: str, path: Path, name: str, source: str, stream: StreamSource, data: TopicData,
                  checked: np.ndarray) -> dict[str, Any]:
    """The stream's stamp checks for the report; each warning is logged with trial, file, stream and remedy."""
    if stream.time is not None:
        label = f"times rebuilt at {fmt_rate(stream.time.rate_hz)} Hz from the first {stream.clock} stamp"
    elif stream.clock == "column":
        assert stream.csv is not None
        label = f"stamps of time column {stream.csv.time_column!r}"
    else:
        label = None
    log_ns = np.asarray(data.log_ns) if stream.clock == "header" else None
    result = check_stamps(checked, clock=stream.clock, log_ns=log_ns, label=label)
    for w in result.warnings:
        log.warning("%s (%s): stream %r (%s): %s; e.g. %s. Remedy: %s", trial, path.name, name, source, w.message,
                    ", ".join(w.examples) or "-", w.remedy)
    stamps = result.as_dict()
    warnings = stamps.pop("warnings")
    return {"stamps": stamps, "stamp_warnings": warnings}


def _arrow(values: np.ndarray, arrow_type: pa.DataType, dtype: type[np.generic]) -> pa.Array:
    """A numeric column without nulls as an Arrow array over the same bytes (zero copy, as ``pa.array`` makes it).

    Not ``pa.array``: on an ndarray it asks pandas whether the values are a Series or a Categorical, and that
    import was the largest single cost of a whole ``auvid ingest`` process, which never uses pandas. NaN stays a
    value, not a null, as with ``pa.array(..., from_pandas=False)``.
    """
    import pyarrow as pa

    values = np.ascontiguousarray(values, dtype=dtype)
    return pa.Array.from_buffers(arrow_type, len(values), [None, pa.py_buffer(values)])


def _build_table(path: Path, name: str, stream: StreamSource, data: TopicData,
                 shown: str) -> tuple[pa.Table, np.ndarray, np.ndarray]:
    """The stream's table, its t_ns in storage order, and the stamps to check (t_ns before the offset).

    A time rebuilt from a text table's rows must span what its own time column spans, within the stamps'
    rounding (:func:`~pipeline.stamps.check_rebuild`): else an IngestError naming the file (``shown``) and the
    rate the stamps imply. Topics are not checked: their rebuild is the remedy for stamps that carry no time.
    """
    import pyarrow as pa

    if stream.clock == "header":
        if data.header_ns is None:
            raise IngestError(f"stream {name!r} uses clock: header, but {data.msgtype} has no header stamp",
                              file=path, topic=data.topic)
        base = np.asarray(data.header_ns, dtype=np.int64)
    else:
        base = np.asarray(data.log_ns, dtype=np.int64)
    if stream.time is not None and base.size:
        rows = getattr(data, "rows", None)
        rows = np.arange(base.size, dtype=np.int64) if rows is None else np.asarray(rows, dtype=np.int64)
        drift = check_rebuild(base, rows, stream.time.rate_hz) if stream.clock == "column" else None
        if drift is not None and not drift.ok:
            raise IngestError(f"stream {name!r}: {drift.message(shown)}; {drift.remedy()}", file=path,
                              topic=stream.file, field="time.rate_hz")
        try:
            base = uniform_times(int(base[0]), rows, stream.time.rate_hz)
        except ValueError as err:
            raise IngestError(f"stream {name!r}: time.rate_hz: {err}", file=path, topic=data.topic,
                              field="time.rate_hz") from None
    shift = round(stream.offset_s * 1e9)
    t_ns = base + np.int64(shift) if shift else base  # no copy of the stamps for a stream without an offset
    # Sorted stably by time; logs are nearly always in order already, and then no permuted copies are made.
    order = None if ascending(t_ns) else np.argsort(t_ns, kind="stable")
    arrays: dict[str, pa.Array] = {"t_ns": _arrow(t_ns if order is None else t_ns[order], pa.int64(), np.int64)}
    for plan in column_plans(stream):
        try:
            raw = np.asarray(data.columns[plan.field], dtype=np.float64)
        except KeyError:
            key = plan.field.strip()
            if key not in data.columns:
                raise IngestError(f"stream {name!r}: the reader returned no column for field {plan.field!r}",
                                  file=path, topic=data.topic, field=plan.field) from None
            raw = np.asarray(data.columns[key], dtype=np.float64)
        values = raw if (plan.factor == 1.0 and plan.offset == 0.0) else raw * plan.factor + plan.offset
        arrays[plan.column] = _arrow(values if order is None else values[order], pa.float64(), np.float64)
    if stream.mixing is not None:  # motor PWMs mixed from the pilot's inputs (already in time order)
        inputs = {s: arrays[s].to_numpy(zero_copy_only=False) for s in stream.mixing.inputs.values()}
        for out, values in mix_pwm(stream.mixing, inputs, len(t_ns)).items():
            arrays[out] = _arrow(values, pa.float64(), np.float64)
    # Every column is REQUIRED (not null): a stream has no nulls (a missing value is NaN), and a Parquet column
    # that may hold nulls stores a definition level per value, a sizeable share of the write's CPU.
    schema = pa.schema([pa.field(name, arr.type, nullable=False) for name, arr in arrays.items()])
    return pa.Table.from_arrays(list(arrays.values()), schema=schema), t_ns, base
