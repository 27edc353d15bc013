"""``inspect_log(path)``: what a log holds, as a JSON-able dict, and a ``rosbag info``-like text table.

For every topic (or text file): message type, count, serialization (``cdr``, ``ros1``, ...; text files:
``text``), time span, mean rate and the largest gap between consecutive messages, and the time-stamp checks of
:mod:`pipeline.stamps` (the same ones ingest runs) on the stamps a config would use: a topic with a header is
checked on its header stamps against its log time (zero, constant, sim-time, duplicate, quantized stamps, steps
back), one without on its log time; ``suggested_clock`` is ``header`` when the type has a header and those
checks found nothing that makes the stamps unusable, else ``log``. Types without a definition in the log are
decoded with the user's (``definitions``, from ``message_definitions``); a topic that still cannot be decoded is
listed with the reason, its log times still checked.

Text logs (one file, or a directory of them) are read with the options the vehicle config gives
(``csv_options``: file name or glob -> :class:`~pipeline.config.sources.CsvOptions`), else with the options
:func:`pipeline.io.csvsniff.sniff_csv` guesses; the result shows the columns and the options used.

:func:`topic_fields` lists the field paths of one topic's type (for ``signals:`` in the vehicle config).
"""

from __future__ import annotations

import fnmatch
import logging
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from pipeline.config.sources import CsvOptions
from pipeline.errors import IngestError
from pipeline.io.msgdefs import UserTypes
from pipeline.stamps import check_rebuild, check_stamps, fmt_rate, time_stats, uniform_times

log = logging.getLogger(__name__)

STORAGE = {"mcap": "mcap", "ros1": "ros1 bag", "ros2-sqlite3": "sqlite3 (ROS 2 bag)",
           "ros2-mcap": "mcap (ROS 2 bag)", "csv": "text"}
# Warnings after which a header stamp is not a usable clock (log time is): the remedy is `clock: log`.
UNUSABLE_HEADER = ("zero", "constant", "far_from_log")
_V = TypeVar("_V")


def _iso(ns: int | None) -> str | None:
    if ns is None:
        return None
    return datetime.fromtimestamp(ns / 1e9, tz=UTC).isoformat(timespec="milliseconds")


def _size(path: Path) -> int:
    if path.is_dir():
        return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
    return path.stat().st_size


def _is_text_file(path: Path) -> bool:
    from pipeline.io.text import TEXT_SUFFIXES

    return path.is_file() and path.name.lower().endswith(TEXT_SUFFIXES)


def open_any(path: Path, definitions: UserTypes | None = None) -> Any:
    """:func:`pipeline.io.open_log`, and a single text file too (a one-file CSV trial)."""
    from pipeline.io.detect import open_log
    from pipeline.io.text import open_text

    if _is_text_file(path):
        try:
            return open_log(path, definitions)
        except IngestError:  # no binary magic: a text file
            return open_text(path)
    return open_log(path, definitions)


def _stamp_entry(checked: np.ndarray, *, clock: str, log_ns: np.ndarray | None, label: str | None = None
                 ) -> dict[str, Any]:
    result = check_stamps(checked, clock=clock, log_ns=log_ns, label=label)
    stamps = result.as_dict()
    warnings = stamps.pop("warnings")
    return {"stamps": stamps, "stamp_warnings": warnings}


def _timing(t_ns: np.ndarray) -> dict[str, Any]:
    stats = time_stats(np.asarray(t_ns, dtype=np.int64))
    return {"first_ns": stats["first_ns"], "last_ns": stats["last_ns"], "first_iso": _iso(stats["first_ns"]),
            "last_iso": _iso(stats["last_ns"]), "duration_s": stats["span_s"] if stats["count"] else None,
            "rate_hz": stats["mean_rate_hz"], "largest_gap_s": stats["largest_gap_s"]}


