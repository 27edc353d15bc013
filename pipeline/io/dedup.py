"""Records written twice: a chunk anywhere in a file, a message among the recent ones of its channel.

A damaged or carelessly concatenated log can hold the same record twice (a chunk copied by a resumed upload, a
message record repeated by a retrying writer); read naively, every message in it counts twice and nothing says
so. The record walks of MCAP files and ROS 1 bags ask :class:`Seen` about each chunk and message
record: a chunk whose bytes equal an earlier chunk's, or a message record equal byte for byte (channel, times,
sequence, payload) to one of the last :data:`WINDOW` message records before it (in the file, or in the same
chunk), is dropped, counted and reported with the salvage report (:class:`pipeline.io.base.SalvageInfo`,
``duplicates``).

A chunk is remembered by its header and a CRC-32 of its bytes, a recent message by its log time and position,
so memory stays at a few dozen bytes per chunk and per recent message however long the file.
"""

from __future__ import annotations

import mmap
from collections import deque
from collections.abc import Hashable
from typing import Any

try:  # ISA-L's CRC-32 (the optional package isal): the same values as zlib's, several times faster
    from isal.isal_zlib import crc32 as _crc32
except ImportError:
    from zlib import crc32 as _crc32

Buffer = bytes | mmap.mmap

WINDOW = 256  # recent message records compared with a new one that does not advance the log time


def crc(data: bytes | memoryview | Any) -> int:
    """CRC-32 (zlib's polynomial, as MCAP's chunk CRCs) of a bytes-like object: the check of every MCAP chunk, a
    visible share of an ingest through zlib, much less through ISA-L (docs/benchmarks.md, "Chunk CRCs")."""
    return int(_crc32(data))


class Seen:
    """Chunks and recent messages of one walk over one file."""

    def __init__(self, window: int = WINDOW) -> None:
        self.window = window
        self.count = 0                     # records dropped as duplicates
        self.first_at: int | None = None   # file offset of the first of them
        self._chunks: set[Hashable] = set()
        self._recent: deque[tuple[int, int]] = deque(maxlen=window)  # (start, stop) of the last message records
        self._latest = -1 << 64            # the latest log time so far
        self._buf: Buffer | None = None    # the buffer the recent records lie in

    def chunk(self, key: Hashable, at: int) -> bool:
        """True when a chunk with this key was seen before in the walk (it is then counted as a duplicate)."""
        if key in self._chunks:
            self._dropped(at)
            return True
        self._chunks.add(key)
        return False

    def message(self, log_ns: int, buf: Buffer, start: int, stop: int, at: int) -> bool:
        """True when the message record ``buf[start:stop]`` (channel, times and payload) equals one of the last
        ``window`` message records of the same buffer (the file, or one chunk's records), then counted.

        Only a record whose log time does not pass the latest so far is compared with earlier ones (a copy
        repeats its original's time), so a recording in time order pays a comparison and an append a message.
        """
        if buf is not self._buf:  # another buffer (a chunk's records, or the file again): a fresh window
            self._buf = buf
            self._recent.clear()
            self._latest = -1 << 64
        if log_ns <= self._latest:
            record = buf[start:stop]
            size = stop - start
            for s, e in self._recent:
                if e - s == size and buf[s:e] == record:
                    self._dropped(at)
                    return True
        else:
            self._latest = log_ns
        self._recent.append((start, stop))
        return False

    def _dropped(self, at: int) -> None:
        self.count += 1
        if self.first_at is None or 0 <= at < self.first_at:
            self.first_at = at

    def describe(self) -> str:
        """The report's words for what was dropped ('' when nothing was)."""
        if not self.count:
            return ""
        where = f", the first at byte {self.first_at}" if self.first_at is not None and self.first_at >= 0 else ""
        return f"{self.count} duplicate record(s) dropped (the same chunk or message twice{where})"
