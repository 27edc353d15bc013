"""ROS 1 bags (format 2.0): uncompressed, bz2 or lz4 chunks; indexed or never indexed (index position 0).

Records are walked in file order. An indexed bag lists its topics, counts and time range from its index
(connection, chunk-info and index-data records) without decompressing a chunk; a bag whose index was never
written is scanned. A bag cut short raises :class:`Damaged` in strict mode; in tolerant mode the walk keeps
every complete message before the damage and reports where it stopped (:mod:`pipeline.io.salvage`).

An intact indexed bag is read through :mod:`pipeline.io.rosbag1_index` (each chunk decompressed once, messages
located from the index-data records with numpy); the record walk here serves unindexed and damaged bags.
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
from pipeline.io.errors import Damaged, Restart, oversized_chunk
from pipeline.io.fields import TypeRegistry
from pipeline.io.reader import RawReader
from pipeline.io.rosbag1_records import (
    MAGIC,
    OP_BAG_HEADER,
    OP_CHUNK,
    OP_CHUNK_INFO,
    OP_CONNECTION,
    OP_INDEX,
    OP_MSG,
    U32,
    BagWalk,
    add_connection,
    decompress,
    read_header,
)

if TYPE_CHECKING:
    from pipeline.io.rosbag1_index import IndexedBag

log = logging.getLogger(__name__)


def _time(value: bytes) -> int:
    sec, nsec = struct.unpack("<II", value)
    return sec * 1_000_000_000 + nsec


def walk_records(
    buf: bytes | mmap.mmap, pos: int, end: int, out: BagWalk, on_message: Callable[[int, int, bytes], None] | None,
    wanted: set[int] | None, *, tolerant: bool, origin: int | None = None, stop_at: int = 0,
) -> None:
    """Walk records from ``pos``; ``origin`` is the file offset of a chunk's data (None: top level)."""
    done = 0  # the file's pages before this are given back (release_behind)
    while pos < end:
        if stop_at and origin is None and pos >= stop_at:
            return
        if pos - done >= RELEASE_BYTES and origin is None:
            done = release_behind(buf, done, pos)
        at = pos if origin is None else origin
        if pos + 4 > end:
            raise Damaged("record header length cut short", at)
        (hlen,) = U32.unpack_from(buf, pos)
        if pos + 8 + hlen > end:
            if tolerant and origin is None and hlen < end:
                _partial_chunk(buf, pos, end, out, on_message, wanted)
            raise Damaged("record cut short", at)
        try:
            hdr = read_header(buf, pos + 4, pos + 4 + hlen)
        except struct.error as err:
            raise Damaged(f"malformed record header ({err})", at) from err
        (dlen,) = U32.unpack_from(buf, pos + 4 + hlen)
        dpos = pos + 8 + hlen
        dend = dpos + dlen
        if dend > end:
            if tolerant and origin is None and hdr.get("op") == bytes([OP_CHUNK]):
                _partial_chunk(buf, pos, end, out, on_message, wanted)
            raise Damaged("record data cut short", at)
        op = hdr.get("op", b"\x00")[0]
        if op == OP_MSG:
            cid = U32.unpack(hdr["conn"])[0]
            if cid not in out.connections:
                raise Damaged(f"message on unknown connection {cid}", at)
            t = _time(hdr["time"])
            if out.seen.message(t, buf, pos + 4, dend, at):
                pos = dend
                continue
            out.counts[cid] = out.counts.get(cid, 0) + 1
            out.first.setdefault(cid, t)
            out.last[cid] = t
            out.kept += 1
            if on_message is not None and (wanted is None or cid in wanted):
                on_message(cid, t, bytes(buf[dpos:dend]))
        elif op == OP_CONNECTION:
            add_connection(out, hdr, buf, dpos, dend)
        elif op == OP_CHUNK:
            comp = hdr.get("compression", b"none").decode()
            raw = bytes(buf[dpos:dend])
            if out.seen.chunk((bytes(buf[pos + 4:pos + 4 + hlen]), dlen, crc(raw)), at):
                log.warning("chunk at byte %d repeats an earlier chunk byte for byte; dropped", at)
                pos = dend
                continue
            claimed = U32.unpack(hdr["size"])[0]
            if oversized_chunk(claimed) is not None:
                raise Damaged(str(oversized_chunk(claimed)), at)
            try:
                data = decompress(comp, raw, partial=False, limit=claimed)
            except Damaged:
                raise Damaged(f"unknown chunk compression {comp!r}", at) from None
            except Exception as err:  # noqa: BLE001 - bz2/lz4 raise their own errors
                raise Damaged(f"chunk does not decompress ({err})", at) from err
            if len(data) != claimed:
                raise Damaged("chunk size mismatch (corrupt bytes)", at)
            staged: list[tuple[int, int, bytes]] = []
            walk_records(data, 0, len(data), out, _stager(staged), wanted, tolerant=tolerant, origin=at)
            if on_message is not None:
                for item in staged:
                    on_message(*item)
        elif op == OP_BAG_HEADER:
            out.index_pos = struct.unpack("<Q", hdr["index_pos"])[0]
            out.has_bag_header = True
        elif op not in (OP_INDEX, OP_CHUNK_INFO):
            raise Damaged(f"unknown record op 0x{op:02x}", at)
        pos = dend