def inspect_log(path: str | Path, *, definitions: UserTypes | None = None,
                csv_options: dict[str, CsvOptions] | None = None,
                time_rates: dict[str, float] | None = None) -> dict[str, Any]:
    """Format, storage, size and per topic: type, count, serialization, span, rate, largest gap, stamp checks.

    ``definitions``: the user's message definitions (types the log does not embed); ``csv_options``: parsing
    options per text file name or glob (from the vehicle config), used instead of the sniffed ones;
    ``time_rates``: per text file name or glob, the config's ``time: {rate_hz}``: the file's times are rebuilt as
    ingest rebuilds them (span, rate and stamp checks of the rebuilt times), and a rebuild that drifts from the
    time column beyond its rounding is a ``rate_mismatch`` warning naming the rate the stamps imply.
    """
    path = Path(path)
    with open_any(path, definitions) as reader:
        fmt = reader.format
        if fmt == "csv":
            topics = _text_topics(reader, csv_options or {}, time_rates or {})
        else:
            topics = _binary_topics(reader)
        salvage = getattr(reader, "salvage", None)
    firsts = [t["first_ns"] for t in topics.values() if t["first_ns"] is not None]
    lasts = [t["last_ns"] for t in topics.values() if t["last_ns"] is not None]
    start, end = (min(firsts), max(lasts)) if firsts else (None, None)
    warnings = sum(len(t["stamp_warnings"]) for t in topics.values())
    return {
        "path": str(path), "format": fmt, "storage": STORAGE.get(fmt, fmt), "size_bytes": _size(path),
        "serialization": sorted({t["serialization"] for t in topics.values() if t["serialization"]}),
        "messages": sum(t["count"] for t in topics.values()),
        "start_ns": start, "end_ns": end, "start_iso": _iso(start), "end_iso": _iso(end),
        "duration_s": (end - start) / 1e9 if start is not None and end is not None else 0.0,
        "stamp_warnings": warnings, "topics": topics,
        "salvage": None if salvage is None else {"kept": salvage.kept, "stopped_at_byte": salvage.stopped_at_byte,
                                                 "reason": salvage.reason},
    }


def _binary_topics(reader: Any) -> dict[str, Any]:
    infos = reader.topics()
    undecodable = {t: reader.undecodable(t) for t in infos}
    readable = [t for t, why in undecodable.items() if why is None]
    result = reader.read({t: [] for t in readable}) if readable else None
    failed = dict(result.failed) if result is not None else {}
    data = dict(result.topics) if result is not None else {}
    raw_only = [t for t in infos if t not in data]
    log_only = reader.log_times(raw_only) if raw_only else {}
    infos = reader.catalog()  # counts checked by the read
    topics: dict[str, Any] = {}
    for name in sorted(infos):
        info = infos[name]
        why = undecodable[name] or failed.get(name)
        item = data.get(name)
        log_ns = np.asarray(item.log_ns if item is not None else log_only.get(name, np.empty(0)), dtype=np.int64)
        header_ns = item.header_ns if item is not None else None
        entry: dict[str, Any] = {
            "msgtype": info.msgtype, "count": int(info.count) if item is None else int(item.read),
            "serialization": reader.encoding(name), "has_header": bool(info.has_header), "decodable": why is None,
            "undecodable_reason": why, **_timing(log_ns),
        }
        if header_ns is not None:
            entry.update(_stamp_entry(np.asarray(header_ns), clock="header", log_ns=log_ns))
        else:
            entry.update(_stamp_entry(log_ns, clock="log", log_ns=None))
        bad = [w["check"] for w in entry["stamp_warnings"] if w["check"] in UNUSABLE_HEADER]
        entry["suggested_clock"] = "header" if header_ns is not None and not bad else "log"
        topics[name] = entry
    return topics


def _options_for(name: str, csv_options: dict[str, _V]) -> _V | None:
    if name in csv_options:
        return csv_options[name]
    return next((o for pattern, o in csv_options.items() if fnmatch.fnmatch(name, pattern)), None)


def _rebuilt(shown: str, data: Any, opts: CsvOptions, rate_hz: float) -> tuple[np.ndarray, dict[str, Any]]:
    """A text file's times rebuilt at ``rate_hz`` as ingest rebuilds them, with their stamp checks, and a
    ``rate_mismatch`` warning where the time column says otherwise (ingest refuses that file)."""
    stamps = np.asarray(data.log_ns, dtype=np.int64)
    rows = np.arange(stamps.size, dtype=np.int64) if data.rows is None else np.asarray(data.rows, dtype=np.int64)
    t_ns = uniform_times(int(stamps[0]), rows, rate_hz) if stamps.size else stamps
    entry = _stamp_entry(t_ns, clock="column", log_ns=None, label=f"times rebuilt at {fmt_rate(rate_hz)} Hz from "
                         f"the first stamp of time column {opts.time_column!r}")
    entry["time_rate_hz"] = rate_hz
    drift = check_rebuild(stamps, rows, rate_hz)
    if drift is not None:
        entry["stamps_rate_hz"] = drift.stamps_rate_hz
        if not drift.ok:
            entry["stamp_warnings"].append({"check": "rate_mismatch", "message": drift.message(shown),
                                            "remedy": drift.remedy(), "count": 1, "examples": []})
    return t_ns, entry


