"""The fast way through an intact, indexed ROS 1 bag: its index section and the index-data records of each chunk.

:func:`index_walk` reads the bag header, the index section (connection and chunk-info records) and, after each
chunk, its index-data records (time and offset of every message, per connection) with positioned reads, never
decompressing a chunk; it returns None when the bag is not of that shape (never indexed, counts that disagree),
and the caller walks the bag record by record instead. :func:`chunk_batches` decompresses each chunk once and
locates the wanted messages from the offsets, checking each record's header against the first one's layout
(same header length, ``op=2`` and ``conn`` in place); a record that does not fit raises :class:`Damaged`.
"""

from __future__ import annotations

import logging
import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.io.base import BATCH_BYTES, Batch, Rows, take_rows
from pipeline.io.mcap_reader import Damaged
from pipeline.io.rosbag1 import (
    MAGIC,
    OP_BAG_HEADER,
    OP_CHUNK,
    OP_CHUNK_INFO,
    OP_CONNECTION,
    OP_INDEX,
    BagWalk,
    _connection,
    _decompress,
    _header,
)

log = logging.getLogger(__name__)
_ENTRY = np.dtype([("sec", "<u4"), ("nsec", "<u4"), ("off", "<u4")])


@dataclass
class ChunkRef:
    data: int
    length: int
    size: int
    compression: str
    at: int
    index: dict[int, np.ndarray] = field(default_factory=dict)  # connection -> record offsets in the chunk


@dataclass
class IndexedBag:
    walk: BagWalk
    chunks: list[ChunkRef]
    duplicates: int = 0  # chunk-info records that list a chunk listed before (dropped)


def _record(fd: int, pos: int, end: int) -> tuple[dict[str, bytes], int, int]:
    """Header fields, data offset and data length of the record at ``pos``."""
    if pos + 4 > end:
        raise struct.error("record cut short")
    (hlen,) = struct.unpack("<I", os.pread(fd, 4, pos))
    if pos + 8 + hlen > end:
        raise struct.error("record cut short")
    raw = os.pread(fd, hlen + 4, pos + 4)
    hdr = _header(raw, 0, hlen)
    (dlen,) = struct.unpack_from("<I", raw, hlen)
    if pos + 8 + hlen + dlen > end:
        raise struct.error("record data cut short")
    return hdr, pos + 8 + hlen, dlen


def index_walk(path: Path) -> IndexedBag | None:
    try:
        return _index_walk(path)
    except (struct.error, KeyError, UnicodeDecodeError, ValueError) as err:
        log.debug("%s: no index walk (%s)", path, err)
        return None


def _index_walk(path: Path) -> IndexedBag | None:
    out = BagWalk()
    chunks: list[ChunkRef] = []
    fd = os.open(path, os.O_RDONLY)
    try:
        size = os.fstat(fd).st_size
        if os.pread(fd, len(MAGIC), 0) != MAGIC:
            return None
        hdr, _, _ = _record(fd, len(MAGIC), size)
        if hdr.get("op") != bytes([OP_BAG_HEADER]):
            return None
        index_pos = struct.unpack("<Q", hdr["index_pos"])[0]
        if not index_pos or index_pos >= size:
            return None
        out.index_pos, out.has_bag_header = index_pos, True
        section = os.pread(fd, size - index_pos, index_pos)
        pos, info_counts, duplicates = 0, {}, 0
        chunk_pos: list[int] = []
        listed: set[int] = set()
        while pos < len(section):
            (hlen,) = struct.unpack_from("<I", section, pos)
            hdr = _header(section, pos + 4, pos + 4 + hlen)
            (dlen,) = struct.unpack_from("<I", section, pos + 4 + hlen)
            dpos = pos + 8 + hlen
            if dpos + dlen > len(section):
                return None
            op = hdr["op"][0]
            if op == OP_CONNECTION:
                _connection(out, hdr, section, dpos, dpos + dlen)
            elif op == OP_CHUNK_INFO:
                cpos = struct.unpack("<Q", hdr["chunk_pos"])[0]
                if cpos in listed:  # the same chunk listed twice: read it once
                    duplicates += 1
                    pos = dpos + dlen
                    continue
                chunk_pos.append(cpos)
                listed.add(cpos)
                for q in range(dpos, dpos + dlen, 8):
                    cid, n = struct.unpack_from("<II", section, q)
                    info_counts[cid] = info_counts.get(cid, 0) + n
            else:
                return None
            pos = dpos + dlen
        del section
        for cpos in chunk_pos:
            hdr, dpos, dlen = _record(fd, cpos, index_pos)
            if hdr.get("op") != bytes([OP_CHUNK]):
                return None
            chunk = ChunkRef(dpos, dlen, struct.unpack("<I", hdr["size"])[0],
                             hdr.get("compression", b"none").decode(), cpos)
            pos = dpos + dlen
            while pos < index_pos:
                ihdr, ipos, ilen = _record(fd, pos, index_pos)
                if ihdr.get("op") != bytes([OP_INDEX]):
                    break
                cid = struct.unpack("<I", ihdr["conn"])[0]
                entries = np.frombuffer(os.pread(fd, ilen, ipos), dtype=_ENTRY)
                chunk.index[cid] = entries["off"].copy()  # uint32 offsets in the chunk
                if len(entries):
                    t = entries["sec"].astype(np.int64) * 1_000_000_000 + entries["nsec"]
                    lo, hi = int(t.min()), int(t.max())
                    out.counts[cid] = out.counts.get(cid, 0) + len(t)
                    out.first[cid] = min(out.first.get(cid, lo), lo)
                    out.last[cid] = max(out.last.get(cid, hi), hi)
                pos = ipos + ilen
            chunks.append(chunk)
    finally:
        os.close(fd)
    if {c: n for c, n in out.counts.items() if n} != {c: n for c, n in info_counts.items() if n}:
        return None
    if any(cid not in out.connections for cid in out.counts):
        return None
    out.kept = sum(out.counts.values())
    return IndexedBag(out, chunks, duplicates)


