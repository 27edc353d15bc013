"""The fast way through an intact, indexed MCAP file: chunk headers and message-index records only.

:func:`index_walk` reads the top-level records with positioned reads (no memory map, so resident memory stays
flat however large the file): schemas, channels, statistics, and for each chunk its header and the
message-index records that follow it. Counts and first/last log times per channel come from those indexes
without decompressing anything. It returns None whenever the file is not of that shape (messages outside
chunks, a chunk without message indexes, an unknown record, counts that disagree with the statistics), and
the caller walks the file record by record instead (:func:`pipeline.io.mcap_reader.walk`).

:func:`chunk_batches` then decompresses each chunk once, checks its size and CRC, locates the message records
of the wanted channels from the chunk's message indexes (checking each record's opcode, channel and length with
vectorized reads), and hands over batches of ~``BATCH_BYTES`` of decompressed chunks with the payload positions of each
topic in storage (file) order. A damaged chunk raises :class:`Damaged`.
"""

from __future__ import annotations

import logging
import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.io.base import BATCH_BYTES, Batch, Rows, ascending, field_view, scratch_buffer, take_rows
from pipeline.io.dedup import crc
from pipeline.io.errors import Damaged
from pipeline.io.mcap_records import (
    MAGIC,
    OP_CHANNEL,
    OP_CHUNK,
    OP_DATA_END,
    OP_FOOTER,
    OP_MESSAGE_INDEX,
    OP_SCHEMA,
    OP_STATISTICS,
    Channel,
    Walk,
    decompress,
    implausible_chunk,
)

log = logging.getLogger(__name__)

_SKIPPABLE = {0x01, 0x08, 0x09, 0x0A, 0x0C, 0x0D, 0x0E, OP_DATA_END}  # header, chunk index, attachments, metadata...
_ENTRY = np.dtype([("t", "<u8"), ("o", "<u8")])


@dataclass
class ChunkRef:
    body: int                    # file offset of the chunk's records (compressed)
    length: int                  # compressed length
    usize: int
    crc: int
    compression: str
    at: int                      # file offset of the chunk record (for damage reports)
    index: dict[int, np.ndarray] = field(default_factory=dict)  # channel -> message offsets in the chunk
    private: int = -1            # records with a private opcode inside (-1: not read yet; :func:`private_records`)


@dataclass
class IndexedFile:
    walk: Walk
    chunks: list[ChunkRef]