def _text_topics(reader: Any, csv_options: dict[str, CsvOptions], time_rates: dict[str, float]) -> dict[str, Any]:
    from pipeline.io.csvsniff import sniff_csv

    base = reader.path if reader.path.is_dir() else reader.path.parent
    topics: dict[str, Any] = {}
    for name in sorted(reader.topics()):
        if reader.is_empty(name):  # nothing to sniff or parse: an empty stream, said so
            log.warning("%s: empty file (no header or data lines)", base / name)
            topics[name] = {"msgtype": "text", "serialization": "text", "has_header": False, "decodable": True,
                            "undecodable_reason": None, "options_from": None, "columns": [], "count": 0,
                            "time_column": None, "csv": None, "sniff_note": "empty file (no header or data lines)",
                            **_timing(np.empty(0, dtype=np.int64)), "stamps": None, "stamp_warnings": [],
                            "suggested_clock": None}
            continue
        given = _options_for(name, csv_options)
        sniffed = sniff_csv(base / name) if given is None else None
        opts = given if given is not None else sniffed.options if sniffed is not None else None
        entry: dict[str, Any] = {"msgtype": "text", "serialization": "text", "has_header": False,
                                 "decodable": True, "undecodable_reason": None,
                                 "options_from": "vehicle config" if given is not None else "sniffed",
                                 "sniff_note": sniffed.note if sniffed is not None else None}
        if opts is None:  # no time column: columns and rows only
            assert sniffed is not None
            opts = CsvOptions(time_column=sniffed.columns[0] if sniffed.columns else "?", skip_rows=sniffed.skip_rows,
                              header=sniffed.header, columns=None if sniffed.header else sniffed.columns,
                              delimiter=sniffed.delimiter if sniffed.delimiter != "," else None,
                              encoding=sniffed.encoding)
            reader.configure({name: opts})
            entry.update(columns=reader.fields(name), count=reader.topics()[name].count, time_column=None,
                         csv=opts.model_dump(exclude_defaults=True) | {"time_column": None},
                         **_timing(np.empty(0, dtype=np.int64)), stamps=None, stamp_warnings=[],
                         suggested_clock=None)
            topics[name] = entry
            continue
        reader.configure({name: opts})
        columns = reader.fields(name)
        data = reader.read({name: []}).topics[name]
        rate_hz = _options_for(name, time_rates) if given is not None else None
        if rate_hz is not None:
            t_ns, stamps = _rebuilt(name, data, opts, rate_hz)
        else:
            t_ns = np.asarray(data.log_ns, dtype=np.int64)
            stamps = _stamp_entry(t_ns, clock="column", log_ns=None,
                                  label=f"stamps of time column {opts.time_column!r}")
        entry.update(columns=columns, count=int(data.read), time_column=opts.time_column,
                     csv=opts.model_dump(exclude_defaults=True), **_timing(t_ns))
        if getattr(data, "dropped_count", 0):
            entry["rows_dropped"] = int(data.dropped_count)
        entry.update(stamps)
        entry["suggested_clock"] = "column"
        topics[name] = entry
    return topics


