"""MCAP files: a small record walker over a memory map, in file order, with a tolerant mode for salvage.

The walker never sorts (the mcap library's default ``log_time_order=True`` sorts a whole stream in memory):
messages come in storage order, chunks are decompressed once each, and only the payloads of requested channels
are kept. A file cut short or damaged raises :class:`Damaged` in strict mode; in tolerant mode the walk stops
at the first damaged record and reports where (:mod:`pipeline.io.salvage`).

An intact file whose chunks carry message-index records is not walked record by record at all: the reader lists
its topics from those indexes and reads it through :mod:`pipeline.io.mcap_index`; the walker here serves files
without indexes or chunks, and damaged ones (damage found while reading restarts the read on the salvage path).
"""

from __future__ import annotations

import logging
import mmap
import struct
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline.errors import IngestError
from pipeline.io.base import RELEASE_BYTES, Batch, SalvageInfo, TopicInfo, release_behind, stream_walk
from pipeline.io.dedup import crc
from pipeline.io.errors import Damaged, Restart
from pipeline.io.fields import TypeRegistry, normalize_msgtype
from pipeline.io.mcap_records import (
    MAGIC,
    OP_CHANNEL,
    OP_CHUNK,
    OP_FOOTER,
    OP_MESSAGE,
    OP_SCHEMA,
    OP_STATISTICS,
    Channel,
    Walk,
    decompress,
    implausible_chunk,
)
from pipeline.io.reader import RawReader

if TYPE_CHECKING:
    from pipeline.io.mcap_index import IndexedFile

log = logging.getLogger(__name__)

_U16, _U32, _U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")
_REC = struct.Struct("<BQ")
_MSG = struct.Struct("<HIQQ")
_INT64_LIMIT = 1 << 63


def _string(buf: bytes | mmap.mmap, pos: int) -> tuple[str, int]:
    (n,) = _U32.unpack_from(buf, pos)
    return bytes(buf[pos + 4:pos + 4 + n]).decode("utf-8", "replace"), pos + 4 + n


def walk(
    path: Path, on_message: Callable[[int, int, bytes | None], None] | None = None,
    wanted: set[int] | None = None, *, tolerant: bool = False,
) -> Walk:
    """Walk every record of ``path`` in file order; call ``on_message(channel, log_ns, payload)``.

    ``payload`` is None for channels not in ``wanted`` (so unwanted payloads are never copied).
    """
    out = Walk()
    with open(path, "rb") as fh:
        size = fh.seek(0, 2)
        if size < len(MAGIC) or fh.seek(0) != 0 or fh.read(8) != MAGIC:
            raise IngestError(f"not an MCAP file: expected magic {MAGIC!r}", file=path)
        with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as mm:
            try:
                _walk_records(mm, 8, size, out, on_message, wanted, tolerant=tolerant, origin=0)
                if not tolerant and (size < 16 or mm[size - 8:size] != MAGIC):
                    raise Damaged("no MCAP magic at the end (file cut short?)", size)
            except Damaged as dmg:
                if not tolerant:
                    raise
                out.damage = dmg
            except (struct.error, UnicodeDecodeError, IndexError) as err:
                dmg = Damaged(f"malformed record ({err})", -1)
                if not tolerant:
                    raise dmg from err
                out.damage = dmg
    return out