def _stager(staged: list[tuple[int, int, bytes]]) -> Callable[[int, int, bytes], None]:
    def stage(cid: int, t: int, payload: bytes) -> None:
        staged.append((cid, t, payload))
    return stage


def _partial_chunk(
    buf: bytes | mmap.mmap, pos: int, end: int, out: BagWalk, on_message: Callable[[int, int, bytes], None] | None,
    wanted: set[int] | None,
) -> None:
    """Keep the complete messages of a chunk that the file's end cut through."""
    try:
        (hlen,) = U32.unpack_from(buf, pos)
        hdr = read_header(buf, pos + 4, pos + 4 + hlen)
        if hdr.get("op") != bytes([OP_CHUNK]):
            return
        data = decompress(hdr.get("compression", b"none").decode(), bytes(buf[pos + 8 + hlen:end]), partial=True)
    except Exception:  # noqa: BLE001 - nothing recoverable
        return
    try:
        walk_records(data, 0, len(data), out, on_message, wanted, tolerant=True, origin=pos)
    except (Damaged, struct.error, KeyError):
        pass


def walk(
    path: Path, on_message: Callable[[int, int, bytes], None] | None = None, wanted: set[int] | None = None, *,
    tolerant: bool = False,
) -> BagWalk:
    out = BagWalk()
    with open(path, "rb") as fh:
        if fh.read(len(MAGIC)) != MAGIC:
            raise IngestError(f"not a ROS 1 bag: expected magic {MAGIC!r}", file=path)
        size = fh.seek(0, 2)
        with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as mm:
            try:
                walk_records(mm, len(MAGIC), size, out, None, None, tolerant=tolerant, stop_at=len(MAGIC) + 1)
                stop_at = out.index_pos
                if stop_at > size:
                    if not tolerant:
                        raise Damaged(f"index position {stop_at} beyond the end of the file (cut short?)", size)
                    stop_at = 0
                out.counts.clear()
                walk_records(mm, len(MAGIC), size, out, on_message, wanted, tolerant=tolerant, stop_at=stop_at)
                if not out.has_bag_header:
                    raise Damaged("no bag header record after the magic", len(MAGIC))
                if out.index_pos > size:
                    raise Damaged("file ends before its index (cut short at a record boundary)", size)
                if out.index_pos:
                    _check_index(mm, out.index_pos, size)
                else:  # the recorder writes the index when it closes the bag: this one was cut short
                    out.damage = Damaged("bag has no index (index_pos 0): the recording was not closed, the file "
                                         "is cut short after its last complete record", size)
            except Damaged as dmg:
                if not tolerant:
                    raise
                out.damage = dmg
            except (struct.error, KeyError, UnicodeDecodeError) as err:
                dmg = Damaged(f"malformed record ({err!r})", -1)
                if not tolerant:
                    raise dmg from err
                out.damage = dmg
    return out


def _check_index(buf: mmap.mmap, pos: int, end: int) -> None:
    """The index section must consist of whole connection / chunk-info records."""
    while pos < end:
        if pos + 4 > end:
            raise Damaged("index record cut short", pos)
        (hlen,) = U32.unpack_from(buf, pos)
        if pos + 8 + hlen > end:
            raise Damaged("index record cut short", pos)
        (dlen,) = U32.unpack_from(buf, pos + 4 + hlen)
        if pos + 8 + hlen + dlen > end:
            raise Damaged("index record cut short", pos)
        pos += 8 + hlen + dlen


