"""ROS 1 bag (format 2.0) record vocabulary, shared by the record walker (:mod:`.rosbag1`) and the index reader
(:mod:`.rosbag1_index`): the magic, the record ops, a record header's fields, connections, what a walk finds
(:class:`BagWalk`), and a chunk's decompression."""

from __future__ import annotations

import bz2
import mmap
import struct
from dataclasses import dataclass, field

from pipeline.io.dedup import Seen
from pipeline.io.errors import MAX_CHUNK_BYTES, Damaged
from pipeline.io.fields import normalize_msgtype

MAGIC = b"#ROSBAG V2.0\n"
OP_MSG, OP_BAG_HEADER, OP_INDEX, OP_CHUNK, OP_CHUNK_INFO, OP_CONNECTION = 0x02, 0x03, 0x04, 0x05, 0x06, 0x07
U32 = struct.Struct("<I")


@dataclass
class Connection:
    id: int
    topic: str
    msgtype: str
    definition: str


@dataclass
class BagWalk:
    connections: dict[int, Connection] = field(default_factory=dict)
    counts: dict[int, int] = field(default_factory=dict)
    first: dict[int, int] = field(default_factory=dict)
    last: dict[int, int] = field(default_factory=dict)
    index_pos: int = 0
    has_bag_header: bool = False
    damage: Damaged | None = None
    kept: int = 0
    seen: Seen = field(default_factory=Seen)  # chunks and messages met twice, dropped


def read_header(buf: bytes | mmap.mmap, pos: int, end: int) -> dict[str, bytes]:
    """The ``name=value`` fields of the record header in ``buf[pos:end]``."""
    fields: dict[str, bytes] = {}
    while pos < end:
        (n,) = U32.unpack_from(buf, pos)
        if pos + 4 + n > end:
            raise struct.error("header field overruns its header")
        raw = bytes(buf[pos + 4:pos + 4 + n])
        key, sep, value = raw.partition(b"=")
        if not sep:
            raise struct.error("header field without '='")
        fields[key.decode("ascii", "replace")] = value
        pos += 4 + n
    return fields


def decompress(compression: str, data: bytes, *, partial: bool, limit: int = MAX_CHUNK_BYTES) -> bytes:
    """A chunk's records, inflated (``partial``: as much as a cut stream gives, for salvage); never more than
    ``limit`` + 1 bytes (the caller compares the length with the chunk's claimed size)."""
    if compression == "none":
        return data
    if compression == "bz2":
        inflater = bz2.BZ2Decompressor()
        out = inflater.decompress(data, max_length=limit + 1)
        if not partial and len(out) <= limit and not inflater.eof:
            raise ValueError("compressed data ended before the end-of-stream marker")
        return out
    if compression == "lz4":
        import lz4.frame

        lz = lz4.frame.LZ4FrameDecompressor()
        # the output buffer is allocated at max_length: bounded by what LZ4 can inflate to (~255x) as well
        out = lz.decompress(data, max_length=min(limit, 256 * len(data) + 1024) + 1)
        if not partial and len(out) <= limit and not lz.eof:
            raise ValueError("compressed data ended before the end-of-frame marker")
        return out
    raise Damaged(f"unknown chunk compression {compression!r}", 0)


def add_connection(out: BagWalk, hdr: dict[str, bytes], buf: bytes | mmap.mmap, dpos: int, dend: int) -> None:
    """Record the connection record with header ``hdr`` and data ``buf[dpos:dend]`` (the first of an id wins)."""
    cid = U32.unpack(hdr["conn"])[0]
    if cid in out.connections:
        return
    data = read_header(buf, dpos, dend)
    out.connections[cid] = Connection(
        cid, hdr["topic"].decode(), normalize_msgtype(data.get("type", b"").decode()),
        data.get("message_definition", b"").decode("utf-8", "replace"))