def _walk_records(
    buf: bytes | mmap.mmap, pos: int, end: int, out: Walk,
    on_message: Callable[[int, int, bytes | None], None] | None, wanted: set[int] | None, *, tolerant: bool,
    origin: int, in_chunk: bool = False,
) -> None:
    done = 0  # the file's pages before this are given back (release_behind)
    while pos < end:
        if pos - done >= RELEASE_BYTES and not in_chunk:
            done = release_behind(buf, done, pos)
        if pos + 9 > end:
            raise Damaged("record header cut short", origin + pos)
        op, length = _REC.unpack_from(buf, pos)
        body = pos + 9
        stop = body + length
        if stop > end:
            if op == OP_CHUNK and tolerant and not in_chunk:
                _partial_chunk(buf, body, end, out, on_message, wanted, origin + pos)
            raise Damaged(f"record (opcode 0x{op:02x}, {length} bytes) cut short", origin + pos)
        if op == OP_MESSAGE:
            ch, _seq, log_ns, _pub = _MSG.unpack_from(buf, body)
            if log_ns >= _INT64_LIMIT:
                raise Damaged(f"message log time {log_ns} beyond int64 nanoseconds", origin + pos)
            if ch not in out.channels:
                raise Damaged(f"message on unknown channel {ch}", origin + pos)
            if out.seen.message(log_ns, buf, body, stop, origin + pos):
                pos = stop
                continue
            out.counts[ch] = out.counts.get(ch, 0) + 1
            out.first.setdefault(ch, log_ns)
            out.last[ch] = log_ns
            out.kept += 1
            if on_message is not None:
                keep = wanted is None or ch in wanted
                on_message(ch, log_ns, bytes(buf[body + 22:stop]) if keep else None)
        elif op == OP_CHUNK:
            _chunk(buf, body, stop, out, on_message, wanted, tolerant=tolerant, origin=origin + pos)
        elif op == OP_SCHEMA:
            (sid,) = _U16.unpack_from(buf, body)
            name, p = _string(buf, body + 2)
            enc, p = _string(buf, p)
            (n,) = _U32.unpack_from(buf, p)
            out.schemas[sid] = (name, enc, bytes(buf[p + 4:p + 4 + n]).decode("utf-8", "replace"))
        elif op == OP_CHANNEL:
            cid, sid = struct.unpack_from("<HH", buf, body)
            topic, p = _string(buf, body + 4)
            enc, p = _string(buf, p)
            out.channels.setdefault(cid, Channel(cid, topic, enc, sid))
        elif op == OP_STATISTICS:
            (n,) = _U32.unpack_from(buf, body + 42)
            counts = {}
            for q in range(body + 46, body + 46 + n, 10):
                cid, cnt = struct.unpack_from("<HQ", buf, q)
                counts[cid] = cnt
            out.stats_counts = counts
        elif op == OP_FOOTER:
            if in_chunk or stop != end - 8:  # a footer is followed by the closing magic and nothing else
                raise Damaged("footer record before the end of the file (a damaged opcode?)", origin + pos)
            return
        elif op == 0 or op > 0x0F and op < 0x80:
            raise Damaged(f"unknown record opcode 0x{op:02x}", origin + pos)
        elif op >= 0x80:  # skipped, and counted: a flipped bit turns a message (0x05) into one (0x85)
            out.private += 1
            out.private_at = origin + pos if out.private_at < 0 else out.private_at
        pos = stop


def _chunk_head(buf: bytes | mmap.mmap, body: int) -> tuple[int, int, str, int, int]:
    _start, _end, usize, check = struct.unpack_from("<QQQI", buf, body)
    compression, p = _string(buf, body + 28)
    (rlen,) = _U64.unpack_from(buf, p)
    return usize, check, compression, p + 8, rlen


def _chunk(
    buf: bytes | mmap.mmap, body: int, stop: int, out: Walk,
    on_message: Callable[[int, int, bytes | None], None] | None, wanted: set[int] | None, *, tolerant: bool,
    origin: int,
) -> None:
    usize, check, compression, rstart, rlen = _chunk_head(buf, body)
    if rstart + rlen != stop:  # the records are the chunk's last field: a damaged length hides messages
        raise Damaged(f"chunk records ({rlen} bytes) do not fill the chunk record", origin)
    why = implausible_chunk(compression, rlen, usize)
    if why is not None:
        raise Damaged(why, origin)
    raw = bytes(buf[rstart:rstart + rlen])
    if out.seen.chunk((bytes(buf[body:rstart]), rlen, crc(raw)), origin):
        log.warning("chunk at byte %d repeats an earlier chunk byte for byte; dropped", origin)
        return
    try:
        data = decompress(compression, raw, usize, partial=False)
    except Damaged as dmg:
        raise Damaged(dmg.reason, origin) from None
    except Exception as err:  # noqa: BLE001 - zstd/lz4 raise their own error types
        raise Damaged(f"chunk does not decompress ({err})", origin) from err
    if len(data) != usize or (check and crc(data) != check):
        raise Damaged("chunk CRC or size mismatch (corrupt bytes)", origin)
    # Validate the whole chunk before delivering any of it: a corrupt chunk is dropped as a unit.
    if on_message is not None:
        staged: list[tuple[int, int, bytes | None]] = []
        _walk_records(data, 0, len(data), out, lambda c, t, p: staged.append((c, t, p)), wanted,
                      tolerant=tolerant, origin=origin, in_chunk=True)
        for item in staged:
            on_message(*item)
    else:
        _walk_records(data, 0, len(data), out, None, wanted, tolerant=tolerant, origin=origin, in_chunk=True)


def _partial_chunk(
    buf: bytes | mmap.mmap, body: int, end: int, out: Walk,
    on_message: Callable[[int, int, bytes | None], None] | None, wanted: set[int] | None, origin: int,
) -> None:
    """Keep the complete messages of a chunk that the file's end cut through."""
    try:
        usize, _crc, compression, rstart, rlen = _chunk_head(buf, body)
        if implausible_chunk(compression, rlen, usize) is not None:
            return
        data = decompress(compression, bytes(buf[rstart:min(end, rstart + rlen)]), usize, partial=True)
    except Exception:  # noqa: BLE001 - nothing recoverable in this chunk
        return
    try:
        _walk_records(data, 0, len(data), out, on_message, wanted, tolerant=True, origin=origin, in_chunk=True)
    except (Damaged, struct.error):
        pass


