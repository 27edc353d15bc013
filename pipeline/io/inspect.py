"""``inspect_log(path)``: what a log holds, as a JSON-able dict, and a ``rosbag info``-like text table."""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from pipeline.io.detect import open_log


def _iso(ns: int | None) -> str | None:
    if ns is None:
        return None
    return datetime.fromtimestamp(ns / 1e9, tz=UTC).isoformat(timespec="milliseconds")


def _size(path: Path) -> int:
    if path.is_dir():
        return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
    return path.stat().st_size


def inspect_log(path: str | Path) -> dict[str, Any]:
    """Format, size and per-topic type, count, first/last stamp (ns and ISO UTC), duration and mean rate."""
    path = Path(path)
    with open_log(path) as reader:
        infos = reader.topics()
        salvage = getattr(reader, "salvage", None)
        fmt = reader.format
    topics: dict[str, Any] = {}
    for name, info in sorted(infos.items()):
        duration = (info.last_ns - info.first_ns) / 1e9 if info.first_ns is not None and info.last_ns is not None \
            else None
        rate = (info.count - 1) / duration if duration and info.count > 1 else None
        topics[name] = {
            "msgtype": info.msgtype, "count": info.count, "has_header": info.has_header,
            "first_ns": info.first_ns, "last_ns": info.last_ns, "first_iso": _iso(info.first_ns),
            "last_iso": _iso(info.last_ns), "duration_s": duration, "rate_hz": rate,
        }
    firsts = [i.first_ns for i in infos.values() if i.first_ns is not None]
    lasts = [i.last_ns for i in infos.values() if i.last_ns is not None]
    start, end = (min(firsts), max(lasts)) if firsts else (None, None)
    return {
        "path": str(path), "format": fmt, "size_bytes": _size(path),
        "messages": sum(i.count for i in infos.values()),
        "start_ns": start, "end_ns": end, "start_iso": _iso(start), "end_iso": _iso(end),
        "duration_s": (end - start) / 1e9 if start is not None and end is not None else 0.0,
        "topics": topics,
        "salvage": None if salvage is None else {"kept": salvage.kept, "stopped_at_byte": salvage.stopped_at_byte,
                                                 "reason": salvage.reason},
    }


def format_inspect(info: dict[str, Any]) -> str:
    """A text table in the spirit of ``rosbag info``."""
    lines = [
        f"path:      {info['path']}",
        f"format:    {info['format']}",
        f"size:      {info['size_bytes'] / 1e6:.2f} MB",
        f"messages:  {info['messages']}",
    ]
    if info["start_ns"] is None:
        lines.append("duration:  0 s (no messages)")
    else:
        lines += [f"start:     {info['start_iso']}", f"end:       {info['end_iso']}",
                  f"duration:  {info['duration_s']:.3f} s"]
    if info.get("salvage"):
        s = info["salvage"]
        lines.append(f"DAMAGED:   kept {s['kept']} messages, stopped at byte {s['stopped_at_byte']}: {s['reason']}")
    rows = [("topic", "type", "count", "rate Hz", "duration s", "header")]
    for name, t in info["topics"].items():
        rows.append((name, t["msgtype"], str(t["count"]), f"{t['rate_hz']:.2f}" if t["rate_hz"] else "-",
                     f"{t['duration_s']:.3f}" if t["duration_s"] is not None else "-",
                     "yes" if t["has_header"] else "no"))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines.append("topics:")
    for row in rows:
        lines.append("  " + "  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)).rstrip())
    return "\n".join(lines)