def _u32(buf: np.ndarray, at: np.ndarray) -> np.ndarray:
    return take_rows(buf, at, 4).view("<u4").ravel().astype(np.int64)


def _layout(data: np.ndarray, off: int) -> tuple[int, int, int, int]:
    """Header length and the offsets (within the header) of the op, conn and time values of one record."""
    hlen = int(_u32(data, np.array([off]))[0])
    raw = data[off + 4:off + 4 + hlen].tobytes()
    pos, at = 0, {}
    while pos < hlen:
        (n,) = struct.unpack_from("<I", raw, pos)
        key, _, _ = raw[pos + 4:pos + 4 + n].partition(b"=")
        at[key] = pos + 4 + len(key) + 1
        pos += 4 + n
    return hlen, at[b"op"], at[b"conn"], at[b"time"]


def chunk_batches(path: Path, bag: IndexedBag, wanted: dict[int, str], limit: int = BATCH_BYTES) -> Iterator[Batch]:
    parts: list[np.ndarray] = []
    pieces: dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = {}
    size = 0
    scratch = [np.empty(0, dtype=np.uint8)]  # reused batch after batch (fresh pages cost more than the copy)

    def flush() -> Batch:
        if len(scratch[0]) < size:
            scratch[0] = np.empty(size + (size >> 3), dtype=np.uint8)
        buf = scratch[0][:size]
        at = 0
        for part in parts:
            buf[at:at + len(part)] = part
            at += len(part)
        rows = {}
        for topic, got in pieces.items():
            starts, lengths, stamps = (np.concatenate(c) if len(c) > 1 else c[0] for c in zip(*got, strict=True))
            rows[topic] = Rows(starts, lengths, stamps)
        return Batch(buf, rows)

    fd = os.open(path, os.O_RDONLY)
    try:
        for chunk in bag.chunks:
            mine = {cid: offs for cid, offs in chunk.index.items() if cid in wanted and len(offs)}
            if not mine:
                continue
            raw = os.pread(fd, chunk.length, chunk.data)
            try:
                dec = _decompress(chunk.compression, raw, partial=False)
            except Exception as err:  # noqa: BLE001 - bz2/lz4 raise their own errors
                raise Damaged(f"chunk does not decompress ({err})", chunk.at) from err
            if len(dec) != chunk.size:
                raise Damaged("chunk size mismatch (corrupt bytes)", chunk.at)
            data = np.frombuffer(dec, dtype=np.uint8)
            by_topic: dict[str, list[tuple[int, np.ndarray]]] = {}
            for cid, offs in mine.items():
                by_topic.setdefault(wanted[cid], []).append((cid, offs.astype(np.int64)))
            for topic, got in by_topic.items():
                starts_l, lengths_l, stamps_l = [], [], []
                for cid, offs in got:
                    s, ln, t = _locate(data, offs, cid, chunk.at)
                    starts_l.append(s)
                    lengths_l.append(ln)
                    stamps_l.append(t)
                starts, lengths, stamps = (np.concatenate(x) for x in (starts_l, lengths_l, stamps_l))
                order = np.argsort(starts, kind="stable")
                pieces.setdefault(topic, []).append((starts[order] + size, lengths[order], stamps[order]))
            parts.append(data)
            size += len(data)
            if size >= limit:
                yield flush()
                parts, pieces, size = [], {}, 0
        if parts:
            yield flush()
    finally:
        os.close(fd)


def _locate(data: np.ndarray, offs: np.ndarray, cid: int, at: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    end = len(data)
    if offs.min() < 0 or offs.max() + 8 > end:
        raise Damaged("bag index points outside its chunk", at)
    try:
        hlen, op_at, conn_at, time_at = _layout(data, int(offs[0]))
    except (struct.error, KeyError) as err:
        raise Damaged(f"bag index points at a malformed record ({err})", at) from err
    hl = _u32(data, offs)
    if (hl != hlen).any() or (offs.max() + 8 + hlen > end):
        raise Damaged("message records of one connection differ in header layout", at)
    head = offs + 4
    if (data[head + op_at] != 2).any() or (_u32(data, head + conn_at) != cid).any():
        raise Damaged("bag index points at a record that is not a message of its connection", at)
    dlen = _u32(data, head + hlen)
    if (offs + 8 + hlen + dlen > end).any():
        raise Damaged("message record overruns its chunk", at)
    stamps = _u32(data, head + time_at) * 1_000_000_000 + _u32(data, head + time_at + 4)
    return offs + 8 + hlen, dlen, stamps