def salvage_info(path: Path, result: Walk) -> SalvageInfo:
    """The report of a walk that found damage, duplicates, or was asked to salvage."""
    dmg, dups = result.damage, result.seen.describe()
    if result.private:
        dups = "; ".join(r for r in (dups, f"{result.private} record(s) with a private opcode (0x80-0xff) skipped, "
                                     f"the first at byte {result.private_at}: no ROS writer makes them (a damaged "
                                     "opcode?)") if r)
    reason = "; ".join(r for r in (dmg.reason if dmg else "", dups) if r) or "no damage found"
    if dups:
        log.warning("%s: %s", path, dups)
    return SalvageInfo(kept=result.kept, stopped_at_byte=None if dmg is None or dmg.at < 0 else dmg.at,
                       reason=reason, duplicates=result.seen.count)


class McapReader(RawReader):
    """A plain MCAP file (ROS 2 CDR or ROS 1 encoded messages)."""

    format = "mcap"

    def __init__(self, path: str | Path) -> None:
        super().__init__(path)
        self._walk: Walk | None = None
        self._tolerant = False
        self._index: IndexedFile | None = None

    def _do_walk(self, on_message: Callable[[int, int, bytes | None], None] | None = None,
                 wanted: set[int] | None = None) -> Walk:
        if not self._tolerant:
            try:
                result = walk(self.path, on_message, wanted)
            except Damaged as dmg:
                log.warning("%s is damaged (%s); reading it by the salvage path", self.path, dmg)
                self._tolerant = True
                if on_message is not None:
                    raise
            else:
                if result.seen.count or result.private:
                    self.salvage = salvage_info(self.path, result)
                return result
        result = walk(self.path, on_message, wanted, tolerant=True)
        self.salvage = salvage_info(self.path, result)
        return result

    def _scan(self) -> None:
        from pipeline.io.mcap_index import index_walk

        self._index = None if self._tolerant else index_walk(self.path)
        w = self._index.walk if self._index is not None else self._do_walk()
        self._walk = w
        self._types = TypeRegistry(ros1=all(c.encoding == "ros1" for c in w.channels.values()) and
                                   bool(w.channels), user=self.user_types)
        infos: dict[str, TopicInfo] = {}
        for cid, ch in sorted(w.channels.items()):
            name, enc, text = w.schemas.get(ch.schema_id, ("", "", ""))
            msgtype = normalize_msgtype(name) if name else ""
            if name:
                self._types.add(msgtype, enc, text)
            count = w.counts.get(cid, 0)
            if w.stats_counts is not None and self.salvage is None:
                count = w.stats_counts.get(cid, count)
            prev = infos.get(ch.topic)
            first, last = w.first.get(cid), w.last.get(cid)
            if prev is not None:
                count += prev.count
                first = min(x for x in (first, prev.first_ns) if x is not None) if (first or prev.first_ns) else None
                last = max(x for x in (last, prev.last_ns) if x is not None) if (last or prev.last_ns) else None
            infos[ch.topic] = TopicInfo(ch.topic, prev.msgtype if prev else msgtype, count, first, last,
                                        self._types.has_header(prev.msgtype if prev else msgtype))
            self._encoding.setdefault(ch.topic, ch.encoding)
        self._infos = infos

    def _batches(self, topics: list[str]) -> Iterator[Batch]:
        assert self._walk is not None
        by_channel = {cid: ch.topic for cid, ch in self._walk.channels.items() if ch.topic in topics}
        if self._index is not None:
            from pipeline.io.mcap_index import chunk_batches, private_records

            try:
                yield from chunk_batches(self.path, self._index, by_channel)
            except Damaged as dmg:
                log.warning("%s is damaged (%s); reading it by the salvage path", self.path, dmg)
                self._tolerant = True
                self._infos = self._index = None
                self._encoding = {}
                raise Restart from dmg
            if private_records(self._index):  # skipped, as the spec says, and reported as the record walk does
                self.salvage = salvage_info(self.path, self._index.walk)
            return
        def walk_wanted(emit: Callable[[str, int, bytes], None]) -> None:
            def on_message(cid: int, log_ns: int, payload: bytes | None) -> None:
                if payload is not None:
                    emit(by_channel[cid], log_ns, payload)

            self._do_walk(on_message, set(by_channel))

        yield from stream_walk(walk_wanted)