def _str(buf: bytes, pos: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", buf, pos)
    return buf[pos + 4:pos + 4 + n].decode("utf-8"), pos + 4 + n


def index_walk(path: Path) -> IndexedFile | None:
    """Schemas, channels, counts and chunk positions from the top-level records; None if not indexed."""
    try:
        return _index_walk(path)
    except (struct.error, UnicodeDecodeError, ValueError) as err:
        log.debug("%s: no index walk (%s)", path, err)
        return None


class _Window:
    """Positioned reads of a file through one window of ``size`` bytes: the small records between two chunks
    (a chunk's header, short message indexes, the next header) come with one system call, not two per record.
    64 KiB: a larger window copies more than the indexes it serves (docs/benchmarks.md, "Index window")."""

    def __init__(self, fd: int, size: int = 64 << 10) -> None:
        self.fd, self.size = fd, size
        self.lo, self.buf = 0, b""

    def read(self, pos: int, n: int) -> bytes:
        at = pos - self.lo
        if 0 <= at and at + n <= len(self.buf):
            return self.buf[at:at + n]
        if n >= self.size:
            return os.pread(self.fd, n, pos)
        self.lo, self.buf = pos, os.pread(self.fd, self.size, pos)
        return self.buf[:n]


def _index_walk(path: Path) -> IndexedFile | None:
    out = Walk()
    chunks: list[ChunkRef] = []
    heads: set[bytes] = set()  # chunk headers (times, sizes, CRC, compression) seen so far
    fd = os.open(path, os.O_RDONLY)
    win = _Window(fd)
    try:
        size = os.fstat(fd).st_size
        if size < 16 or os.pread(fd, 8, 0) != MAGIC or os.pread(fd, 8, size - 8) != MAGIC:
            return None
        pos = 8
        while True:
            if pos + 9 > size - 8:
                return None
            op, length = struct.unpack("<BQ", win.read(pos, 9))
            body, stop = pos + 9, pos + 9 + length
            if stop > size - 8:
                return None
            if op == OP_CHUNK:
                head = win.read(body, min(length, 4096))
                _s, _e, usize, check = struct.unpack_from("<QQQI", head, 0)
                compression, p = _str(head, 28)
                (rlen,) = struct.unpack_from("<Q", head, p)
                if p + 8 + rlen != length or implausible_chunk(compression, rlen, usize) is not None:
                    return None  # the record walk reports the damage
                if head[:p + 8] in heads:
                    return None  # a chunk written twice: the record walk drops and reports it
                heads.add(head[:p + 8])
                chunks.append(ChunkRef(body + p + 8, rlen, usize, check, compression, pos))
            elif op == OP_MESSAGE_INDEX:
                if not chunks:
                    return None
                raw = win.read(body, length)
                cid, n = struct.unpack_from("<HI", raw, 0)
                if n % 16 or 6 + n > length:
                    return None
                if cid in chunks[-1].index:
                    return None  # two message indexes of one channel for one chunk (a record written twice)
                entries = np.frombuffer(raw, dtype=_ENTRY, count=n // 16, offset=6)
                if len(entries) and int(entries["o"].max()) >= 1 << 32:
                    return None
                chunks[-1].index[cid] = entries["o"].astype(np.uint32)  # offsets in a chunk; 4 bytes a message
                if len(entries):
                    t = entries["t"]
                    lo, hi = int(t.min()), int(t.max())
                    out.counts[cid] = out.counts.get(cid, 0) + len(entries)
                    out.first[cid] = min(out.first.get(cid, lo), lo)
                    out.last[cid] = max(out.last.get(cid, hi), hi)
            elif op in (OP_SCHEMA, OP_CHANNEL, OP_STATISTICS):
                raw = win.read(body, length)
                _record(op, raw, out)
            elif op == OP_FOOTER:
                if stop != size - 8:
                    return None  # a footer before the end (a damaged opcode): the record walk reports it
                break
            elif op not in _SKIPPABLE:
                return None  # messages outside chunks, a record this walk does not know, or a private one
            pos = stop
    finally:
        os.close(fd)
    for chunk in chunks:
        if chunk.usize and not chunk.index:
            return None  # a chunk without message indexes: walk it
    if any(cid not in out.channels for cid in out.counts):
        return None
    if out.stats_counts is not None:
        for cid in out.channels:
            if out.stats_counts.get(cid, 0) != out.counts.get(cid, 0):
                return None
    out.kept = sum(out.counts.values())
    return IndexedFile(out, chunks)


def _record(op: int, raw: bytes, out: Walk) -> None:
    if op == OP_SCHEMA:
        (sid,) = struct.unpack_from("<H", raw, 0)
        name, p = _str(raw, 2)
        enc, p = _str(raw, p)
        (n,) = struct.unpack_from("<I", raw, p)
        out.schemas.setdefault(sid, (name, enc, raw[p + 4:p + 4 + n].decode("utf-8", "replace")))
    elif op == OP_CHANNEL:
        cid, sid = struct.unpack_from("<HH", raw, 0)
        topic, p = _str(raw, 4)
        enc, p = _str(raw, p)
        out.channels.setdefault(cid, Channel(cid, topic, enc, sid))
    else:
        (n,) = struct.unpack_from("<I", raw, 42)
        counts = {}
        for q in range(46, 46 + n, 10):
            cid, cnt = struct.unpack_from("<HQ", raw, q)
            counts[cid] = cnt
        out.stats_counts = counts


def chunk_batches(path: Path, indexed: IndexedFile, wanted: dict[int, str],
                  limit: int = BATCH_BYTES) -> Iterator[Batch]:
    """Batches of decompressed chunks holding the wanted channels (channel -> topic), in file order.

    Uncompressed chunks that follow each other are read with one positioned read and used in place.
    """
    group: list[ChunkRef] = []
    size = 0
    scratch = [np.empty(0, dtype=np.uint8)]  # reused batch after batch (fresh pages cost more than the copy)
    fd = os.open(path, os.O_RDONLY)
    try:
        for chunk in indexed.chunks:
            if not any(cid in wanted and len(offs) for cid, offs in chunk.index.items()):
                continue
            group.append(chunk)
            size += chunk.usize
            if size >= limit:
                yield _batch(fd, group, wanted, scratch)
                group, size = [], 0
        if group:
            yield _batch(fd, group, wanted, scratch)
    finally:
        os.close(fd)


def _batch(fd: int, group: list[ChunkRef], wanted: dict[int, str], scratch: list[np.ndarray]) -> Batch:
    if all(c.compression == "" for c in group):
        lo, hi = group[0].body, group[-1].body + group[-1].length
        buf = scratch_buffer(scratch, hi - lo, phase=lo)
        if os.preadv(fd, [buf], lo) != hi - lo:
            raise Damaged("chunk cut short", group[0].at)
        where = [(c, c.body - lo) for c in group]
        for chunk, at in where:
            if chunk.length != chunk.usize or (chunk.crc and crc(buf[at:at + chunk.length]) != chunk.crc):
                raise Damaged("chunk CRC or size mismatch (corrupt bytes)", chunk.at)
    else:
        buf = scratch_buffer(scratch, sum(c.usize for c in group))
        where, at = [], 0
        for chunk in group:
            buf[at:at + chunk.usize] = np.frombuffer(_chunk_data(fd, chunk), dtype=np.uint8)
            where.append((chunk, at))
            at += chunk.usize
    # Message offsets of each topic over the whole batch: each chunk's index entries moved by where the chunk lies
    # in the buffer, joined in one go (a few numpy calls per topic and batch, not per chunk and channel).
    pieces: dict[str, list[tuple[np.ndarray, int, ChunkRef]]] = {}
    channels: dict[str, set[int]] = {}
    for chunk, at in where:
        for cid, offs in chunk.index.items():
            if cid in wanted and len(offs):
                pieces.setdefault(wanted[cid], []).append((offs, at, chunk))
                channels.setdefault(wanted[cid], set()).add(cid)
    located: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for topic, parts in pieces.items():
        counts = [len(o) for o, _, _ in parts]
        offs = np.concatenate([o for o, _, _ in parts]).astype(np.int64)
        offs += np.repeat(np.array([at for _, at, _ in parts], dtype=np.int64), counts)
        end = np.repeat(np.array([at + chunk.usize for _, at, chunk in parts], dtype=np.int64), counts)
        outside = offs + 31 > end
        if outside.any():
            _, _, bad = parts[int(np.searchsorted(np.cumsum(counts), int(np.argmax(outside)), side="right"))]
            raise Damaged("message index points outside its chunk", bad.at)
        located[topic] = offs, end
    rows = {}
    for topic, (offs, end) in located.items():
        # Storage order: each chunk's records by offset. The chunks lie one after another in the buffer and every
        # offset is inside its own, so one sort of the whole (needed only when a chunk's index is out of order
        # or a topic has several channels) keeps each row with its chunk and its chunk's end.
        if not ascending(offs):
            offs = np.sort(offs, kind="stable")
        rows[topic] = Rows(*_locate(buf, offs, end, channels[topic], where[0][0].at))
    for chunk, at in where:
        if chunk.private < 0:
            chunk.private = _unindexed_records(buf, chunk, at)
    return Batch(buf, rows)


def _unindexed_records(buf: np.ndarray, chunk: ChunkRef, at: int) -> int:
    """How many private records (0x80-0xff, which the spec tells readers to skip) lie in the chunk at ``at`` of
    ``buf`` between the messages its indexes list. The gaps are walked record by record (a few schemas, channels
    and private records; messages are located from the indexes, vectorized); a message no index lists, or any
    other record, is :class:`Damaged` (the record walk then reads the chunk whole)."""
    offs = np.concatenate([np.zeros(0, dtype=np.int64), *(o.astype(np.int64) for o in chunk.index.values())])
    offs = np.sort(offs, kind="stable") + at
    end = at + chunk.usize
    if len(offs) and int(offs[-1]) + 9 > end:
        raise Damaged("message index points outside its chunk", chunk.at)
    length = field_view(take_rows(buf, offs, 9), 1, "<u8")
    if len(length) and int(length.max()) > chunk.usize:
        raise Damaged("message record overruns its chunk", chunk.at)
    stops = offs + 9 + length.astype(np.int64)
    starts = np.append(offs, end)
    if (stops > starts[1:]).any():
        raise Damaged("message records overlap or overrun their chunk", chunk.at)
    gaps = [(at, int(starts[0]))] + [(int(a), int(b)) for a, b in zip(stops[stops < starts[1:]],
                                                                       starts[1:][stops < starts[1:]], strict=True)]
    private = 0
    for pos, stop in gaps:
        while pos < stop:
            if pos + 9 > stop:
                raise Damaged("record header cut short between a chunk's messages", chunk.at)
            op, n = struct.unpack_from("<BQ", buf, pos)
            if pos + 9 + n > stop or op not in (OP_SCHEMA, OP_CHANNEL) and op < 0x80:
                raise Damaged(f"chunk holds a record (opcode 0x{op:02x}) that its message indexes do not list",
                              chunk.at)
            private += op >= 0x80
            pos += 9 + n
    return private


def private_records(indexed: IndexedFile) -> bool:
    """Whether the chunks read so far hold private records; their count and the first one's chunk go into
    ``indexed.walk`` (``private``, ``private_at``), which the salvage report states."""
    found = [c for c in indexed.chunks if c.private > 0]
    indexed.walk.private = sum(c.private for c in found)
    indexed.walk.private_at = found[0].at if found else -1
    return bool(found)


def _chunk_data(fd: int, chunk: ChunkRef) -> bytes:
    raw = os.pread(fd, chunk.length, chunk.body)
    if len(raw) != chunk.length:
        raise Damaged("chunk cut short", chunk.at)
    try:
        data = decompress(chunk.compression, raw, chunk.usize, partial=False)
    except Damaged as dmg:
        raise Damaged(dmg.reason, chunk.at) from None
    except Exception as err:  # noqa: BLE001 - zstd/lz4 raise their own error types
        raise Damaged(f"chunk does not decompress ({err})", chunk.at) from err
    if len(data) != chunk.usize or (chunk.crc and crc(data) != chunk.crc):
        raise Damaged("chunk CRC or size mismatch (corrupt bytes)", chunk.at)
    return data


def _locate(data: np.ndarray, offs: np.ndarray, end: np.ndarray, channels: set[int], at: int) -> tuple[np.ndarray, ...]:
    """Payload starts, lengths and log times of the message records at ``offs``, checked against their chunks."""
    head = take_rows(data, offs, 23)  # opcode, length, channel, sequence, log time
    if (field_view(head, 0, "u1") != 0x05).any():
        raise Damaged("message index points at a record that is not a message", at)
    length = field_view(head, 1, "<u8").astype(np.int64)
    cid = field_view(head, 9, "<u2")
    if len(channels) == 1:
        bad = (cid != next(iter(channels))).any()
    else:
        bad = not np.isin(cid, list(channels)).all()
    if bad:
        raise Damaged("message index points at a message of another channel", at)
    if (length < 22).any() or (offs + 9 + length > end).any():
        raise Damaged("message record overruns its chunk", at)
    stamps = field_view(head, 15, "<u8")
    if len(stamps) and int(stamps.max()) >= 1 << 63:
        raise Damaged("message log time beyond int64 nanoseconds", at)
    return offs + 31, length - 22, stamps.astype(np.int64)
