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

from pipeline.io.base import BATCH_BYTES, Batch, Rows, ascending, field_view, take_rows
from pipeline.io.errors import Damaged, oversized_chunk
from pipeline.io.rosbag1_records import (
    MAGIC,
    OP_BAG_HEADER,
    OP_CHUNK,
    OP_CHUNK_INFO,
    OP_CONNECTION,
    OP_INDEX,
    BagWalk,
    add_connection,
    decompress,
    read_header,
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
    hdr = read_header(raw, 0, hlen)
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
            hdr = read_header(section, pos + 4, pos + 4 + hlen)
            (dlen,) = struct.unpack_from("<I", section, pos + 4 + hlen)
            dpos = pos + 8 + hlen
            if dpos + dlen > len(section):
                return None
            op = hdr["op"][0]
            if op == OP_CONNECTION:
                add_connection(out, hdr, section, dpos, dpos + dlen)
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
    """Batches of ~``limit`` bytes of (decompressed) chunks holding wanted messages, in file order. An
    uncompressed chunk is read straight into the batch's buffer (reused batch after batch); the messages of a batch
    are located at once, per connection and header layout (:func:`_located`), not chunk by chunk."""
    scratch = [np.empty(0, dtype=np.uint8)]
    size = 0
    groups: dict[tuple[int, tuple[int, int, int, int]], list[tuple[np.ndarray, int, int]]] = {}
    fd = os.open(path, os.O_RDONLY)
    try:
        for chunk in bag.chunks:
            mine = {cid: offs for cid, offs in chunk.index.items() if cid in wanted and len(offs)}
            if not mine:
                continue
            # The claimed size is checked (cap, and an uncompressed chunk's own length) or met by inflating,
            # bounded by it, before the batch buffer grows for it.
            too_large = oversized_chunk(chunk.size)
            if too_large is not None:
                raise Damaged(too_large, chunk.at)
            if chunk.compression == "none" and chunk.length == chunk.size:
                data = _room(scratch, size, chunk.size, limit)[size:size + chunk.size]
                if os.preadv(fd, [data], chunk.data) != chunk.size:
                    raise Damaged("chunk size mismatch (corrupt bytes)", chunk.at)
            else:
                raw = os.pread(fd, chunk.length, chunk.data)
                try:
                    dec = decompress(chunk.compression, raw, partial=False, limit=chunk.size)
                except Exception as err:  # noqa: BLE001 - bz2/lz4 raise their own errors
                    raise Damaged(f"chunk does not decompress ({err})", chunk.at) from err
                if len(dec) != chunk.size:
                    raise Damaged("chunk size mismatch (corrupt bytes)", chunk.at)
                data = _room(scratch, size, chunk.size, limit)[size:size + chunk.size]
                data[:] = np.frombuffer(dec, dtype=np.uint8)
            for cid, offs in mine.items():
                offs = offs.astype(np.int64)
                if offs.min() < 0 or offs.max() + 8 > chunk.size:
                    raise Damaged("bag index points outside its chunk", chunk.at)
                try:
                    layout = _layout(data, int(offs[0]))
                except (struct.error, KeyError) as err:
                    raise Damaged(f"bag index points at a malformed record ({err})", chunk.at) from err
                groups.setdefault((cid, layout), []).append((offs + size, size + chunk.size, chunk.at))
            size += chunk.size
            if size >= limit:
                yield _located(scratch[0][:size], groups, wanted)
                size, groups = 0, {}
        if groups:
            yield _located(scratch[0][:size], groups, wanted)
    finally:
        os.close(fd)


def _room(scratch: list[np.ndarray], size: int, more: int, limit: int) -> np.ndarray:
    """The reused batch buffer, grown (keeping its first ``size`` bytes) to hold ``more`` bytes after them: at once
    to a whole batch (``limit`` and a chunk), so that filling the first batch does not copy it again and again."""
    need = size + more
    if len(scratch[0]) < need:
        grown = np.empty(max(need, limit + more) + (need >> 3), dtype=np.uint8)
        grown[:size] = scratch[0][:size]
        scratch[0] = grown
    return scratch[0]


def _located(buf: np.ndarray, groups: dict[tuple[int, tuple[int, int, int, int]], list[tuple[np.ndarray, int, int]]],
             wanted: dict[int, str]) -> Batch:
    """The batch's wanted messages from the index offsets of each (connection, header layout): every record's
    header is checked against the layout (same length, ``op=2``, its connection) and must end in its chunk."""
    pieces: dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = {}
    for (cid, (hlen, op_at, conn_at, time_at)), parts in groups.items():
        offs = np.concatenate([p[0] for p in parts]) if len(parts) > 1 else parts[0][0]
        ends = np.repeat([p[1] for p in parts], [len(p[0]) for p in parts])
        ats = np.repeat([p[2] for p in parts], [len(p[0]) for p in parts])

        def damaged(bad: np.ndarray, why: str, ats: np.ndarray = ats) -> Damaged:
            return Damaged(why, int(ats[int(np.argmax(bad))]))

        bad = offs + 8 + hlen > ends
        if bad.any():
            raise damaged(bad, "message records of one connection differ in header layout")
        # Each record's header length, header and data length with one gather, read as strided fields.
        rec = take_rows(buf, offs, 8 + hlen)
        bad = field_view(rec, 0, "<u4") != hlen
        if bad.any():
            raise damaged(bad, "message records of one connection differ in header layout")
        bad = (field_view(rec, 4 + op_at, "u1") != 2) | (field_view(rec, 4 + conn_at, "<u4") != cid)
        if bad.any():
            raise damaged(bad, "bag index points at a record that is not a message of its connection")
        dlen = field_view(rec, 4 + hlen, "<u4").astype(np.int64)
        bad = offs + 8 + hlen + dlen > ends
        if bad.any():
            raise damaged(bad, "message record overruns its chunk")
        stamps = (field_view(rec, 4 + time_at, "<u4").astype(np.int64) * 1_000_000_000
                  + field_view(rec, 4 + time_at + 4, "<u4"))
        pieces.setdefault(wanted[cid], []).append((offs + 8 + hlen, dlen, stamps))
    rows = {}
    for topic, got in pieces.items():
        starts, lengths, stamps = (np.concatenate(c) if len(c) > 1 else c[0] for c in zip(*got, strict=True))
        # File order across the topic's connections and header layouts; a topic of one connection whose chunks'
        # indexes list its records in file order (what a recorder writes) already has it, and is not sorted.
        if not ascending(starts):
            order = np.argsort(starts, kind="stable")
            starts, lengths, stamps = starts[order], lengths[order], stamps[order]
        rows[topic] = Rows(starts, lengths, stamps)
    return Batch(buf, rows)