def index_counts(path: Path) -> dict[int, int] | None:
    """Message counts per connection from the bag's own index (chunk-info records), None when unindexed."""
    with open(path, "rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as mm:
        probe = BagWalk()
        walk_records(mm, len(MAGIC), len(mm), probe, None, None, tolerant=False, stop_at=len(MAGIC) + 1)
        if not probe.index_pos or probe.index_pos >= len(mm):
            return None
        counts: dict[int, int] = {}
        chunks: set[bytes] = set()
        pos = probe.index_pos
        while pos + 4 <= len(mm):
            (hlen,) = U32.unpack_from(mm, pos)
            hdr = read_header(mm, pos + 4, pos + 4 + hlen)
            (dlen,) = U32.unpack_from(mm, pos + 4 + hlen)
            dpos = pos + 8 + hlen
            if hdr.get("op") == bytes([OP_CHUNK_INFO]) and hdr.get("chunk_pos") not in chunks:
                chunks.add(hdr.get("chunk_pos", b""))
                for q in range(dpos, dpos + dlen, 8):
                    cid, n = struct.unpack_from("<II", mm, q)
                    counts[cid] = counts.get(cid, 0) + n
            pos = dpos + dlen
        return counts


def salvage_info(path: Path, result: BagWalk, dups: int = 0, dup_words: str = "") -> SalvageInfo:
    """The report of a walk that found damage, duplicates, or was asked to salvage."""
    dmg = result.damage
    dup_words = dup_words or result.seen.describe()
    reason = "; ".join(r for r in (dmg.reason if dmg else "", dup_words) if r) or "no damage found"
    if dup_words:
        log.warning("%s: %s", path, dup_words)
    return SalvageInfo(result.kept, None if dmg is None or dmg.at < 0 else dmg.at, reason,
                       duplicates=dups or result.seen.count)


class Rosbag1Reader(RawReader):
    format = "ros1"

    def __init__(self, path: str | Path) -> None:
        super().__init__(path)
        self._walk: BagWalk | None = None
        self._index: IndexedBag | None = None
        self._no_index = False
        self._tolerant = False  # damage found: read by the salvage walk

    def _do_walk(self, on_message: Callable[[int, int, bytes], None] | None = None,
                 wanted: set[int] | None = None) -> BagWalk:
        if not self._tolerant:
            try:
                result = walk(self.path, on_message, wanted)
            except Damaged as dmg:
                if on_message is not None:
                    raise IngestError(f"bag changed while reading: {dmg}", file=self.path) from dmg
                log.warning("%s is damaged (%s); reading it by the salvage path", self.path, dmg)
                self._tolerant = True
            else:
                if result.seen.count or result.damage is not None:  # duplicates, or never indexed (cut)
                    self.salvage = salvage_info(self.path, result)
                return result
        result = walk(self.path, on_message, wanted, tolerant=True)
        self.salvage = salvage_info(self.path, result)
        return result

    def _scan(self) -> None:
        from pipeline.io.rosbag1_index import index_walk

        self._index = None if self._no_index or self._tolerant else index_walk(self.path)
        w = self._index.walk if self._index is not None else self._do_walk()
        if self._index is not None and self._index.duplicates:
            self.salvage = salvage_info(self.path, w, self._index.duplicates,
                                        f"{self._index.duplicates} duplicate chunk-info record(s) dropped (the "
                                        "same chunk listed twice in the index)")
        self._walk = w
        stored = None
        if self._index is not None:
            stored = dict(w.counts)
        elif self.salvage is None:
            try:
                stored = index_counts(self.path)
            except (struct.error, KeyError, Damaged) as err:
                log.warning("%s: bag index unreadable (%s); counting by scanning", self.path, err)
        self._types = TypeRegistry(ros1=True, user=self.user_types)
        infos: dict[str, TopicInfo] = {}
        for cid, conn in sorted(w.connections.items()):
            self._types.add(conn.msgtype, "ros1msg", conn.definition)
            count = (stored or {}).get(cid, w.counts.get(cid, 0)) if stored is not None else w.counts.get(cid, 0)
            first, last = w.first.get(cid), w.last.get(cid)
            prev = infos.get(conn.topic)
            if prev is not None:
                count += prev.count
                first = min(x for x in (first, prev.first_ns) if x is not None) if first or prev.first_ns else None
                last = max(x for x in (last, prev.last_ns) if x is not None) if last or prev.last_ns else None
            msgtype = prev.msgtype if prev else conn.msgtype
            infos[conn.topic] = TopicInfo(conn.topic, msgtype, count, first, last, self._types.has_header(msgtype))
            self._encoding[conn.topic] = "ros1"
        self._infos = infos

    def _batches(self, topics: list[str]) -> Iterator[Batch]:
        assert self._walk is not None
        by_conn = {cid: c.topic for cid, c in self._walk.connections.items() if c.topic in topics}
        if self._index is not None:
            from pipeline.io.rosbag1_index import chunk_batches

            try:
                yield from chunk_batches(self.path, self._index, by_conn)
            except Damaged as dmg:
                log.warning("%s: %s; reading it record by record", self.path, dmg)
                self._no_index = True
                self._infos = self._index = None
                raise Restart from dmg
            return
        def walk_wanted(emit: Callable[[str, int, bytes], None]) -> None:
            self._do_walk(lambda cid, log_ns, payload: emit(by_conn[cid], log_ns, payload), set(by_conn))

        yield from stream_walk(walk_wanted)