def topic_fields(path: str | Path, topic: str, *, definitions: UserTypes | None = None,
                 csv_options: dict[str, CsvOptions] | None = None) -> dict[str, Any]:
    """The field paths of ``topic``'s type (a text file: its columns), with the type; IngestError listing the
    topics when there is no such topic."""
    path = Path(path)
    with open_any(path, definitions) as reader:
        infos = reader.catalog() if hasattr(reader, "catalog") else reader.topics()
        if topic not in infos:
            raise IngestError(f"topic {topic!r} not in {path.name}; available: {sorted(infos)}", file=path,
                              topic=topic)
        if reader.format == "csv":
            from pipeline.io.csvsniff import sniff_csv

            opts = _options_for(topic, csv_options or {})
            if opts is None:
                base = reader.path if reader.path.is_dir() else reader.path.parent
                opts = sniff_csv(base / topic).options
            if opts is not None:
                reader.configure({topic: opts})
            return {"topic": topic, "msgtype": "text", "fields": reader.fields(topic)}
        fields = reader.field_paths(topic)
        out: dict[str, Any] = {"topic": topic, "msgtype": infos[topic].msgtype, "fields": fields}
        if infos[topic].msgtype in ("sensor_msgs/msg/JointState", "sensor_msgs/JointState"):
            msg = reader.first_message(topic)
            names = list(getattr(msg, "name", []) or [])
            out["joint_names"] = names
            out["fields"] = fields + [f"{arr}[name={n}]" for arr in ("position", "velocity", "effort") for n in names]
        return out


def format_inspect(info: dict[str, Any]) -> str:
    """A text table in the spirit of ``rosbag info``, then the stamp warnings with their remedies."""
    lines = [
        f"path:      {info['path']}",
        f"format:    {info['format']}",
        f"storage:   {info.get('storage', info['format'])}",
        f"serialization: {', '.join(info.get('serialization') or []) or '-'}",
        f"size:      {info['size_bytes'] / 1e6:.2f} MB",
        f"messages:  {info['messages']}",
    ]
    if info["start_ns"] is None:
        lines.append("duration:  no time stamps" if info["messages"] else "duration:  0 s (no messages)")
    else:
        lines += [f"start:     {info['start_iso']}", f"end:       {info['end_iso']}",
                  f"duration:  {info['duration_s']:.3f} s"]
    if info.get("salvage"):
        s = info["salvage"]
        lines.append(f"DAMAGED:   kept {s['kept']} messages, stopped at byte {s['stopped_at_byte']}: {s['reason']}")
    topics = info["topics"]
    text = any(t.get("msgtype") == "text" for t in topics.values())
    head = ("file", "time column", "rows") if text else ("topic", "type", "count")
    rows = [(*head, "rate Hz", "duration s", "max gap s", "header" if not text else "clock", "ser.")]
    for name, t in topics.items():
        rows.append((name, (t.get("time_column") or "-") if text else t["msgtype"], str(t["count"]),
                     f"{t['rate_hz']:.2f}" if t.get("rate_hz") else "-",
                     f"{t['duration_s']:.3f}" if t.get("duration_s") is not None else "-",
                     f"{t['largest_gap_s']:.3f}" if t.get("largest_gap_s") is not None else "-",
                     (t.get("suggested_clock") or "-") if text else ("yes" if t["has_header"] else "no"),
                     t.get("serialization") or "?"))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines.append("topics:" if not text else "files:")
    for row in rows:
        lines.append("  " + "  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)).rstrip())
    for name, t in topics.items():
        if text:
            how = t.get("options_from", "sniffed")
            lines.append(f"{name}: columns {t.get('columns')}")
            if t.get("csv") is None:  # an empty file
                lines.append(f"  {t.get('sniff_note')}")
            else:
                lines.append(f"  csv ({how}): {t.get('csv')}" + (f"  [{t['sniff_note']}]" if t.get("sniff_note")
                                                                  else ""))
        if t.get("undecodable_reason"):
            lines.append(f"{name}: cannot decode: {t['undecodable_reason']}")
        if not text and t.get("has_header") and t.get("suggested_clock") == "log":
            lines.append(f"{name}: header stamps unusable: use `clock: log`")
        for w in t.get("stamp_warnings") or []:
            examples = ", ".join(w.get("examples") or []) or "-"
            lines.append(f"{name}: WARNING {w['check']}: {w['message']}; e.g. {examples}. Remedy: {w['remedy']}")
    return "\n".join(lines)


def format_fields(fields: dict[str, Any]) -> str:
    """One field path per line, under the topic and its type."""
    lines = [f"{fields['topic']} ({fields['msgtype']}):"]
    lines += [f"  {f}" for f in fields["fields"]]
    return "\n".join(lines)
